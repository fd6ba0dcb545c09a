"""Spillage along a pushed route: spline, curvature and ``Spill(P; Theta)`` (Section 3.2).

A route's waypoints (cell centres, then the target cell it enters or its fallback point on the
boundary) are joined by a centripetal Catmull-Rom spline (``SpillParams.spline_alpha = 0.5``; 0 gives
the uniform one): it passes through every waypoint, is smooth, and is differentiable in the
waypoints. The centripetal form scales each waypoint's tangent to the segments beside it, so a
one-cell step next to a long fallback segment does not loop (the uniform form borrows half the long
segment as the short one's tangent and does). Each segment between two waypoints is sampled at
``samples_per_step`` midpoints. At sample ``i`` the pusher carries ``load_i`` objects; it picks up a
cell's objects at the first sample of the segment leaving that cell, and turning spills

    spill_i = lam * kappa_i * ds_i * load_i      (= lam * turning angle of the sample * load),

clipped to the load and dropped when below ``threshold`` objects (with ``temperature > 0`` the drop is
soft: the spill is scaled by ``sigmoid((spill - threshold) / temperature)``, differentiable in the
threshold; ``temperature = 0``, the default, is the exact hard rule). ``kappa_i * ds_i`` rather than the
paper's bare ``kappa_i`` makes the spill independent of how densely the spline is sampled: ``lam`` is
the fraction of the load lost per radian of turning. Delivered = collected - sum(spill): the residual
load at the end.

The evaluator is pluggable: any ``evaluator(samples: PathSamples, pickup: f32[N], params) ->
(delivered: f32[], spill: f32[N])`` can replace ``curvature_spill``; the planner and ``execute``
only call it through that signature.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

_TINY = 1e-12   # guards |r'|^2 for a (degenerate) stationary spline point
CENTRIPETAL = 0.5   # spline_alpha of the centripetal Catmull-Rom spline (0 = uniform, 1 = chordal)


@dataclasses.dataclass(frozen=True)
class SpillParams:
    """Parameters of the curvature spill model.

    Traced:
      lam: f32[], fraction of the load spilled per radian of turning (>= 0).
      threshold: f32[], objects; a sample's spill below it is ignored (>= 0).
      temperature: f32[], objects; 0 (default) = the hard threshold; > 0 = a sigmoid of this width,
        so the spill is differentiable in ``threshold`` (``jaxplan.tune.spill`` fits with it).
    Static:
      samples_per_step: spline samples per segment between two waypoints (>= 1).
      spline_alpha: knot exponent of the Catmull-Rom spline, in [0, 1]: 0.5 (default) centripetal,
        0 uniform (loops beside long segments), 1 chordal.
      enabled: whether routes are selected by delivered mass (Eq. 6) rather than raw count (Eq. 5).
    """

    model: ClassVar[str] = "curvature"
    lam: Any = 0.05
    threshold: Any = 1e-3
    temperature: Any = 0.0
    samples_per_step: int = 8
    enabled: bool = True
    spline_alpha: float = CENTRIPETAL

    def replace(self, **changes) -> SpillParams:
        return dataclasses.replace(self, **changes)


jax.tree_util.register_dataclass(SpillParams, data_fields=["lam", "threshold", "temperature"],
                                 meta_fields=["samples_per_step", "enabled", "spline_alpha"])


def validate_spill_params(params: SpillParams) -> None:
    """Raise ``ValueError`` naming the field for out-of-range concrete spill parameters."""
    if not isinstance(params, SpillParams):
        raise ValueError(f"spill: expected a SpillParams, got {type(params).__name__}. "
                         "Build one with jaxplan.SpillParams(lam=0.05).")
    for name in ("lam", "threshold", "temperature"):
        value = getattr(params, name)
        if isinstance(value, jax.core.Tracer):
            continue
        arr = np.asarray(value, np.float64)
        if not np.all(np.isfinite(arr)) or np.any(arr < 0):
            raise ValueError(f"SpillParams.{name}: must be finite and >= 0; got {value!r}.")
    if not isinstance(params.samples_per_step, (int, np.integer)) or params.samples_per_step < 1:
        raise ValueError(f"SpillParams.samples_per_step: must be an int >= 1; got {params.samples_per_step!r}.")
    _check_alpha(params.spline_alpha, "SpillParams.spline_alpha")


def _check_alpha(alpha, field):
    if isinstance(alpha, bool) or not isinstance(alpha, (int, float, np.number)) or not 0.0 <= float(alpha) <= 1.0:
        raise ValueError(f"{field}: must be a number in [0, 1] (0.5 centripetal, 0 uniform); got {alpha!r}.")


class PathSamples(NamedTuple):
    """Dense samples of a route's spline; N = (S - 1) * samples_per_step for S waypoint slots.

    pos: f32[N, 2], world (x, y).  tangent: f32[N, 2], unit direction of travel.
    turn: f32[N], signed turning angle over the sample (radians, + = counter-clockwise), kappa * ds.
    ds: f32[N], arc length of the sample, world units.  segment: i32[N], waypoint the sample leaves.
    first: bool[N], first sample of its segment (where that waypoint's objects are picked up).
    valid: bool[N], the sample lies on the route (False in padding).
    """

    pos: jax.Array
    tangent: jax.Array
    turn: jax.Array
    ds: jax.Array
    segment: jax.Array
    first: jax.Array
    valid: jax.Array


def _control_points(waypoints, n_points):
    """``[S-1, 4, 2]`` Catmull-Rom control points (P0, P1, P2, P3) of every segment; the ends are
    extended by reflection (P_{-1} = 2 P_0 - P_1), so an end segment starts or ends straight."""
    s = waypoints.shape[0]
    idx = jnp.arange(s - 1)
    last = jnp.maximum(n_points - 1, 1)
    at = lambda i: waypoints[jnp.clip(i, 0, s - 1)]  # noqa: E731
    p1, p2 = at(idx), at(idx + 1)
    before = jnp.where((idx == 0)[:, None], 2 * p1 - p2, at(idx - 1))
    after = jnp.where((idx + 1 >= last)[:, None], 2 * p2 - p1, at(idx + 2))
    return jnp.stack([before, p1, p2, after], axis=1)


def _knot_gap(a, b, alpha: float):
    """``|b - a|^alpha`` over the last axis; 0 (with a finite gradient) where a = b."""
    d2 = jnp.sum((b - a) ** 2, -1, keepdims=True)
    apart = d2 > _TINY
    return jnp.where(apart, jnp.where(apart, d2, 1.0) ** (0.5 * alpha), 0.0)


def _safe_ratio(num, den):
    """``num / den``, 0 where ``den`` is 0 (coincident waypoints), with finite gradients."""
    nonzero = den > 0
    return jnp.where(nonzero, num / jnp.where(nonzero, den, 1.0), 0.0)


def _tangents(ctrl, alpha: float):
    """Per-segment end tangents ``(m1, m2)``, each ``[S-1, 2]``, of the Catmull-Rom spline with knot
    exponent ``alpha``, in the segment's own parameter t in [0, 1] (Barry-Goldman / Yuksel et al.).
    At alpha 0 they are the uniform spline's ``(P2 - P0) / 2`` and ``(P3 - P1) / 2``."""
    p0, p1, p2, p3 = (ctrl[:, i] for i in range(4))
    d0, d1, d2 = _knot_gap(p0, p1, alpha), _knot_gap(p1, p2, alpha), _knot_gap(p2, p3, alpha)
    m1 = (p2 - p1) + d1 * (_safe_ratio(p1 - p0, d0) - _safe_ratio(p2 - p0, d0 + d1))
    m2 = (p2 - p1) + d1 * (_safe_ratio(p3 - p2, d2) - _safe_ratio(p3 - p1, d1 + d2))
    return m1, m2


def _hermite(ctrl, t, alpha: float):
    """Position, first and second derivative (per unit parameter) at ``t`` of segments ``ctrl``:
    the cubic from P1 to P2 with the tangents of ``_tangents``."""
    p1, p2 = ctrl[:, 1], ctrl[:, 2]
    m1, m2 = _tangents(ctrl, alpha)
    a, b = p1, m1
    c = 3 * (p2 - p1) - 2 * m1 - m2
    d = 2 * (p1 - p2) + m1 + m2
    a, b, c, d = (x[:, None, :] for x in (a, b, c, d))
    t = t[None, :, None]
    pos = a + b * t + c * t ** 2 + d * t ** 3
    vel = b + 2 * c * t + 3 * d * t ** 2
    acc = 2 * c + 6 * d * t
    return pos, vel, acc


def _segment_samples(ctrl, t, alpha: float, m: int):
    """``(pos [G, m, 2], tangent [G, m, 2], turn [G, m], ds [G, m])`` at parameters ``t: f32[m]`` of
    the G segments whose control points are ``ctrl: f32[G, 4, 2]``; turn and ds per sample (1/m of a
    segment), as ``PathSamples`` holds them."""
    pos, vel, acc = _hermite(ctrl, t, float(alpha))
    speed2 = jnp.sum(vel ** 2, -1)
    cross = vel[..., 0] * acc[..., 1] - vel[..., 1] * acc[..., 0]
    # kappa * ds = cross / |r'|^3 * |r'| dt
    turn = cross / jnp.maximum(speed2, _TINY) / m
    # Double where: exactly 0 on zero-length (padding) segments, with a finite gradient there.
    moving = speed2 > _TINY
    ds = jnp.where(moving, jnp.sqrt(jnp.where(moving, speed2, 1.0)), 0.0) / m
    tangent = vel / jnp.sqrt(jnp.maximum(speed2, _TINY))[..., None]
    return pos, tangent, turn, ds


def sample_route(waypoints, n_points, samples_per_step: int, alpha: float = CENTRIPETAL) -> PathSamples:
    """Sample the spline through ``waypoints[:n_points]`` at the midpoints of ``samples_per_step``
    equal parameter steps per segment.

    waypoints: f32[S, 2] world (x, y), rows past ``n_points`` ignored; n_points: i32[] (>= 1);
    alpha: the knot exponent (static; ``SpillParams.spline_alpha``).
    """
    _check_alpha(alpha, "sample_route: alpha")
    waypoints = jnp.asarray(waypoints, jnp.float32)
    s = waypoints.shape[0]
    m = samples_per_step
    ctrl = _control_points(waypoints, n_points)
    t = (jnp.arange(m, dtype=jnp.float32) + 0.5) / m
    pos, tangent, turn, ds = _segment_samples(ctrl, t, alpha, m)   # [S-1, m, ...]
    segment = jnp.repeat(jnp.arange(s - 1, dtype=jnp.int32), m)
    valid = segment < n_points - 1
    flat = lambda a: a.reshape((-1,) + a.shape[2:])  # noqa: E731
    return PathSamples(flat(pos), flat(tangent), jnp.where(valid, flat(turn), 0.0),
                       jnp.where(valid, flat(ds), 0.0), segment,
                       jnp.tile(jnp.arange(m) == 0, s - 1), valid)


def sample_route_prefix(waypoints, n_points, samples_per_step: int, alpha: float = CENTRIPETAL, *,
                        chunk: int = 32) -> PathSamples:
    """``sample_route``'s samples, computed only for the route's own segments, ``chunk`` at a time.

    waypoints: f32[S, 2] world (x, y); n_points: i32[] (>= 1); samples_per_step, alpha: as in
    ``sample_route``; chunk (static): segments per round. Returns the same ``PathSamples`` (N = (S - 1)
    * samples_per_step): equal to ``sample_route``'s on the valid samples; on the padding samples turn
    and ds are 0 as there, pos and tangent are 0 (``sample_route`` leaves the clipped spline's values
    there, which nothing reads: their spill is 0).

    Why: S comes from a static walk cap (``2 (cap + 1)`` route slots in an episode, 514 on 32 x 32)
    while routes are a few dozen cells, and the spline's per-sample arithmetic over every padding
    slot was most of a push's cost. Here a ``while_loop`` runs ceil((n_points - 1) / chunk) rounds,
    each the same arithmetic on ``chunk`` segments; under ``vmap`` the rounds of the longest route.
    Not reverse-differentiable (a ``while_loop``): the spill fits differentiate ``sample_route``.
    """
    _check_alpha(alpha, "sample_route_prefix: alpha")
    waypoints = jnp.asarray(waypoints, jnp.float32)
    s = waypoints.shape[0]
    m = samples_per_step
    segments = s - 1
    if segments < 1:          # a single waypoint: no segment, nothing to loop over
        return sample_route(waypoints, n_points, samples_per_step, alpha)
    chunk = max(1, min(int(chunk), segments))
    rounds = -(-segments // chunk)
    # control points of every segment (cheap gathers), padded to whole chunks with copies of the last
    ctrl = _control_points(waypoints, n_points)
    ctrl = jnp.concatenate([ctrl, jnp.broadcast_to(ctrl[-1:], (rounds * chunk - segments, 4, 2))], 0)
    t = (jnp.arange(m, dtype=jnp.float32) + 0.5) / m
    planes, points = jnp.zeros((rounds * chunk, m), jnp.float32), jnp.zeros((rounds * chunk, m, 2), jnp.float32)
    start = (jnp.int32(0), points, points, planes, planes)
    valid_segments = jnp.maximum(n_points - 1, 0)

    def more(carry):
        return carry[0] * chunk < valid_segments

    def sample_chunk(carry):
        c, pos_all, tangent_all, turn_all, ds_all = carry
        first = c * chunk
        part = jax.lax.dynamic_slice_in_dim(ctrl, first, chunk, 0)
        pos, tangent, turn, ds = _segment_samples(part, t, alpha, m)   # [chunk, m, ...]
        put = lambda whole, new: jax.lax.dynamic_update_slice_in_dim(whole, new, first, 0)  # noqa: E731
        return c + 1, put(pos_all, pos), put(tangent_all, tangent), put(turn_all, turn), put(ds_all, ds)

    _, pos, tangent, turn, ds = jax.lax.while_loop(more, sample_chunk, start)
    segment = jnp.repeat(jnp.arange(segments, dtype=jnp.int32), m)
    valid = segment < n_points - 1
    flat = lambda a: a[:segments].reshape((-1,) + a.shape[2:])  # noqa: E731
    return PathSamples(jnp.where(valid[:, None], flat(pos), 0.0), jnp.where(valid[:, None], flat(tangent), 0.0),
                       jnp.where(valid, flat(turn), 0.0), jnp.where(valid, flat(ds), 0.0), segment,
                       jnp.tile(jnp.arange(m) == 0, segments), valid)


def pickups_per_sample(samples: PathSamples, waypoint_pickup):
    """``f32[N]``: each waypoint's objects (``waypoint_pickup: f32[S]``) at its segment's first sample."""
    return jnp.where(samples.first & samples.valid, waypoint_pickup[samples.segment], 0.0)


def chord_lengths(samples: PathSamples):
    """f32[N]: distance from the previous sample's position to this one's (0 at the first sample and
    in padding), world units.

    Used instead of ``samples.ds`` where a gradient is taken: ``ds`` comes from ``sqrt(|r'|^2)``, whose
    gradient is NaN on the zero-length padding segments of a route shorter than its slots; the chord
    norm here is guarded.
    """
    d = samples.pos[1:] - samples.pos[:-1]
    d2 = jnp.sum(d * d, -1)
    ok = samples.valid[1:] & samples.valid[:-1] & (d2 > 1e-12)
    chord = jnp.where(ok, jnp.sqrt(jnp.where(ok, d2, 1.0)), 0.0)
    return jnp.concatenate([jnp.zeros((1,), chord.dtype), chord])


def threshold_spill(spill, threshold, temperature):
    """Apply the spill threshold: ``f32[...]`` objects kept of ``spill: f32[...]`` objects.

    temperature: f32[] objects. At 0 the hard rule ``spill if spill >= threshold else 0`` (exact); above
    0 ``spill * sigmoid((spill - threshold) / temperature)``, which tends to the hard rule as
    ``temperature -> 0`` and has finite gradients in ``spill``, ``threshold`` and ``temperature``.
    """
    hard = jnp.where(spill >= threshold, spill, 0.0)
    soft_on = temperature > 0
    # double-where: the soft branch sees a safe temperature when it is not taken, so its gradient
    # (0 * inf otherwise) stays finite at temperature 0
    safe_t = jnp.where(soft_on, temperature, 1.0)
    soft = spill * jax.nn.sigmoid((spill - threshold) / safe_t)
    return jnp.where(soft_on, soft, hard)


Evaluator = Callable[[PathSamples, jax.Array, Any], tuple]


EVALUATORS: dict[str, Evaluator] = {}


def register(model: str, evaluator: Evaluator) -> None:
    """Make ``evaluator`` the spill model named ``model``: the one ``evaluator_for`` returns for
    parameters whose class sets ``model: ClassVar[str] = model``. A new spill model is one module
    (its params class and evaluator) plus this call."""
    EVALUATORS[model] = evaluator


def evaluator_for(params: SpillParams) -> Evaluator:
    """The evaluator of the model ``params`` are for (``type(params).model``), so that parameters of
    one model are never read by another's evaluator (which would ignore their extra fields)."""
    model = getattr(type(params), "model", None)
    if model not in EVALUATORS:
        raise ValueError(f"spill: no spill model registered as {model!r} (for {type(params).__name__}); "
                         f"known models: {sorted(EVALUATORS)}. Register one with "
                         "jaxplan.transport.spillage.register(name, evaluator).")
    return EVALUATORS[model]


def evaluate_route(waypoints, n_points, waypoint_pickup, params: SpillParams,
                   evaluator: Evaluator | None = None, *, chunk: int | None = None):
    """``(delivered f32[], spill f32[N], samples)`` for one route; ``vmap`` it over routes.

    waypoints: f32[S, 2] world units; n_points: i32[]; waypoint_pickup: f32[S] objects collected at
    each waypoint (0 for the final target cell or fallback point and for repeated cells).
    evaluator: the spill model (default: ``evaluator_for(params)``). chunk (static): None samples
    the spline over all S slots (``sample_route``; differentiable); an int samples only the route's
    own segments, that many at a time (``sample_route_prefix``; the same delivered mass and spills,
    for planning with long static route buffers, not for gradients).
    """
    evaluator = evaluator_for(params) if evaluator is None else evaluator
    if chunk is None:
        samples = sample_route(waypoints, n_points, params.samples_per_step, params.spline_alpha)
    else:
        samples = sample_route_prefix(waypoints, n_points, params.samples_per_step, params.spline_alpha, chunk=chunk)
    delivered, spill = evaluator(samples, pickups_per_sample(samples, waypoint_pickup), params)
    return delivered, jnp.where(samples.valid, spill, 0.0), samples
