"""Selective rebuild after a push (Section 3.5, Algorithm 5, Eq. 13).

A push changes the counts of a few cells (``A_exec``). With the monotone rule the successor graph is
a DAG, and a cell's continuation table depends only on its own count, on which neighbours are
occupied, and on its successors' tables. So the tables that can change are exactly those of the
cells that can *reach* ``A_exec`` through a successor step of the old or the new graph: the upstream
closure of ``A_exec`` (``Affected.dirty``). The rebuild

1. lists the dirty cells breadth-first from ``A_exec`` against the successor steps (the old graph's,
   plus the new steps into each listed cell, tested on the spot), in work proportional to the set;
   on grids of up to 80^2 cells by a whole-grid dilation instead (``DENSE_LISTING_CELLS``);
2. gathers the dirty cells into a compact buffer of static ``capacity`` and solves for their
   tables there, reading the unchanged tables of all other cells (``jaxplan.transport.compact``: policy
   iteration warm-started from the old first steps, then the sidetrack levels, as in the full
   build; the result equals the from-scratch table, ties included), and rewrites the dirty cells'
   own fields (first hop, heading, fallback, successors; no other cell's can change);
3. refreshes psi, the heatmap and the highways, as Algorithm 5 does: for the whole grid, or
   (``local_flow``, the default from 128^2) only where they can change: psi along the dirty
   cells' old and new paths, the heatmap around them; the highways' threshold is global.

When the dirty set does not fit in ``capacity`` (or without the monotone rule, where the graph may
have cycles) the rebuild falls back to the full build; ``Affected.full`` says so. The buffer size is
chosen on the host (one small read of the dirty count), so only the sizes a run needs are compiled;
under a caller's ``jit`` all sizes are compiled behind a ``lax.switch`` instead. The paper's
``A_vis`` (Eq. 13: sources whose forward cone sees a changed cell) is computed by ``paper_sets``
for reporting; it is not needed for exactness (and not sufficient for it: a path may bend out of
its source's cone).
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.core import grid_jit, lattice, traced
from jaxplan.transport import compact, connectors, heatmap, obstacles, visibility
from jaxplan.transport.connectors import Connectors
from jaxplan.transport.fabric import (
    Fabric,
    Table,
    fabric_of,
    full_table,
    highways_of,
    hop_lengths,
    hops_from_steps,
    own_fields,
    with_flow,
)
from jaxplan.transport.params import FabricParams
from jaxplan.transport.scene import occupied_cells


class Affected(NamedTuple):
    """What a selective rebuild touched. H x W masks.

    exec: bool[H, W], A_exec: non-target cells whose count changed.
    dirty: bool[H, W], cells whose table was recomputed (upstream closure of A_exec).
    n_dirty: i32[], number of dirty cells.  rounds: i32[], policy iterations on the dirty buffer (of
    the full build when ``full``).
    full: bool[], the dirty set overflowed ``capacity`` (or monotone is off): a full build ran.
    """

    exec: jax.Array
    dirty: jax.Array
    n_dirty: jax.Array
    rounds: jax.Array
    full: jax.Array


def changed_cells(old_obj, new_obj, target_mask):
    """``bool[H, W]`` A_exec: non-target cells whose count changed."""
    return (jnp.asarray(old_obj) != jnp.asarray(new_obj)) & ~jnp.asarray(target_mask)


def upstream_closure(seed, feasible_old, feasible_new):
    """``bool[H, W]``: cells that reach ``seed`` through successor steps of either graph.

    seed: bool[H, W]; feasible_old, feasible_new: bool[8, H, W]. One backward dilation per round.
    """
    edges = feasible_old | feasible_new

    def grow(carry):
        mask, _ = carry
        reach = jnp.any(jnp.stack([edges[d] & lattice.shift(mask, dr, dc, False)
                                   for d, (dr, dc) in enumerate(lattice.DIRS)]), axis=0)
        new = mask | reach
        return new, jnp.any(new != mask)

    mask, _ = jax.lax.while_loop(lambda c: c[1], grow, (seed, jnp.bool_(True)))
    return mask


def _upstream_queue(changed, old_feasible, occupied, goal, dist, tvec, cos_t, monotone: bool, cell_size,
                    capacity: int, window: int = 64, blocked=None):
    """The upstream closure of ``changed`` as a list: ``(cells i32[capacity], count i32[], dirty
    bool[H, W])``, breadth-first from the changed cells, ``window`` queued cells at a time.

    Edges between unchanged cells are the same in the old and the new graph, and edges out of a
    changed cell do not matter (it is in the set already), so the old graph (old_feasible:
    bool[H, W, 8]) and the new steps *into* each queued cell, tested on the spot, are all it needs:
    work in proportion to the closure, not to the grid. count > capacity: the closure overflowed
    (cells and dirty are then partial, and the caller runs the full build).
    """
    h, w = changed.shape
    n = h * w
    flat = changed.reshape(-1)
    enterable = occupied | goal
    old_edges = old_feasible.reshape(n, lattice.N_DIRS)
    into = jnp.arange(lattice.N_DIRS)[None]                             # a predecessor's step onto the cell
    corner = None if blocked is None else jnp.moveaxis(obstacles.corner_free(blocked), 0, -1).reshape(n, -1)
    seeds = lattice.true_indices(flat, capacity + window)

    def more(carry):
        _, count, start, _, _, _ = carry
        return (start < count) & (count <= capacity)

    def visit(carry):
        cells, count, start, in_set, owner, it = carry
        head = jax.lax.dynamic_slice(cells, (start,), (window,))
        head = jnp.where(start + jnp.arange(window) < count, head, n)
        pred = lattice.lane_predecessors(head, (h, w)).T                   # [window, 8]
        new_edge = visibility.step_feasible(
            lattice.take_cells(occupied, pred, False), lattice.take_cells(enterable, head, False)[:, None],
            jnp.stack([visibility.step_alignment(lattice.take_cells(tvec, pred[:, d], 0.0), d)
                       for d in range(lattice.N_DIRS)], -1),
            lattice.take_cells(dist, pred, 0.0), lattice.take_cells(dist, head, jnp.inf)[:, None], cos_t, monotone,
            cell_size, True if corner is None else corner.at[pred, into].get(mode="fill", fill_value=False))
        old_edge = old_edges.at[pred, into].get(mode="fill", fill_value=False)
        found = jnp.where(old_edge | new_edge, pred, n).reshape(-1)
        cells, grown, in_set, owner, _ = lattice.append_new(cells, count, in_set, owner, it * found.size, found)
        # the head was the queue up to the old count; what this visit appended comes next
        return cells, grown, jnp.minimum(start + window, count), in_set, owner, it + 1

    start = (seeds, jnp.sum(flat, dtype=jnp.int32), jnp.int32(0), jnp.append(flat, True),
             jnp.full(n + 1, -1, jnp.int32), jnp.int32(0))
    cells, count, _, in_set, _, _ = jax.lax.while_loop(more, visit, start)
    return jnp.where(jnp.arange(capacity) < count, cells[:capacity], n), count, in_set[:-1].reshape(h, w)


def _compact_dp(g: visibility.SuccessorGraph, table: Table, cells, cell_size, max_rounds: int):
    """Recompute the table rows of the cells ``cells: i32[C]`` (flat, ``H*W`` padding): ``(table, rounds)``.

    g: their rows of the new successor graph (``visibility.successor_lanes``). ``jaxplan.transport.compact``:
    policy iteration and sidetracks on a compact buffer of these cells, reading the unchanged tables
    of the others, warm-started from the old first steps; a round (policy iteration) costs
    O(C log(path length)), not O(H W). rounds: policy iterations.
    """
    k = table.raw.shape[-1]
    b = compact.gather(g, cells, table.raw, table.length)
    warm = lattice.take_cells(table.next_dir[..., 0], cells, -1)
    rows, rounds = compact.solve_rows(b, warm, k, cell_size, max_rounds)    # fields [C, K]
    return Table(*(_put_rows(a, cells, new) for a, new in zip(table, rows))), rounds


def _put_rows(a, cells, rows):
    """``a: [H, W, ...]`` with the entries of ``cells: i32[C]`` (``H*W`` padding) replaced by ``rows: [C, ...]``."""
    h, w = a.shape[:2]
    return a.reshape((h * w,) + a.shape[2:]).at[cells].set(rows, mode="drop").reshape(a.shape)


def _lanes(scene, params: FabricParams, cells):
    """The new successor graph's rows of ``cells`` (``visibility.successor_lanes``)."""
    obj = jnp.asarray(scene.obj, jnp.float32)
    target = jnp.asarray(scene.target_mask, bool)
    return visibility.successor_lanes(cells, obj, occupied_cells(obj, target, scene.dist), target, scene.dist,
                                      scene.tvec, params.theta_tol_deg, scene.cell_size, params.monotone,
                                      scene.blocked)


