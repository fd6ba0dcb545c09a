"""A task's footprint (the cells its push can change or drive through) and the rover's path along it.

A route (``execute.Route``) lists its cells c_0 .. c_{n-1}; consecutive cells are 8-neighbours except
for at most one *jump*: a Rearrange route whose connector ends with a straight fallback segment to
the highway anchor. A fallback route also ends with a straight segment from c_{n-1} to the target's
boundary (``route.end``), which the spline, and so the spill, follows.

- **Push path**: the cells the rover drives through while pushing, one per step: the route's cells,
  with the jump (if any) replaced by the cells of a Chebyshev walk along the straight line (cell k
  of a jump of D steps is ``a + round(k (b - a) / D)``, so consecutive path cells are neighbours).
  The rover stops at c_{n-1}; the final fallback segment is pushed without driving it.
- **Core**: the push path's cells plus the cells of the spline's samples (the points ``execute``
  evaluates the spill at: ``spillage.sample_route_prefix`` of the route's waypoints, clipped to the
  grid).
- **Footprint**: the core dilated by one cell (Chebyshev radius 1, clipped to the grid) plus the
  deposit cell (``execute.deposit_cell``). It holds every cell a push changes, by construction: the
  route's cells are emptied (in the core), a sample's spill lands one cell size beside the sample
  (a unit offset moves each coordinate by at most one cell, so into the dilation) or on the route's
  own cell, and the load lands on the deposit cell (``tests/fleet/test_footprint.py`` checks it on
  ``execute``'s real changes). The route's cells dilated by one alone do not suffice: a sharp turn
  next to a long straight segment makes the spline overshoot a cell, and its spill lands two cells
  from the route.

Static sizes: a route of S slots has a push path of ``P = S + max(H, W)`` slots and ``S *
samples_per_step`` spline samples, so a core list of ``P + S samples_per_step`` cells.
"""
from __future__ import annotations

import jax.numpy as jnp

from jaxplan.core import lattice
from jaxplan.transport import execute, spillage

__all__ = ["core_cells", "dilate", "footprint_mask", "mask_from_core", "path_cell", "path_length", "path_slots",
           "push_steps", "route_samples"]


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


def route_samples(scene, route, spill: spillage.SpillParams) -> spillage.PathSamples:
    """The spline samples ``execute`` evaluates the spill at for ``route`` (the same call)."""
    points, n_points = execute.waypoints(scene, route)
    return spillage.sample_route_prefix(points, n_points, spill.samples_per_step, spill.spline_alpha,
                                        chunk=execute.SPLINE_CHUNK)


def core_cells(scene, route, samples: spillage.PathSamples):
    """``(cells i32[C, 2], valid bool[C])``: the footprint's core (module docstring), C = P + the
    samples; invalid rows are -1. Cells may repeat. samples: ``route_samples`` of the route."""
    h, w = scene.shape
    k = jnp.arange(path_slots(route.cells.shape[0], scene.shape), dtype=jnp.int32)
    path_valid = k < path_length(route)
    path = jnp.where(path_valid[:, None], _path_cells(route, k), -1)
    rc = jnp.floor((samples.pos - jnp.asarray(scene.origin, jnp.float32)) / scene.cell_size).astype(jnp.int32)
    on_spline = jnp.stack([jnp.clip(rc[:, 1], 0, h - 1), jnp.clip(rc[:, 0], 0, w - 1)], -1)
    on_spline = jnp.where(samples.valid[:, None], on_spline, -1)
    return jnp.concatenate([path, on_spline]), jnp.concatenate([path_valid, samples.valid])


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


def dilate(mask):
    """bool[H, W]: ``mask`` grown by one cell in all 8 directions (Chebyshev radius 1)."""
    return mask | jnp.any(lattice.neighbours(mask, False), 0)


def mask_from_core(shape, cells, valid, deposit):
    """bool[H, W]: the footprint of a core list (``core_cells``) and a flat deposit cell (i32[])."""
    h, w = shape
    flat = jnp.where(valid, cells[:, 0] * w + cells[:, 1], h * w)
    core = jnp.zeros(h * w + 1, bool).at[flat].set(True)[: h * w].reshape(h, w)
    deposit = (jnp.arange(h * w) == deposit).reshape(h, w)
    return dilate(core) | deposit


def footprint_mask(scene, route, samples: spillage.PathSamples):
    """bool[H, W]: the task's footprint (module docstring); samples: ``route_samples`` of the route."""
    cells, valid = core_cells(scene, route, samples)
    return mask_from_core(scene.shape, cells, valid, execute.deposit_cell(scene, route))
