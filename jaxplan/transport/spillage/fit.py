"""Fitting the capacity-aware spill model to observed deliveries (e.g. physics rollouts): batched
prediction over routes, a coarse grid search, then Adam (optax) from its best point."""
from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.transport.spillage import base as spillage
from jaxplan.transport.spillage.capacity import (
    CapacitySpillParams,
    capacity_spill,
    turning_near_pickups,
    validate_capacity_params,
)

__all__ = ["FIT_FIELDS", "FIT_GRID", "CapacityFit", "fit_capacity", "fit_miss", "predict_delivered", "predict_missed"]


# jitted (one program per route shape and model): called eagerly, each of the spline's small
# operations compiled apart, dozens of programs for every new route length
@functools.partial(jax.jit, static_argnames=("evaluator",))
def predict_delivered(waypoints, n_points, waypoint_pickup, params: spillage.SpillParams,
                      evaluator: spillage.Evaluator = capacity_spill):
    """``f32[R]``: delivered objects of R routes under one parameter set (``vmap`` of ``evaluate_route``).

    waypoints: f32[R, S, 2] world units (rows past ``n_points`` ignored); n_points: i32[R];
    waypoint_pickup: f32[R, S] objects collected at each waypoint. ``vmap`` this over a leading axis
    of ``params``' leaves to evaluate many parameter sets at once.
    """
    one = lambda p, n, k: spillage.evaluate_route(p, n, k, params, evaluator)[0]  # noqa: E731
    return jax.vmap(one)(jnp.asarray(waypoints, jnp.float32), jnp.asarray(n_points, jnp.int32),
                         jnp.asarray(waypoint_pickup, jnp.float32))


FIT_FIELDS = ("capacity", "lam", "mu", "turn_saturation")
# coarse start grids; a large value stands for "no limit" (capacity, turn_saturation) where Adam
# needs a finite point: loads stay well below it
FIT_GRID = {"capacity": (4.0, 8.0, 16.0, 24.0, 48.0, 96.0, 192.0, 1000.0),
            "lam": (0.0, 0.01, 0.02, 0.03, 0.05, 0.1, 0.2, 0.5),
            "mu": (0.0, 0.002, 0.005, 0.01, 0.03, 0.1),
            "turn_saturation": (1.0, 3.0, 10.0, 30.0, 1e4)}
GRID_BATCH = 16
"""Grid points ``fit_capacity`` (and ``fit_miss``) evaluate together (a ``vmap``); the rest of the grid
runs in turn, so the memory does not grow with the grid."""
_LOG_FIELDS = ("capacity", "turn_saturation")   # fitted on a log scale; the others through softplus


def _inv_softplus(x):
    x = np.maximum(np.asarray(x, np.float64), 1e-6)
    return x + np.log(-np.expm1(-x))


class CapacityFit(NamedTuple):
    """Result of :func:`fit_capacity`.

    params: the fitted ``CapacitySpillParams`` (float leaves). loss: f[steps], mean squared error
    (objects^2) per optimiser step. grid_best: the coarse-grid start point (``CapacitySpillParams``).
    """

    params: CapacitySpillParams
    loss: np.ndarray
    grid_best: CapacitySpillParams


def _turning_and_pickups(waypoints, n_points, waypoint_pickup, samples_per_step: int, spline_alpha: float):
    """``(near f32[R, N], pickup f32[R, N])`` of R routes: ``turning_near_pickups`` and the objects
    picked up at each spline sample. Neither depends on ``miss``, so a fit samples the splines once."""
    def one(p, n, k):
        samples = spillage.sample_route(p, n, samples_per_step, spline_alpha)
        return turning_near_pickups(samples, samples_per_step), spillage.pickups_per_sample(samples, k)
    return jax.vmap(one)(jnp.asarray(waypoints, jnp.float32), jnp.asarray(n_points, jnp.int32),
                         jnp.asarray(waypoint_pickup, jnp.float32))


