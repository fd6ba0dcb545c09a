"""SL-Push (Table I): a route cleared by displacing its blockers perpendicular to it.

- :func:`sl_push_offline` (**SL-Push, offline**): a waypointed route (the W-clear path around the
  fixed obstacles only, Section III-A.3 with no movables, ``route_margin`` off them), the movables
  within W/2 of it are the blockers, and each is displaced geometrically by the minimal distance
  perpendicular to the local route direction that clears the corridor (the nearer side, unless
  that puts it into a fixed obstacle or out of the workspace). No physics during planning: the
  displacements are then executed open loop in physics
  (:func:`jaxplan.pusharound.baselines.execute_open_loop`), which may fail.
- :func:`sl_push_sim` (**SL-Push, sim**): the same route and blockers, but every displacement is
  validated in physics while planning: for the first blocker along the route, the candidates (both
  sides and both ways along the route x team of 2 or 1 x the minimal distance and 0.25 m more) are
  simulated in one batch from the
  current physical state; the valid candidate leaving the fewest blockers (then the cheapest) is
  applied, and so on until the corridor is clear.
"""
from __future__ import annotations

import math
import time

import numpy as np
from shapely.geometry import LineString

from jaxplan.pusharound.baselines.common import (
    BaselineConfig,
    Env,
    check_config,
    displacements,
    eq7,
    make_result,
    moved_polygon,
    open_loop_result,
    push_tasks,
    route_blockers,
    scheduled,
    sweep_ok,
)
from jaxplan.pusharound.scene import PushScene
from jaxplan.pusharound.search import SearchResult
from jaxplan.pusharound.wccg import build_wccg, w_clear_path

__all__ = ["sl_push_offline", "sl_push_sim"]


def _fixed_route(scene: PushScene, margin: float) -> np.ndarray | None:
    """The W-clear path around the fixed obstacles only (f64[P, 2]), kept ``margin`` beyond W/2 from
    them where it fits (else the tightest W-clear path), or None."""
    g = build_wccg(scene.replace(movables=()))
    for delta in (margin, None):
        path = w_clear_path(g, scene.start, scene.goal, delta=delta)
        if path is not None:
            return path
    return None


def _feasible_first(scene: PushScene, poses, m: int, options: list) -> list:
    """``options`` [(angle, distance)] reordered: displacements that keep the body in the workspace and
    off the fixed obstacles first (a geometric check only, no physics)."""
    return sorted(options, key=lambda o: not sweep_ok(scene, poses, m, *o))


def sl_push_offline(scene: PushScene, config: BaselineConfig = BaselineConfig(), world=None, sim=None) -> SearchResult:
    """SL-Push without physics in planning (module docstring), then executed open loop in physics."""
    check_config(config)
    env = Env(scene, config, world, sim)
    t0 = time.perf_counter()
    path = _fixed_route(scene, config.route_margin)
    if path is None:
        return make_result(env, False, [], scene.poses, "no route around the fixed obstacles")
    route = LineString(path)
    clear = 0.5 * scene.width + config.margin
    poses = scene.poses.copy()
    plan = []
    for m in route_blockers(scene, poses, route, 0.5 * scene.width):
        # A few rounds: a curved route may still touch the body after one straight shift.
        for _ in range(3):
            poly = scene.with_poses(poses).movables[m].polygon
            if poly.distance(route) >= 0.5 * scene.width:
                break
            angle, dist = _feasible_first(scene, poses, m, displacements(poly, route, clear))[0]
            plan.append((m, angle, dist))
            _, poses[m] = moved_polygon(scene, poses, m, angle, dist)
    plan_time = time.perf_counter() - t0
    return open_loop_result(env, plan, plan_time, "")


def sl_push_sim(scene: PushScene, config: BaselineConfig = BaselineConfig(), world=None, sim=None) -> SearchResult:
    """SL-Push with every displacement validated in physics while planning (module docstring)."""
    check_config(config)
    env = Env(scene, config, world, sim)
    path = _fixed_route(scene, config.route_margin)
    if path is None:
        return make_result(env, False, [], scene.poses, "no route around the fixed obstacles")
    route = LineString(path)
    half, clear = 0.5 * scene.width, 0.5 * scene.width + config.margin
    poses = scene.poses.copy()
    robots = np.asarray(scene.robots, np.float64).copy()
    schedule, tries = [], {}
    while True:
        blockers = route_blockers(scene, poses, route, half)
        if not blockers:
            ok = eq7(scene, poses)
            return make_result(env, ok, schedule, poses, "" if ok else "corridor clear but Eq. 7 fails")
        if env.elapsed() > config.time_limit_s:
            return make_result(env, False, schedule, poses, "time limit")
        m = blockers[0]
        tries[m] = tries.get(m, 0) + 1
        if tries[m] > config.max_rounds:
            return make_result(env, False, schedule, poses, f"movable {m} could not be cleared")
        env.expansions += 1
        poly = scene.with_poses(poses).movables[m].polygon
        side = displacements(poly, route, clear)
        # Sideways (both sides, minimal and longer) and, as a fallback, along the route both ways.
        along = [(side[0][0] + 0.5 * math.pi, clear), (side[0][0] - 0.5 * math.pi, clear)]
        tasks = [t for angle, dist in side + along for extra in (0.0, 0.25)
                 for t in push_tasks(env, m, angle, dist + extra, poses)]
        if not tasks:
            return make_result(env, False, schedule, poses, f"no contact mode for movable {m}")
        st, out, cost = env.simulate(tasks, poses, robots)
        if not np.any(out.valid):
            return make_result(env, False, schedule, poses, f"no physically valid push for movable {m}")
        left = [len(route_blockers(scene, out.poses[k], route, half)) if out.valid[k] else np.inf
                for k in range(len(cost))]
        k = min(range(len(cost)), key=lambda i: (left[i], cost[i]))
        schedule.append(scheduled(st, k, cost[k], poses, out, robots))
        poses, robots = out.poses[k].copy(), out.robots[k].copy()
