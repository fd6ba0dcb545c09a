"""A task's footprint (the cells its push can change or drive through) and the rover's path along it.

A route (``execute.Route``) lists its cells c_0 .. c_{n-1}; consecutive cells are 8-neighbours except
for at most one *jump*: a Rearrange route whose connector ends with a straight fallback segment to
the highway anchor. A fallback route also ends with a straight segment from c_{n-1} to the target's
boundary (``route.end``), which the spline, and so the spill, follows.

- **Push path**: the cells the rover drives through while pushing, one per step: the route's cells,
  with the jump (if any) replaced by the cells of a Chebyshev walk along the straight line (cell k
  of a jump of D steps is ``a + round(k (b - a) / D)``, so consecutive path cells are neighbours).
  The rover stops at c_{n-1}; the final fallback segment is pushed without driving it.
- **Footprint** with clearance r (``FleetConfig.clearance``, 0 or 1): a *core* of cells grown by r
  cells (Chebyshev), without target cells, plus the push path's own cells (target cells included:
  the rover drives there).
  - r = 0: the core is the push path and the cell each spline sample's spill lands on
    (``execute.spill_cells``: one cell size beside the sample, outside the targets, or the route's
    own cell). These are exactly the cells a push can change outside the targets, whatever the
    counts, so the footprint is the route's cells plus the cells its spill can reach.
  - r = 1: the core is the push path and the cells of the spline's samples; grown by one cell, it
    holds the r = 0 footprint (a spill lands within one cell of its sample) and keeps one cell of
    clearance around every route. The route's cells grown by one alone would not: a sharp turn next
    to a long straight segment makes the spline overshoot a cell, and its spill lands two cells
    from the route.
  - r = 2 (**body**): the cells the rover's body passes over, target cells included: the push
    path, the spline's samples, the points up to ``BODY_BEHIND`` cells behind the spline's start
    (where the physical rover starts) and up to
    ``BODY_AHEAD`` cells past its end (the shovel rover of ``transport.physics.model`` drives its blade
    past the route's end), all grown by one cell (the blade is one cell wide). It holds the r = 1
    footprint's cells outside the targets; it is what two rovers need so that their bodies never
    touch in physics (``jaxplan.fleet.physics``), at the price of serialising pushes into a target
    from nearby directions.
  ``tests/fleet/test_footprint.py`` checks r = 0 and r = 1 on ``execute``'s real changes. Target cells are only
  ever added to (the delivered load, on ``execute.deposit_cell``), never collected, so pushes that
  deposit on the same target cell commute: footprints reserve no target cell the rover does not
  drive on (reserving the margin inside a small target serialised every push into it).

Static sizes: a route of S slots has a push path of ``P = S + max(H, W)`` slots and ``S *
samples_per_step`` spline samples, so a core list of ``C = P + S samples_per_step`` cells (the
first P rows are the path), and ``BODY_POINTS`` more for r = 2.
"""
from __future__ import annotations

import jax.numpy as jnp

from jaxplan.core import lattice
from jaxplan.transport import SPLINE_CHUNK, spill_cells, waypoints
from jaxplan.transport.spillage import PathSamples, SpillParams, sample_route_prefix

__all__ = ["CLEARANCES", "core_cells", "dilate", "footprint_mask", "mask_from_core", "path_cell", "path_length",
           "path_slots", "push_steps", "route_samples"]

CLEARANCES = (0, 1, 2)
"""Allowed clearances: cells around a route reserved beyond the cells its push changes (2: the
rover's body, module docstring)."""
BODY = 2
BODY_BEHIND = 2.75
"""Cells the rover reaches behind its route's first point: the bridge starts it with the side plates'
tips a gap behind the source (``bridge.route_path``), so its back stands about 2.5 cells behind."""
BODY_AHEAD = 2.5
"""Cells the rover reaches past its route's end: the bridge's push-in (1 cell), axle to blade (0.44)
and the side plates (0.98), rounded up."""
_BODY_STEP = 0.25
BODY_POINTS = 1 + int(BODY_BEHIND / _BODY_STEP) + int(BODY_AHEAD / _BODY_STEP)


def path_slots(route_slots: int, shape) -> int:
    """``P``: slots of a push path for routes of ``route_slots`` slots on a grid of ``shape``."""
    return int(route_slots) + max(int(shape[0]), int(shape[1]))


def _jump(route):
    """``(j i32[], d i32[])``: the hop j -> j+1 that is not a single step (j = -1 and d = 1 when every
    hop is one) and its Chebyshev length d."""
    cells = route.cells
    hop = jnp.max(jnp.abs(cells[1:] - cells[:-1]), -1)
    hop = jnp.where(jnp.arange(hop.shape[0]) < route.n_cells - 1, hop, 1)
    far = hop > 1
    j = jnp.where(jnp.any(far), jnp.argmax(far), -1).astype(jnp.int32)
    return j, jnp.where(j >= 0, hop[jnp.maximum(j, 0)], 1).astype(jnp.int32)


def path_length(route):
    """i32[]: cells of the push path (the route's cells, a jump of d steps adding d - 1)."""
    _, d = _jump(route)
    return (route.n_cells + d - 1).astype(jnp.int32)


def push_steps(route):
    """i32[]: steps a push takes once the rover stands on c_0: one per path step, at least one."""
    return jnp.maximum(path_length(route) - 1, 1)


def path_cell(route, k):
    """i32[2]: cell ``k`` (i32[], 0 = c_0) of the push path, clamped to its last cell."""
    return _path_cells(route, jnp.asarray(k, jnp.int32)[None])[0]