def _patch_own_fields(scene, fabric: Fabric, table: Table, g, cells, rounds, converged):
    """``(fabric, hop_len)`` as ``fabric.own_fields`` gives them for the new ``table``, rewriting only
    the rows of ``cells`` (every other cell's table row, occupancy and successors are unchanged).
    Valid when ``fabric`` follows entry 0 everywhere (``selected`` all 0)."""
    w = table.raw.shape[1]
    row = lambda a, fill: lattice.take_cells(a, cells, fill)  # noqa: E731
    put = lambda a, rows: _put_rows(a, cells, rows)  # noqa: E731
    step = row(table.next_dir[..., 0], -1)
    occupied = jnp.any(g.feasible, axis=0) | g.fallback
    hop, heading, _ = hops_from_steps(step, visibility.fallback_direction_at(scene.tvec, cells), cells // w,
                                      cells % w, scene.cell_size)
    patched = fabric._replace(
        value=put(fabric.value, jnp.where(occupied, row(table.raw[..., 0], 0.0), 0.0)),
        length=put(fabric.length, jnp.where(occupied, row(table.length[..., 0], 0.0), 0.0)),
        first_hop=put(fabric.first_hop, hop), heading=put(fabric.heading, heading),
        fallback=put(fabric.fallback, step == lattice.FALLBACK), occupied=put(fabric.occupied, occupied),
        feasible=put(fabric.feasible, g.feasible.T), table=table, psi=None, heat=None, highways=None,
        rounds=rounds, converged=converged)
    return patched, hop_lengths(patched.first_hop, scene.cell_size)


