"""Plumbing shared by the baseline planners of :mod:`jaxplan.pusharound.baselines`.

:class:`BaselineConfig` (their static settings); :class:`Env` (world, simulator and counters of one
planner run, with batched simulation and Eq. 11 costs); the search's result types filled from a
planner's schedule (:func:`make_result`, :func:`scheduled`); :func:`execute_open_loop` (geometric
pushes executed open loop in physics) and :func:`open_loop_result` (success judged on the executed
state); :func:`schedule_duration` (the execution-time measure of every planner); and the route
geometry: :func:`route_blockers` (movables too close to a route), :func:`displacements` (the two
perpendicular shifts that clear it), :func:`moved_polygon` and :func:`sweep_ok` (a geometric check of
a straight displacement).
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import shapely
from shapely.geometry import LineString
from shapely.ops import nearest_points

from jaxplan.pusharound.physics import PushWorld, build_push_world
from jaxplan.pusharound.push import (
    MAX_BATCH,
    PushOutcome,
    PushTask,
    direction_tasks,
    make_push_simulator,
    push_cost,
    simulate_pushes,
    stack_tasks,
    start_positions,
)
from jaxplan.pusharound.scene import PushScene
from jaxplan.pusharound.search import ScheduledPush, SearchResult, SearchStats
from jaxplan.pusharound.wccg import build_wccg, connectivity, w_clear_path

__all__ = ["BaselineConfig", "Env", "check_config", "displacements", "eq7", "execute_open_loop", "make_result",
           "moved_polygon", "open_loop_result", "push_tasks", "route_blockers", "schedule_duration", "scheduled",
           "sweep_ok"]


@dataclasses.dataclass(frozen=True)
class BaselineConfig:
    """Static settings of the baselines (all ours; the paper does not give them).

    time_limit_s: planning wall-clock limit [s]; speed: push speed of the movable [m/s];
    max_push_s: longest single push task [s] (<= the rollout horizon, 2 s); margin: extra clearance
    beyond W/2 a displacement aims for [m]; dfs_distance: length of DFS-WCCG's axis-aligned pushes [m];
    dfs_depth: DFS depth limit; dfs_max_sims: DFS simulation budget; grid: Rec-NAMO cell size [m];
    mass_penalty: Rec-NAMO cost per kg of a movable a route passes through [m / kg];
    recursion: Rec-NAMO's push-recursion depth; max_rounds: SL-Push (sim) push attempts per blocker;
    route_margin: SL-Push's route keeps this much beyond W/2 from fixed obstacles where it fits [m];
    backend: physics engine ("auto", "c", "mjx").
    """

    time_limit_s: float = 60.0
    speed: float = 0.4
    max_push_s: float = 2.0
    margin: float = 0.1
    dfs_distance: float = 0.6
    dfs_depth: int = 8
    dfs_max_sims: int = 600
    grid: float = 0.1
    mass_penalty: float = 0.3
    recursion: int = 2
    max_rounds: int = 4
    route_margin: float = 0.25
    backend: str = "auto"

    def replace(self, **changes) -> BaselineConfig:
        return dataclasses.replace(self, **changes)


def check_config(cfg: BaselineConfig) -> None:
    if not isinstance(cfg, BaselineConfig):
        raise ValueError(f"config: expected a BaselineConfig; got {type(cfg).__name__}.")
    for name in ("time_limit_s", "speed", "max_push_s", "dfs_distance", "grid"):
        if not getattr(cfg, name) > 0:
            raise ValueError(f"BaselineConfig.{name}: must be > 0; got {getattr(cfg, name)!r}.")
    if not 0 < cfg.max_push_s <= 2.0 + 1e-9:
        raise ValueError("BaselineConfig.max_push_s: must be in (0, 2] s (the rollout horizon); "
                         f"got {cfg.max_push_s!r}.")


# --------------------------------------------------------------------------------------------- plumbing

_BUCKETS = (8, 16, 32, 64)    # physics batch sizes (as the search's)


class Env:
    """World, simulator and counters shared by one planner run."""

    def __init__(self, scene: PushScene, cfg: BaselineConfig, world: PushWorld | None, sim):
        self.scene, self.cfg = scene, cfg
        self.world = build_push_world(scene) if world is None else world
        self.sim = make_push_simulator(self.world, cfg.backend) if sim is None else sim
        self.sims = 0
        self.calls = 0
        self.expansions = 0
        self.t0 = time.perf_counter()

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def simulate(self, tasks: list, poses, robots, count: bool = True) -> tuple[PushTask, PushOutcome, np.ndarray]:
        """Simulate ``tasks`` (any number, in chunks of MAX_BATCH) from (poses f[M, 3], robots f[N, 2]);
        returns the stacked tasks, outcomes and Eq. 11 costs f[B]."""
        outs, costs = [], []
        for k in range(0, len(tasks), MAX_BATCH):
            chunk = tasks[k:k + MAX_BATCH]
            # Pad to a bucket size by repeating the last task: the simulator compiles its policy once
            # per batch size (about 2 s each on the shared 2-core CPU), so few sizes keep that bounded.
            size = next(b for b in _BUCKETS if b >= len(chunk))
            batch = stack_tasks(chunk + [chunk[-1]] * (size - len(chunk)))
            out = simulate_pushes(self.world, batch, sim=self.sim, poses=poses, robots=robots)
            cost = push_cost(self.world, batch, out, robots=robots, poses=poses)[0]
            costs.append(cost[:len(chunk)])
            outs.append(PushOutcome(*(np.asarray(v)[:len(chunk)] for v in out)))
            if count:
                self.sims += len(chunk)
                self.calls += 1
        out = PushOutcome(*(np.concatenate([getattr(o, f) for o in outs]) for f in PushOutcome._fields))
        return stack_tasks(tasks), out, np.concatenate(costs)


def _task_at(tasks: PushTask, k: int) -> PushTask:
    return PushTask(*(np.asarray(getattr(tasks, f))[k] for f in PushTask._fields))


def eq7(scene: PushScene, poses) -> bool:
    return bool(connectivity(build_wccg(scene, poses=poses), scene.start, scene.goal).connected)


def make_result(env: Env, success: bool, schedule: list, poses, reason: str, path=None,
                robots=None) -> SearchResult:
    """The search's result type, filled field by field (statistics this module does not keep are 0)."""
    if robots is None:
        robots = schedule[-1].robots_after if schedule else env.scene.robots
    final = env.scene.with_poses(poses).replace(robots=np.asarray(robots, np.float64))
    if success and path is None:
        path = w_clear_path(build_wccg(final), final.start, final.goal)
    values = {"planning_time_s": env.elapsed(), "simulated_pushes": env.sims, "expansions": env.expansions,
              "physics_calls": env.calls, "max_depth": len(schedule)}
    stats = SearchStats(**{f: values.get(f, 0) for f in SearchStats._fields})
    values = {"success": bool(success), "schedule": list(schedule), "final_scene": final, "path": path,
              "stats": stats, "reason": reason}
    return SearchResult(**{f: values.get(f) for f in SearchResult._fields})


