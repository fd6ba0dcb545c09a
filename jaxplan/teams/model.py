"""The coordinator's performance model: Eqs. 1-4 of Endo et al. and the number of cooperators needed.

Every function is pure ``jax.numpy`` and elementwise, so it takes scalars or arrays of one common
shape (e.g. ``f32[M]``, one entry per team) and works under ``jit`` and ``vmap``.

Units: masses in kg, distances in m, velocities in m/s, times in s, performance in kg/s.

Eq. 1 is garbled in the paper's typesetting. We implement its queueing reading (see docs/teams.md):
a truck's cycle is ``T_c = 2 D / v + t_ld + t_dp``; the excavator loads one truck per ``t_ld``, so
with ``n >= T_c / t_ld`` trucks it is the bottleneck and the team moves ``w / t_ld``; with fewer
trucks the excavator waits for them and the team moves ``n w / T_c``.
"""
from __future__ import annotations

import jax.numpy as jnp

__all__ = ["cycle_time", "predicted_performance", "real_performance", "misses_deadline",
           "velocity_estimate", "correct_estimate", "saturation_trucks", "cooperators_needed"]


def cycle_time(dist, v, t_ld, t_dp):
    """One truck's round trip without queueing, ``T_c = 2 D / v + t_ld + t_dp`` [s]."""
    return 2.0 * dist / v + t_ld + t_dp


def predicted_performance(n, w, dist, v, t_ld, t_dp):
    """Eq. 1, queueing reading: ``w / t_ld`` if ``n >= T_c / t_ld`` else ``n w / T_c`` [kg/s].

    n: trucks in the team (int or float, >= 0); w: mean load [kg]; dist: loading-dumping distance D
    [m]; v: truck velocity [m/s]; t_ld, t_dp: loading and dumping times [s].
    """
    t_c = cycle_time(dist, v, t_ld, t_dp)
    return jnp.where(n * t_ld >= t_c, w / t_ld, n * w / t_c)


def real_performance(member, w_last, t_last, cycled, t):
    """Eq. 2, from the trucks' last loads: ``sum_k w_last^k / (t - min_k t_last^k)`` [kg/s].

    member: bool[..., N], truck k belongs to the team; w_last: f[N] its last load [kg]; t_last: f[N]
    the start time of that load [s]; cycled: bool[N], it has come back to the excavator at least once
    since joining (the paper: real performance needs one round trip of every truck); t: now [s].
    Returns ``(r_real, available)``; ``r_real`` is 0 where not available (no member, or a member that
    has not cycled yet).
    """
    available = jnp.any(member, axis=-1) & jnp.all(cycled | ~member, axis=-1)
    t_first = jnp.min(jnp.where(member, t_last, jnp.inf), axis=-1)
    span = t - t_first
    available = available & (span > 0)
    total = jnp.sum(jnp.where(member, w_last, 0.0), axis=-1)
    return jnp.where(available, total / jnp.where(available, span, 1.0), 0.0), available


def misses_deadline(t, remaining, perf, deadline):
    """Eq. 3: ``t + X(t) / r > T_DL``. A team with soil left and ``r <= 0`` misses it; none left never."""
    safe = jnp.where(perf > 0, perf, 1.0)
    late = t + remaining / safe > deadline
    return (remaining > 0) & ((perf <= 0) | late)


def velocity_estimate(dist, t_circ, t_ld, t_dp):
    """Eq. 4, ``v = 2 D / (t_circ - t_ld - t_dp)`` [m/s]; ``nan`` where the travel time is not positive."""
    travel = t_circ - t_ld - t_dp
    return jnp.where(travel > 0, 2.0 * dist / jnp.where(travel > 0, travel, 1.0), jnp.nan)


def correct_estimate(estimate, measured, tol):
    """Error correction of one model parameter: take ``measured`` where it is finite, positive and more
    than ``tol`` (a fraction) away from ``estimate``; keep ``estimate`` otherwise."""
    valid = jnp.isfinite(measured) & (measured > 0)
    moved = jnp.abs(measured - estimate) > tol * estimate
    return jnp.where(valid & moved, measured, estimate)


def saturation_trucks(dist, v, t_ld, t_dp):
    """``ceil(T_c / t_ld)``: the smallest team with which the excavator is the bottleneck (Eq. 1)."""
    return jnp.ceil(cycle_time(dist, v, t_ld, t_dp) / t_ld).astype(jnp.int32)


def cooperators_needed(remaining, t, deadline, w, dist, v, t_ld, t_dp):
    """The smallest ``n`` with ``t + X / r_pred(n) <= T_DL`` (Eqs. 1 and 3), as int32.

    0 when no soil is left. When no team meets the deadline (too little time left, or more than the
    excavator can load), the saturation size ``ceil(T_c / t_ld)``: more trucks than that only queue.
    Closed form: ``r_need = X / (T_DL - t)`` and ``n = ceil(r_need T_c / w)``, which is below the
    saturation size whenever ``r_need <= w / t_ld``.
    """
    t_c = cycle_time(dist, v, t_ld, t_dp)
    n_sat = saturation_trucks(dist, v, t_ld, t_dp)
    time_left = deadline - t
    r_need = remaining / jnp.where(time_left > 0, time_left, 1.0)
    feasible = (time_left > 0) & (r_need * t_ld <= w)
    n = jnp.maximum(jnp.ceil(r_need * t_c / w), 1.0).astype(jnp.int32)
    n = jnp.where(feasible, jnp.minimum(n, n_sat), n_sat)
    return jnp.where(remaining > 0, n, 0)
