"""Built-in sites: the paper's scenario (Section III, Table III) and randomised sites for Monte-Carlo.

Both return ``SiteParams`` of numpy arrays (float32 unless ``dtype`` says otherwise), so the same
draws feed the JAX simulation and the plain reference.
"""
from __future__ import annotations

import math

import numpy as np

from jaxplan.teams.params import SiteParams, TeamsConfig

__all__ = ["PAPER", "paper_scenario", "paper_config", "random_sites", "draw_loads"]

# Table III and Section III. The paper does not give the actual velocities, the size of the drop,
# the spread of the loads or how far recruits drive; the values marked "ours" are our choices.
PAPER = {
    "mass": (12000.0, 8000.0),   # kg at the two loading sites
    "w": 950.0,                  # initial average load, kg
    "dist": 150.0,               # m, loading site to dumping site
    "v_spec": 4.0,               # m/s, the coordinators' prior
    "deadline": 900.0,           # s
    "t_ld": 35.0,                # s
    "t_dp": 30.0,                # s
    "n_trucks": 10,
    "v_actual": 3.0,             # m/s, below the specification (ours)
    "v_drop_t": 400.0,           # s, the velocity change of Fig. 6
    "v_after": 1.2,              # m/s after the drop (ours)
    "load_sigma": 0.1,           # relative spread of a load (ours)
    "join_dist": 100.0,          # m, waiting area (or another site) to a loading site (ours)
}


def draw_loads(rng: np.random.Generator, mean, sigma: float, n_loads: int, dtype=np.float32):
    """Pre-drawn loads ``[..., M, n_loads]``: normal around ``mean`` (``[..., M]``) with relative spread
    ``sigma``, clipped to [0.5, 1.5] x mean (an excavator never scoops nothing or double)."""
    mean = np.asarray(mean, dtype=np.float64)[..., None]
    z = rng.standard_normal(mean.shape[:-1] + (n_loads,))
    return np.clip(mean * (1.0 + sigma * z), 0.5 * mean, 1.5 * mean).astype(dtype)


def _loads_needed(mass, w) -> int:
    """Enough pre-drawn loads to empty the largest site even if every load is the smallest (0.5 w)."""
    return int(math.ceil(float(np.max(mass)) / (0.5 * float(np.min(w))))) + 2


def paper_scenario(seed: int = 0, dtype=np.float32, **overrides) -> SiteParams:
    """The paper's site: 12,000 and 8,000 kg, D = 150 m, spec velocity 4 m/s, actual 3 m/s dropping to
    1.2 m/s at t = 400 s, t_ld 35 s, t_dp 30 s, loads around 950 kg, deadline 900 s, no failure.

    ``overrides`` replace ``PAPER`` entries (e.g. ``v_after=1.5``). ``seed`` draws the load noise.
    """
    unknown = set(overrides) - set(PAPER)
    if unknown:
        raise ValueError(f"paper_scenario: unknown setting(s) {sorted(unknown)}; "
                         f"choose from {sorted(PAPER)}.")
    c = {**PAPER, **overrides}
    mass = np.asarray(c["mass"], dtype=np.float64)
    m = mass.shape[0]
    full = lambda value: np.full(m, value, dtype=dtype)  # noqa: E731
    rng = np.random.default_rng(seed)
    loads = draw_loads(rng, full(c["w"]), c["load_sigma"], _loads_needed(mass, full(c["w"])), dtype)
    return SiteParams(
        mass=mass.astype(dtype), dist=full(c["dist"]),
        v_true=full(c["v_actual"]), v_after=full(c["v_after"]), v_change_t=dtype(c["v_drop_t"]),
        tld_true=full(c["t_ld"]), tld_after=full(c["t_ld"]), tld_change_t=dtype(np.inf),
        tdp_true=full(c["t_dp"]), loads=loads, fail_truck=np.int32(-1), fail_t=dtype(np.inf),
        deadline=dtype(c["deadline"]), w_prior=full(c["w"]), tld_prior=full(c["t_ld"]),
        v_prior=full(c["v_spec"]), tdp_prior=full(c["t_dp"]), join_dist=dtype(c["join_dist"]),
        tol_perf=dtype(0.1), tol_param=dtype(0.1), dt=dtype(1.0))