def scheduled(tasks: PushTask, k: int, cost: float, poses, out: PushOutcome, robots) -> ScheduledPush:
    values = {"task": _task_at(tasks, k), "gap": (int(np.asarray(tasks.movable)[k]),), "cost": float(cost),
              "poses_before": np.asarray(poses, np.float64), "poses_after": np.asarray(out.poses[k], np.float64),
              "robots_before": np.asarray(robots, np.float64), "robots_after": np.asarray(out.robots[k], np.float64)}
    return ScheduledPush(**{f: values.get(f) for f in ScheduledPush._fields})


def schedule_duration(world: PushWorld, schedule) -> float:
    """Execution time of a schedule [s]: the sum over its pushes of Eq. 11's ``delta_T`` (transition
    from the robots' previous positions at ``transit_speed`` plus the push duration)."""
    total = 0.0
    for p in schedule:
        one = stack_tasks([p.task])
        dist = np.where(one.active[0],
                        np.linalg.norm(_starts(world, one, p.poses_before) - p.robots_before, axis=-1), 0)
        total += float(dist.max()) / world.config.transit_speed + float(one.duration[0])
    return total


def _starts(world: PushWorld, tasks: PushTask, poses) -> np.ndarray:
    return start_positions(world, tasks, np.asarray(poses, np.float64))[0]


def push_tasks(env: Env, movable: int, angle: float, distance: float, poses, teams=(2, 1)) -> list:
    """Tasks moving ``movable`` by ``distance`` [m] along world ``angle`` [rad], one per team size in
    ``teams`` that fits the face (a push longer than ``speed * max_push_s`` is cut to that length)."""
    n_all = len(env.world.robot_adr)
    teams = tuple(t for t in teams if 1 <= t <= n_all)
    dur = float(np.clip(distance / env.cfg.speed, 0.05, env.cfg.max_push_s))
    return direction_tasks(env.world, int(movable), [angle], env.cfg.speed, dur, n_robots=teams, poses=poses)


# ------------------------------------------------------------------------------------------ execution

