"""Rover motion: approach distance fields and the prioritised one-step move (docs/fleet.md, "Motion").

- **Distance field** of one rover: the number of 8-connected steps from every cell to its task's
  start c_0 through the cells it may drive on (``passable``: not in another rover's footprint, not
  an idle rover's cell), by breadth-first relaxation in a ``lax.while_loop`` (one round lowers every
  cell to 1 + its smallest neighbour; it stops when a round changes nothing, after at most the
  longest shortest path + 1 rounds). ``FAR`` marks cells that cannot reach c_0. ``distance_fields``
  vmaps it over rovers.
- **Early stop** (``distance_field_to``): with unit steps, after k rounds every cell at distance
  <= k holds its exact distance and every other cell holds ``FAR``. A rover only ever moves to a
  neighbour whose value is strictly smaller than its own cell's, so its field only has to be *exact*
  (equal to ``distance_field``) on the cells at distance <= d* = the distance of the rover's own
  cell: the relaxation stops after round d*, as soon as the rover's cell is reached. Every cell
  at distance <= d* is then exact and every other cell is ``FAR``; in such a field any walk through
  strictly smaller neighbours from a cell of value v reaches c_0 in exactly v steps (a smaller
  neighbour is exact, so it is at v - 1). When the rover's cell cannot reach c_0 no round reaches
  it: the loop runs until nothing changes and the field equals ``distance_field`` (``FAR`` at the
  rover's cell). It costs d* + 1 rounds instead of the longest shortest path + 1, each round on a
  padded flat layout (``lattice.pad_flat``) with the 3 x 3 minimum taken as a column minimum, then a
  row minimum of that: four slices, no per-direction pad.
- **Blocked cells** are never passable, and on a site with blocked cells (``corner``, the scene's
  ``transport.corner_free``) a diagonal step may not cut a blocked cell's corner: the fields then
  take the minimum over the 8 neighbours one direction at a time, masked by the corner rule, and
  ``move_rovers`` never takes such a step.
- **Field update** (``update_fields``): only the stale rows are recomputed (early stop, at their
  rovers' cells), ``chunk`` rows at a time (vmapped; a chunk runs until its last row is done), so the
  cost grows with the number of stale rows and is nothing when none is stale. A row's passable mask
  may be given as a function of the row, so that no N x H x W mask is built.
- **Approach distance** (``approach_distance``): a rover with no field of its own drives by the
  Chebyshev distance to its goal, the exact step count on a grid with nothing in the way, computed
  for the cells it looks at and stored nowhere. Only a rover that waited ``PATIENCE`` steps in a
  row (a footprint, a parked rover or a building in the way) gets a breadth-first field over the
  cells it may drive on now, in one of R slots of a ``FieldPool``: the planning cost of a step
  grows with the rovers that are stuck, not with the fleet, and a reservation anywhere else
  outdates no rover's field.
- **One step** (``move_rovers``): rovers move one after another, lowest index first (priority). A
  rover that is not pushing (approaching its task's start, or idle and driving back to its home
  cell) moves to the neighbour with the smallest distance that is strictly smaller than its own
  cell's (ties: the first in ``lattice.DIRS`` order) among the *free* neighbours: in the grid, not
  in another rover's footprint, and not held by any rover now (a rover that moved earlier this step
  holds its new cell and has freed its old one); the distance is its pool field's when it holds a
  slot, else the Chebyshev distance. If none is free and closer, it waits. A pushing rover moves to
  the next cell of its push path if that cell is free, else waits.

No two rovers share a cell after a step (each move goes to a cell no rover holds), and no two swap:
a rover moves into a cell another rover held at the start of the step only after that rover left
it, and that rover could not have entered the mover's cell, which the mover still held.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.core import lattice

__all__ = ["APPROACH", "FAR", "IDLE", "PATIENCE", "PUSH", "FieldPool", "approach_distance", "distance_field",
           "distance_field_to", "distance_fields", "empty_pool", "move_rovers", "update_fields"]

FAR = 2 ** 30
"""Distance of a cell that cannot reach the goal (an int32 that one more step does not overflow)."""

IDLE, APPROACH, PUSH = 0, 1, 2
"""Rover phases: no task, driving to the task's start, pushing along its route."""

