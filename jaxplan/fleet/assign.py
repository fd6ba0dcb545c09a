"""Giving idle rovers tasks: the three strategies (docs/fleet.md, "Strategies").

A **task** is one planned push (``Task``): ``episode.plan_for_source`` from a source on the current
fabric, the delivered mass the spill model predicts for its route, the push's steps and its
footprint (``footprint``). A task may start only if its footprint is **free**: it meets no cell of a
running task's footprint (the ownership map) and holds no rover's cell but the assigned rover's.
A task carries its footprint as a mask, so both checks are one masked reduction, and a rover
stands in a footprint when the mask is set at its cell.

- ``coordinated`` (``assign_greedy``): the top ``M`` sources by the source rule's score among the
  occupied cells outside every footprint, each planned (``vmap``); then, as long as a pair is left,
  the (idle rover, candidate) pair of the best score ``predicted / (approach + push steps)`` whose
  footprint is free of the footprints reserved so far is assigned and its footprint reserved.
  ``approach`` is the Chebyshev distance from the rover to the route's start, a lower bound of the
  steps it drives (detours around footprints only add). Greedy, because with footprint conflicts the
  choice is no linear assignment problem, and each round is one vectorised argmax over all pairs:
  the pair an auction's first round would settle first. The candidates' footprint relations (free
  of reservations, pairwise overlaps) are computed once when they are planned, so the rounds do no
  whole-grid work; a planning after the reservations changed keeps the tasks of the sources it
  planned before.
- ``independent`` and ``partitioned`` (``assign_each``): the single-rover rule, rover by rover in
  index order: the source ``choose_source`` picks among the occupied cells outside every footprint
  (and, partitioned, inside the rover's sector), planned with ``plan_for_source``. If that plan
  cannot be pushed (no complete route) the rover stays idle, as a lone rover would stop. If its
  footprint is not free, the source is skipped and the next best tried, up to ``retries`` times in
  all. With one rover this is ``run_episode``'s tick exactly.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.fleet import footprint
from jaxplan.transport import (
    CLEARED,
    NO_ROUTE,
    RUNNING,
    SPLINE_CHUNK,
    WALK_CAP,
    FabricChanges,
    PlanReads,
    Route,
    choose_source,
    connector_walk,
    plan_code,
    plan_for_source,
    plan_reads,
    plan_with_connector,
    plans_unchanged,
    source_anchors,
    waypoint_pickup,
    waypoints,
)
from jaxplan.transport.spillage import evaluate_route

__all__ = ["Attempts", "BLOCKED", "Candidates", "PLAN_CHUNK", "RATE_BLOCK", "RATE_BLOCKS", "RATE_CHUNK", "RATE_REACH",
           "RATE_WIDEN", "Task", "assign_each", "assign_greedy", "assign_planned", "bits_at", "choose_sources",
           "clear_of", "failure_rank", "footprint_free", "footprint_relations", "greedy_choice", "keep_only",
           "newly_planned", "no_attempts", "no_candidates", "overlap_rows", "pack_bits", "plan_candidates",
           "plan_task", "rate_sources", "reserve", "rovers_in", "rovers_inside", "select_rows", "unchanged_tasks",
           "unpack_bits", "walks_fit", "wanted_candidates", "widen"]

BLOCKED = 9
"""Code of an assignment that found pushable tasks whose footprints were all taken (the fleet's
stop code "no_reachable_task" when nothing else runs)."""
PLAN_CHUNK = 2
"""Candidates planned together (one ``vmap``) by ``plan_candidates``: with the task table kept across
pushes a planning has a few new sources, and on ``site512`` with 64 rovers chunks of 2 planned them
sooner than chunks of 1, 4 or 8."""
RATE_CHUNK = 8
"""Rovers whose rates ``rate_sources`` scores together over the whole grid."""
RATE_BLOCK = 16
"""Side of the tiles whose bounds let ``rate_sources`` score a few tiles per rover, not the grid."""
RATE_BLOCKS = 8
"""Tiles ``rate_sources`` scores per rover before it checks that no other tile could beat them."""
RATE_WIDEN = 8
"""A rover whose ``RATE_BLOCKS`` best tiles do not settle its sources scores this many times more
before the whole grid."""
RATE_REACH = (0, 4, 8, 16, 32, 64, 128, 256, 512)
"""Distances at which ``rate_sources`` bounds each tile's rates (the nearest not beyond a rover's)."""


class Task(NamedTuple):
    """One planned push (a leading batch axis when batched). H x W grid.

    source: i32[2]; route: execute.Route; mode: i32[] (0 deliver, 1 rearrange); code: i32[] the
    episode's plan code (``RUNNING`` = pushable, ``CLEARED`` no source, ``NO_ROUTE``, ``WALK_CAP``);
    predicted: f32[] objects the spill model delivers; steps: i32[] push steps; footprint: bool[H, W]
    the cells it reserves (``footprint.mask_from_core``).
    """

    source: jax.Array
    route: Route
    mode: jax.Array
    code: jax.Array
    predicted: jax.Array
    steps: jax.Array
    footprint: jax.Array


def plan_task(scene, params, ep, spill, fabric, source, has_source, cap: int, evaluator, clearance: int,
              connector=None) -> Task:
    """The ``Task`` of pushing from ``source: i32[2]`` (``has_source``: it is a candidate at all);
    cap, evaluator, clearance: static. connector: optional ``(anchor i32[], Paths)``, the source's
    anchor and its connector path when already computed (``plan_candidates``)."""
    if connector is None:
        plan = plan_for_source(scene, params, ep, spill, fabric, source, cap, evaluator)
    else:
        plan = plan_with_connector(scene, params, ep, spill, fabric, source, *connector, cap, evaluator)
    plan = plan._replace(has_source=has_source & plan.has_source)
    route = plan.route
    points, n_points = waypoints(scene, route)
    pickup, _ = waypoint_pickup(scene, route)
    predicted, _, samples = evaluate_route(points, n_points, pickup, spill, evaluator,
                                           chunk=SPLINE_CHUNK)
    cells = footprint.core_cells(scene, route, samples, clearance)
    return Task(plan.source, route, plan.mode, plan_code(plan, cap, scene.shape), predicted,
                footprint.push_steps(route), footprint.mask_from_core(scene.target_mask, *cells, clearance))


def failure_rank(code):
    """i32[]: how much an assignment failure says, to report the most telling one: none (0) <
    no source (``CLEARED``) < footprints taken (``BLOCKED``) < ``WALK_CAP`` < ``NO_ROUTE``."""
    return jnp.select([code == CLEARED, code == BLOCKED, code == WALK_CAP, code == NO_ROUTE], [1, 2, 3, 4], 0)


def _worse(a, b):
    return jnp.where(failure_rank(b) > failure_rank(a), b, a)


def rovers_inside(mask, pos):
    """bool[N]: which rovers (cells ``pos: i32[N, 2]``) stand in ``mask: bool[H, W]``."""
    return mask[pos[:, 0], pos[:, 1]]


def footprint_free(task: Task, owner, pos, rover):
    """bool[]: ``task``'s footprint is free for ``rover`` (module docstring). owner: i32[H, W] (-1
    free); pos: i32[N, 2] the rovers' cells; rover: i32[]."""
    others = rovers_inside(task.footprint, pos) & (jnp.arange(pos.shape[0]) != rover)
    return ~jnp.any(task.footprint & (owner >= 0)) & ~jnp.any(others)


