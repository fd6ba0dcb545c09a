"""``FabricParams``: the fabric's parameters as one pytree.

Traced fields (arrays you may ``vmap`` over and, in the soft kernels, differentiate) are the angle,
thresholds and weights. Static fields change the graph or array shapes and are part of the jit cache
key: changing them recompiles.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import numpy as np

TRACED_FIELDS = ("theta_tol_deg", "tau_h", "anchor_lambda", "slack_tau", "temperature")
STATIC_FIELDS = ("monotone", "k", "max_hops", "highway_relative", "highway_smoothing", "highway_nms",
           "solver", "soft_rounds")

K_MAX = 24
"""The deepest continuation table ``FabricParams.k`` may ask for. The K-best merge
(``jaxplan.transport.kbest``) is unrolled into the compiled program, so compiling it takes memory and
time growing about as K^5 (``jaxplan.transport.fabric.estimate_build_bytes``, measured on the CPU
backend): about 0.3 GB and 15 s at K = 8, 7 GB and 140 s at K = 16, 50 GB at K = 24, 200 GB at 32.
Routes are chosen among the entries within ``slack_tau`` of the best, so a few entries suffice."""


def resolve_solver(solver: str, monotone: bool) -> str:
    """The DP solver a build runs: ``solver`` unless it is "auto", which is "policy" with the monotone
    rule and "wavefront" without."""
    if solver != "auto":
        return solver
    return "policy" if monotone else "wavefront"


@dataclasses.dataclass(frozen=True)
class FabricParams:
    """Parameters of ``build_fabric``.

    Traced:
      theta_tol_deg: f32[], cone half-angle of Eq. 1 in degrees, in (0, 180).
      tau_h: f32[], highway threshold of Eq. 11; a fraction of ``max H`` when ``highway_relative``.
      anchor_lambda: f32[], distance weight of Eq. 12, heat units per world unit, >= 0.
      slack_tau: f32[], slack of the candidate set (Section 3.2), object units, >= 0.
      temperature: None (default) = the exact hard kernels; a number > 0 = the soft (differentiable)
        kernels of ``jaxplan.transport.soft`` and ``build_fabric`` returns a ``SoftFabric``. A concrete 0 is the
        same as None. None is an empty pytree node, so the hard path's jit cache key and ``vmap``
        batches are unchanged; any float (or tracer) shares one soft trace (no recompile per value).
    Static:
      monotone: the strict monotone rule (Eq. 2, strict); off gives the hop-capped walk DP.
      k: continuation-table depth K, an int in [1, ``K_MAX``] (24; its compile cost grows about as K^5).
      max_hops: DP round cap; None = H*W + 1 with the monotone rule, 2*(H+W) without.
      highway_relative, highway_smoothing, highway_nms: highway extraction options (Eq. 11).
      solver: "auto" (policy iteration with the monotone rule, wavefront without), "policy" or
        "wavefront"; all give the same fabric (see ``fabric.continuation_dp``).
      soft_rounds: rounds of the soft Bellman recursion (soft kernels only); None = 2 * (H + W).
    """

    theta_tol_deg: Any = 60.0
    tau_h: Any = 0.5
    anchor_lambda: Any = 1.0
    slack_tau: Any = 0.0
    monotone: bool = True
    k: int = 4
    max_hops: int | None = None
    highway_relative: bool = True
    highway_smoothing: bool = False
    highway_nms: bool = False
    solver: str = "auto"
    temperature: Any = None
    soft_rounds: int | None = None

    @property
    def is_soft(self) -> bool:
        """Whether ``build_fabric`` runs the soft kernels: a temperature is set and is not a concrete 0."""
        t = self.temperature
        if t is None:
            return False
        if _concrete(t) and np.ndim(t) == 0 and float(t) == 0.0:
            return False
        return True

    def resolved_soft_rounds(self, shape) -> int:
        if self.soft_rounds is not None:
            return int(self.soft_rounds)
        h, w = shape
        return 2 * (h + w)

    def replace(self, **changes) -> FabricParams:
        return dataclasses.replace(self, **changes)

    def resolved_solver(self) -> str:
        """The solver the build runs (``resolve_solver``)."""
        return resolve_solver(self.solver, self.monotone)

    def with_canonical_solver(self) -> FabricParams:
        """These parameters with ``solver`` spelled "auto" where it names the solver "auto" runs, so that
        both spellings share one jit cache key (one compiled program); any other solver is kept."""
        auto = self.replace(solver="auto")
        return auto if auto.resolved_solver() == self.solver else self

    def resolved_max_hops(self, shape) -> int:
        if self.max_hops is not None:
            return int(self.max_hops)
        h, w = shape
        # +1: the loop needs one more round than the longest path to see the fixed point
        return h * w + 1 if self.monotone else 2 * (h + w)


jax.tree_util.register_dataclass(FabricParams, data_fields=list(TRACED_FIELDS), meta_fields=list(STATIC_FIELDS))


def _concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def _check_range(name: str, value, lo: float, hi: float, lo_open: bool, hi_open: bool, fix: str):
    if not _concrete(value):
        return
    if isinstance(value, (int, float)):   # the common case, without numpy's per-call cost (~8 us)
        x = float(value)
        bad = not math.isfinite(x) or (x <= lo if lo_open else x < lo) or (x >= hi if hi_open else x > hi)
    else:
        arr = np.asarray(value, dtype=np.float64)
        bad_lo = arr <= lo if lo_open else arr < lo
        bad_hi = arr >= hi if hi_open else arr > hi
        bad = not np.all(np.isfinite(arr)) or np.any(bad_lo) or np.any(bad_hi)
    if bad:
        lo_b, hi_b = ("(" if lo_open else "["), (")" if hi_open else "]")
        raise ValueError(f"FabricParams.{name}: must lie in {lo_b}{lo}, {hi}{hi_b}; got {value!r}. {fix}")


def validate_params(params: FabricParams) -> None:
    """Raise ``ValueError`` naming the field for out-of-range concrete parameters."""
    if not isinstance(params, FabricParams):
        raise ValueError(f"params: expected a FabricParams, got {type(params).__name__}. "
                         "Build one with jaxplan.FabricParams(theta_tol_deg=...).")
    _check_range("theta_tol_deg", params.theta_tol_deg, 0.0, 180.0, True, True,
                 "Use a cone half-angle in degrees, e.g. 60.")
    _check_range("tau_h", params.tau_h, 0.0, math.inf, False, True,
                 "Use a non-negative threshold (a fraction of max heat when highway_relative).")
    _check_range("anchor_lambda", params.anchor_lambda, 0.0, math.inf, False, True,
                 "Use a non-negative distance weight.")
    _check_range("slack_tau", params.slack_tau, 0.0, math.inf, False, True,
                 "Use a non-negative slack in object units.")
    if (isinstance(params.k, (bool, np.bool_)) or not isinstance(params.k, (int, np.integer))
            or not 1 <= params.k <= K_MAX):
        raise ValueError(f"FabricParams.k: {params.k!r} is out of range; K must be an int in [1, {K_MAX}]: the "
                         "K-best merge is compiled unrolled and its compile memory grows about as K^5 (about "
                         "7 GB at K = 16, 50 GB at K = 24; jaxplan.transport.fabric.estimate_build_bytes). Use "
                         "a small K such as 4 (the default): routes are chosen among the entries within "
                         "slack_tau of the best.")
    if params.max_hops is not None and (not isinstance(params.max_hops, (int, np.integer)) or params.max_hops < 1):
        raise ValueError(f"FabricParams.max_hops: must be None or an int >= 1; got {params.max_hops!r}.")
    if params.solver not in ("auto", "policy", "wavefront"):
        raise ValueError(f"FabricParams.solver: must be 'auto', 'policy' or 'wavefront'; got {params.solver!r}.")
    if params.solver == "policy" and not params.monotone:
        raise ValueError("FabricParams.solver: 'policy' needs monotone=True (an acyclic successor graph); "
                         "use 'auto' or 'wavefront'.")
    if params.temperature is not None:
        _check_range("temperature", params.temperature, 0.0, math.inf, False, True,
                     "Use None (or 0) for the exact hard kernels, or a positive temperature for the soft ones.")
    if params.soft_rounds is not None and (not isinstance(params.soft_rounds, (int, np.integer))
                                           or params.soft_rounds < 1):
        raise ValueError(f"FabricParams.soft_rounds: must be None or an int >= 1; got {params.soft_rounds!r}.")
    if not isinstance(params.monotone, (bool, np.bool_)):
        raise ValueError(f"FabricParams.monotone: must be True or False; got {params.monotone!r}.")
