"""Evaluating a node (Algorithm 1, step 1): Eq. 7's termination test, then what to open next: the
ranked gaps of the blocking frontier (Eqs. 8-9) or, when start and goal share a face, the movables
intruding on an endpoint disk (Remark 5), and the node's estimate ``h = min Cost``."""
from __future__ import annotations

import math

import numpy as np
import shapely

from jaxplan.pusharound.faces import build_skeleton
from jaxplan.pusharound.ranking import DEAD_END_PENALTY, Gap, candidate_gaps, one_hop_terms, rank_gaps
from jaxplan.pusharound.scene import PushScene
from jaxplan.pusharound.search.bodies import unit
from jaxplan.pusharound.search.context import SearchContext, SearchRun
from jaxplan.pusharound.search.facegraph import face_graph
from jaxplan.pusharound.search.nodes import EMPTY_CHECK, Eq7Check, SearchNode, Target, remaining_estimate
from jaxplan.pusharound.search.records import TargetTerms
from jaxplan.pusharound.wccg import build_wccg, connectivity, w_clear_path

__all__ = ["check_node", "endpoint_targets", "evaluate_node", "refresh_stuck", "scene_at"]


def scene_at(ctx: SearchContext, node: SearchNode) -> PushScene:
    """The scene with the node's movable poses and robot positions."""
    return ctx.scene.with_poses(node.poses).replace(robots=node.robots)


def check_node(ctx: SearchContext, run: SearchRun, node: SearchNode):
    """WCCG and Eq. 7 of ``node`` (Algorithm 1's termination test), once per node. Returns the W-clear
    path f64[P, 2] when Eq. 7 holds (and a path is found), else None; keeps the WCCG, the frontier
    and the skeleton in ``node.check`` for the ranking."""
    if node.check is not None:
        return node.check.path
    with run.timed("time_rank_s"):
        run.stats["checks"] += 1
        state = scene_at(ctx, node)
        g = build_wccg(state)
        sk = build_skeleton(g)
        conn = connectivity(g, state.start, state.goal, skeleton=sk)
        path = w_clear_path(g, state.start, state.goal) if conn.connected else None
        node.check = Eq7Check(g, conn, path, sk)
    return path


def evaluate_node(ctx: SearchContext, run: SearchRun, node: SearchNode):
    """:func:`check_node`, then the targets of ``node`` and its estimate ``h`` (min Cost). Returns the
    W-clear path when Eq. 7 holds, else None."""
    path = check_node(ctx, run, node)
    node.evaluated = True
    if path is not None:
        return path
    with run.timed("time_rank_s"):
        run.stats["evaluations"] += 1
        g, conn, _, sk = node.check
        if not conn.same_face:
            targets = _gap_targets(ctx, run, node, g, sk, candidate_gaps(g, conn.frontier))
        else:
            targets = endpoint_targets(ctx, node.poses, terms=run.records is not None)
        _set_targets(run, node, targets)
        node.check = EMPTY_CHECK      # the WCCG is not needed any more
    return None


def _set_targets(run: SearchRun, node: SearchNode, targets: list) -> None:
    node.targets = targets
    node.stuck_at = {tg.bodies: run.stuck.get(tg.bodies, 0.0) for tg in targets if tg.kind == "gap"}
    node.h = min((tg.cost for tg in targets), default=math.inf)
    if node.opened and not node.h < node.parent_h - 1e-6:
        node.opened -= 1      # the gap it opened did not bring the goal closer: no bonus


def _one_hop(ctx: SearchContext, gap: Gap, robots, width: float) -> float:
    """Eq. 8's ``C(g)`` of ``gap`` for the team at ``robots`` f[N, 2] (W = ``width`` [m])."""
    c_t, c_p = one_hop_terms(gap, robots, width, ctx.params.mass_ref)
    return float(ctx.params.lambda_t) * c_t + float(ctx.params.lambda_p) * c_p


def _gap_targets(ctx: SearchContext, run: SearchRun, node: SearchNode, g, sk, gaps: list) -> list:
    """The frontier's ``gaps`` as targets, cheapest first: ``Cost(g)`` = the one-hop cost plus the
    stuck penalty, plus the presearch's tail. When the search records gaps, each target carries its
    :class:`TargetTerms`."""
    tails, leaves = _tails(ctx, run, node, g, sk, gaps)
    targets = []
    for gap in gaps:
        one = _one_hop(ctx, gap, node.robots, g.width) + run.stuck.get(gap.bodies, 0.0)
        tail, final = tails.get(gap.bodies, (0.0, False))
        tg = _gap_target(ctx, g, gap, node.poses, one + tail, tail, one, final)
        if leaves is not None:
            first = np.asarray(one_hop_terms(gap, node.robots, g.width, ctx.params.mass_ref), np.float64)
            tg = tg._replace(terms=TargetTerms(first, *leaves.get(gap.bodies, _NO_TAIL)))
        targets.append(tg)
    targets.sort(key=lambda tg: tg.cost)
    return targets


# The tail terms of a target without a presearch continuation: one leaf of zeros.
_NO_TAIL = (np.zeros((1, 3)), np.ones(1, bool))


