"""Pushing a route on the grid: collect, carry, spill beside the path, deposit in the target.

Mass bookkeeping (docs/transport.md, "Executing a route"): the route's non-target cells are emptied
(each cell once), every spline sample's spill is dropped one cell size to the *outside* of the turn
(or, if that point is off the grid, in the target or on a blocked cell, back on the cell the sample's
segment leaves, a free route cell; also where the sample turns by less than ``STRAIGHT_TURN``),
and the rest, ``delivered = collected - sum(spill)``, is added to one target cell: the cell the route
enters, or for a fallback route the target cell nearest to its boundary point. The grid's total mass
is therefore unchanged up to float rounding.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.core import grid_jit
from jaxplan.transport import spillage
from jaxplan.transport.fabric import Paths

# Counts written by a push are multiples of QUANTUM objects. Sums of such numbers are exact in
# float32 (up to 2**14 objects per path), so every solver order gives bit-identical tables and the
# selective rebuild equals a from-scratch build exactly.
QUANTUM = 2.0 ** -10

# Spline segments sampled per round when a route is evaluated (``spillage.sample_route_prefix``):
# route buffers are as long as the static walk cap allows (2 (cap + 1) slots in an episode), routes
# a few dozen cells, so the spline is sampled over the route's own segments only, this many at a time.
SPLINE_CHUNK = 32

# Samples turning less than this (radians) count as straight: their spill lands on the route's own
# cell. On a straight segment the spline's turn is rounding noise whose sign, and so the side a
# spill would land on, changes with how the program was compiled.
STRAIGHT_TURN = 1e-4


@grid_jit
def quantize(obj):
    """Round counts to multiples of ``QUANTUM`` objects (``f32[...]``)."""
    return jnp.round(jnp.asarray(obj, jnp.float32) / QUANTUM) * QUANTUM


class Route(NamedTuple):
    """One route to push. S cell slots.

    cells: i32[S, 2], (row, col) of the source, then every cell entered (a final target cell
      included); padded with -1.  n_cells: i32[], valid rows.
    fallback: bool[], the route ends with a straight segment from its last cell to the boundary.
    end: f32[2], world (x, y) where the load is delivered: the fallback point on the boundary, or the
      centre of the final target cell.
    """

    cells: jax.Array
    n_cells: jax.Array
    fallback: jax.Array
    end: jax.Array


class Push(NamedTuple):
    """What executing one route did (objects; world units for lengths).

    collected: f32[], picked up from the route's cells.  spilled: f32[], dropped beside the route.
    delivered: f32[], added to the target (= collected - spilled; spills are rounded to ``QUANTUM``).
    length: f32[], spline length.
    changed: bool[H, W], non-target cells whose count changed (A_exec of Eq. 13).
    samples: spillage.PathSamples of the pushed spline (``sample_route_prefix``: padding samples
      are zero); spill: f32[N] per sample.
    """

    collected: jax.Array
    spilled: jax.Array
    delivered: jax.Array
    length: jax.Array
    changed: jax.Array
    samples: spillage.PathSamples
    spill: jax.Array


def _cell_of(scene, pos):
    """``(row, col, inside)`` of the cell containing world point ``pos: f32[..., 2]``."""
    h, w = scene.shape
    rc = jnp.floor((pos - jnp.asarray(scene.origin, jnp.float32)) / scene.cell_size).astype(jnp.int32)
    col, row = rc[..., 0], rc[..., 1]
    inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
    return jnp.clip(row, 0, h - 1), jnp.clip(col, 0, w - 1), inside


def route_from_path(scene, cells, n_cells, fallback) -> Route:
    """A ``Route`` from one row of ``fabric.Paths`` (``cells: i32[S, 2]``)."""
    last = cells[jnp.maximum(n_cells - 1, 0)]
    centre = scene.cell_centers()[last[0], last[1]]
    boundary = centre + scene.tvec[last[0], last[1]] * scene.dist[last[0], last[1]]
    return Route(cells, n_cells, fallback, jnp.where(fallback, boundary, centre))


@grid_jit
def routes_from_paths(scene, paths: Paths) -> Route:
    """Batched ``route_from_path`` over the rows of ``paths`` (leading axis B). Jitted: run op by op,
    its dozen small operations would each compile (and keep resident) a program of their own."""
    return jax.vmap(lambda c, n, f: route_from_path(scene, c, n, f))(paths.cells, paths.n_cells, paths.fallback)


def waypoints(scene, route: Route):
    """``(points f32[S+1, 2], n_points i32[])``: cell centres, then the fallback point if any."""
    s = route.cells.shape[0]
    safe = jnp.maximum(route.cells, 0)
    centres = scene.cell_centers()[safe[:, 0], safe[:, 1]]
    points = jnp.concatenate([centres, centres[-1:]], 0)
    slot = jnp.arange(s + 1)
    points = jnp.where((slot == route.n_cells)[:, None] & route.fallback, route.end[None], points)
    return points, route.n_cells + route.fallback.astype(jnp.int32)


def _first_visit(cells, n_cells, shape):
    """``bool[S]``: valid rows whose cell does not appear in an earlier row (walks may revisit).

    cells: i32[S, 2] (row, col), the first ``n_cells`` rows valid (the padding after them is not
    read); shape: (H, W). Each cell's earliest row is found by one scatter-min over the grid, O(S +
    H W): the pairwise test of every row against every earlier one was O(S^2), which at the walk
    caps of a batch (S = 2 (cap + 1) = 514 route slots for routes of 20-odd cells) cost more than
    the rest of the push.
    """
    s = cells.shape[0]
    h, w = shape
    rows = jnp.arange(s, dtype=jnp.int32)
    valid = rows < n_cells
    safe = jnp.maximum(cells, 0)
    flat = jnp.where(valid, safe[:, 0] * w + safe[:, 1], h * w)     # padding rows go to a spare slot
    earliest = jnp.full(h * w + 1, s, jnp.int32).at[flat].min(rows)
    return valid & (earliest[flat] == rows)


def waypoint_pickup(scene, route: Route):
    """``f32[S+1]`` objects collected at each waypoint: non-target route cells, each cell once."""
    safe = jnp.maximum(route.cells, 0)
    obj = scene.obj[safe[:, 0], safe[:, 1]]
    collect = _first_visit(route.cells, route.n_cells, scene.shape) & ~scene.target_mask[safe[:, 0], safe[:, 1]]
    return jnp.append(jnp.where(collect, obj, 0.0), 0.0), collect


def spill_cells(scene, route: Route, samples: spillage.PathSamples):
    """i32[N]: flat index of the cell each sample's spill lands on (see the module docstring): one
    cell size to the outside of the turn, or the cell the sample's segment leaves. Depends on the
    route's geometry only, not on the counts."""
    h, w = scene.shape
    left = jnp.stack([-samples.tangent[:, 1], samples.tangent[:, 0]], -1)
    outside = -jnp.sign(samples.turn)[:, None] * left
    r, c, inside = _cell_of(scene, samples.pos + outside * scene.cell_size)
    ok = inside & ~scene.target_mask[r, c] & ~scene.blocked[r, c] & (jnp.abs(samples.turn) > STRAIGHT_TURN)
    own = jnp.maximum(route.cells[jnp.clip(samples.segment, 0, route.cells.shape[0] - 1)], 0)
    return jnp.where(ok, r * w + c, own[:, 0] * w + own[:, 1])


