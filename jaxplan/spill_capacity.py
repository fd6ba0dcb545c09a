"""A capacity-aware spill evaluator: the blade holds at most ``capacity`` objects (issue 7).

The curvature model of :mod:`jaxplan.spillage` removes a fraction of the load per radian of
turning, so its delivered mass scales with the collected mass. The shovel rover in physics does not
behave like that: a one-cell blade carries a roughly fixed amount whatever it collects (see
docs/physics.md, "Capacity-aware spill model"). This evaluator adds that limit, a loss per unit of
distance, the part of a cell the blade misses where it turns, and a turning loss that stops growing
with the load. Sample by sample along the route's spline (as ``curvature_spill``):

    missed_i  = min(1, miss * near_i) * pickup_i    (near_i: |turning| within half a step of the
                                                      waypoint whose objects are picked up at i)
    load     <- load + pickup_i - missed_i
    overflow  = T * softplus((load - capacity) / T)       (smooth max(load - capacity, 0)),
                clipped to [0, load]; 0 where pickup_i - missed_i = 0
    turn_frac = min(1, lam * |turn_i| * S / (S + load))   (S = turn_saturation)
    frac      = 1 - (1 - turn_frac) * (1 - min(1, mu * dl_i))
    spill_i   = overflow + frac * (load - overflow), set to 0 when below ``threshold``
    load     <- load - spill_i
    spill_i  += missed_i

``dl_i`` is the distance from the previous sample's position (0 at the first sample): the route's
length between its first and last sample. ``T = temperature`` (objects) makes the blade's limit a
smooth saturation, so delivered mass is differentiable in ``capacity`` and in the load; as ``T -> 0``
the overflow is the hard ``max(load - capacity, 0)``. The overflow is only taken at samples that take
something in (``pickup_i - missed_i > 0``): elsewhere the load can only fall, and applying the soft
overflow at every sample would bleed about ``T * softplus(0)`` objects per sample from a full blade.

The two turning terms come from the physics (docs/physics.md, "The turning terms"): where the
path turns at a cell, the spline cuts the cell's corner and the blade leaves the outer part of it
behind (``miss``, a fraction of the cell's objects per radian), and a turn spills the pile's edge
over the side plates, an amount that grows with the load only while the pile is small
(``turn_saturation``: with ``S`` infinite, the default, ``turn_frac = lam |turn|`` as before; with
``S`` finite a full blade loses about ``lam * S`` objects per radian). The missed objects are part of
the sample's spill: they stay on the grid (``execute`` drops them beside the path there), so
delivered + spilled = collected still holds. With ``miss = 0`` and ``turn_saturation = inf`` the
evaluator is the three-term model of earlier sessions exactly.

It plugs into the pipeline as any evaluator: pass ``CapacitySpillParams`` where a ``SpillParams`` is
expected (it is one: a subclass with five more traced fields) and ``capacity_spill`` as the
``evaluator`` (``execute.execute``, ``selection.select_routes``, ``episode.run_episode``,
``spillage.evaluate_route``). Parameters are traced pytree leaves: ``jax.grad`` and ``jax.vmap`` go
through them (fit them with optax, vmap over parameter sets).
"""
from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan import spillage

__all__ = ["FIT_FIELDS", "FIT_GRID", "ROVER_FIT", "CapacityFit", "CapacitySpillParams", "capacity_spill",
           "evaluator_for", "fit_capacity", "fit_miss", "missed_objects", "predict_delivered", "predict_missed",
           "turning_near_pickups", "validate_capacity_params"]


@dataclasses.dataclass(frozen=True)
class CapacitySpillParams(spillage.SpillParams):
    """Parameters of the capacity-aware spill model (a ``SpillParams`` with three more fields).

    Traced (besides ``lam`` and ``threshold`` of ``SpillParams``):
      capacity: f32[], objects the blade carries at most (> 0).
      mu: f32[], fraction of the load lost per world unit travelled (>= 0; 1/cell at cell size 1).
      temperature: f32[], objects; softness of the capacity limit (> 0; smaller = closer to a hard min).
      miss: f32[], fraction of a cell's objects the blade leaves behind per radian of turning within
        half a step of the cell (>= 0; 0 = it collects everything).
      turn_saturation: f32[], objects; the load at which the turning spill is half of
        ``lam * |turn| * load`` (> 0; inf, the default, = the proportional rule).
    ``lam`` keeps its meaning for a light load (fraction of the load lost per radian of turning).
    """

    capacity: Any = 10.0
    mu: Any = 0.0
    temperature: Any = 0.5
    miss: Any = 0.0
    turn_saturation: Any = float("inf")


