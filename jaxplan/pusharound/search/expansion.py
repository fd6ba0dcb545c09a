"""Expanding a node (Algorithm 1, steps 2-3): the next batch of candidates that pass the quick-pass,
ONE physics call for all of them, the ModeTable updated with every simulated mode, and the children
``nu' = (s', pi + tau)`` of the rollouts that widened (or opened) their target. Children that opened
a gap predicted to connect are tested against Eq. 7 at once (Algorithm 1, line 5.5)."""
from __future__ import annotations

import numpy as np
import shapely

from jaxplan.pusharound.push import PushTask, push_cost, simulate_pushes, stack_tasks
from jaxplan.pusharound.quickpass import quick_pass
from jaxplan.pusharound.search.candidates import candidate_task, candidates
from jaxplan.pusharound.search.context import SearchContext, SearchRun
from jaxplan.pusharound.search.evaluation import check_node
from jaxplan.pusharound.search.nodes import Candidate, SearchNode, Target, priority, state_key
from jaxplan.pusharound.search.records import expansion_record
from jaxplan.pusharound.search.results import ScheduledPush

__all__ = ["expand", "next_batch"]

BUCKETS = (16, 64)   # physics batch sizes (the C engine's policy is jitted once per size and scene)
_CHUNK = 32          # candidates built and quick-passed together


def next_batch(ctx: SearchContext, run: SearchRun, node: SearchNode) -> list:
    """The next ``batch_size`` (<= max_batch) candidates of ``node`` that pass the quick-pass, in list
    order (first pass, second pass, modes the ModeTable saw fail); advances ``node.cursor``."""
    limit = min(ctx.cfg.batch_size, ctx.cfg.max_batch)
    out = []
    while node.cursor < len(node.cands) and len(out) < limit:
        chunk = node.cands[node.cursor:node.cursor + _CHUNK]
        node.cursor += len(chunk)
        chunk = _passing(ctx, run, node, _with_tasks(ctx, run, node, chunk))
        room = limit - len(out)
        if len(chunk) > room:   # survivors beyond the batch go back to the front of the list
            node.cands[node.cursor:node.cursor] = chunk[room:]
            chunk = chunk[:room]
        out += chunk
    return out


def _with_tasks(ctx: SearchContext, run: SearchRun, node: SearchNode, chunk: list) -> list:
    """``chunk`` with every candidate's task built; those without room for the team dropped."""
    with run.timed("time_candidates_s"):
        chunk = [c if c.task is not None else c._replace(task=candidate_task(ctx, node, c)) for c in chunk]
        return [c for c in chunk if c.task is not None]


def _passing(ctx: SearchContext, run: SearchRun, node: SearchNode, chunk: list) -> list:
    """The candidates of ``chunk`` that pass the quick-pass (those that passed before are not tested
    again), marked as passed."""
    todo = [k for k, c in enumerate(chunk) if not c.passed]
    if ctx.cfg.quick_pass and todo:
        with run.timed("time_quick_pass_s"):
            qp = quick_pass(ctx.world, stack_tasks([chunk[k].task for k in todo]), poses=node.poses,
                            robots=node.robots)
        # A start walled off from the robots is not hopeless (in clutter the robots' own pocket can be
        # small): such candidates go once to the end of the list, behind every reachable one, and are
        # simulated when they come round again.
        walled = [k for k, w in zip(todo, qp.walled_off) if w]
        node.cands += [chunk[k]._replace(deferred=True) for k in walled if not chunk[k].deferred]
        run.stats["quick_pass_rejected"] += int(np.sum(~qp.ok)) - len(walled)
        bad = {k for k, o in zip(todo, qp.ok) if not o and not (k in walled and chunk[k].deferred)}
        chunk = [c for k, c in enumerate(chunk) if k not in bad]
    return [c._replace(passed=True) for c in chunk]


def expand(ctx: SearchContext, run: SearchRun, node: SearchNode) -> tuple:
    """One batch of ``node``: simulate, make children. Returns ``(found, children)``: found is
    ``(path, child)`` when a child passed Eq. 7 (children then empty), else None; children: the new
    nodes for the queue, in the order they were made."""
    if node.cands is None:
        node.cands = candidates(ctx, run, node)
    batch = next_batch(ctx, run, node)
    run.stats["expansions"] += 1
    if not batch:
        return None, []
    out, cost = _simulate(ctx, run, node, batch)
    ends = (shapely.Point(ctx.scene.start), shapely.Point(ctx.scene.goal))
    children = []
    for i, cand in enumerate(batch):
        _record_mode(ctx, cand, out, i)
        child = _child(ctx, run, node, cand, out, i, float(cost[i]), ends)
        if child is not None:
            children.append(child)
    node.children += len(children)
    if run.records is not None:
        run.records.append(expansion_record(ctx.params, node, batch, children))
    _penalise_stuck(ctx, run, node, batch, children)
    run.stats["children"] += len(children)
    found = _terminal_checks(ctx, run, children)
    return found, ([] if found is not None else [child for _, _, child in children])


def _simulate(ctx: SearchContext, run: SearchRun, node: SearchNode, batch: list) -> tuple:
    """ONE physics call for ``batch`` (padded to a bucket size by repeating its last candidate).
    Returns (PushOutcome, cost f[B'] of Eq. 11), B' the padded size."""
    b = len(batch)
    size = next((s for s in BUCKETS if s >= b), b)
    tasks = stack_tasks([c.task for c in batch + [batch[-1]] * (size - b)])
    with run.timed("time_physics_s"):
        out = simulate_pushes(ctx.world, tasks, sim=ctx.sim, poses=node.poses, robots=node.robots)
        cost, _, _ = push_cost(ctx.world, tasks, out, robots=node.robots, poses=node.poses)
    run.stats["physics_calls"] += 1
    run.stats["simulated_pushes"] += b
    run.stats["mode_table_hits"] += sum(c.hit for c in batch)
    run.stats["valid_rollouts"] += int(np.sum(out.valid[:b]))
    return out, cost