def _own_fields_after(scene, params, fabric: Fabric, table: Table, g, cells, rounds, reselected):
    """The new fabric's own fields: patched at ``cells``, or recomputed for the whole grid when the
    old fabric followed Eq. 6 entries (``selection.reselect``) somewhere. reselected: whether it
    did (static bool), or None to test it inside the program (both branches compiled)."""
    converged = rounds < params.resolved_max_hops(scene.shape)
    patch = lambda _: _patch_own_fields(scene, fabric, table, g, cells, rounds, converged)  # noqa: E731

    def whole(_):
        feasible = jnp.moveaxis(_put_rows(fabric.feasible, cells, g.feasible.T), -1, 0)
        return own_fields(scene, table, feasible, rounds, converged)

    if reselected is None:
        return jax.lax.cond(jnp.any(fabric.selected != 0), whole, patch, None)
    return whole(None) if reselected else patch(None)


WALK_FACTOR = 4   # room for the cells downstream of the dirty ones, in dirty buffers


def _path_pointer(table: Table):
    """``i32[H*W]``: the next cell of each cell's selected path (entry 0), ``H*W`` where it ends."""
    first = table.next_dir[..., 0]
    return lattice.tree_pointer(first, (first < 0) | (first >= lattice.FALLBACK))[:-1]


def local_flow_default(shape) -> bool:
    """Whether ``selective_rebuild`` refreshes psi and the heatmap near the changed paths only: on
    grids of 128^2 cells and more. On smaller grids the whole-grid kernels are cheaper than the walk
    and its bookkeeping; above, the local refresh wins by more the larger the grid."""
    return shape[0] * shape[1] >= 128 * 128


