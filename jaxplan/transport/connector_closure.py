"""Connector paths solved on the few cells a connector can visit: its sources' downstream closure.

A connector step (``visibility.step_feasible``) enters an occupied cell or the anchor, inside the cone
toward the anchor and, with the monotone rule, strictly nearer to it. The cells reachable from a
source by such steps, its *downstream closure*, are few where material lies in piles, while the disc
around the anchor that must hold them for the window DP (``connectors.connector_walks``) can be most
of the grid. A cell's K = 1 row depends only on its own count and its successors' rows, so the rows
solved on the closure alone equal the window's or the whole grid's, ties included: the closure is
listed breadth-first (``downstream_cells``), its successor rows computed per cell
(``connector_lanes``), and the table solved on a compact buffer with nothing outside it
(``compact.best_paths`` and ``compact.kbest_rows``, as the selective rebuild does). The walks
(``closure_walks``) then equal ``walk_table`` on the whole-grid connector table.

The buffer holds ``capacity`` cells (static); the listing stops once it overflows and the caller
falls back to the window DP.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan.core import lattice
from jaxplan.transport import compact, visibility
from jaxplan.transport.fabric import Fabric, Paths, follow_entries
from jaxplan.transport.params import FabricParams

__all__ = ["CLOSURE_CAPACITY", "CLOSURE_ROUND", "closure_walks", "connector_lanes", "downstream_cells"]

CLOSURE_CAPACITY = 512
"""Cells of the buffer a connector's closure is solved on; a larger closure runs the window DP."""
CLOSURE_ROUND = 16
"""Listed cells whose successors one round of ``downstream_cells`` appends."""


def connector_lanes(scene, fabric: Fabric, params: FabricParams, cells, anchor_flat):
    """``(SuccessorGraph, nb i32[8, C])``: the rows of ``cells: i32[C]`` (flat, ``H*W`` for padding) in
    the connector successor graph toward ``anchor_flat`` (i32[], a cell), the rows
    ``connectors.connector_table``'s DP builds (the anchor the goal, the fabric's occupied cells but
    the anchor expandable), the distance and direction to the anchor computed per cell, O(C); and
    the cells' neighbours (``lattice.lane_neighbours``)."""
    h, w = fabric.occupied.shape
    n = h * w
    nb = lattice.lane_neighbours(cells, (h, w))
    anchor_xy = lattice.centers_at(anchor_flat, (h, w), scene.cell_size, scene.origin)

    def toward(at):
        return lattice.norm_and_unit(anchor_xy - lattice.centers_at(jnp.minimum(at, n - 1), (h, w), scene.cell_size,
                                                                     scene.origin))

    dist, unit = toward(cells)
    goal_nb = nb == anchor_flat
    occupied = lattice.take_cells(fabric.occupied, cells, False) & (cells != anchor_flat)
    enterable = lattice.take_cells(fabric.occupied, nb, False) | goal_nb
    nb_dist = jnp.where(nb < n, toward(nb)[0], jnp.inf)
    return visibility.lane_graph(lattice.take_cells(jnp.asarray(scene.obj, jnp.float32), cells, 0.0), occupied,
                                 enterable, goal_nb, unit, dist, nb_dist, params.theta_tol_deg, scene.cell_size,
                                 params.monotone, lattice.take_cells(scene.blocked, nb, False)), nb


def downstream_cells(successors, seeds, n: int, capacity: int, per_round: int = CLOSURE_ROUND):
    """``(cells i32[capacity], count i32[])``: the distinct ``seeds`` (i32[B], flat, ``n`` for none)
    and every cell reachable from them, breadth-first, ``per_round`` listed cells a round.
    successors(cells i32[R]) -> i32[8, R]: each cell's successor cells (``n`` for none). count >
    capacity: the closure overflowed (the list is then partial); unused slots hold ``n``. A new cell
    is checked against the list, so a round costs O(capacity), not O(grid)."""
    size = capacity + lattice.N_DIRS * per_round

    def append(listed, count, found):
        found = jnp.where((found < n) & ~jnp.any(found[:, None] == listed[None], 1), found, n)
        first = ~jnp.any(jnp.tril(found[:, None] == found[None], -1), 1)
        won = (found < n) & first
        slot = count + jnp.cumsum(won, dtype=jnp.int32) - 1
        return listed.at[jnp.where(won, slot, size)].set(found, mode="drop"), count + jnp.sum(won, dtype=jnp.int32)

    def more(carry):
        _, count, start = carry
        return (start < count) & (count <= capacity)

    def visit(carry):
        listed, count, start = carry
        head = jax.lax.dynamic_slice(listed, (start,), (per_round,))
        head = jnp.where(start + jnp.arange(per_round) < count, head, n)
        listed, grown = append(listed, count, successors(head).reshape(-1))
        # the head was the list up to the old count; what this round appended comes next
        return listed, grown, jnp.minimum(start + per_round, count)

    listed, count = append(jnp.full(size, n, jnp.int32), jnp.int32(0), jnp.asarray(seeds, jnp.int32))
    listed, count, _ = jax.lax.while_loop(more, visit, (listed, count, jnp.int32(0)))
    return jnp.where(jnp.arange(capacity) < count, listed[:capacity], n), count


def _positions(cells, nb, n: int):
    """i32[8, C]: where each neighbour ``nb: i32[8, C]`` sits in ``cells: i32[C]``, C where it is not
    listed (a sorted search, O(C log C))."""
    capacity = cells.shape[0]
    order = jnp.argsort(cells)
    ordered = cells[order]
    at = jnp.clip(jnp.searchsorted(ordered, nb), 0, capacity - 1)
    return jnp.where((ordered[at] == nb) & (nb < n), order[at], capacity).astype(jnp.int32)


def closure_walks(scene, fabric: Fabric, params: FabricParams, sources, anchor_flat, cells, max_steps: int) -> Paths:
    """``Paths[B]``: the connector walks of ``sources: i32[B, 2]`` toward ``anchor_flat``, solved on
    ``cells`` (i32[C], ``downstream_cells`` of those sources, complete), each equal to ``walk_table``
    of the whole-grid ``connectors.connector_table``. A source not listed gives an arbitrary row.
    max_steps: static."""
    h, w = fabric.occupied.shape
    n = h * w
    g, nb = connector_lanes(scene, fabric, params, cells, anchor_flat)
    b = compact.closed_buffer(g, cells, _positions(cells, nb, n), 1)
    rows, _ = compact.solve_rows(b, jnp.full(cells.shape, -1, jnp.int32), 1, scene.cell_size,
                                 params.resolved_max_hops((h, w)))            # fields [C, 1]
    start = _positions(cells, jnp.asarray(sources, jnp.int32)[None, :, 0] * w + sources[None, :, 1], n)[0]
    return jax.vmap(lambda s, p: _walk_rows(rows, b, s, p, max_steps))(jnp.asarray(sources, jnp.int32), start)


def _walk_rows(rows, b: compact.Buffer, source, position, max_steps: int) -> Paths:
    """``walk_table`` over a buffer's K = 1 rows (``rows``: a Table of fields [C, 1]) from ``source:
    i32[2]`` listed at ``position`` (i32[])."""
    at = jnp.minimum(position, b.idx.shape[0] - 1)
    cells, done, fell_back = follow_entries(lambda at, rk: (rows.next_dir[at, rk], rows.next_rank[at, rk]),
                                            lambda at, new_rc, d: b.nb_pos[d, at], source, at, 0, max_steps)
    return Paths(cells, jnp.sum(cells[:, 0] >= 0), rows.raw[at, 0], rows.length[at, 0], fell_back, done)