def paper_config(strategy: str = "performance", record: bool = True, n_steps: int = 1200,
                 n_trucks: int = PAPER["n_trucks"]) -> TeamsConfig:
    """Static options for the paper scenario: 10 trucks, 1200 steps of 1 s (past the deadline)."""
    return TeamsConfig(n_trucks=n_trucks, n_steps=n_steps, strategy=strategy, record=record)


def random_sites(seed: int, batch: int, n_teams: int = 2, n_trucks: int = 10, dtype=np.float32,
                 dt: float = 1.0) -> SiteParams:
    """``batch`` randomised sites (leading axis ``batch``) around the paper's scenario.

    Per team: soil U(4,000, 14,000) kg, distance U(80, 250) m, actual velocity U(0.6, 1.0) x the
    4 m/s spec, loading time U(0.9, 1.2) x 35 s, dumping time U(0.9, 1.1) x 30 s. Per site: with
    probability 0.7 a velocity drop at U(100, 700) s to U(0.4, 0.9) x the velocity; with probability
    0.3 a loading-time rise at U(100, 700) s to U(1.0, 1.5) x; with probability 0.3 one random truck
    fails at U(0, 800) s. Loads around 950 kg, 10% spread; deadline 900 s; recruits drive 100 m.
    """
    if batch < 1:
        raise ValueError(f"random_sites: batch must be >= 1; got {batch}.")
    rng = np.random.default_rng(seed)
    shape = (batch, n_teams)
    u = lambda lo, hi, size=shape: rng.uniform(lo, hi, size)  # noqa: E731
    mass = u(4000.0, 14000.0)
    v_true = PAPER["v_spec"] * u(0.6, 1.0)
    drop = rng.random(batch) < 0.7
    v_after = np.where(drop[:, None], v_true * u(0.4, 0.9), v_true)
    slow_load = rng.random(batch) < 0.3
    tld_true = PAPER["t_ld"] * u(0.9, 1.2)
    tld_after = np.where(slow_load[:, None], tld_true * u(1.0, 1.5), tld_true)
    fails = rng.random(batch) < 0.3
    w = np.full(shape, PAPER["w"])
    loads = draw_loads(rng, w, PAPER["load_sigma"], _loads_needed(mass, w), dtype)
    full = lambda value: np.full(shape, value, dtype=dtype)  # noqa: E731
    scalar = lambda value: np.full(batch, value, dtype=dtype)  # noqa: E731
    return SiteParams(
        mass=mass.astype(dtype), dist=u(80.0, 250.0).astype(dtype),
        v_true=v_true.astype(dtype), v_after=v_after.astype(dtype),
        v_change_t=np.where(drop, u(100.0, 700.0, batch), np.inf).astype(dtype),
        tld_true=tld_true.astype(dtype), tld_after=tld_after.astype(dtype),
        tld_change_t=np.where(slow_load, u(100.0, 700.0, batch), np.inf).astype(dtype),
        tdp_true=(PAPER["t_dp"] * u(0.9, 1.1)).astype(dtype), loads=loads,
        fail_truck=np.where(fails, rng.integers(0, n_trucks, batch), -1).astype(np.int32),
        fail_t=np.where(fails, u(0.0, 800.0, batch), np.inf).astype(dtype),
        deadline=scalar(PAPER["deadline"]), w_prior=full(PAPER["w"]), tld_prior=full(PAPER["t_ld"]),
        v_prior=full(PAPER["v_spec"]), tdp_prior=full(PAPER["t_dp"]),
        join_dist=scalar(PAPER["join_dist"]), tol_perf=scalar(0.1), tol_param=scalar(0.1),
        dt=scalar(dt))