def reserve(owner, task: Task, rover):
    """i32[H, W]: ``owner`` with the task's footprint given to ``rover``."""
    return jnp.where(task.footprint, rover, owner)


def _source_score(scene, fabric, rule: str):
    return fabric.value if rule == "max_value" else -scene.dist


class Candidates(NamedTuple):
    """The coordinated strategy's planned candidates (M of them). A task stays what planning its
    source again would give while the fabric and counts it read stay the same (``reads``,
    ``unchanged_tasks``); the footprint relations, while the reservations stay the same too.

    tasks: Task[M], whose ``footprint`` holds each mask packed 32 cells to a word (``pack_bits``:
    u32[M, ceil(H W / 32)], an eighth of the bytes, copied and compared word by word); exists:
    bool[M] the slot holds an occupied source's task, planned on the current fabric or on one that
    differs from it nowhere the task read; usable: bool[M] it holds a pushable task. What the
    greedy rounds need of the footprints, computed once when planned, so that an assignment on
    cached candidates does no whole-grid work: clear: bool[M] the footprint meets no reservation it
    was planned with; overlap: bool[M, M] two footprints share a cell. reads: PlanReads[M] what each
    task's plan read (``transport.plan_reads``), to tell after a refresh which tasks it left
    unchanged (``unchanged_tasks``).
    """

    tasks: Task
    exists: jax.Array
    usable: jax.Array
    clear: jax.Array
    overlap: jax.Array
    reads: PlanReads


def rate_sources(fabric, owner, pos, idle, m: int, cell_size, per_rover: int = 2, block: int | None = None,
                 blocks: int = RATE_BLOCKS):
    """``(flat i32[m], ok bool[m])``: each idle rover's ``per_rover`` best sources by the rate the
    fabric promises it, ``J / (Chebyshev distance from the rover + route length in cells + 1)``,
    among occupied cells outside every footprint; rank by rank (every idle rover's best, then every
    second best, ...), each cell once, the first m kept.

    block, blocks (static): the grid is cut into ``block`` x ``block`` tiles (default ``RATE_BLOCK``
    on grids at least ``4 RATE_BLOCK`` cells a side, else none, and every rover is scored over the
    whole grid, ``RATE_CHUNK`` at a time). A tile's rates are bounded by its best ``J / (d + route
    length + 1)`` at a distance d no farther than the rover's least distance to the tile
    (``RATE_REACH``), so each rover scores the cells of its ``blocks`` best-bounded tiles only, and
    its sources are the grid's when its ``per_rover``-th best there beats every other tile's bound;
    a rover whose does not scores ``RATE_WIDEN`` times as many tiles the same way, then the whole
    grid. The same sources either way (ties to the lowest flat index)."""
    h, w = owner.shape
    allowed = fabric.occupied & (owner < 0)
    cells_long = fabric.length / cell_size
    if block is None:
        block = RATE_BLOCK if min(h, w) >= 4 * RATE_BLOCK else 0
    if block and blocks * block * block < h * w:
        best, flat = _rates_by_tile(fabric.value, cells_long, allowed, pos, idle, per_rover, block, blocks)
    else:
        best, flat = jax.lax.map(lambda r: _best_on_grid(fabric.value, cells_long, allowed, *r, per_rover),
                                 (pos, idle), batch_size=min(RATE_CHUNK, pos.shape[0]))
    best, flat = best.T.reshape(-1), flat.T.reshape(-1)       # rank-major
    flat = jnp.where(best > -jnp.inf, flat, 0)
    k = flat.shape[0]
    earlier = jnp.tril(flat[:, None] == flat[None], -1)
    ok = (best > -jnp.inf) & ~jnp.any(earlier, 1)
    order = jnp.argsort(~ok, stable=True)
    flat, ok = flat[order], ok[order]
    if k < m:
        flat, ok = jnp.pad(flat, (0, m - k)), jnp.pad(ok, (0, m - k))
    return flat[:m], ok[:m]