def execute_open_loop(env_or_scene, plan: list, config: BaselineConfig = BaselineConfig(), world=None, sim=None,
                      count: bool = False):
    """Execute geometric pushes ``plan = [(movable, angle [rad], distance [m]), ...]`` open loop in
    physics from the scene's state: each is cut into tasks of at most ``speed * max_push_s`` and
    simulated one after another (two robots on the back face, one when it is too narrow).

    Returns ``(schedule, poses f[M, 3], robots f[N, 2], ok, reason)``: ``ok`` is False at the first
    push with no contact mode or a physically invalid outcome (hit a fixed obstacle, left the
    workspace, tipped, diverged); execution stops there.
    """
    env = env_or_scene if isinstance(env_or_scene, Env) else Env(env_or_scene, config, world, sim)
    poses = env.scene.poses.copy()
    robots = np.asarray(env.scene.robots, np.float64).copy()
    schedule = []
    step = env.cfg.speed * env.cfg.max_push_s
    for m, angle, dist in plan:
        left = float(dist)
        while left > 1e-3:
            d = min(left, step)
            tasks = push_tasks(env, m, angle, d, poses)
            if not tasks:
                return schedule, poses, robots, False, f"no contact mode for movable {m}"
            st, out, cost = env.simulate(tasks[:1], poses, robots, count=count)
            schedule.append(scheduled(st, 0, cost[0], poses, out, robots))
            poses, robots = out.poses[0].copy(), out.robots[0].copy()
            if not out.valid[0]:
                why = ("hit a fixed obstacle" if out.hit_fixed[0] else "left the workspace" if out.left_workspace[0]
                       else "tipped" if out.tipped[0] else "diverged")
                return schedule, poses, robots, False, f"push of movable {m} {why}"
            left -= d
    return schedule, poses, robots, True, ""


def open_loop_result(env: Env, plan: list, plan_time: float, reason: str) -> SearchResult:
    """Execute ``plan`` in physics (not counted as planning) and judge success on the final state."""
    schedule, poses, robots, ok, why = execute_open_loop(env, plan)
    success = ok and eq7(env.scene, poses)
    if not reason:
        reason = "" if success else (why or "executed, but Eq. 7 fails on the final state")
    res = make_result(env, success, schedule, poses, reason)
    return _with_planning_time(res, plan_time)


def _with_planning_time(res: SearchResult, seconds: float) -> SearchResult:
    return res._replace(stats=res.stats._replace(planning_time_s=float(seconds)))


# ------------------------------------------------------------------------------------------ routes

def sweep_ok(scene: PushScene, poses, m: int, angle: float, dist: float, tol: float = 0.02) -> bool:
    """Geometric check of a straight displacement: the body's swept hull stays in the workspace and
    comes no closer than ``tol`` [m] to a fixed obstacle it was not already that close to (the same
    1 cm-scale contact rule as the physics' ``hit_fixed``)."""
    before = scene.with_poses(poses).movables[m].polygon
    after, _ = moved_polygon(scene, poses, m, angle, dist)
    sweep = shapely.union_all([before, after]).convex_hull
    if not scene.workspace_polygon.contains(after):
        return False
    for f in scene.fixed:
        d = sweep.distance(f.polygon)
        if d < tol and d < before.distance(f.polygon) - 1e-9 or (d < tol and after.distance(f.polygon) < tol):
            return False
    return True


def route_blockers(scene: PushScene, poses, route: LineString, clear: float) -> list:
    """Movables closer than ``clear`` to the route, in the order of their nearest point along it."""
    placed = scene.with_poses(poses)
    polys = np.asarray([m.polygon for m in placed.movables], dtype=object)
    if len(polys) == 0:
        return []
    d = shapely.distance(polys, route)
    hit = np.nonzero(d < clear)[0]
    along = [route.project(nearest_points(route, polys[k])[0]) for k in hit]
    return [int(hit[i]) for i in np.argsort(along, kind="stable")]


def displacements(poly, route: LineString, clear: float) -> list:
    """Both perpendicular displacements ``(angle, distance)`` that move ``poly`` at least ``clear``
    off the route's local line (nearer side first)."""
    p_route, _ = nearest_points(route, poly)
    s = route.project(p_route)
    a, b = route.interpolate(max(s - 0.05, 0.0)), route.interpolate(min(s + 0.05, route.length))
    t = np.array([b.x - a.x, b.y - a.y])
    t = t / max(np.linalg.norm(t), 1e-12)
    n = np.array([-t[1], t[0]])
    xy = np.asarray(poly.exterior.coords)[:, :2] - np.array([p_route.x, p_route.y])
    off = xy @ n
    plus = clear - off.min()          # shift along +n so that every vertex is beyond +clear
    minus = clear + off.max()         # shift along -n
    cands = [(math.atan2(n[1], n[0]), max(plus, 0.0)), (math.atan2(-n[1], -n[0]), max(minus, 0.0))]
    return sorted(cands, key=lambda c: c[1])


def moved_polygon(scene: PushScene, poses, m: int, angle: float, dist: float):
    pose = np.array(poses[m], np.float64)
    pose[:2] += dist * np.array([math.cos(angle), math.sin(angle)])
    return scene.movables[m].at(tuple(float(v) for v in pose)).polygon, pose