def _flow(scene, params: FabricParams, old: Fabric, own: Fabric, hop_len, cells, dirty, local: bool,
          reselected, everywhere=False):
    """``own`` with psi, heat and highways. With ``local`` (static), recomputed only where the dirty
    cells' old or new paths run, and around them (``heatmap.repropagated_mass``,
    ``heatmap.heat_at``); for the whole grid when those cells overflow ``WALK_FACTOR`` buffers, the
    old fabric followed Eq. 6 entries (``reselected`` as in ``_own_fields_after``), or
    ``everywhere`` (bool[]) holds."""
    if not local or reselected:
        return with_flow(scene, params, own, hop_len)
    target = jnp.asarray(scene.target_mask, bool)
    psi, touched, count = heatmap.repropagated_mass(
        old.psi, own.value, _path_pointer(old.table), _path_pointer(own.table), dirty, cells,
        WALK_FACTOR * cells.shape[0], params.resolved_max_hops(scene.shape))

    def nearby(_):
        around = jnp.concatenate([touched, lattice.lane_neighbours(touched, scene.shape).reshape(-1)])
        fresh = heatmap.heat_at(around, psi, own.occupied, own.heading, hop_len, target, scene.cell_size)
        heat = old.heat.reshape(-1).at[around].set(fresh, mode="drop").reshape(scene.shape)
        return own._replace(psi=psi, heat=heat, highways=highways_of(scene, params, heat))

    if reselected is None:
        everywhere = everywhere | jnp.any(old.selected != 0)
    everywhere = everywhere | (count > touched.shape[0])
    return jax.lax.cond(everywhere, lambda _: with_flow(scene, params, own, hop_len), nearby, None)


DENSE_LISTING_CELLS = 80 * 80
"""Grids of at most this many cells list their dirty cells by whole-grid dilation
(``upstream_closure``, then ``lattice.true_indices``); larger ones by the breadth-first queue, whose
work grows with the dirty set rather than the grid. The dilation's few whole-grid passes are cheaper
than the queue's sequential steps on small grids; near 90^2 they cost the same. Both give the same
set."""


def dense_listing_default(shape) -> bool:
    """Whether ``selective_rebuild`` lists the dirty cells by whole-grid dilation (``DENSE_LISTING_CELLS``)."""
    return shape[0] * shape[1] <= DENSE_LISTING_CELLS


def _dirty_cells(scene, params: FabricParams, fabric: Fabric, changed, capacity: int, dense: bool):
    """Step 1 of the module docstring: ``(cells i32[capacity], count, dirty bool[H, W])``. With
    ``dense`` (static) the cells are listed in raster order from a whole-grid dilation, else
    breadth-first by the queue; the solver does not depend on the order."""
    obj = jnp.asarray(scene.obj, jnp.float32)
    target = jnp.asarray(scene.target_mask, bool)
    if dense:
        feasible = visibility.feasible_successors(occupied_cells(obj, target, scene.dist), target, scene.dist,
                                                  scene.tvec, params.theta_tol_deg, params.monotone, scene.cell_size,
                                                  scene.blocked)
        dirty = upstream_closure(changed, jnp.moveaxis(fabric.feasible, -1, 0), feasible)
        return lattice.true_indices(dirty.reshape(-1), capacity), jnp.sum(dirty, dtype=jnp.int32), dirty
    return _upstream_queue(changed, fabric.feasible, occupied_cells(obj, target, scene.dist), target, scene.dist,
                           scene.tvec, visibility.cone_cos(params.theta_tol_deg), params.monotone, scene.cell_size,
                           capacity, blocked=scene.blocked)


def _exact_dirty(scene, params: FabricParams, fabric: Fabric, changed, new_feasible):
    """The whole upstream closure (when the queue overflowed): ``(dirty, n_dirty)``."""
    dirty = upstream_closure(changed, jnp.moveaxis(fabric.feasible, -1, 0), new_feasible)
    return dirty, jnp.sum(dirty, dtype=jnp.int32)


def _partial(scene, params: FabricParams, fabric: Fabric, cells, reselected):
    """Steps 2-3 on the buffer ``cells``: ``(own-field fabric, hop_len)``."""
    g = _lanes(scene, params, cells)
    table, rounds = _compact_dp(g, fabric.table, cells, scene.cell_size, params.resolved_max_hops(scene.shape))
    return _own_fields_after(scene, params, fabric, table, g, cells, rounds, reselected)