def _fields_split():
    """(data, meta) field names: the parent's traced leaves plus ours; every other field is static.

    Read from the parent's own registration so that a field added to ``SpillParams`` later keeps
    the parent's traced/static choice here too.
    """
    parent_leaves = {p[0].name for p, _ in jax.tree_util.tree_flatten_with_path(spillage.SpillParams())[0]}
    ours = ("capacity", "mu", "temperature", "miss", "turn_saturation")
    names = [f.name for f in dataclasses.fields(CapacitySpillParams)]
    data = [n for n in names if n in parent_leaves or n in ours]
    return data, [n for n in names if n not in data]


_DATA, _META = _fields_split()
jax.tree_util.register_dataclass(CapacitySpillParams, data_fields=_DATA, meta_fields=_META)


# The in-sample fit of ``experiments/bench_rover.py`` (run of 2026-11-25 03:32 UTC,
# ``experiments/results/rover.md``: every one of its 24 routes within 10% of the simulated delivery).
# It describes the default rover (``RoverConfig()``: CG solver, one-cell shovel with one-cell side
# plates, 0.8 cell/s, the blade pushed one cell past the route's end); another rover needs its own fit.
# ``tests/test_rover_capacity.py`` holds it equal to that results file. mu is ~1e-8 there: 0.
ROVER_FIT = CapacitySpillParams(capacity=96.84, lam=0.1548, mu=0.0, temperature=0.5, miss=0.18,
                                turn_saturation=1.59)


def validate_capacity_params(params: CapacitySpillParams) -> None:
    """Raise ``ValueError`` naming the field for out-of-range concrete parameters."""
    if not isinstance(params, CapacitySpillParams):
        raise ValueError(f"capacity_spill: expected a CapacitySpillParams, got {type(params).__name__}. "
                         "Build one with jaxplan.spill_capacity.CapacitySpillParams(capacity=10.0).")
    spillage.validate_spill_params(params)
    for name, strict in (("capacity", True), ("mu", False), ("temperature", True), ("miss", False),
                         ("turn_saturation", True)):
        value = getattr(params, name)
        if isinstance(value, jax.core.Tracer):
            continue
        arr = np.asarray(value, np.float64)
        may_be_inf = name == "turn_saturation"
        bad = (np.isnan(arr) if may_be_inf else ~np.isfinite(arr)) | ((arr <= 0) if strict else (arr < 0))
        if np.any(bad):
            what = "not NaN" if may_be_inf else "finite"
            raise ValueError(f"CapacitySpillParams.{name}: must be {what} and {'> 0' if strict else '>= 0'}; "
                             f"got {value!r}.")


def _chords(samples: spillage.PathSamples):
    """f32[N]: distance from the previous sample's position to this one's (0 at the first sample and
    in padding), world units.

    Used instead of ``samples.ds`` because ``ds`` comes from ``sqrt(|r'|^2)``, whose gradient is NaN on
    the zero-length padding segments of a route shorter than its slots; the chord norm here is guarded.
    """
    d = samples.pos[1:] - samples.pos[:-1]
    d2 = jnp.sum(d * d, -1)
    ok = samples.valid[1:] & samples.valid[:-1] & (d2 > 1e-12)
    chord = jnp.where(ok, jnp.sqrt(jnp.where(ok, d2, 1.0)), 0.0)
    return jnp.concatenate([jnp.zeros((1,), chord.dtype), chord])