PATIENCE = 3
"""Steps in a row a driving rover waits before it gets a field of its own (module docstring)."""


class FieldPool(NamedTuple):
    """R breadth-first fields for the rovers that got stuck (module docstring, "Approach distance").

    dist: i32[R, H, W] steps to the slot's goal over the cells its rover could drive on when it was
    computed (``FAR``: cannot reach); goal: i32[R, 2] (row, col); rover: i32[R] the rover holding
    the slot (-1: free).
    """

    dist: jax.Array
    goal: jax.Array
    rover: jax.Array


def empty_pool(slots: int, shape) -> FieldPool:
    """A ``FieldPool`` of ``slots`` free slots on a grid of ``shape``."""
    return FieldPool(jnp.full((slots,) + tuple(shape), FAR, jnp.int32), jnp.zeros((slots, 2), jnp.int32),
                     jnp.full(slots, -1, jnp.int32))


def approach_distance(cells, goal):
    """i32[...]: Chebyshev steps from ``cells: i32[..., 2]`` to ``goal: i32[2]`` (row, col)."""
    return jnp.max(jnp.abs(cells - goal), -1).astype(jnp.int32)


def distance_field(goal, passable, corner=None):
    """i32[H, W]: 8-connected steps from every cell to ``goal: i32[2]`` through ``passable: bool[H, W]``
    cells; ``FAR`` for impassable cells, cells that cannot reach the goal, and everywhere when the
    goal itself is not passable. corner: optional bool[8, H, W], the steps that cut no blocked
    corner (``transport.corner_free``)."""
    h, w = passable.shape
    rows, cols = jnp.meshgrid(jnp.arange(h), jnp.arange(w), indexing="ij")
    start = jnp.where((rows == goal[0]) & (cols == goal[1]) & passable, 0, FAR).astype(jnp.int32)

    def relax(carry):
        d, _ = carry
        near = lattice.neighbours(d, FAR)
        nearest = jnp.min(near if corner is None else jnp.where(corner, near, FAR), 0)
        new = jnp.where(passable, jnp.minimum(d, jnp.minimum(nearest, FAR - 1) + 1), FAR)
        return new, jnp.any(new != d)

    d, _ = jax.lax.while_loop(lambda carry: carry[1], relax, (start, jnp.bool_(True)))
    return d


distance_fields = jax.vmap(distance_field)
"""i32[N, H, W]: ``distance_field`` for ``goals: i32[N, 2]`` and ``passable: bool[N, H, W]``."""


def _relax_flat(d, open_rows, width, corner_rows=None):
    """One relaxation round on ``lattice.pad_flat``'s layout: ``(d, changed)``.

    d: i32[(H + 2) * (W + 2)] distances, ``FAR`` on the border; open_rows: bool[H * (W + 2) - 2]
    passable cells in the rows layout (``lattice.padded_rows``; False on its border positions, which
    so stay ``FAR``); width: W. The 3 x 3 minimum is separable: a column minimum over the rows above
    and below, then a row minimum of that (a cell's own value is in it: min(d, d + 1) = d).
    corner_rows: optional bool[8, H * (W + 2) - 2], the corner rule in the rows layout: then the
    minimum is taken direction by direction, each neighbour masked by it.
    """
    stride = width + 2
    n = d.shape[0]
    old = d[stride + 1:n - stride - 1]
    if corner_rows is None:
        column = jnp.minimum(jnp.minimum(d[:n - 2 * stride], d[stride:n - stride]), d[2 * stride:])
        block = jnp.minimum(jnp.minimum(column[:-2], column[1:-1]), column[2:])
    else:
        block = old
        for k, (dr, dc) in enumerate(lattice.DIRS):
            start = stride + 1 + dr * stride + dc
            block = jnp.minimum(block, jnp.where(corner_rows[k], d[start:start + old.shape[0]], FAR))
    new = jnp.where(open_rows, jnp.minimum(old, block + 1), FAR)        # FAR + 1 still fits an int32
    return jnp.concatenate([d[:stride + 1], new, d[n - stride - 1:]]), jnp.any(new != old)