def _finish(scene, params, fabric, changed, cells, count, dirty, bucket: int | None, local: bool, reselected: bool):
    """Steps 2-3 with the buffer of ``bucket`` cells (``None``: the full build), then psi, heat and
    highways (``local``, ``reselected``: ``_flow``)."""
    if bucket is None:
        table, feasible, rounds, converged = full_table(scene, params)
        own, hop_len = own_fields(scene, table, feasible, rounds, converged)
        dirty, count = _exact_dirty(scene, params, fabric, changed, feasible)
        rebuilt = with_flow(scene, params, own, hop_len)
    else:
        own, hop_len = _partial(scene, params, fabric, cells[:bucket], reselected)
        rebuilt = _flow(scene, params, fabric, own, hop_len, cells[:bucket], dirty, local, reselected)
    return rebuilt, Affected(changed, dirty, count, rebuilt.rounds, jnp.bool_(bucket is None))


def _selective_switch(scene, params: FabricParams, fabric: Fabric, changed, capacity: int, local: bool,
                      dense: bool):
    """All of it in one traced program: every buffer size is compiled and ``lax.switch`` picks the
    smallest that holds the dirty set (usable inside a caller's ``jit``)."""
    cells, count, dirty = _dirty_cells(scene, params, fabric, changed, capacity, dense)
    buckets = capacity_buckets(capacity)

    def partial_with(size):
        return lambda _: (*_partial(scene, params, fabric, cells[:size], None), dirty, count)

    def full(_):
        table, feasible, rounds, converged = full_table(scene, params)
        return (*own_fields(scene, table, feasible, rounds, converged),
                *_exact_dirty(scene, params, fabric, changed, feasible))

    fits = jnp.asarray(buckets) >= count
    branch = jnp.where(jnp.any(fits), jnp.argmax(fits), len(buckets))
    # only the tables and own fields go through the switch; the global refresh runs once, after it
    own, hop_len, dirty, count = jax.lax.switch(branch, [partial_with(c) for c in buckets] + [full], None)
    rebuilt = _flow(scene, params, fabric, own, hop_len, cells, dirty, local, None, everywhere=branch == len(buckets))
    return rebuilt, Affected(changed, dirty, count, rebuilt.rounds, branch == len(buckets))


def capacity_buckets(capacity: int, smallest: int = 64) -> tuple[int, ...]:
    """Dirty-buffer sizes for one grid: ``smallest`` (64), doubling, up to ``capacity`` (always the
    last). A round's cost grows faster than linearly with the buffer (cache), so the buckets are
    close together; a doubling within 1.5x of ``capacity`` is left out, as ``capacity`` costs about
    the same and is one program fewer to compile and hold (65^2: 512 beside 528).
    ``selection.select_all`` sizes its buffers the same way."""
    sizes = []
    size = smallest
    while size * 3 < capacity * 2:
        sizes.append(size)
        size *= 2
    return tuple(sizes) + (capacity,)


def _full_only(scene, params, changed):
    rebuilt = fabric_of(scene, params)
    return rebuilt, Affected(changed, jnp.ones_like(changed), jnp.int32(changed.size), rebuilt.rounds, jnp.bool_(True))


