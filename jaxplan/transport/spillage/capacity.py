"""A capacity-aware spill evaluator: the blade holds at most ``capacity`` objects.

The curvature model of :mod:`jaxplan.transport.spillage` removes a fraction of the load per radian of
turning, so its delivered mass scales with the collected mass. The shovel rover in physics does not
behave like that: a one-cell blade carries a roughly fixed amount whatever it collects (see
docs/transport.md, "The capacity-aware model"). This evaluator adds that limit, a loss per unit of
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

The two turning terms come from the physics (docs/transport.md, "The capacity-aware model"): where the
path turns at a cell, the spline cuts the cell's corner and the blade leaves the outer part of it
behind (``miss``, a fraction of the cell's objects per radian), and a turn spills the pile's edge
over the side plates, an amount that grows with the load only while the pile is small
(``turn_saturation``: with ``S`` infinite, the default, ``turn_frac = lam |turn|`` as before; with
``S`` finite a full blade loses about ``lam * S`` objects per radian). The missed objects are part of
the sample's spill: they stay on the grid (``execute`` drops them beside the path there), so
delivered + spilled = collected still holds. With ``miss = 0`` and ``turn_saturation = inf`` the
evaluator is the three-term model (capacity, turning, distance) exactly.

It plugs into the pipeline as any evaluator: pass ``CapacitySpillParams`` where a ``SpillParams`` is
expected (it is one: a subclass with five more traced fields) and ``capacity_spill`` as the
``evaluator`` (``execute.execute_push``, ``selection.select_routes``, ``episode.run_episode``,
``spillage.evaluate_route``). Parameters are traced pytree leaves: ``jax.grad`` and ``jax.vmap`` go
through them (fit them with optax, vmap over parameter sets).
"""
from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.transport.spillage import base as spillage

__all__ = ["ROVER_FIT", "CapacitySpillParams", "capacity_spill",
           "missed_objects", "turning_near_pickups", "validate_capacity_params"]


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

    model: ClassVar[str] = "capacity"
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


# The in-sample fit of ``experiments/bench_rover.py`` (``experiments/results/rover.md``).
# It describes the default rover (``RoverConfig()``: CG solver, one-cell shovel with one-cell side
# plates, 0.8 cell/s, the blade pushed one cell past the route's end); another rover needs its own fit.
# ``tests/transport/test_spill_capacity.py`` holds it equal to that results file. mu is ~1e-8 there: 0.
ROVER_FIT = CapacitySpillParams(capacity=96.84, lam=0.1548, mu=0.0, temperature=0.5, miss=0.18,
                                turn_saturation=1.59)


def validate_capacity_params(params: CapacitySpillParams) -> None:
    """Raise ``ValueError`` naming the field for out-of-range concrete parameters."""
    if not isinstance(params, CapacitySpillParams):
        raise ValueError(f"capacity_spill: expected a CapacitySpillParams, got {type(params).__name__}. "
                         "Build one with jaxplan.transport.spillage.capacity.CapacitySpillParams(capacity=10.0).")
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


def capacity_spill(samples: spillage.PathSamples, pickup, params: CapacitySpillParams):
    """``(delivered f32[], spill f32[N])`` in objects: blade capacity + curvature + distance losses.

    samples: the route's spline samples (``spillage.sample_route``); pickup: f32[N] objects picked
    up at each sample. A sequential scan because the load at a sample depends on what spilled before.
    """
    missed = missed_objects(samples, pickup, params.miss, params.samples_per_step)
    turn = jnp.abs(samples.turn)
    dist_frac = jnp.clip(params.mu * spillage.chord_lengths(samples), 0.0, 1.0)
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


spillage.register("capacity", capacity_spill)