def _rate(value, far, cells_long):
    """The rate of cells with J ``value``, Chebyshev distance ``far`` and route length ``cells_long``."""
    return value / (far + cells_long + 1.0)


def _best_on_grid(value, cells_long, allowed, here, may, per_rover: int):
    """``(best f32[per_rover], flat i32[per_rover])``: one rover's best rates over the whole grid."""
    h, w = allowed.shape
    rows, cols = jnp.meshgrid(jnp.arange(h), jnp.arange(w), indexing="ij")
    far = jnp.maximum(jnp.abs(rows - here[0]), jnp.abs(cols - here[1]))
    rate = jnp.where(allowed & may, _rate(value, far, cells_long), -jnp.inf)
    best, flat = jax.lax.top_k(rate.reshape(-1), per_rover)
    return best, flat.astype(jnp.int32)


def _top_by_rate(rate, flat, k: int):
    """``(best f32[k], flat i32[k])``: the k best of ``rate: f32[C]`` at the cells ``flat: i32[C]``
    (distinct), ties to the lowest flat index (``lax.top_k`` on the grid's row-major order)."""
    def pick(rate, _):
        best = jnp.max(rate)
        first = jnp.min(jnp.where(rate == best, flat, jnp.iinfo(jnp.int32).max))
        return jnp.where(flat == first, -jnp.inf, rate), (best, first)

    _, (best, first) = jax.lax.scan(pick, rate, None, length=k)
    return best, first.astype(jnp.int32)