def default_capacity(shape) -> int:
    """Dirty-buffer size: 1/8 of the grid, at least 256 cells, at most half the grid.

    Larger dirty sets take the full build: the compact solver's cost grows with its buffer, and
    near an eighth of the grid it approaches the full build's (Table 2, docs/benchmarks.md).
    """
    h, w = shape
    n = h * w
    return max(1, min(n // 2, max(256, n // 8)))


def _rebuild(scene, params: FabricParams, fabric: Fabric, changed, capacity: int, local: bool, dense: bool):
    if not params.monotone:
        return _full_only(scene, params, changed)
    return _selective_switch(scene, params, fabric, changed, capacity, local, dense)


def _listing(scene, params: FabricParams, fabric: Fabric, changed, capacity: int, dense: bool):
    """``_dirty_cells`` and whether the old fabric follows Eq. 6 entries somewhere (such a fabric
    cannot be patched), computed together so that the host reads both at once."""
    return (*_dirty_cells(scene, params, fabric, changed, capacity, dense), jnp.any(fabric.selected != 0))


_listing_jit = grid_jit(_listing, static_argnums=(4, 5))
_finish_jit = grid_jit(_finish, static_argnums=(7, 8, 9))
_full_only_jit = grid_jit(_full_only)


def selective_rebuild(scene, params: FabricParams, fabric: Fabric, changed, *, capacity: int | None = None,
                      local_flow: bool | None = None, dense_listing: bool | None = None):
    """Update ``fabric`` (built for the counts before a push) to ``scene``'s counts after it.

    scene: the scene after the push; fabric: the fabric before it; changed: bool[H, W], A_exec
    (``changed_cells`` or ``Push.changed``). Returns ``(fabric, Affected)``; the fabric equals
    ``build_fabric(scene, params)`` (``rounds`` aside). capacity: the largest dirty-buffer size
    (default ``default_capacity``); a larger dirty set triggers a full build. local_flow: refresh
    psi and the heatmap only along the changed paths (default ``local_flow_default``: on grids of
    128^2 and more); the result is the same either way. dense_listing: list the dirty cells by
    whole-grid dilation rather than the breadth-first queue (default ``dense_listing_default``: on
    grids of up to 80^2); the same set either way.

    Called with concrete arrays, it lists the dirty cells (jitted), reads their number on the host
    and runs the jitted compact solver for the smallest buffer of 64, 128, 256, ... cells that holds
    them; each size is compiled the first time it is needed. With no dirty cell it returns
    ``fabric`` itself (rounds 0). Inside a caller's ``jit`` (traced
    arguments) it runs one program with every size compiled behind a ``lax.switch``. Both give the
    same result.
    """
    capacity = default_capacity(scene.shape) if capacity is None else int(capacity)
    changed = jnp.asarray(changed, bool)
    local = local_flow_default(scene.shape) if local_flow is None else bool(local_flow)
    dense = dense_listing_default(scene.shape) if dense_listing is None else bool(dense_listing)
    if traced(scene, params, fabric, changed):
        return _rebuild(scene, params, fabric, changed, capacity, local, dense)
    if not params.monotone:
        return _full_only_jit(scene, params, changed)
    cells, count, dirty, reselected = _listing_jit(scene, params, fabric, changed, capacity, dense)
    # read on the host, so that each program holds one buffer size and one way of finishing
    n_dirty, reselected = (int(v) for v in jax.device_get((count, reselected)))
    if n_dirty == 0 and not reselected:
        # no table can change, so neither can anything derived from the tables (a push that moved
        # nothing, or the target cells' counts only)
        return fabric, Affected(changed, dirty, count, jnp.int32(0), jnp.bool_(False))
    fitting = [c for c in capacity_buckets(capacity) if c >= n_dirty]
    return _finish_jit(scene, params, fabric, changed, cells, count, dirty, fitting[0] if fitting else None, local,
                       bool(reselected))


# ----------------------------------------------------------------------------------- connectors

def _refresh_connectors(scene, params: FabricParams, fabric: Fabric, old_occupied, old: Connectors, changed,
                        capacity: int, max_candidates: int | None = None):
    h, w = scene.shape
    max_hops = params.resolved_max_hops((h, w))
    centers = lattice.cell_centers((h, w), scene.cell_size, scene.origin)
    anchor_flat = connectors.choose_anchors(fabric.heat, fabric.highways, fabric.occupied, centers,
                                            params.anchor_lambda, max_candidates=max_candidates)
    anchors = connectors.slot_anchors(anchor_flat, old.anchors.shape[0])

    def one(anchor):
        # an anchor planned before keeps its table except where the push can reach it (the same
        # upstream-closure argument as for the target fabric, in the anchor's own graph)
        match = (old.anchors == anchor) & (anchor >= 0)
        old_table = jax.tree.map(lambda t: t[jnp.argmax(match)], old.tables)
        goal, dist, unit = connectors.anchor_frame(centers, jnp.maximum(anchor, 0))
        graph = visibility.successor_graph(scene.obj, fabric.occupied & ~goal, goal, dist, unit,
                                           params.theta_tol_deg, scene.cell_size, params.monotone, scene.blocked)
        old_feasible = visibility.feasible_successors(old_occupied & ~goal, goal, dist, unit, params.theta_tol_deg,
                                                      params.monotone, scene.cell_size, scene.blocked)
        dirty = upstream_closure(changed, old_feasible, graph.feasible)
        reuse = jnp.any(match) & (jnp.sum(dirty) <= capacity)

        def selective(_):
            cells = lattice.true_indices(dirty.reshape(-1), capacity)
            return _compact_dp(visibility.graph_at(graph, cells), old_table, cells, scene.cell_size, max_hops)[0]

        def fresh(_):
            return connectors.connector_table(scene, fabric, params, jnp.maximum(anchor, 0))

        return jax.lax.cond(reuse, selective, fresh, None), reuse

    # lax.map without batching, so that lax.cond runs one branch per anchor
    tables, reused = jax.lax.map(one, anchors)
    return connectors.assemble(scene, fabric, anchor_flat, anchors, tables), reused


_refresh_connectors_jit = grid_jit(_refresh_connectors, static_argnums=(6, 7))


def refresh_connectors(scene, params: FabricParams, fabric: Fabric, old_fabric: Fabric, old: Connectors, changed,
                       *, capacity: int = 256):
    """Connectors after a push, replanning only what can change (Algorithm 5, step 14).

    scene, fabric: after the push (``selective_rebuild``'s output); old_fabric, old: before it;
    changed: bool[H, W], A_exec. Anchors (Eq. 12) are re-chosen over the new heatmap. An anchor that
    was planned before keeps its connector table, updated on the cells that can reach a changed cell
    in its graph (the compact solver, buffer ``capacity``); a new anchor, or one whose dirty set
    overflows, is planned from scratch. Returns ``(Connectors, reused: bool[A])``; the connectors
    equal ``plan_connectors(scene, params, fabric)`` with the same ``max_anchors`` (lengths up to
    rounding). Monotone rule only (raises otherwise).
    """
    if not params.monotone:
        raise ValueError("refresh_connectors: needs FabricParams.monotone=True (an acyclic connector graph); "
                         "call plan_connectors instead.")
    return _refresh_connectors_jit(scene, params, fabric, old_fabric.occupied, old, jnp.asarray(changed, bool),
                                   int(capacity), connectors.candidate_buffer(fabric))


def paper_sets(scene, changed, theta_tol_deg, *, block_rows: int = 8):
    """The paper's ``(A_vis, A_all)`` of Eq. 13 as bool[H, W] masks.

    A_vis: occupied cells C with some changed cell X such that t(C) . unit(x - c) >= cos(theta_tol).
    Every cell against every changed cell, ``block_rows`` rows of cells at a time.
    """
    h, w = scene.shape
    centres = scene.cell_centers().reshape(-1, 2)
    flat_changed = changed.reshape(-1)
    cos_t = visibility.cone_cos(theta_tol_deg)
    pad = (-h) % block_rows
    blocks_c = jnp.pad(scene.cell_centers(), ((0, pad), (0, 0), (0, 0))).reshape(-1, block_rows * w, 2)
    blocks_t = jnp.pad(scene.tvec, ((0, pad), (0, 0), (0, 0))).reshape(-1, block_rows * w, 2)

    def sees(args):
        c, t = args
        delta = centres[None] - c[:, None]
        norm = jnp.linalg.norm(delta, axis=-1)
        align = jnp.sum(delta * t[:, None], -1) / jnp.maximum(norm, 1e-30)
        return jnp.any(flat_changed[None] & (norm > 0) & (align >= cos_t), axis=1)

    vis = jax.lax.map(sees, (blocks_c, blocks_t)).reshape(-1)[: h * w].reshape(h, w)
    vis = vis & scene.occupied
    return vis, vis | changed