def deposit_cell(scene, route: Route):
    """i32[]: flat index (row * W + col) of the target cell that receives the delivered load: the
    route's last cell, or for a fallback route the target cell whose centre is nearest to ``route.end``."""
    h, w = scene.shape
    last = jnp.maximum(route.cells[jnp.maximum(route.n_cells - 1, 0)], 0)
    d2 = jnp.sum((scene.cell_centers() - route.end) ** 2, -1)
    nearest = jnp.argmin(jnp.where(scene.target_mask, d2, jnp.inf).reshape(-1))
    return jnp.where(route.fallback, nearest, last[0] * w + last[1])


def execute_push(scene, route: Route, spill: spillage.SpillParams,
                 evaluator: spillage.Evaluator = spillage.curvature_spill):
    """Push ``route`` on ``scene``: ``(obj f32[H, W] after the push, Push)``. Jit-compatible.

    spill: ``SpillParams`` (``lam = 0`` pushes without losses); evaluator: the ``Spill(P; Theta)``
    function (``spillage`` module docstring).
    """
    h, w = scene.shape
    obj = jnp.asarray(scene.obj, jnp.float32)
    points, n_points = waypoints(scene, route)
    pickup, collect = waypoint_pickup(scene, route)
    _, spill_per_sample, samples = spillage.evaluate_route(points, n_points, pickup, spill, evaluator,
                                                           chunk=SPLINE_CHUNK)
    spill_per_sample = quantize(spill_per_sample)
    safe = jnp.maximum(route.cells, 0)
    flat_route = safe[:, 0] * w + safe[:, 1]
    collected = jnp.sum(pickup)
    spilled = jnp.sum(spill_per_sample)
    delivered = collected - spilled
    flat = obj.reshape(-1)
    emptied = jnp.zeros(h * w, bool).at[flat_route].max(collect)   # max: padding rows must not undo
    flat = jnp.where(emptied, 0.0, flat)
    flat = flat.at[spill_cells(scene, route, samples)].add(spill_per_sample)
    flat = flat.at[deposit_cell(scene, route)].add(delivered)
    new_obj = flat.reshape(h, w)
    changed = (new_obj != obj) & ~scene.target_mask
    return new_obj, Push(collected, spilled, delivered, jnp.sum(samples.ds), changed, samples, spill_per_sample)


execute_jit = grid_jit(execute_push, static_argnums=3)