def _record_mode(ctx: SearchContext, cand: Candidate, out, i: int) -> None:
    """Record rollout ``i`` in the ModeTable: validated when it is valid and the body moved at least
    half the commanded distance (the robots kept contact)."""
    if not ctx.use_table:
        return
    tracked = bool(out.valid[i]) and out.displacement[i] >= 0.5 * np.linalg.norm(cand.task.velocity[:2]) * ctx.duration
    ctx.table.record(ctx.scene.movables[cand.movable], cand.key, tracked,
                     cand.task.contacts[cand.task.active] if tracked else None)


def _progress(ctx: SearchContext, node: SearchNode, tg: Target, poses, ends) -> tuple:
    """How far the rollout ending at ``poses`` f[M, 3] got on ``tg``: (opened, fraction of the one-hop
    widening achieved in [0, 1], widening [m])."""
    w = float(ctx.scene.width)
    if tg.kind == "gap":
        a, b = (ctx.bodies.body(x, poses) for x in tg.bodies)
        new_w = float(a.distance(b))
        opened = new_w >= w + ctx.cfg.open_margin
        frac = 1.0 if opened else max(0.0, (new_w - tg.width) / max(w - tg.width, 1e-9))
        return opened, frac, new_w - tg.width
    r = 0.5 * w
    m = tg.movables[0]
    ep = ends[0] if ctx.bodies.movable(m, node.poses[m]).distance(ends[0]) < r else ends[1]
    new_w = float(ctx.bodies.movable(m, poses[m]).distance(ep))
    opened = new_w >= r
    frac = 1.0 if opened else max(0.0, (new_w - tg.width) / max(r - tg.width, 1e-9))
    return opened, frac, new_w - tg.width


def _drops_on_endpoint(ctx: SearchContext, out, i: int, poses, ends) -> bool:
    """Whether rollout ``i`` left a movable it moved on an endpoint disk ``B(., W/2)``."""
    r = 0.5 * float(ctx.scene.width)
    moved = np.nonzero(out.moved[i] > 0.01)[0]
    return any(ctx.bodies.movable(mm, poses[mm]).distance(e) < r for mm in moved for e in ends)


def _child(ctx: SearchContext, run: SearchRun, node: SearchNode, cand: Candidate, out, i: int, cost: float,
           ends) -> tuple | None:
    """The child of rollout ``i`` as (opened, predicted to connect, node), or None when the rollout is
    invalid, made too little progress, dropped a body on an endpoint, or reached a state seen before.
    Its estimate: ``Cost(g)`` less the achieved part of the one-hop cost (opened: the tail)."""
    tg = node.targets[cand.target]
    if not out.valid[i] or not np.isfinite(cost):
        return None
    poses = out.poses[i]
    opened, frac, progress = _progress(ctx, node, tg, poses, ends)
    if not opened and progress < ctx.cfg.min_progress:
        return None
    if tg.kind == "gap" and _drops_on_endpoint(ctx, out, i, poses, ends):
        return None
    key = state_key(poses, out.robots[i], ctx.cfg)
    if key in run.seen:
        return None
    run.seen.add(key)
    sp = ScheduledPush(task=PushTask(*(np.asarray(getattr(cand.task, f)) for f in PushTask._fields)),
                       gap=tg.bodies, cost=cost, poses_before=node.poses.copy(),
                       poses_after=np.asarray(poses, np.float64).copy(),
                       robots_before=node.robots.copy(), robots_after=np.asarray(out.robots[i], np.float64).copy())
    h = tg.tail if opened else max(tg.cost - frac * tg.one_hop, tg.tail)
    child = run.new_node(poses, out.robots[i], node.schedule + (sp,), node.chi + cost, h)
    child.origin = (node.nid, cand.target)
    child.opened = node.opened + int(opened)
    child.parent_h = node.h
    return opened, tg.final, child


def _penalise_stuck(ctx: SearchContext, run: SearchRun, node: SearchNode, batch: list, children: list) -> None:
    # Gaps whose every simulated push in this batch failed to widen them get dearer (for the rest of
    # the search): the presearch then prefers routes around obstacles stuck in clutter.
    tried = {node.targets[c.target].bodies for c in batch}
    widened = {node.targets[ch.origin[1]].bodies for _, _, ch in children}
    for pair in tried - widened:
        run.stuck[pair] = run.stuck.get(pair, 0.0) + ctx.cfg.stuck_penalty


def _terminal_checks(ctx: SearchContext, run: SearchRun, children: list):
    """Algorithm 1, line 5.5: the children that opened their gap are tested against Eq. 7 at once,
    those the presearch predicts to connect first (a WCCG and a connectivity query each), at most
    ``terminal_checks``. Returns (path, child) for the first that passes, else None."""
    cfg = ctx.cfg
    checks = sorted([c for c in children if c[0] and (c[1] or not cfg.presearch)],
                    key=lambda c: priority(c[2], cfg))
    for _, _, child in checks[:cfg.terminal_checks]:
        path = check_node(ctx, run, child)
        if path is not None:
            return path, child
    return None