def distance_field_to(goal, passable, stop_at, corner=None):
    """i32[H, W]: ``distance_field`` stopped once the cell ``stop_at: i32[2]`` is reached (module
    docstring, "Early stop").

    goal: i32[2] (row, col); passable: bool[H, W]; stop_at: i32[2], a cell of the grid. With d* the
    distance of ``stop_at``: every cell at distance <= d* holds its exact distance (as
    ``distance_field``), every other cell holds ``FAR``. When ``stop_at`` cannot reach the goal (or
    the goal is not passable) the result equals ``distance_field``. Costs d* + 1 rounds.
    corner: optional bool[8, H, W] (``distance_field``).
    """
    h, w = passable.shape
    stride = w + 2
    open_rows = lattice.pad_flat(passable, False)[stride + 1:(h + 1) * stride - 1]
    corner_rows = None if corner is None else jnp.stack(
        [lattice.padded_rows(lattice.pad_flat(c, False), 0, 0, (h, w)) for c in corner])
    goal_open = passable[goal[0], goal[1]]
    start = jnp.full((h + 2) * stride, FAR, jnp.int32).at[(goal[0] + 1) * stride + goal[1] + 1].set(
        jnp.where(goal_open, 0, FAR))
    stop = (stop_at[0] + 1) * stride + stop_at[1] + 1

    def going(carry):
        d, changed = carry
        return changed & (d[stop] >= FAR)

    # An impassable goal leaves everything FAR: no round at all.
    d, _ = jax.lax.while_loop(going, lambda carry: _relax_flat(carry[0], open_rows, w, corner_rows),
                              (start, goal_open))
    return d.reshape(h + 2, stride)[1:-1, 1:-1]