def _rates_by_tile(value, cells_long, allowed, pos, idle, per_rover: int, block: int, blocks: int):
    """``(best f32[N, per_rover], flat i32[N, per_rover])``: every rover's best rates over the cells of
    its ``blocks`` best-bounded tiles, over the whole grid for a rover where another tile's bound
    reaches its ``per_rover``-th (``rate_sources``)."""
    h, w = allowed.shape
    hb, wb = -(-h // block), -(-w // block)
    pad = ((0, hb * block - h), (0, wb * block - w))
    reach = jnp.asarray(RATE_REACH, jnp.float32)
    # envelope[d, tile]: the tile's best J / (reach[d] + length + 1), for reach[d] <= the rover's distance
    # J clipped at 0 so that a farther cell can never rate higher than its bound
    rate_at = jnp.where(allowed[None], _rate(jnp.maximum(value, 0.0)[None], reach[:, None, None], cells_long[None]),
                        -jnp.inf)
    envelope = jnp.pad(rate_at, ((0, 0),) + pad, constant_values=-jnp.inf).reshape(
        len(RATE_REACH), hb, block, wb, block).max((2, 4)).reshape(len(RATE_REACH), -1)
    first_row, first_col = jnp.arange(hb) * block, jnp.arange(wb) * block
    inner = jnp.arange(block)

    def best_of(here, may, blocks: int):
        near_r = jnp.maximum(jnp.maximum(first_row - here[0], here[0] - (first_row + block - 1)), 0)
        near_c = jnp.maximum(jnp.maximum(first_col - here[1], here[1] - (first_col + block - 1)), 0)
        near = jnp.maximum(near_r[:, None], near_c[None]).reshape(-1)
        level = jnp.sum(near[None] >= reach[:, None], 0) - 1
        bound = jnp.where(may, jnp.take_along_axis(envelope, level[None], 0)[0], -jnp.inf)
        _, chosen = jax.lax.top_k(bound, blocks)
        rest = jnp.max(bound.at[chosen].set(-jnp.inf))
        rows = (chosen // wb)[:, None, None] * block + inner[None, :, None]
        cols = (chosen % wb)[:, None, None] * block + inner[None, None, :]
        rows, cols = jnp.broadcast_to(rows, (blocks, block, block)), jnp.broadcast_to(cols, (blocks, block, block))
        flat = (rows * w + cols).reshape(-1)
        r, c = flat // w, flat % w
        inside = (r < h) & (c < w)
        r, c = jnp.minimum(r, h - 1), jnp.minimum(c, w - 1)
        far = jnp.maximum(jnp.abs(r - here[0]), jnp.abs(c - here[1]))
        rate = jnp.where(inside & allowed[r, c] & may, _rate(value[r, c], far, cells_long[r, c]), -jnp.inf)
        best, first = _top_by_rate(rate, flat, per_rover)
        return best, first, (best[-1] > rest) | (rest == -jnp.inf)

    best, flat, ok = jax.vmap(lambda here, may: best_of(here, may, blocks))(pos, idle)

    def wider(here, may):
        b, f, good = best_of(here, may, min(blocks * RATE_WIDEN, hb * wb))
        return jax.lax.cond(good, lambda: (b, f), lambda: _best_on_grid(value, cells_long, allowed, here, may,
                                                                          per_rover))

    def settle(rover):
        here, may, good, b, f = rover
        return jax.lax.cond(good, lambda: (b, f), lambda: wider(here, may))

    return jax.lax.map(settle, (pos, idle, ok, best, flat))


def choose_sources(scene, ep, fabric, owner, m: int, wanted=None, by_rate=None, withheld=None):
    """``(flat i32[m], exists bool[m])``: the sources ``plan_candidates`` plans (its arguments of the
    same names): the top m by the source rule's score, or by rate (``by_rate``), among the occupied
    cells outside every footprint and not ``withheld``, the first ``wanted`` of them."""
    wanted = m if wanted is None else jnp.clip(wanted, 1, m)
    # withheld cells count as taken for the choice of sources only, not for the footprints
    taken = owner if withheld is None else jnp.where(withheld, jnp.maximum(owner, 0), owner)
    if by_rate is None:
        score_src = _source_score(scene, fabric, ep.source_rule)
        vals = jnp.where(fabric.occupied & (taken < 0), score_src, -jnp.inf).reshape(-1)
        top, idx = jax.lax.top_k(vals, m)
        found = top > -jnp.inf
    else:
        idx, found = rate_sources(fabric, taken, *by_rate, m, scene.cell_size)
    return idx, found & (jnp.arange(m) < wanted)


def plan_candidates(scene, params, ep, spill, fabric, owner, *, candidates: int, cap: int, evaluator,
                    clearance: int, wanted=None, by_rate=None, previous: Candidates | None = None,
                    withheld=None, chosen=None, short_cap: int | None = None) -> Candidates:
    """The top ``M = candidates`` sources by the source rule's score among the occupied cells outside
    every footprint (``owner: i32[H, W]``, -1 free); the first ``wanted`` of them (i32[], default M)
    planned as ``Task`` s, the others left empty (``exists`` False). by_rate: optional ``(cells
    i32[N, 2], idle bool[N])``: the candidates are the idle rovers' best sources by rate instead
    (``rate_sources``). previous: candidates planned on this same fabric (``exists`` False where
    not): a source planned there keeps its task, which depends on the fabric and the source only,
    so that only new sources are planned; the result is the same as planning them all. withheld:
    optional bool[H, W] cells that are no sources this time (``set_aside``). chosen: the sources
    ``choose_sources`` chose with these arguments, or a subset of them (``exists`` cleared), instead
    of choosing them here.

    The sources to plan are packed and planned ``PLAN_CHUNK`` at a time, chunks past the last one
    skipped, so a few new sources cost a few chunks whatever M is. The sources are grouped by
    highway anchor first; within a chunk, the sources sharing an anchor share its connector DP, run on
    a window around the anchor when that holds them (``transport.connector_walk``), and the rest of
    each plan is vmapped.

    short_cap (static, default ``cap``): a chunk is planned with this walk length first; when every
    walk its plans read ends within it (``walks_fit``), its tasks are those of planning with ``cap``
    (the predicted mass within float rounding: it is summed over shorter arrays), padded to ``cap``'s
    slots (``widen``), and otherwise the chunk is planned again with ``cap``. A task's arrays are
    sized by the walk length, so routes much shorter than ``cap`` plan sooner.
    """
    h, w = scene.shape
    m = min(int(candidates), h * w)
    short = cap if short_cap is None else min(int(short_cap), cap)
    if chosen is None:
        chosen = choose_sources(scene, ep, fabric, owner, m, wanted, by_rate, withheld)
    idx, exists = chosen
    sources = jnp.stack([idx // w, idx % w], -1).astype(jnp.int32)
    if previous is None:
        kept = jnp.zeros(m, bool)
        reused = None
    else:
        before = jnp.where(previous.exists, previous.tasks.source[:, 0] * w + previous.tasks.source[:, 1], -1)
        match = (idx[:, None] == before[None]) & exists[:, None]
        kept = jnp.any(match, 1)
        was = jnp.argmax(match, 1)
        reused = jax.tree.map(lambda a: a[was], (previous.tasks, previous.reads))
    need = exists & ~kept
    # the sources to plan first, in slot order; the rest of the list is padding (slot m)
    order = jnp.nonzero(need, size=m, fill_value=m)[0]
    slots = order
    n_need = jnp.sum(need, dtype=jnp.int32)
    safe = jnp.minimum(order, m - 1)
    todo = jnp.arange(m) < n_need
    src = sources[safe]
    anchors = jax.lax.cond(n_need > 0, lambda: jnp.where(todo, source_anchors(scene, params, fabric, src), -1),
                           lambda: jnp.full(m, -1, jnp.int32))
    # sources that share an anchor planned side by side: each chunk computes the connector DP of its
    # distinct anchors, so grouping them computes each anchor's about once, not once a chunk
    group = jnp.argsort(jnp.where(todo, anchors, h * w), stable=True)
    order, src, todo, anchors = order[group], src[group], todo[group], anchors[group]

    def plan_at(args, walk: int):
        sources, exists, anchors = args
        conns = connector_walk(scene, params, fabric, sources, anchors, walk)
        tasks = jax.vmap(lambda s, e, a, c: plan_task(
            scene, params, ep, spill, fabric, s, e, walk, evaluator, clearance, connector=(a, c)))(
            sources, exists, anchors, conns)
        reads = jax.vmap(lambda s, a: plan_reads(scene, params, fabric, s, a, walk))(sources, anchors)
        return tasks._replace(footprint=pack_bits(tasks.footprint)), reads, conns.complete

    def plan_chunk(args):
        if short >= cap:
            return plan_at(args, cap)[:2]
        tasks, reads, connected = plan_at(args, short)
        fits = walks_fit(reads, connected) | ~args[1]
        return jax.lax.cond(jnp.all(fits), lambda: widen(tasks, reads, cap), lambda: plan_at(args, cap)[:2])

    chunk = min(PLAN_CHUNK, m)
    pad = -m % chunk
    args = jax.tree.map(lambda a: jnp.pad(a, [(0, pad)] + [(0, 0)] * (a.ndim - 1)).reshape((-1, chunk) + a.shape[1:]),
                        (src, todo, anchors))
    into = jnp.where(todo, order, m)
    into = jnp.pad(into, (0, pad), constant_values=m).reshape(-1, chunk)
    if reused is None:
        empty = no_candidates(m, (h, w), fabric.table.raw.shape[-1], cap)
        reused = (empty.tasks, empty.reads)

    def plan_into(carry):
        # planned chunk by chunk straight into their slots: the table is written in place, and
        # nothing is planned, filled or copied for the chunks past the last source to plan
        k, table = carry
        planned = plan_chunk(jax.tree.map(lambda a: a[k], args))
        return k + 1, jax.tree.map(lambda a, b: a.at[into[k]].set(b, mode="drop"), table, planned)

    # rows neither kept nor planned (``exists`` False) hold no task
    _, (tasks, reads) = jax.lax.while_loop(lambda carry: carry[0] * chunk < n_need, plan_into, (jnp.int32(0), reused))
    usable = exists & (tasks.code == RUNNING)
    if previous is None:
        return Candidates(tasks, exists, usable, *footprint_relations(tasks.footprint, usable, owner), reads)
    # two kept tasks overlap as they did: only the new tasks' rows are compared
    rows = overlap_rows(tasks.footprint, slots, n_need)
    overlap = jnp.where(kept[:, None] & kept[None], previous.overlap[was][:, was], rows | rows.T)
    return Candidates(tasks, exists, usable, clear_of(tasks.footprint, owner), overlap & usable[:, None] & usable[None],
                      reads)


def walks_fit(reads: PlanReads, connected):
    """bool[B]: which of B plans read only walks that ended within their walk length: no walk of
    ``reads`` (``PlanReads[B]``) fills its last slot and the connector walked to its end
    (``connected``: bool[B], ``Paths.complete`` of ``connector_walk``). A walk that fills its last
    slot may have been cut; a plan whose walks all fit is the same with any longer walk length."""
    return connected & ~jnp.any(reads.walks[..., -1] >= 0, -1)


def widen(tasks: Task, reads: PlanReads, cap: int):
    """``(tasks, reads)`` planned with a shorter walk length, padded (-1) to the slots of walk length
    ``cap``: routes to S = 2 (cap + 1) rows, each read walk to cap + 1 cells."""
    cells = tasks.route.cells
    route = tasks.route._replace(cells=jnp.pad(cells, ((0, 0), (0, 2 * (cap + 1) - cells.shape[1]), (0, 0)),
                                                constant_values=-1))
    walks = jnp.pad(reads.walks, ((0, 0), (0, 0), (0, cap + 1 - reads.walks.shape[-1])), constant_values=-1)
    return tasks._replace(route=route), reads._replace(walks=walks)


def newly_planned(planned: Candidates, previous: Candidates):
    """i32[]: tasks of ``planned`` whose sources ``previous`` (the candidates it was planned from) held
    no task for: the tasks that planning planned rather than kept."""
    same = jnp.all(planned.tasks.source[:, None] == previous.tasks.source[None], -1)
    held = jnp.any(same & previous.exists[None], 1)
    return jnp.sum(planned.exists & ~held, dtype=jnp.int32)


def unchanged_tasks(candidates: Candidates, scene, params, old, new, changes: FabricChanges):
    """bool[M]: which candidates' tasks planning their sources again on the fabric ``new``, refreshed
    from ``old`` (``changes``: ``transport.fabric_changes``; ``scene`` has the new counts), would give
    the same: those whose plans read nothing that changed (``transport.plans_unchanged``)."""
    return plans_unchanged(scene, params, candidates.reads, old, new, changes)


def keep_only(candidates: Candidates, kept) -> Candidates:
    """The candidates with only the tasks ``kept: bool[M]``, so that the next planning plans the other
    sources again."""
    return candidates._replace(exists=candidates.exists & kept, usable=candidates.usable & kept)


def pack_bits(masks):
    """u32[M, ceil(H W / 32)]: each of M masks (bool[M, H, W]) as 32 cells per word, cell ``i`` (flat,
    row-major) in bit ``i % 32`` of word ``i // 32``."""
    m = masks.shape[0]
    flat = masks.reshape(m, -1)
    flat = jnp.pad(flat, ((0, 0), (0, -flat.shape[1] % 32))).reshape(m, -1, 32).astype(jnp.uint32)
    return jnp.sum(flat << jnp.arange(32, dtype=jnp.uint32), -1, dtype=jnp.uint32)


def unpack_bits(words, shape):
    """bool[H, W]: the mask of one row of ``pack_bits`` (``words``: u32[ceil(H W / 32)])."""
    bits = (words[:, None] >> jnp.arange(32, dtype=jnp.uint32)) & 1
    return bits.reshape(-1)[:shape[0] * shape[1]].reshape(shape).astype(bool)


def bits_at(words, flat):
    """bool[...]: the bits of the cells ``flat: i32[...]`` (row-major indices) in one packed mask."""
    return ((words[flat // 32] >> (flat % 32).astype(jnp.uint32)) & 1).astype(bool)


def clear_of(words, owner):
    """bool[M]: which of M packed footprint masks (u32[M, ceil(H W / 32)], ``pack_bits``) meet no
    cell of ``owner`` (i32[H, W], -1 free), compared 32 cells to a word."""
    reserved = pack_bits((owner >= 0)[None])[0]
    return ~jnp.any((words & reserved[None]) != 0, 1)


def rovers_in(words, pos, width: int):
    """bool[M, N]: which rovers (cells ``pos: i32[N, 2]``) stand in each of M packed footprint masks
    of a grid ``width`` cells wide."""
    return jax.vmap(lambda row: bits_at(row, pos[:, 0] * width + pos[:, 1]))(words)


def overlap_rows(words, slots, n):
    """bool[M, M]: which of M packed footprint masks (u32[M, ceil(H W / 32)]) share a cell with each
    of the first ``n`` (i32[]) of ``slots`` (i32[M], slot indices, padded with M), in those rows;
    the other rows False. ``PLAN_CHUNK`` rows at a time, chunks past the n-th skipped."""
    m = words.shape[0]
    chunk = min(PLAN_CHUNK, m)
    padded = jnp.pad(slots, (0, -m % chunk), constant_values=m).reshape(-1, chunk)

    def rows_of(chunk_slots):
        return jax.vmap(lambda i: jnp.any((words & words[jnp.minimum(i, m - 1)][None]) != 0, 1))(chunk_slots)

    first = (jnp.arange(padded.size) < n).reshape(padded.shape)
    into = jnp.where(first, padded, m)

    def one_chunk(carry):
        # a loop over the chunks to compute only: a map with a skipping branch copied the masks each chunk
        k, rows = carry
        return k + 1, rows.at[into[k]].set(rows_of(padded[k]), mode="drop")

    _, rows = jax.lax.while_loop(lambda carry: carry[0] * chunk < n, one_chunk,
                                 (jnp.int32(0), jnp.zeros((m, m), bool)))
    return rows


def footprint_relations(words, usable, owner):
    """``(clear bool[M], overlap bool[M, M])`` of M packed footprint masks (u32[M, ceil(H W / 32)],
    ``pack_bits``): whether each meets no cell of ``owner`` (i32[H, W], -1 free), and which pairs
    share a cell (unusable slots share none), compared 32 cells to a word."""
    clear = clear_of(words, owner)
    overlap = jax.vmap(lambda row: jnp.any((words & row[None]) != 0, 1))(words)
    return clear, overlap & usable[:, None] & usable[None]


def assign_greedy(scene, params, ep, spill, fabric, pos, idle, owner, budget, routes, *, candidates: int,
                  cap: int, evaluator, clearance: int):
    """The coordinated strategy (module docstring): ``(route, mode i32[N], assigned bool[N], owner, failure)``.

    pos: i32[N, 2]; idle: bool[N] rovers that may take a task; owner: i32[H, W]; budget: i32[] most
    tasks to start; routes: the rovers' current ``execute.Route`` batch (kept where none is assigned);
    candidates (M), cap (walk cap), evaluator, clearance: static. route[r] and mode[r] are rover r's new task
    where assigned[r]; failure: i32[] the episode's code saying why nothing could be assigned
    (``RUNNING`` when something was).
    """
    planned = plan_candidates(scene, params, ep, spill, fabric, owner, candidates=candidates, cap=cap,
                              evaluator=evaluator, clearance=clearance, wanted=wanted_candidates(idle, candidates))
    return assign_planned(planned, pos, idle, owner, budget, routes)


def wanted_candidates(idle, candidates: int):
    """i32[]: candidates an assignment plans for ``idle: bool[N]`` rovers: two per idle rover, at least
    ``PLAN_CHUNK`` and at most ``candidates`` (M)."""
    return jnp.clip(2 * jnp.sum(idle, dtype=jnp.int32), min(PLAN_CHUNK, candidates), candidates)


def assign_planned(planned: Candidates, pos, idle, owner, budget, routes, waiting=False):
    """``assign_greedy`` on candidates already planned (``plan_candidates`` on this fabric and this
    ``owner``); the same results. waiting: bool[] sources were left out of the candidates because they
    wait for a running task (``set_aside``): when no candidate is left, the footprints are taken
    (``BLOCKED``), not the site cleared."""
    tasks = planned.tasks
    choice, owner, count = greedy_choice(pos, idle, owner, budget, planned.usable, tasks,
                                         (planned.clear, planned.overlap))
    assigned = choice >= 0
    mine = jax.tree.map(lambda a: a[jnp.maximum(choice, 0)], (tasks.route, tasks.mode))
    route, mode = select_rows(assigned, mine, (routes, jnp.zeros(pos.shape[0], jnp.int32)))
    failure = jnp.select([count > 0, ~jnp.any(planned.exists) & ~waiting, ~jnp.any(planned.exists),
                          ~jnp.any(planned.usable)], [RUNNING, CLEARED, BLOCKED, tasks.code[0]], BLOCKED)
    return route, mode, assigned, owner, failure.astype(jnp.int32)


def select_rows(mask, new, old):
    """``new`` where ``mask: bool[N]`` else ``old``, leaf by leaf (leading axis N)."""
    return jax.tree.map(lambda a, b: jnp.where(mask.reshape((-1,) + (1,) * (a.ndim - 1)), a, b), new, old)


def greedy_choice(pos, idle, owner, budget, usable, tasks: Task, relations):
    """The greedy rounds of ``assign_greedy``: ``(choice i32[N], owner, count i32[])``.

    pos: i32[N, 2]; idle: bool[N]; owner: i32[H, W]; budget: i32[] most assignments; usable: bool[M]
    candidates that may be assigned; tasks: Task[M] (its source, predicted, steps and footprint are
    read; the footprints packed, ``Candidates``); relations: ``(clear, overlap)`` of their footprints
    (``footprint_relations`` with this ``owner``). choice[r] is the candidate rover r took (-1 none);
    owner has their footprints. Each round assigns the best-scoring free pair (module docstring; ties:
    lowest rover, then candidate); rounds stop when no pair is left. A chosen footprint rules out the
    candidates it meets (a row of ``overlap``), so a round costs O(N M), and nothing here is whole-grid
    work but the chosen footprints written into ``owner`` at the end, when there are any.
    """
    clear, overlap = relations
    n = pos.shape[0]
    m = usable.shape[0]
    h, w = owner.shape
    inside = rovers_in(tasks.footprint, pos, w).T                                                  # [N, M]
    crowd = jnp.sum(inside, 0)
    alone = (crowd == 0)[None] | ((crowd == 1)[None] & inside)
    approach = jnp.max(jnp.abs(pos[:, None, :] - tasks.source[None]), -1)
    score = tasks.predicted[None] / (approach + tasks.steps[None]).astype(jnp.float32)
    pairs = alone & usable[None]

    def more(carry):
        return carry[-1]

    def round_(carry):
        idle, unused, clear, choice, count, _ = carry
        ok = pairs & idle[:, None] & (unused & clear)[None] & (count < budget)
        best = jnp.argmax(jnp.where(ok, score, -jnp.inf).reshape(-1))
        r, c = best // m, best % m
        found = jnp.any(ok)
        clear = clear & ~(overlap[c] & found)
        idle = idle.at[r].set(idle[r] & ~found)
        unused = unused.at[c].set(unused[c] & ~found)
        choice = choice.at[r].set(jnp.where(found, c, choice[r]))
        count = count + found
        return idle, unused, clear, choice, count, found & jnp.any(idle) & (count < budget)

    start = (idle, jnp.ones(m, bool), clear, jnp.full(n, -1, jnp.int32), jnp.int32(0),
             jnp.any(idle) & (budget > 0))
    _, _, _, choice, count, _ = jax.lax.while_loop(more, round_, start)

    def reserve_chosen(owner):
        def one(r, owner):
            mine = lambda o: jnp.where(unpack_bits(tasks.footprint[choice[r]], (h, w)), r, o)  # noqa: E731
            return jax.lax.cond(choice[r] >= 0, mine, lambda o: o, owner)
        return jax.lax.fori_loop(0, n, one, owner)

    # only a step that assigned writes footprints into the grid
    return choice, jax.lax.cond(count > 0, reserve_chosen, lambda o: o, owner), count


class Attempts(NamedTuple):
    """What each rover's last failed attempt of ``assign_each`` depended on, so that an attempt
    whose inputs did not change is not planned again. N rovers, H x W grid.

    tried: bool[N, H, W] the footprints it planned that met no reservation (the only ones rovers
    standing in them could have blocked), together; seen: i32[N, N, 2] every rover's
    cell at the time; failure: i32[N] the attempt's code; valid: bool[N] the rover's last attempt
    failed and nothing is recorded to have changed since.
    """

    tried: jax.Array
    seen: jax.Array
    failure: jax.Array
    valid: jax.Array


def no_candidates(m: int, shape, k: int, cap: int) -> Candidates:
    """``Candidates`` of M = ``m`` empty slots (every field zero, ``exists`` False), shaped as
    ``plan_candidates``'s result for an H x W grid (``shape``), K table entries and walk length
    ``cap``: routes of 2 (cap + 1) slots, read walks of cap + 1 cells. Built directly: learning the
    shapes by tracing a planning took seconds per grid."""
    h, w = shape
    i32 = lambda *dims: jnp.zeros((m,) + dims, jnp.int32)   # noqa: E731
    no = lambda *dims: jnp.zeros((m,) + dims, bool)   # noqa: E731
    route = Route(cells=i32(2 * (cap + 1), 2), n_cells=i32(), fallback=no(), end=jnp.zeros((m, 2), jnp.float32))
    tasks = Task(source=i32(2), route=route, mode=i32(), code=i32(), predicted=jnp.zeros(m, jnp.float32),
                 steps=i32(), footprint=jnp.zeros((m, -(-h * w // 32)), jnp.uint32))
    reads = PlanReads(source=i32(2), anchor=i32(), walks=i32(k + 1, cap + 1), window=i32(4))
    return Candidates(tasks, exists=no(), usable=no(), clear=no(), overlap=no(m), reads=reads)


def no_attempts(n: int, shape) -> Attempts:
    """An ``Attempts`` record with nothing recorded (``n`` = 0 for a strategy that keeps none)."""
    return Attempts(jnp.zeros((n,) + tuple(shape), bool), jnp.zeros((n, n, 2), jnp.int32),
                    jnp.zeros(n, jnp.int32), jnp.zeros(n, bool))


def _same_outcome(attempts: Attempts, r, pos):
    """bool[]: rover r's recorded attempt would fail again the same way with the rovers at ``pos``
    (on the same fabric and reservations): no other rover entered, left or moved inside the
    footprints it tried, the only way rovers enter its outcome."""
    tried, then = attempts.tried[r], attempts.seen[r]
    others = jnp.arange(pos.shape[0]) != r
    moved = jnp.any(pos != then, -1)
    touches = rovers_inside(tried, pos) | rovers_inside(tried, then)
    return attempts.valid[r] & ~jnp.any(others & moved & touches)


def assign_each(scene, params, ep, spill, fabric, pos, idle, owner, budget, routes, region, attempts: Attempts,
                unchanged, *, retries: int, cap: int, evaluator, clearance: int):
    """The independent and partitioned strategies (module docstring): ``assign_greedy``'s results and
    the updated ``Attempts``.

    region: i32[H, W] the sector each cell belongs to, -1 everywhere for ``independent`` (rover r
    takes sources where region is -1 or r); attempts: the rovers' last failed attempts; unchanged:
    bool[] the fabric and the reservations are those they were made on. An idle rover whose
    recorded attempt would fail the same way (``_same_outcome``, while no rover before it was
    assigned this step) is not planned again: the same result, without its cost. retries
    (static): sources tried per rover and step.
    """
    h, w = scene.shape
    n = pos.shape[0]

    def rover(r, carry):
        owner, tasks, assigned, count, failure, attempts = carry
        mine = (region < 0) | (region == r)

        def attempt(carry):
            owner, tasks, assigned, count, failure, attempts = carry

            def more(c):
                return c[-1]

            def try_(c):
                excluded, tries, owner, tasks, assigned, failure, tried, _ = c
                source, has = choose_source(scene, fabric, ep.source_rule, mine & (owner < 0) & ~excluded)
                task = plan_task(scene, params, ep, spill, fabric, source, has, cap, evaluator, clearance)
                pushable = task.code == RUNNING
                free = pushable & footprint_free(task, owner, pos, r)
                owner = jnp.where(free, reserve(owner, task, r), owner)
                tasks = jax.tree.map(lambda all_, one: all_.at[r].set(jnp.where(free, one, all_[r])), tasks,
                                     (task.route, task.mode))
                assigned = assigned.at[r].set(free)
                failure = jnp.where(free, failure, jnp.where(pushable, BLOCKED, task.code))
                excluded = excluded.at[source[0], source[1]].set(True)
                again = pushable & ~free & (tries + 1 < retries)
                # only a footprint free of reservations can be blocked by rovers standing in it
                reserved = jnp.any(task.footprint & (owner >= 0))
                return excluded, tries + 1, owner, tasks, assigned, failure, tried | (task.footprint & ~reserved), again

            start = (jnp.zeros((h, w), bool), jnp.int32(0), owner, tasks, assigned, jnp.int32(RUNNING),
                     jnp.zeros((h, w), bool), jnp.bool_(True))
            _, _, owner, tasks, assigned, mine_failure, tried, _ = jax.lax.while_loop(more, try_, start)
            attempts = Attempts(attempts.tried.at[r].set(tried), attempts.seen.at[r].set(pos),
                                attempts.failure.at[r].set(mine_failure), attempts.valid.at[r].set(~assigned[r]))
            return owner, tasks, assigned, count + assigned[r], _worse(failure, mine_failure), attempts

        def recall(carry):
            owner, tasks, assigned, count, failure, attempts = carry
            return owner, tasks, assigned, count, _worse(failure, attempts.failure[r]), attempts

        repeat = unchanged & (count == 0) & _same_outcome(attempts, r, pos)
        return jax.lax.cond(idle[r] & (count < budget),
                            lambda c: jax.lax.cond(repeat, recall, attempt, c), lambda c: c, carry)

    attempts = attempts._replace(valid=attempts.valid & unchanged)
    start = (owner, (routes, jnp.zeros(n, jnp.int32)), jnp.zeros(n, bool), jnp.int32(0), jnp.int32(RUNNING), attempts)
    owner, (route, mode), assigned, count, failure, attempts = jax.lax.fori_loop(0, n, rover, start)
    return route, mode, assigned, owner, jnp.where(count > 0, RUNNING, failure).astype(jnp.int32), attempts