def _missed_totals(near, pickup, miss):
    """``f32[..., R]``: objects missed per route for ``miss`` of any leading shape (``missed_objects``
    summed over the samples of ``near``, ``pickup`` f32[R, N])."""
    miss = jnp.asarray(miss, jnp.float32)[..., None, None]
    return jnp.sum(jnp.clip(miss * near, 0.0, 1.0) * pickup, -1)


@functools.partial(jax.jit, static_argnames=("samples_per_step", "spline_alpha"))
def predict_missed(waypoints, n_points, waypoint_pickup, miss, samples_per_step: int = 8,
                   spline_alpha: float = spillage.CENTRIPETAL):
    """``f32[R]``: objects the blade leaves behind on each of R routes at ``miss`` (per radian).

    waypoints f32[R, S, 2], n_points i32[R], waypoint_pickup f32[R, S] as in :func:`predict_delivered`.
    """
    near, pickup = _turning_and_pickups(waypoints, n_points, waypoint_pickup, samples_per_step, spline_alpha)
    return _missed_totals(near, pickup, miss)


def fit_miss(waypoints, n_points, waypoint_pickup, left_behind, *, samples_per_step: int = 8,
             spline_alpha: float = spillage.CENTRIPETAL, max_miss: float = 2.0, resolution: float = 5e-4) -> float:
    """``miss`` (per radian) that best predicts the objects left behind on R routes (least squares).

    left_behind: f[R] observed objects left on the routes' own cells (e.g. ``RouteOutcome.left_behind``
    of physics rollouts). The predicted mass is linear in ``miss`` until ``miss * near`` reaches 1 at
    a sharp turn, so the fit is a plain search: every multiple of ``resolution`` in ``[0, max_miss]``,
    ``GRID_BATCH`` candidates at a time (the splines are sampled once).
    """
    near, pickup = _turning_and_pickups(waypoints, n_points, waypoint_pickup, samples_per_step, spline_alpha)
    candidates = jnp.arange(0.0, max_miss + resolution / 2, resolution, dtype=jnp.float32)
    observed = jnp.asarray(left_behind, jnp.float32)
    # GRID_BATCH candidates at a time: all of them times the routes' samples need not fit in memory
    sse = jax.jit(lambda c: jax.lax.map(lambda m: jnp.sum((_missed_totals(near, pickup, m) - observed) ** 2), c,
                                        batch_size=GRID_BATCH))(candidates)
    return float(candidates[int(jnp.argmin(sse))])


def _check_fit_fields(fields, grid):
    unknown = [f for f in fields if f not in FIT_FIELDS]
    if unknown or not fields:
        raise ValueError(f"fit_capacity: fields must be a non-empty subset of {FIT_FIELDS}; got {tuple(fields)!r}.")
    missing = [f for f in fields if f not in grid or len(grid[f]) == 0]
    if missing:
        raise ValueError(f"fit_capacity: grid has no start values for {missing}; "
                         "give a sequence for each fitted field.")


