"""The best-first loop of Algorithm 1 (:func:`plan_pushes`): pop, evaluate lazily (correcting the
estimate), expand one batch, queue the children, reinsert the node while candidates remain."""
from __future__ import annotations

import heapq
import math
import time
from collections.abc import Callable

import numpy as np

from jaxplan.pusharound.modetable import ModeTable
from jaxplan.pusharound.physics import PushWorld
from jaxplan.pusharound.ranking import RankingParams
from jaxplan.pusharound.scene import PushScene
from jaxplan.pusharound.search.config import SEARCH_RANKING, SearchConfig, check_inputs
from jaxplan.pusharound.search.context import SearchContext, SearchRun, new_context, with_physics
from jaxplan.pusharound.search.evaluation import evaluate_node, refresh_stuck, scene_at
from jaxplan.pusharound.search.expansion import expand
from jaxplan.pusharound.search.nodes import SearchNode, priority, remaining_estimate, state_key
from jaxplan.pusharound.search.records import label_records
from jaxplan.pusharound.search.results import SearchResult, SearchStats

__all__ = ["OpenList", "plan_pushes"]


class OpenList:
    """The priority queue of nodes: least ``f`` first; ties: deeper first, then first queued."""

    def __init__(self):
        self._heap: list = []
        self._count = 0

    def __len__(self) -> int:
        return len(self._heap)

    def push(self, node: SearchNode, f: float) -> None:
        self._count += 1
        heapq.heappush(self._heap, (float(f), -node.depth, self._count, node))

    def pop(self) -> tuple:
        """(f, node) of the best node."""
        f, _, _, node = heapq.heappop(self._heap)
        return f, node

    def beaten(self, f: float) -> bool:
        """Whether a queued node is better than ``f`` (beyond round-off)."""
        return bool(self._heap) and f > self._heap[0][0] + 1e-9


def plan_pushes(scene: PushScene, config: SearchConfig | None = None, ranking: RankingParams = SEARCH_RANKING,
                *, world: PushWorld | None = None, sim=None, mode_table: ModeTable | None = None,
                progress: Callable[[dict], None] | None = None, record: bool = False) -> SearchResult:
    """Plan a pushing schedule that opens a W-clear corridor (Algorithm 1; docstring of
    :mod:`jaxplan.pusharound.search`).

    scene: the initial state; config: :class:`SearchConfig` (the defaults when None); ranking: Eqs. 8-9 weights and the
    presearch's beam / depth; world / sim: a prebuilt :func:`build_push_world` of ``scene`` and its
    :func:`make_push_simulator` (built here when None; pass them to reuse across calls); mode_table: a
    :class:`ModeTable` to read and update (a fresh one when None); progress: called with a dict after
    every expansion (``event``, ``elapsed_s``, ``queue``, the counters of :class:`SearchStats`, ...);
    record: keep an ``ExpansionRecord`` of every expansion (the ranked targets with their Eq. 8-9
    terms, what the batch did on each, and which target led to the solution) in
    ``SearchResult.records`` (:mod:`jaxplan.pusharound.search.records`); the plan is the same either way.

    Returns a :class:`SearchResult`. If Eq. 7 already holds: success with an empty schedule.
    """
    if config is None:
        config = SearchConfig()
    check_inputs(scene, config, ranking, mode_table, world, sim)
    ctx = new_context(scene, config, ranking, world, sim, mode_table)
    if not isinstance(record, (bool, np.bool_)):
        raise ValueError(f"record: must be a bool; got {record!r}.")
    run = SearchRun(np.random.default_rng(config.seed), progress, records=[] if record else None)
    return _search(ctx, run)