def _tails(ctx: SearchContext, run: SearchRun, node: SearchNode, g, sk, gaps: list) -> tuple:
    """(gap bodies -> (Eq. 9's tail ``Cost(g) - C(g)``, crossing it is predicted to connect), and
    when recording gap bodies -> the tail's leaves (tail f[P, 3], mask bool[P]), else None); both
    empty without presearch (one-hop costs only)."""
    leaves = {} if run.records is not None else None
    if not (ctx.cfg.presearch and gaps):
        return {}, leaves
    if ctx.cfg.presearch_mode == "graph":
        return _graph_tails(ctx, run, g, sk, leaves)
    return _beam_tails(ctx, run, node, g, gaps), (None if leaves is None else run.leaf_memo)


def _graph_tails(ctx: SearchContext, run: SearchRun, g, sk, leaves: dict | None) -> tuple:
    run.stats["rank_calls"] += 1
    fg = face_graph(g, ctx.scene.goal, ctx.params, run.stuck, skeleton=sk, terms=leaves is not None)
    if leaves is not None:
        leaves.update({pair: (t[None], np.ones(1, bool)) for pair, t in fg.terms.items()})
    return {pair: (t if math.isfinite(t) else DEAD_END_PENALTY, fg.final[pair]) for pair, t in fg.tail.items()}, leaves


def _beam_tails(ctx: SearchContext, run: SearchRun, node: SearchNode, g, gaps: list) -> dict:
    # Eq. 9's tail of a gap depends on the region behind the gap, not on where the robots are:
    # memoised per gap (Remark 3's cached transitions), and only gaps not seen before are presearched.
    new = [gap.bodies for gap in gaps if gap.bodies not in run.tail_memo]
    if new:
        run.stats["rank_calls"] += 1
        rk = rank_gaps(scene_at(ctx, node), ctx.params, g=g, robots=node.robots, first=new)
        for k, gap in enumerate(rk.gaps):
            cost = float(rk.cost[k])
            run.tail_memo[gap.bodies] = (max(cost - _one_hop(ctx, gap, node.robots, g.width), 0.0),
                                         len(rk.sequences[k]) == 0 and cost < DEAD_END_PENALTY)
            if run.records is not None:
                run.leaf_memo[gap.bodies] = (np.asarray(rk.features.tail[k], np.float64),
                                             np.asarray(rk.features.mask[k], bool))
    return run.tail_memo


def _gap_target(ctx: SearchContext, g, gap: Gap, poses, cost, tail, one, final) -> Target:
    """The target of ``gap`` with the movables at ``poses`` f[M, 3]: per adjacent movable the unit
    direction that widens the gap (from the other body's bridge node to its own; from the other
    body's centroid where the bodies touch)."""
    away = {}
    pu, pv = gap.points
    for m in gap.movables:
        mine_first = int(g.comp_body[g.bridge_uv[gap.bridges[np.argmin(g.bridge_width[gap.bridges])], 0]]) == m
        d = (pu - pv) if mine_first else (pv - pu)
        if np.linalg.norm(d) < 1e-6:
            other = [b for b in gap.bodies if b != m]
            oc = ctx.bodies.body(other[0], poses).centroid if other else shapely.Point(gap.insertion)
            d = np.asarray(poses[m][:2]) - np.array([oc.x, oc.y])
        away[m] = unit(d)
    return Target("gap", tuple(int(b) for b in gap.bodies), tuple(int(m) for m in gap.movables),
                  float(gap.width), float(cost), float(tail), float(one), away, bool(final))


def endpoint_targets(ctx: SearchContext, poses, *, terms: bool = False) -> list:
    """Remark 5: the movables (at ``poses`` f[M, 3]) within W/2 of the start or the goal, cheapest
    first; each is pushed away from its endpoint at the cost of Eq. 8's widening term. terms: attach
    each target's :class:`TargetTerms` (the gap recorder)."""
    r = 0.5 * float(ctx.scene.width)
    out = []
    for ep in (ctx.scene.start, ctx.scene.goal):
        pt = shapely.Point(ep)
        for m in range(ctx.bodies.m):
            d = ctx.bodies.movable(m, poses[m]).distance(pt)
            if d < r:
                away = unit(np.asarray(poses[m][:2]) - np.asarray(ep, np.float64))
                c_p = (r - d) * ctx.scene.movables[m].mass / ctx.params.mass_ref
                cost = float(ctx.params.lambda_p) * (r - d) * ctx.scene.movables[m].mass / ctx.params.mass_ref
                tt = TargetTerms(np.array([0.0, c_p]), *_NO_TAIL) if terms else None
                out.append(Target("endpoint", (m,), (m,), float(d), cost + 1e-3, 0.0, cost + 1e-3, {m: away}, True,
                                  tt))
    out.sort(key=lambda tg: tg.cost)
    return out


def refresh_stuck(ctx: SearchContext, run: SearchRun, node: SearchNode) -> bool:
    """Raise the one-hop costs of an evaluated node's targets by the stuck penalties added since it
    was evaluated (the penalties only grow, and an estimate fixed at evaluation would make nodes
    evaluated early look cheaper than their later siblings). Returns whether any cost changed."""
    changed = False
    for k, tg in enumerate(node.targets or ()):
        if tg.kind != "gap":
            continue
        grown = run.stuck.get(tg.bodies, 0.0) - node.stuck_at.get(tg.bodies, 0.0)
        if grown > 0:
            node.targets[k] = tg._replace(cost=tg.cost + grown, one_hop=tg.one_hop + grown)
            node.stuck_at[tg.bodies] = run.stuck[tg.bodies]
            changed = True
    if changed:
        node.h = (remaining_estimate(node, ctx.cfg) if node.cands is not None
                  else min(tg.cost for tg in node.targets))
    return changed
