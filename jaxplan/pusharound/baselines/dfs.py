"""DFS-WCCG (Table I): simulation-in-the-loop depth-first search guided by the WCCG.

:func:`dfs_wccg`: at a node whose state fails Eq. 7, the movables adjacent to the frontier gaps
(unranked, in the frontier's order) each get four fixed axis-aligned pushes (+x, +y, -x, -y; both
robots on the back face, one robot when the face is too narrow for two), all simulated (no
quick-pass), and the valid children are pushed onto a stack, first candidate explored first. Depth,
simulation and time limits stop it.
"""
from __future__ import annotations

import math

import numpy as np

from jaxplan.pusharound.baselines.common import BaselineConfig, Env, check_config, make_result, push_tasks, scheduled
from jaxplan.pusharound.ranking import candidate_gaps
from jaxplan.pusharound.scene import PushScene
from jaxplan.pusharound.search import SearchResult
from jaxplan.pusharound.wccg import build_wccg, connectivity

__all__ = ["dfs_wccg"]

_AXES = (0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi)


def dfs_wccg(scene: PushScene, config: BaselineConfig = BaselineConfig(), world=None, sim=None) -> SearchResult:
    """DFS-WCCG (module docstring): depth-first, four axis-aligned pushes per frontier movable, every
    candidate simulated."""
    check_config(config)
    env = Env(scene, config, world, sim)
    robots0 = np.asarray(scene.robots, np.float64)
    stack = [(scene.poses.copy(), robots0.copy(), [])]
    seen = set()
    best = stack[0]
    reason = "search space exhausted"
    while stack:
        poses, robots, schedule = stack.pop()
        key = tuple(np.round(poses[:, :2], 2).reshape(-1))
        if key in seen:
            continue
        seen.add(key)
        g = build_wccg(scene, poses=poses)
        conn = connectivity(g, scene.start, scene.goal)
        if conn.connected:
            return make_result(env, True, schedule, poses, "")
        if len(schedule) > len(best[2]):
            best = (poses, robots, schedule)
        if env.elapsed() > config.time_limit_s:
            reason = "time limit"
            break
        if env.sims >= config.dfs_max_sims:
            reason = "simulation budget"
            break
        if len(schedule) >= config.dfs_depth or conn.frontier is None:
            continue
        env.expansions += 1
        movables = []
        for gap in candidate_gaps(g, conn.frontier):
            movables += [m for m in gap.movables if m not in movables]
        tasks = []
        for m in movables:
            for a in _AXES:
                tasks += push_tasks(env, m, a, config.dfs_distance, poses, teams=(2,)) or \
                    push_tasks(env, m, a, config.dfs_distance, poses, teams=(1,))
        if not tasks:
            continue
        st, out, cost = env.simulate(tasks, poses, robots)
        children = [k for k in range(len(cost)) if out.valid[k] and out.displacement[k] > env.world.config.move_tol]
        for k in reversed(children):     # first candidate on top of the stack
            stack.append((out.poses[k].copy(), out.robots[k].copy(),
                          schedule + [scheduled(st, k, cost[k], poses, out, robots)]))
    return make_result(env, False, best[2], best[0], reason)
