"""``SiteParams`` (traced arrays of one site) and ``TeamsConfig`` (static shapes and options).

Shapes: ``M`` teams (one excavator = coordinator each, one loading site each), ``N`` trucks
(cooperators), ``L`` pre-drawn loads per excavator, ``T`` time steps. A batch of sites is the same
pytree with a leading batch axis on every array (see ``jaxplan.teams.sim.run_sites``).
"""
from __future__ import annotations

import dataclasses
from typing import Any

import jax
import numpy as np

__all__ = ["SiteParams", "TeamsConfig", "STRATEGIES", "validate_config", "validate_site"]

# performance: the paper's coordinators (Eqs. 1-4, error correction, blackboard);
# even / largest: fixed shares (even split; all trucks to the largest unfinished site), re-dealt only
# when a site is finished; oracle: Eqs. 1 and 3 with the true load mean, loading time and the worst
# velocity still to come on each route (it knows the future velocities, not the failures).
STRATEGIES = ("performance", "even", "largest", "oracle")

_TRACED = ("mass", "dist", "v_true", "v_after", "v_change_t", "tld_true", "tld_after",
           "tld_change_t", "tdp_true", "loads", "fail_truck", "fail_t", "deadline", "w_prior",
           "tld_prior", "v_prior", "tdp_prior", "join_dist", "tol_perf", "tol_param", "dt")
_STATIC = ("n_trucks", "n_steps", "strategy", "record")


@dataclasses.dataclass(frozen=True)
class SiteParams:
    """One earthmoving site: its true conditions, the scheduled changes, and the coordinators' priors.

    Truth (what the simulation does; the coordinators do not see it):
      mass: f[M] soil at each loading site at t = 0 [kg].
      dist: f[M] distance D between loading site i and its dumping site [m].
      v_true, v_after: f[M] actual truck velocity on route i before / from ``v_change_t`` [m/s].
      v_change_t: f[] time of the velocity change [s] (``inf``: none).
      tld_true, tld_after: f[M] actual loading time of excavator i before / from ``tld_change_t`` [s].
      tld_change_t: f[] time of the loading-time change [s] (``inf``: none).
      tdp_true: f[M] actual dumping time on route i [s].
      loads: f[M, L] the masses excavator i puts into its 1st, 2nd, ... truck [kg] (pre-drawn noise,
        so that the JAX simulation and the reference see the same draws; the last load is capped by
        what is left; past L the last column is reused).
      fail_truck: i32[] the truck that breaks down (-1: none); fail_t: f[] when [s].
    Task and coordinators' model (Table III):
      deadline: f[] T_DL [s].
      w_prior, tld_prior, v_prior, tdp_prior: f[M] the model's initial w, t_ld, v, t_dp (specs).
      join_dist: f[] distance a recruited truck drives to its new loading site [m].
      tol_perf: f[] relative change of real performance that triggers error correction (0.1).
      tol_param: f[] relative error beyond which a model parameter is overwritten (0.1).
      dt: f[] time step [s].
    """

    mass: Any
    dist: Any
    v_true: Any
    v_after: Any
    v_change_t: Any
    tld_true: Any
    tld_after: Any
    tld_change_t: Any
    tdp_true: Any
    loads: Any
    fail_truck: Any
    fail_t: Any
    deadline: Any
    w_prior: Any
    tld_prior: Any
    v_prior: Any
    tdp_prior: Any
    join_dist: Any
    tol_perf: Any = 0.1
    tol_param: Any = 0.1
    dt: Any = 1.0

    def replace(self, **changes) -> SiteParams:
        return dataclasses.replace(self, **changes)

    @property
    def n_teams(self) -> int:
        return int(np.shape(self.mass)[-1])