def fit_capacity(waypoints, n_points, waypoint_pickup, delivered, *, temperature: float = 0.5,
                 steps: int = 300, learning_rate: float = 0.05, fields=("capacity", "lam", "mu"),
                 grid: dict | None = None, left_behind=None,
                 base: CapacitySpillParams | None = None) -> CapacityFit:
    """Fit ``fields`` of the model (``capacity``, ``lam``, ``mu``, ``turn_saturation``) to observed
    delivered objects of R routes.

    waypoints f32[R, S, 2], n_points i32[R], waypoint_pickup f32[R, S] as in :func:`predict_delivered`;
    delivered: f[R] observed objects (e.g. the physics rollouts of the same routes). left_behind:
    optional f[R] observed objects left on the routes' cells; when given, ``miss`` is fitted to them
    first (:func:`fit_miss`) and held there, otherwise it stays ``base.miss``. Fields not fitted keep
    ``base``'s values.
    Loss: mean squared error in objects^2. A coarse grid (``grid[field]`` start values, default
    ``FIT_GRID``; every combination evaluated, ``GRID_BATCH`` at a time) picks the start,
    then ``steps`` Adam steps (optax) on the logarithm of ``capacity`` and ``turn_saturation`` and
    the softplus-inverse of ``lam`` and ``mu`` (so they stay positive). ``temperature`` is held fixed.
    The grid's capacities reach 1000 objects (no cap in practice): Adam started from a small capacity
    does not find the uncapped regime of a shovel that holds its load (it settled at capacity 98,
    lam and mu ~0 where the uncapped fit is far better).
    """
    import optax

    fields = tuple(fields)
    grid = dict(FIT_GRID if grid is None else grid)
    _check_fit_fields(fields, grid)
    base = CapacitySpillParams() if base is None else base
    validate_capacity_params(base.replace(temperature=temperature))
    if left_behind is not None:
        base = base.replace(miss=fit_miss(waypoints, n_points, waypoint_pickup, left_behind,
                                          samples_per_step=base.samples_per_step, spline_alpha=base.spline_alpha))
    obs = jnp.asarray(delivered, jnp.float32)
    args = (jnp.asarray(waypoints, jnp.float32), jnp.asarray(n_points, jnp.int32),
            jnp.asarray(waypoint_pickup, jnp.float32))
    fixed = {k: jnp.float32(getattr(base, k)) for k in ("miss", "turn_saturation", "capacity", "lam", "mu")
             if k not in fields}

    def params_of(values):
        return base.replace(temperature=jnp.float32(temperature), **fixed, **dict(zip(fields, values)))

    def mse(values):
        return jnp.mean((predict_delivered(*args, params_of(values)) - obs) ** 2)

    k = len(fields)
    mesh = np.stack(np.meshgrid(*[np.asarray(grid[f], np.float32) for f in fields], indexing="ij"), -1).reshape(-1, k)
    # a few parameter sets at a time: the grid times the routes' samples does not fit in memory at once
    grid_loss = np.asarray(jax.jit(lambda m: jax.lax.map(lambda v: mse(tuple(v[i] for i in range(k))), m,
                                                         batch_size=GRID_BATCH))(jnp.asarray(mesh)))
    start = mesh[int(np.argmin(grid_loss))]

    # capacity and the saturation load on a log scale (Adam's step is then a relative change, right
    # for values of ~10 objects), lam and mu through softplus (they may approach 0)
    logs = np.array([f in _LOG_FIELDS for f in fields])

    def positive(raw):
        return jnp.where(logs, jnp.exp(raw), jax.nn.softplus(raw))

    def loss_raw(raw):
        v = positive(raw)
        return mse(tuple(v[i] for i in range(k)))

    opt = optax.adam(learning_rate)

    @jax.jit
    def run(raw):
        def step(carry, _):
            raw, state = carry
            value, g = jax.value_and_grad(loss_raw)(raw)
            upd, state = opt.update(g, state, raw)
            return (optax.apply_updates(raw, upd), state), value
        (raw, _), hist = jax.lax.scan(step, (raw, opt.init(raw)), None, length=steps)
        return raw, hist

    raw0 = jnp.asarray(np.where(logs, np.log(np.maximum(start, 1e-6)), _inv_softplus(start)), jnp.float32)
    raw, hist = run(raw0)
    fitted = np.asarray(positive(raw), np.float64)
    final = float(loss_raw(raw))
    if not np.isfinite(final) or final > float(grid_loss.min()):   # never return worse than the grid
        fitted, final = start.astype(np.float64), float(grid_loss.min())
    as_params = lambda v: base.replace(temperature=float(temperature),  # noqa: E731
                                       **{f: float(x) for f, x in zip(fields, v)})
    return CapacityFit(as_params(fitted), np.append(np.asarray(hist), final), as_params(start))