def capacity_spill(samples: spillage.PathSamples, pickup, params: CapacitySpillParams):
    """``(delivered f32[], spill f32[N])`` in objects: blade capacity + curvature + distance losses.

    samples: the route's spline samples (``spillage.sample_route``); pickup: f32[N] objects picked
    up at each sample. A sequential scan because the load at a sample depends on what spilled before.
    """
    missed = missed_objects(samples, pickup, params.miss, params.samples_per_step)
    turn = jnp.abs(samples.turn)
    dist_frac = jnp.clip(params.mu * _chords(samples), 0.0, 1.0)
    cap = jnp.asarray(params.capacity, jnp.float32)
    temp = jnp.asarray(params.temperature, jnp.float32)
    sat = jnp.asarray(params.turn_saturation, jnp.float32)

    def step(load, x):
        pick, t, d = x
        load = load + pick
        over = jnp.clip(temp * jax.nn.softplus((load - cap) / temp), 0.0, load)
        over = jnp.where(pick > 0, over, 0.0)
        # S / (S + load) as 1 / (1 + load / S): exactly 1 for S = inf, with a finite gradient
        turn_frac = jnp.clip(params.lam * t / (1.0 + load / sat), 0.0, 1.0)
        f = 1.0 - (1.0 - turn_frac) * (1.0 - d)
        spill = over + f * (load - over)
        spill = jnp.where(spill >= params.threshold, spill, 0.0)
        return load - spill, spill

    delivered, spill = jax.lax.scan(step, jnp.float32(0.0), (pickup - missed, turn, dist_frac))
    return delivered, spill + missed


def turning_near_pickups(samples: spillage.PathSamples, samples_per_step: int):
    """``f32[N]``: at each sample, the |turning| (radians) within half a step of the waypoint whose
    objects are picked up there: the first half of the waypoint's own segment and the second half of
    the segment before it (``samples_per_step`` the sampling density, static)."""
    m = samples_per_step
    turn = jnp.abs(samples.turn).reshape(-1, m)      # 0 on padding samples (sample_route)
    half = m // 2
    after, before = turn[:, :half].sum(1), turn[:, half:].sum(1)
    near = after + jnp.concatenate([jnp.zeros((1,), turn.dtype), before[:-1]])
    return near[samples.segment]


def missed_objects(samples: spillage.PathSamples, pickup, miss, samples_per_step: int):
    """``f32[N]``: objects the blade leaves behind at each sample, ``min(1, miss * near) * pickup``
    (``near`` from :func:`turning_near_pickups`; ``pickup: f32[N]``, ``miss: f32[]`` per radian)."""
    near = turning_near_pickups(samples, samples_per_step)
    return jnp.clip(miss * near, 0.0, 1.0) * pickup


def evaluator_for(params: spillage.SpillParams) -> spillage.Evaluator:
    """The evaluator that reads ``params``: ``capacity_spill`` for ``CapacitySpillParams``, else
    ``spillage.curvature_spill`` (which would silently ignore capacity and mu)."""
    return capacity_spill if isinstance(params, CapacitySpillParams) else spillage.curvature_spill


# --------------------------------------------------------------------------------------------------
# Batched prediction and fitting to observed deliveries (e.g. physics rollouts)
# --------------------------------------------------------------------------------------------------

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
    one array operation over the candidates (the splines are sampled once).
    """
    near, pickup = _turning_and_pickups(waypoints, n_points, waypoint_pickup, samples_per_step, spline_alpha)
    candidates = jnp.arange(0.0, max_miss + resolution / 2, resolution, dtype=jnp.float32)
    sse = jnp.sum((_missed_totals(near, pickup, candidates) - jnp.asarray(left_behind, jnp.float32)) ** 2, -1)
    return float(candidates[int(jnp.argmin(sse))])


def _check_fit_fields(fields, grid):
    unknown = [f for f in fields if f not in FIT_FIELDS]
    if unknown or not fields:
        raise ValueError(f"fit_capacity: fields must be a non-empty subset of {FIT_FIELDS}; got {tuple(fields)!r}.")
    missing = [f for f in fields if f not in grid or len(grid[f]) == 0]
    if missing:
        raise ValueError(f"fit_capacity: grid has no start values for {missing}; give a sequence for each fitted field.")


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
    ``FIT_GRID``; every combination evaluated in one ``vmap`` over parameter sets) picks the start,
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
    grid_loss = np.asarray(jax.jit(jax.vmap(lambda v: mse(tuple(v[i] for i in range(k)))))(jnp.asarray(mesh)))
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
