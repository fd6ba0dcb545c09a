"""Selective rebuild after a push (Section 3.5, Algorithm 5, Eq. 13).

A push changes the counts of a few cells (``A_exec``). With the monotone rule the successor graph is
a DAG, and a cell's continuation table depends only on its own count, on which neighbours are
occupied, and on its successors' tables. So the tables that can change are exactly those of the
cells that can *reach* ``A_exec`` through a successor step of the old or the new graph: the upstream
closure of ``A_exec`` (``Affected.dirty``). The rebuild

1. computes ``dirty`` by dilating ``A_exec`` backwards along successor steps until it stops growing;
2. gathers the dirty cells into a compact buffer of static ``capacity`` and solves for their
   tables there, reading the unchanged tables of all other cells (``jaxplan._compact``: policy
   iteration warm-started from the old first steps, then the sidetrack levels, as in the full
   build; the result equals the from-scratch table, ties included);
3. recomputes the global quantities once (first hops, psi, heatmap, highways, occupied set),
   as Algorithm 5 does.

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

from jaxplan import _compact, _grid, connectors, visibility
from jaxplan.connectors import Connectors
from jaxplan.fabric import Fabric, Table, _build, _traced, derive, full_table, ranks_from_directions
from jaxplan.params import FabricParams


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
        reach = jnp.any(jnp.stack([edges[d] & _grid.shift(mask, dr, dc, False)
                                   for d, (dr, dc) in enumerate(_grid.DIRS)]), axis=0)
        new = mask | reach
        return new, jnp.any(new != mask)

    mask, _ = jax.lax.while_loop(lambda c: c[1], grow, (seed, jnp.bool_(True)))
    return mask


def _compact_dp(graph: visibility.SuccessorGraph, table: Table, dirty, capacity: int, cell_size,
                max_rounds: int):
    """Recompute the table rows of the ``dirty`` cells (at most ``capacity``): ``(table, rounds)``.

    ``jaxplan._compact``: policy iteration and sidetracks on a compact buffer of the dirty cells,
    reading the unchanged tables of the others, warm-started from the old first steps; a round
    (policy iteration) costs O(capacity log(path length)), not O(H W). rounds: policy iterations.
    """
    h, w, k = table.raw.shape
    n = h * w
    b = _compact.gather(graph, table.raw, table.length, dirty, capacity)
    warm = table.next_dir.reshape(n, k)[jnp.minimum(b.idx, n - 1), 0]
    best_raw, best_len, policy, rounds = _compact.best_paths(b, warm, cell_size, max_rounds)
    raw, length, direction = _compact.kbest_rows(b, best_raw, best_len, policy, k, cell_size)
    used = raw > -jnp.inf
    entered_goal = jnp.take_along_axis(b.enters_goal, jnp.clip(direction, 0, 7), axis=0)
    steps = used & (direction >= 0) & (direction < _grid.FALLBACK)
    next_dir = jnp.where(used, direction, -1)
    next_rank = jnp.where(steps & ~entered_goal, ranks_from_directions(direction[..., None])[..., 0], -1)
    scatter = lambda a, new: a.reshape(n, k).at[b.idx].set(new.T, mode="drop").reshape(h, w, k)  # noqa: E731
    return Table(scatter(table.raw, raw), scatter(table.length, jnp.where(used, length, jnp.inf)),
                 scatter(table.next_dir, next_dir), scatter(table.next_rank, next_rank)), rounds


def _graph_and_dirty(scene, params: FabricParams, fabric: Fabric, changed):
    """The new successor graph, the dirty mask and its size (step 1 of the module docstring)."""
    obj = jnp.asarray(scene.obj, jnp.float32)
    target = jnp.asarray(scene.target_mask, bool)
    graph = visibility.successor_graph(obj, ~target & (obj > 0), target, scene.dist, scene.tvec,
                                       params.theta_tol_deg, scene.cell_size, params.monotone)
    dirty = upstream_closure(changed, jnp.moveaxis(fabric.feasible, -1, 0), graph.feasible)
    return graph, dirty, jnp.sum(dirty, dtype=jnp.int32)


def _finish(scene, params, fabric, changed, graph, dirty, n_dirty, capacity: int | None):
    """Steps 2-3: the compact solver (or, with ``capacity=None``, the full table), then the
    global refresh."""
    max_hops = params.resolved_max_hops(scene.shape)
    if capacity is None:
        table, _, rounds, converged = full_table(scene, params)
    else:
        table, rounds = _compact_dp(graph, fabric.table, dirty, capacity, scene.cell_size, max_hops)
        converged = rounds < max_hops
    rebuilt = derive(scene, params, table, graph.feasible, rounds, converged)
    return rebuilt, Affected(changed, dirty, n_dirty, rounds, jnp.bool_(capacity is None))


def _selective_switch(scene, params: FabricParams, fabric: Fabric, changed, capacity: int):
    """All of it in one traced program: every buffer size is compiled and ``lax.switch`` picks the
    smallest that holds the dirty set (usable inside a caller's ``jit``)."""
    graph, dirty, n_dirty = _graph_and_dirty(scene, params, fabric, changed)
    max_hops = params.resolved_max_hops(scene.shape)
    buckets = capacity_buckets(capacity)

    def partial_with(cap):
        return lambda _: _compact_dp(graph, fabric.table, dirty, cap, scene.cell_size, max_hops)

    fits = jnp.asarray(buckets) >= n_dirty
    branch = jnp.where(jnp.any(fits), jnp.argmax(fits), len(buckets))
    # only the table goes through the switch; the global refresh runs once, after it
    def full(_):
        table, _, rounds, _ = full_table(scene, params)
        return table, rounds

    table, rounds = jax.lax.switch(branch, [partial_with(c) for c in buckets] + [full], None)
    rebuilt = derive(scene, params, table, graph.feasible, rounds, rounds < max_hops)
    return rebuilt, Affected(changed, dirty, n_dirty, rounds, branch == len(buckets))


def capacity_buckets(capacity: int, smallest: int = 64) -> tuple[int, ...]:
    """Dirty-buffer sizes for one grid: ``smallest`` (64), doubling, up to ``capacity`` (always the
    last). A round's cost grows faster than linearly with the buffer (cache), so the buckets are
    close together. ``selection.select_all`` sizes its buffers the same way."""
    sizes = []
    size = smallest
    while size < capacity:
        sizes.append(size)
        size *= 2
    return tuple(sizes) + (capacity,)


def _full_only(scene, params, changed):
    rebuilt = _build(scene, params)
    return rebuilt, Affected(changed, jnp.ones_like(changed), jnp.int32(changed.size), rebuilt.rounds, jnp.bool_(True))


def default_capacity(shape) -> int:
    """Dirty-buffer size: 1/64 of the grid, at least 256 cells, at most half the grid.

    The compact solver costs about (dirty cells) x (rounds), the full build about H W log(H W);
    measured on the 2-core CPU, the full build was already faster at 329 dirty cells on 65^2 (7.6 vs
    8.6 ms) and at 2,471 on 256^2 (131 vs 392 ms), while 632 dirty cells on 512^2 took 45-97 ms
    against 280-512 ms. Larger dirty sets therefore take the full build. Those figures are of the
    previous solver (one Bellman round per hop); the bound has not been re-measured for the compact
    policy iteration (``jaxplan._compact``), which needs far fewer rounds.
    """
    h, w = shape
    n = h * w
    return max(1, min(n // 2, max(256, n // 64)))


def _rebuild(scene, params: FabricParams, fabric: Fabric, changed, capacity: int):
    if not params.monotone:
        return _full_only(scene, params, changed)
    return _selective_switch(scene, params, fabric, changed, capacity)


_rebuild_jit = jax.jit(_rebuild, static_argnums=4)
_dirty_jit = jax.jit(_graph_and_dirty)
_finish_jit = jax.jit(_finish, static_argnums=7)
_full_only_jit = jax.jit(_full_only)


def selective_rebuild(scene, params: FabricParams, fabric: Fabric, changed, *, capacity: int | None = None):
    """Update ``fabric`` (built for the counts before a push) to ``scene``'s counts after it.

    scene: the scene after the push; fabric: the fabric before it; changed: bool[H, W], A_exec
    (``changed_cells`` or ``Push.changed``). Returns ``(fabric, Affected)``; the fabric equals
    ``build_fabric(scene, params)`` (``rounds`` aside). capacity: the largest dirty-buffer size
    (default ``default_capacity``); a larger dirty set triggers a full build.

    Called with concrete arrays, it computes the dirty set (jitted), reads its size on the host and
    runs the jitted compact solver for the smallest buffer of 64, 128, 256, ... cells that holds it; each
    size is compiled the first time it is needed. Inside a caller's ``jit`` (traced arguments) it
    runs one program with every size compiled behind a ``lax.switch``. Both give the same result.
    """
    capacity = default_capacity(scene.shape) if capacity is None else int(capacity)
    changed = jnp.asarray(changed, bool)
    if _traced(scene, params, fabric, changed):
        return _rebuild(scene, params, fabric, changed, capacity)
    if not params.monotone:
        return _full_only_jit(scene, params, changed)
    graph, dirty, n_dirty = _dirty_jit(scene, params, fabric, changed)
    fitting = [c for c in capacity_buckets(capacity) if c >= int(n_dirty)]
    return _finish_jit(scene, params, fabric, changed, graph, dirty, n_dirty, fitting[0] if fitting else None)


# ----------------------------------------------------------------------------------- connectors

def _refresh_connectors(scene, params: FabricParams, fabric: Fabric, old_occupied, old: Connectors, changed,
                        capacity: int, max_candidates: int | None = None):
    h, w = scene.shape
    max_hops = params.resolved_max_hops((h, w))
    centers = _grid.cell_centers((h, w), scene.cell_size, scene.origin)
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
                                           params.theta_tol_deg, scene.cell_size, params.monotone)
        old_feasible = visibility.feasible_successors(old_occupied & ~goal, goal, dist, unit, params.theta_tol_deg,
                                                      params.monotone, scene.cell_size)
        dirty = upstream_closure(changed, old_feasible, graph.feasible)
        reuse = jnp.any(match) & (jnp.sum(dirty) <= capacity)

        def selective(_):
            return _compact_dp(graph, old_table, dirty, capacity, scene.cell_size, max_hops)[0]

        def fresh(_):
            return connectors.connector_table(scene, fabric, params, jnp.maximum(anchor, 0))

        return jax.lax.cond(reuse, selective, fresh, None), reuse

    # lax.map without batching, so that lax.cond runs one branch per anchor
    tables, reused = jax.lax.map(one, anchors)
    return connectors.assemble(scene, fabric, anchor_flat, anchors, tables), reused


_refresh_connectors_jit = jax.jit(_refresh_connectors, static_argnums=(6, 7))


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