def update_fields(dist, goals, passable, pos, stale, *, chunk=8, corner=None, use_corner=None):
    """i32[N, H, W]: the stale rovers' fields recomputed (``distance_field_to`` toward their goals,
    stopped at their own cells), every other row of ``dist`` unchanged.

    dist: i32[N, H, W] the current fields; goals: i32[N, 2]; passable: bool[N, H, W] (read only for
    stale rows), or a function of a row index (i32[]) giving that row's bool[H, W], built only for
    the stale rows; pos: i32[N, 2] rover cells; stale: bool[N]; chunk: rows per batch (static).
    corner: optional bool[8, H, W] shared by all rovers (``distance_field``); use_corner: optional
    bool[], apply it only when True (the separable minimum is cheaper, and a grid without blocked
    cells needs no corner rule): decided chunk by chunk, so that ``dist`` is never copied.
    The stale rovers are gathered in index order and run ``chunk`` at a time in a ``lax.while_loop``
    over ceil(#stale / chunk) chunks, each chunk vmapped (it runs as many rounds as its slowest rover
    needs; a finished rover's field is held), so nothing runs when no rover is stale.
    """
    n = stale.shape[0]
    chunk = max(1, min(chunk, n))
    rows = jnp.nonzero(stale, size=-(-n // chunk) * chunk, fill_value=n)[0].astype(jnp.int32).reshape(-1, chunk)
    chunks = (jnp.sum(stale, dtype=jnp.int32) + chunk - 1) // chunk
    fields_to = jax.vmap(lambda g, p, s, c: distance_field_to(g, p, s, c), in_axes=(0, 0, 0, None))

    def chunk_fields(goals, masks, stops):
        if corner is None or use_corner is None:
            return fields_to(goals, masks, stops, corner)
        return jax.lax.cond(use_corner, lambda: fields_to(goals, masks, stops, corner),
                            lambda: fields_to(goals, masks, stops, None))

    def one_chunk(carry):
        k, dist = carry
        rover = rows[k]
        real = rover < n                      # the last chunk is filled up with index n
        take = jnp.where(real, rover, 0)
        # A filler lane gets no passable cell, so it runs no round; its row n is dropped.
        mask = jax.vmap(passable)(take) if callable(passable) else passable[take]
        fields = chunk_fields(goals[take], mask & real[:, None, None], pos[take])
        return k + 1, dist.at[rover].set(fields, mode="drop")

    return jax.lax.while_loop(lambda carry: carry[0] < chunks, one_chunk, (jnp.int32(0), dist))[1]


def move_rovers(pos, phase, goal, slot, pool_dist, owner, push_next, blocked=None, corner=None):
    """One step of every rover, in index order (module docstring): ``(pos i32[N, 2], moved bool[N])``.

    pos: i32[N, 2] (row, col), distinct cells; phase: i32[N] (``IDLE``, ``APPROACH``, ``PUSH``);
    goal: i32[N, 2] each rover's goal (read for rovers not pushing); slot: i32[N] its ``FieldPool``
    slot (-1: it drives by ``approach_distance``); pool_dist: i32[R, H, W] the pool's fields;
    owner: i32[H, W] footprint owner (-1 none); push_next: i32[N, 2] the next push-path cell of
    pushing rovers (their own cell when the path is done); blocked: optional bool[H, W], cells no
    rover enters; corner: optional bool[8, H, W], the steps that cut no blocked corner.
    """
    n = pos.shape[0]
    h, w = owner.shape
    dirs = jnp.asarray(lattice.DIRS_ARRAY)
    flat = pos[:, 0] * w + pos[:, 1]
    held = jnp.full(h * w, -1, jnp.int32).at[flat].set(jnp.arange(n, dtype=jnp.int32))
    fields = pool_dist.reshape(pool_dist.shape[0], -1)
    owners = owner.reshape(-1)
    # a blocked cell counts as another rover's footprint: no rover enters it
    if blocked is not None:
        owners = jnp.where(blocked.reshape(-1), n, owners)

    def distance(r, cells, cells_flat):
        """i32[...]: rover r's distance to its goal at ``cells`` (i32[..., 2], flat ``cells_flat``)."""
        own = fields[jnp.maximum(slot[r], 0), cells_flat]
        return jnp.where(slot[r] >= 0, own, approach_distance(cells, goal[r]))

    def one(r, carry):
        pos, held, moved = carry
        here = pos[r]
        q = here[None] + dirs
        inside = (q[:, 0] >= 0) & (q[:, 0] < h) & (q[:, 1] >= 0) & (q[:, 1] < w)
        qf = jnp.where(inside, q[:, 0] * w + q[:, 1], 0)
        mine = (owners[qf] < 0) | (owners[qf] == r)
        free = inside & mine & (held[qf] < 0)
        if corner is not None:
            free = free & corner[:, here[0], here[1]]
        d_nb = jnp.where(free, distance(r, q, qf), FAR + 1)
        k = jnp.argmin(d_nb)
        closer = d_nb[k] < distance(r, here, here[0] * w + here[1])
        approach_to = jnp.where(closer, q[k], here)
        nxt = push_next[r]
        nxt_flat = nxt[0] * w + nxt[1]
        push_free = (held[nxt_flat] < 0) & ((owners[nxt_flat] < 0) | (owners[nxt_flat] == r))
        push_to = jnp.where(push_free, nxt, here)
        to = jnp.where(phase[r] == PUSH, push_to, approach_to)
        go = jnp.any(to != here)
        held = held.at[here[0] * w + here[1]].set(jnp.where(go, -1, r))
        held = held.at[to[0] * w + to[1]].set(r)
        return pos.at[r].set(to), held, moved.at[r].set(go)

    # a rover at its goal (distance 0) or at the end of its push path keeps its cell whatever the
    # others do: the loop visits the others only, in index order, so a step costs what the moving
    # rovers do
    at_goal = jax.vmap(distance)(jnp.arange(n), pos, flat) == 0
    may_move = jnp.where(phase == PUSH, jnp.any(push_next != pos, -1), ~at_goal)
    order = jnp.nonzero(may_move, size=n, fill_value=0)[0]
    count = jnp.sum(may_move, dtype=jnp.int32)

    def visit(i, carry):
        return one(order[i], carry)

    pos, _, moved = jax.lax.fori_loop(0, count, visit, (pos, held, jnp.zeros(n, bool)))
    return pos, moved