def route_samples(scene, route, spill: SpillParams) -> PathSamples:
    """The spline samples ``execute`` evaluates the spill at for ``route`` (the same call)."""
    points, n_points = waypoints(scene, route)
    return sample_route_prefix(points, n_points, spill.samples_per_step, spill.spline_alpha,
                               chunk=SPLINE_CHUNK)


def core_cells(scene, route, samples: PathSamples, clearance: int = 1):
    """``(cells i32[C, 2], valid bool[C], on_path bool[C])``: the footprint's core for a static
    ``clearance`` (module docstring), invalid rows -1; on_path marks the push path's cells. Cells may
    repeat. samples: ``route_samples`` of the route."""
    h, w = scene.shape
    k = jnp.arange(path_slots(route.cells.shape[0], scene.shape), dtype=jnp.int32)
    path_valid = k < path_length(route)
    path = jnp.where(path_valid[:, None], _path_cells(route, k), -1)
    if clearance == 0:
        flat = spill_cells(scene, route, samples)
        beside = jnp.stack([flat // w, flat % w], -1).astype(jnp.int32)
    else:
        beside = _cells_of(scene, samples.pos)
    beside = jnp.where(samples.valid[:, None], beside, -1)
    on_path = jnp.concatenate([path_valid, jnp.zeros_like(samples.valid)])
    cells, valid = jnp.concatenate([path, beside]), jnp.concatenate([path_valid, samples.valid])
    if clearance == BODY:
        body, body_valid = _body_points(samples, scene.cell_size)
        cells = jnp.concatenate([cells, jnp.where(body_valid[:, None], _cells_of(scene, body), -1)])
        valid = jnp.concatenate([valid, body_valid])
        on_path = jnp.concatenate([on_path, jnp.zeros_like(body_valid)])
    return cells, valid, on_path


def _cells_of(scene, points):
    """i32[K, 2]: the (row, col) of world ``points: f32[K, 2]``, clipped to the grid."""
    h, w = scene.shape
    rc = jnp.floor((points - jnp.asarray(scene.origin, jnp.float32)) / scene.cell_size).astype(jnp.int32)
    return jnp.stack([jnp.clip(rc[:, 1], 0, h - 1), jnp.clip(rc[:, 0], 0, w - 1)], -1)


def _body_points(samples: PathSamples, cell_size):
    """``(points f32[BODY_POINTS, 2], valid bool[BODY_POINTS])``: world points of the rover's body
    beyond the spline: its back behind the first sample, and its blade and side plates past the last,
    ``_BODY_STEP`` cells apart (module docstring)."""
    n = samples.valid.shape[0]
    last = jnp.clip(jnp.sum(samples.valid) - 1, 0, n - 1)
    any_ = jnp.any(samples.valid)
    back = _BODY_STEP * jnp.arange(int(BODY_BEHIND / _BODY_STEP) + 1, dtype=jnp.float32)
    ahead = _BODY_STEP * jnp.arange(1, int(BODY_AHEAD / _BODY_STEP) + 1, dtype=jnp.float32)
    behind = samples.pos[0] - cell_size * back[:, None] * samples.tangent[0]
    tail = samples.pos[last] + cell_size * ahead[:, None] * samples.tangent[last]
    return jnp.concatenate([behind, tail]), jnp.full(BODY_POINTS, any_)


def _path_cells(route, k):
    """i32[P, 2]: push-path cells at indices ``k: i32[P]`` (vectorised ``path_cell``)."""
    j, d = _jump(route)
    n = path_length(route)
    kk = jnp.clip(k, 0, n - 1)
    cells = route.cells
    s = cells.shape[0]
    a, b = cells[jnp.maximum(j, 0)], cells[jnp.clip(j + 1, 0, s - 1)]
    i = (kk - j)[:, None]
    inside = a[None] + jnp.floor_divide(2 * i * (b - a)[None] + d, 2 * d)
    after = cells[jnp.clip(kk - d + 1, 0, s - 1)]
    before = cells[jnp.clip(kk, 0, s - 1)]
    pick = jnp.where(((j < 0) | (kk <= j))[:, None], before, jnp.where((kk < j + d)[:, None], inside, after))
    return pick.astype(jnp.int32)


def dilate(mask, radius: int = 1):
    """bool[H, W]: ``mask`` grown by ``radius`` (static, 0 or 1) cells in all 8 directions (Chebyshev)."""
    if radius == 0:
        return mask
    return mask | jnp.any(lattice.neighbours(mask, False), 0)


def _mark(shape, cells, valid):
    h, w = shape
    flat = jnp.where(valid, cells[:, 0] * w + cells[:, 1], h * w)
    return jnp.zeros(h * w + 1, bool).at[flat].set(True)[: h * w].reshape(h, w)


def mask_from_core(target_mask, cells, valid, on_path, clearance: int = 1):
    """bool[H, W]: the footprint of a core list (``core_cells``) on a grid with ``target_mask``."""
    core = _mark(target_mask.shape, cells, valid)
    if clearance == BODY:
        return dilate(core, 1)
    return (dilate(core, clearance) & ~target_mask) | _mark(target_mask.shape, cells, valid & on_path)


def footprint_mask(scene, route, samples: PathSamples, clearance: int = 1):
    """bool[H, W]: the task's footprint (module docstring); samples: ``route_samples`` of the route."""
    return mask_from_core(scene.target_mask, *core_cells(scene, route, samples, clearance), clearance)