def _search(ctx: SearchContext, run: SearchRun) -> SearchResult:
    cfg = ctx.cfg
    run.t0 = time.perf_counter()
    queue = OpenList()
    root = run.new_node(ctx.scene.poses, np.asarray(ctx.scene.robots, np.float64), (), 0.0, 0.0)
    run.seen.add(state_key(root.poses, root.robots, cfg))
    path = evaluate_node(ctx, run, root)
    if path is not None:
        return _result(ctx, run, queue, True, root, path, "")
    if root.h == math.inf:       # blocked, and no movable borders the frontier
        return _result(ctx, run, queue, False, root, None, "exhausted")
    ctx = with_physics(ctx)
    best = root
    queue.push(root, priority(root, cfg))
    run.emit("start", len(queue), h=root.h)
    reason = "exhausted"
    while queue:
        spent = _budget_spent(ctx, run)
        if spent:
            reason = spent
            break
        f, node = queue.pop()
        ready, path = _settle(ctx, run, queue, node)
        if path is not None:
            return _result(ctx, run, queue, True, node, path, "")
        if not ready:
            continue
        if node.h < best.h:
            best = node
        found, children = expand(ctx, run, node)
        for child in children:
            queue.push(child, priority(child, cfg))
        node.expansions += 1
        run.emit("expand", len(queue), node=node.nid, depth=node.depth, f=f, h=node.h, chi=node.chi,
                 batch_left=len(node.cands) - node.cursor)
        if found is not None:
            return _result(ctx, run, queue, True, found[1], found[0], "")
        if cfg.reinsertion and node.cursor < len(node.cands):
            # Deferred expansion: back to the queue with its best unexplored gap.
            node.h = remaining_estimate(node, cfg)
            queue.push(node, priority(node, cfg))
    return _result(ctx, run, queue, False, best, None, reason)


def _budget_spent(ctx: SearchContext, run: SearchRun) -> str:
    """Why the search must stop now ("time limit", "expansion limit"), or ""."""
    if time.perf_counter() - run.t0 > ctx.cfg.time_limit_s:
        return "time limit"
    if run.stats["expansions"] >= ctx.cfg.max_expansions:
        return "expansion limit"
    return ""


def _settle(ctx: SearchContext, run: SearchRun, queue: OpenList, node: SearchNode) -> tuple:
    """Bring a popped node's estimate up to date before it is expanded: the error its siblings'
    evaluation showed, its own evaluation, or the stuck penalties added since. Returns ``(ready,
    path)``: path when its evaluation found Eq. 7; ready False when it went back to the queue (no
    longer best) or was dropped (no target)."""
    cfg = ctx.cfg
    if _apply_sibling_error(run, node) and queue.beaten(priority(node, cfg)):
        queue.push(node, priority(node, cfg))
        return False, None
    if not node.evaluated:
        return _evaluate_popped(ctx, run, queue, node)
    if cfg.refresh_stuck and refresh_stuck(ctx, run, node) and queue.beaten(priority(node, cfg)):
        queue.push(node, priority(node, cfg))
        return False, None
    return True, None


def _apply_sibling_error(run: SearchRun, node: SearchNode) -> bool:
    """Shift an unevaluated node's estimate by the error seen on a sibling from the same gap, once.
    Returns whether it was shifted."""
    if node.evaluated or node.corrected or node.origin not in run.corrections:
        return False
    node.corrected = True
    node.h = max(node.h + run.corrections[node.origin], 0.0)
    return True


def _evaluate_popped(ctx: SearchContext, run: SearchRun, queue: OpenList, node: SearchNode) -> tuple:
    """Evaluate a popped node; record its estimate's error for its siblings. Returns as
    :func:`_settle`."""
    h_est = node.h
    path = evaluate_node(ctx, run, node)
    if path is not None:
        return False, path
    if node.h == math.inf:
        return False, None
    if node.origin and not node.corrected:
        err = node.h - h_est
        run.corrections[node.origin] = min(run.corrections.get(node.origin, err), err)
    if queue.beaten(priority(node, ctx.cfg)):
        queue.push(node, priority(node, ctx.cfg))
        return False, None
    return True, None


def _result(ctx: SearchContext, run: SearchRun, queue: OpenList, success: bool, node: SearchNode, path,
            reason: str) -> SearchResult:
    run.stats["max_depth"] = max(run.stats["max_depth"], node.depth)
    stats = SearchStats(planning_time_s=time.perf_counter() - run.t0, **run.stats)
    final = scene_at(ctx, node)
    run.emit("done", len(queue), success=success, reason=reason, pushes=node.depth)
    records = (None if run.records is None
               else label_records(run.records, bool(success), node.nid, node.chi, node.depth))
    return SearchResult(bool(success), list(node.schedule), final, path, stats, reason, records)