@dataclasses.dataclass(frozen=True)
class TeamsConfig:
    """Static options (part of the jit cache key; changing them recompiles).

    n_trucks: N, trucks on the site (all start idle in the waiting area).
    n_steps: T, simulated steps of ``dt`` seconds (the horizon; may run past the deadline to see when
      late sites finish).
    strategy: one of ``STRATEGIES``.
    record: also return the per-step ``Trace`` (for plots and the reference comparison).
    """

    n_trucks: int = 10
    n_steps: int = 1200
    strategy: str = "performance"
    record: bool = False

    def replace(self, **changes) -> TeamsConfig:
        return dataclasses.replace(self, **changes)


jax.tree_util.register_dataclass(SiteParams, data_fields=list(_TRACED), meta_fields=[])


def validate_config(cfg: TeamsConfig) -> None:
    """Raise ``ValueError`` naming the field of a bad static option."""
    if not isinstance(cfg, TeamsConfig):
        raise ValueError(f"cfg: expected a TeamsConfig, got {type(cfg).__name__}.")
    for name in ("n_trucks", "n_steps"):
        value = getattr(cfg, name)
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 1:
            raise ValueError(f"TeamsConfig.{name}: must be an int >= 1; got {value!r}.")
    if cfg.strategy not in STRATEGIES:
        raise ValueError(f"TeamsConfig.strategy: must be one of {', '.join(STRATEGIES)}; "
                         f"got {cfg.strategy!r}.")


def validate_site(params: SiteParams, cfg: TeamsConfig) -> None:
    """Raise ``ValueError`` naming the field for concrete parameters that are out of range.

    Checks one site or a batch (leading axes); skipped for traced values.
    """
    validate_config(cfg)
    if not isinstance(params, SiteParams):
        raise ValueError(f"params: expected a SiteParams, got {type(params).__name__}. "
                         "Build one with jaxplan.teams.paper_scenario() or SiteParams(...).")
    if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(params)):
        return
    m = params.n_teams
    positive = ("dist", "v_true", "v_after", "tld_true", "tld_after", "tdp_true", "w_prior",
                "tld_prior", "v_prior", "tdp_prior", "deadline", "dt")
    non_negative = ("mass", "join_dist", "tol_perf", "tol_param")
    for name in positive + non_negative:
        arr = np.asarray(getattr(params, name), dtype=np.float64)
        bad = ~np.isfinite(arr) | ((arr <= 0) if name in positive else (arr < 0))
        if np.any(bad):
            kind = "positive" if name in positive else "non-negative"
            raise ValueError(f"SiteParams.{name}: must be finite and {kind}; got {arr[bad].ravel()[:3]}.")
    for name in ("mass", "dist", "v_true", "v_after", "tld_true", "tld_after", "tdp_true",
                 "w_prior", "tld_prior", "v_prior", "tdp_prior"):
        if np.shape(getattr(params, name))[-1:] != (m,):
            raise ValueError(f"SiteParams.{name}: needs one entry per team (last axis {m}, like "
                             f"mass); got shape {np.shape(getattr(params, name))}.")
    loads = np.asarray(params.loads, dtype=np.float64)
    if loads.ndim < 2 or loads.shape[-2] != m or loads.shape[-1] < 1:
        raise ValueError(f"SiteParams.loads: must have shape [..., {m}, L] with L >= 1; "
                         f"got {loads.shape}.")
    if not np.all(np.isfinite(loads)) or np.any(loads <= 0):
        raise ValueError("SiteParams.loads: every pre-drawn load must be finite and positive [kg].")
    fail = np.asarray(params.fail_truck)
    if np.any((fail < -1) | (fail >= cfg.n_trucks)):
        raise ValueError(f"SiteParams.fail_truck: must be -1 (none) or a truck index below "
                         f"n_trucks={cfg.n_trucks}; got {fail.ravel()[:3]}.")
    for name in ("v_change_t", "tld_change_t", "fail_t"):
        if np.any(np.isnan(np.asarray(getattr(params, name), dtype=np.float64))):
            raise ValueError(f"SiteParams.{name}: must be a time in s (inf for never); got nan.")
