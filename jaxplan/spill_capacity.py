"""A capacity-aware spill evaluator: the blade holds at most ``capacity`` objects (issue 7).

The curvature model of :mod:`jaxplan.spillage` removes a fraction of the load per radian of
turning, so its delivered mass scales with the collected mass. The shovel rover in physics does not
behave like that: a one-cell blade carries a roughly fixed amount whatever it collects (see
docs/physics.md, "Capacity-aware spill model"). This evaluator adds that limit, and a loss per unit of
distance, to the curvature term. Sample by sample along the route's spline (as ``curvature_spill``):

    load     <- load + pickup_i
    overflow  = T * softplus((load - capacity) / T)       (smooth max(load - capacity, 0)),
                clipped to [0, load]; 0 where pickup_i = 0
    frac      = 1 - (1 - min(1, lam * |turn_i|)) * (1 - min(1, mu * dl_i))
    spill_i   = overflow + frac * (load - overflow), set to 0 when below ``threshold``
    load     <- load - spill_i

``dl_i`` is the distance from the previous sample's position (0 at the first sample): the route's
length between its first and last sample. ``T = temperature`` (objects) makes the blade's limit a smooth saturation, so delivered mass is
differentiable in ``capacity`` and in the load; as ``T -> 0`` the overflow is the hard
``max(load - capacity, 0)``. The overflow is only taken at samples that pick something up
(``pickup_i > 0``): elsewhere the load can only fall, and applying the soft overflow at every sample
would bleed about ``T * softplus(0)`` objects per sample from a full blade.

It plugs into the pipeline as any evaluator: pass ``CapacitySpillParams`` where a ``SpillParams`` is
expected (it is one: a subclass with three more traced fields) and ``capacity_spill`` as the
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

__all__ = ["CapacityFit", "CapacitySpillParams", "capacity_spill", "evaluator_for", "fit_capacity",
           "predict_delivered", "validate_capacity_params"]


@dataclasses.dataclass(frozen=True)
class CapacitySpillParams(spillage.SpillParams):
    """Parameters of the capacity-aware spill model (a ``SpillParams`` with three more fields).

    Traced (besides ``lam`` and ``threshold`` of ``SpillParams``):
      capacity: f32[], objects the blade carries at most (> 0).
      mu: f32[], fraction of the load lost per world unit travelled (>= 0; 1/cell at cell size 1).
      temperature: f32[], objects; softness of the capacity limit (> 0; smaller = closer to a hard min).
    ``lam`` keeps its meaning (fraction of the load lost per radian of turning).
    """

    capacity: Any = 10.0
    mu: Any = 0.0
    temperature: Any = 0.5


def _fields_split():
    """(data, meta) field names: the parent's traced leaves plus ours; every other field is static.

    Read from the parent's own registration so that a field added to ``SpillParams`` later keeps
    the parent's traced/static choice here too.
    """
    parent_leaves = {p[0].name for p, _ in jax.tree_util.tree_flatten_with_path(spillage.SpillParams())[0]}
    ours = ("capacity", "mu", "temperature")
    names = [f.name for f in dataclasses.fields(CapacitySpillParams)]
    data = [n for n in names if n in parent_leaves or n in ours]
    return data, [n for n in names if n not in data]


_DATA, _META = _fields_split()
jax.tree_util.register_dataclass(CapacitySpillParams, data_fields=_DATA, meta_fields=_META)


def validate_capacity_params(params: CapacitySpillParams) -> None:
    """Raise ``ValueError`` naming the field for out-of-range concrete parameters."""
    if not isinstance(params, CapacitySpillParams):
        raise ValueError(f"capacity_spill: expected a CapacitySpillParams, got {type(params).__name__}. "
                         "Build one with jaxplan.spill_capacity.CapacitySpillParams(capacity=10.0).")
    spillage.validate_spill_params(params)
    for name, strict in (("capacity", True), ("mu", False), ("temperature", True)):
        value = getattr(params, name)
        if isinstance(value, jax.core.Tracer):
            continue
        arr = np.asarray(value, np.float64)
        bad = ~np.isfinite(arr) | ((arr <= 0) if strict else (arr < 0))
        if np.any(bad):
            raise ValueError(f"CapacitySpillParams.{name}: must be finite and {'> 0' if strict else '>= 0'}; "
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
    turn_frac = jnp.clip(params.lam * jnp.abs(samples.turn), 0.0, 1.0)
    dist_frac = jnp.clip(params.mu * _chords(samples), 0.0, 1.0)
    frac = 1.0 - (1.0 - turn_frac) * (1.0 - dist_frac)
    cap = jnp.asarray(params.capacity, jnp.float32)
    temp = jnp.asarray(params.temperature, jnp.float32)

    def step(load, x):
        pick, f = x
        load = load + pick
        over = jnp.clip(temp * jax.nn.softplus((load - cap) / temp), 0.0, load)
        over = jnp.where(pick > 0, over, 0.0)
        spill = over + f * (load - over)
        spill = jnp.where(spill >= params.threshold, spill, 0.0)
        return load - spill, spill

    delivered, spill = jax.lax.scan(step, jnp.float32(0.0), (pickup, frac))
    return delivered, spill


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


_FIT_FIELDS = ("capacity", "lam", "mu")


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


def fit_capacity(waypoints, n_points, waypoint_pickup, delivered, *, temperature: float = 0.5,
                 steps: int = 300, learning_rate: float = 0.05,
                 grid=((4.0, 8.0, 16.0, 24.0, 48.0, 96.0, 192.0, 1000.0),
                       (0.0, 0.01, 0.02, 0.03, 0.05, 0.1, 0.2, 0.5), (0.0, 0.002, 0.005, 0.01, 0.03, 0.1)),
                 base: CapacitySpillParams | None = None) -> CapacityFit:
    """Fit ``capacity``, ``lam`` and ``mu`` to observed delivered objects of R routes.

    waypoints f32[R, S, 2], n_points i32[R], waypoint_pickup f32[R, S] as in :func:`predict_delivered`;
    delivered: f[R] observed objects (e.g. the physics rollouts of the same routes).
    Loss: mean squared error in objects^2. A coarse grid (capacity x lam x mu, evaluated in one
    ``vmap`` over parameter sets) picks the start, then ``steps`` Adam steps (optax) on
    ``log(capacity)`` and the softplus-inverse of ``lam`` and ``mu`` (so they stay positive).
    ``temperature`` is held fixed. The grid's capacities reach 1000 objects (no cap in practice):
    Adam started from a small capacity does not find the uncapped regime of a shovel that holds
    its load (it settled at capacity 98, lam and mu ~0 where the uncapped fit is far better).
    """
    import optax

    base = CapacitySpillParams() if base is None else base
    validate_capacity_params(base.replace(temperature=temperature))
    obs = jnp.asarray(delivered, jnp.float32)
    args = (jnp.asarray(waypoints, jnp.float32), jnp.asarray(n_points, jnp.int32),
            jnp.asarray(waypoint_pickup, jnp.float32))

    def params_of(values):
        return base.replace(temperature=jnp.float32(temperature), **dict(zip(_FIT_FIELDS, values)))

    def mse(values):
        return jnp.mean((predict_delivered(*args, params_of(values)) - obs) ** 2)

    mesh = np.stack(np.meshgrid(*[np.asarray(g, np.float32) for g in grid], indexing="ij"), -1).reshape(-1, 3)
    grid_loss = np.asarray(jax.jit(jax.vmap(lambda v: mse(tuple(v[i] for i in range(3)))))(jnp.asarray(mesh)))
    start = mesh[int(np.argmin(grid_loss))]

    # capacity on a log scale (Adam's step is then a relative change, right for a value of ~10
    # objects), lam and mu through softplus (they may approach 0)
    def positive(raw):
        return jnp.stack([jnp.exp(raw[0]), jax.nn.softplus(raw[1]), jax.nn.softplus(raw[2])])

    def loss_raw(raw):
        v = positive(raw)
        return mse((v[0], v[1], v[2]))

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

    raw0 = jnp.asarray(np.concatenate([np.log(start[:1]), _inv_softplus(start[1:])]), jnp.float32)
    raw, hist = run(raw0)
    fitted = np.asarray(positive(raw), np.float64)
    final = float(loss_raw(raw))
    if not np.isfinite(final) or final > float(grid_loss.min()):   # never return worse than the grid
        fitted, final = start.astype(np.float64), float(grid_loss.min())
    as_params = lambda v: base.replace(temperature=float(temperature),  # noqa: E731
                                       **{k: float(x) for k, x in zip(_FIT_FIELDS, v)})
    return CapacityFit(as_params(fitted), np.append(np.asarray(hist), final), as_params(start))
