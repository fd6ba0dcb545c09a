"""Baseline planners of Table I (Section IV-A.2), in the same harness and contact models as the search.

Every planner takes a :class:`PushScene` and returns the search's result type (``SearchResult`` with
``ScheduledPush`` entries and ``SearchStats``; see ``jaxplan.pusharound.search``), so
``experiments/table1.py`` treats all planners alike. Pushes are the physics module's
:class:`PushTask` (``direction_tasks`` face contacts, the P-controlled rollout of
``simulate_pushes``, Eq. 11's ``push_cost``); ``ScheduledPush.gap`` is ``(m,)``, the WCCG body of
the pushed movable (these planners reason about movables, not gaps).

- :func:`dfs_wccg` (**DFS-WCCG**): simulation-in-the-loop depth-first search guided by the WCCG:
  at a node whose state fails Eq. 7, the movables adjacent to the frontier gaps (unranked, in the
  frontier's order) each get four fixed axis-aligned pushes (+x, +y, -x, -y; both robots on the
  back face, one robot when the face is too narrow for two), all simulated (no quick-pass), and the
  valid children are pushed onto a stack, first candidate explored first. Depth, simulation and
  time limits stop it.
- :func:`sl_push_offline` (**SL-Push, offline**): a waypointed route (the W-clear path around the
  fixed obstacles only, Section III-A.3 with no movables, ``route_margin`` off them), the movables
  within W/2 of it are the blockers, and each is displaced geometrically by the minimal distance
  perpendicular to the local route direction that clears the corridor (the nearer side, unless
  that puts it into a fixed obstacle or out of the workspace). No physics during planning: the
  displacements are then executed open loop in physics (:func:`execute_open_loop`), which may fail.
- :func:`sl_push_sim` (**SL-Push, sim**): the same route and blockers, but every displacement is
  validated in physics while planning: for the first blocker along the route, the candidates (both
  sides and both ways along the route x team of 2 or 1 x the minimal distance and 0.25 m more) are
  simulated in one batch from the
  current physical state; the valid candidate leaving the fewest blockers (then the cheapest) is
  applied, and so on until the corridor is clear.
- :func:`rec_namo` (**Rec-NAMO**): Dijkstra routing on a grid where cells within W/2 of a movable
  cost extra (proportional to its mass) and cells within W/2 of a fixed obstacle or the walls are
  impassable; the route's blockers are decomposed into local pushes perpendicular to the route,
  recursively pushing a movable that the displaced one would overlap (depth 2); a blocker whose
  displacement is geometrically impossible (into a fixed obstacle or out of the workspace) prunes
  its cells from the graph and Dijkstra runs again. No physics during planning; executed open loop.

Execution time (``SearchResult`` does not carry it): :func:`schedule_duration` sums Eq. 11's
``delta_T`` (robot transition at ``transit_speed`` plus the push duration) over a schedule, the same
measure for every planner. Success of the open-loop planners is judged after execution: every
executed push physically valid (``PushOutcome.valid``) and Eq. 7 holding on the final physical
state.

The paper's baselines are described in two sentences each; the concrete choices above (distances,
speeds, grid resolution, mass penalty, recursion depth) are ours and listed in ``BaselineConfig``.
"""
from __future__ import annotations

import dataclasses
import heapq
import math
import time
from collections.abc import Callable

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
from jaxplan.pusharound.ranking import candidate_gaps
from jaxplan.pusharound.scene import PushScene
from jaxplan.pusharound.search import ScheduledPush, SearchResult, SearchStats
from jaxplan.pusharound.wccg import build_wccg, connectivity, w_clear_path

__all__ = ["BASELINES", "BaselineConfig", "dfs_wccg", "execute_open_loop", "rec_namo", "schedule_duration",
           "sl_push_offline", "sl_push_sim"]


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


def _check_config(cfg: BaselineConfig) -> None:
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


class _Env:
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


def _eq7(scene: PushScene, poses) -> bool:
    return bool(connectivity(build_wccg(scene, poses=poses), scene.start, scene.goal).connected)


def _make_result(env: _Env, success: bool, schedule: list, poses, reason: str, path=None,
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


def _scheduled(tasks: PushTask, k: int, cost: float, poses, out: PushOutcome, robots) -> ScheduledPush:
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


def _push_tasks(env: _Env, movable: int, angle: float, distance: float, poses, teams=(2, 1)) -> list:
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
    env = env_or_scene if isinstance(env_or_scene, _Env) else _Env(env_or_scene, config, world, sim)
    poses = env.scene.poses.copy()
    robots = np.asarray(env.scene.robots, np.float64).copy()
    schedule = []
    step = env.cfg.speed * env.cfg.max_push_s
    for m, angle, dist in plan:
        left = float(dist)
        while left > 1e-3:
            d = min(left, step)
            tasks = _push_tasks(env, m, angle, d, poses)
            if not tasks:
                return schedule, poses, robots, False, f"no contact mode for movable {m}"
            st, out, cost = env.simulate(tasks[:1], poses, robots, count=count)
            schedule.append(_scheduled(st, 0, cost[0], poses, out, robots))
            poses, robots = out.poses[0].copy(), out.robots[0].copy()
            if not out.valid[0]:
                why = ("hit a fixed obstacle" if out.hit_fixed[0] else "left the workspace" if out.left_workspace[0]
                       else "tipped" if out.tipped[0] else "diverged")
                return schedule, poses, robots, False, f"push of movable {m} {why}"
            left -= d
    return schedule, poses, robots, True, ""


def _open_loop_result(env: _Env, plan: list, plan_time: float, reason: str) -> SearchResult:
    """Execute ``plan`` in physics (not counted as planning) and judge success on the final state."""
    schedule, poses, robots, ok, why = execute_open_loop(env, plan)
    success = ok and _eq7(env.scene, poses)
    if not reason:
        reason = "" if success else (why or "executed, but Eq. 7 fails on the final state")
    res = _make_result(env, success, schedule, poses, reason)
    return _with_planning_time(res, plan_time)


def _with_planning_time(res: SearchResult, seconds: float) -> SearchResult:
    return res._replace(stats=res.stats._replace(planning_time_s=float(seconds)))


# ------------------------------------------------------------------------------------------ routes

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
    return sorted(options, key=lambda o: not _sweep_ok(scene, poses, m, *o))


def _sweep_ok(scene: PushScene, poses, m: int, angle: float, dist: float, tol: float = 0.02) -> bool:
    """Geometric check of a straight displacement: the body's swept hull stays in the workspace and
    comes no closer than ``tol`` [m] to a fixed obstacle it was not already that close to (the same
    1 cm-scale contact rule as the physics' ``hit_fixed``)."""
    before = scene.with_poses(poses).movables[m].polygon
    after, _ = _moved_polygon(scene, poses, m, angle, dist)
    sweep = shapely.union_all([before, after]).convex_hull
    if not scene.workspace_polygon.contains(after):
        return False
    for f in scene.fixed:
        d = sweep.distance(f.polygon)
        if d < tol and d < before.distance(f.polygon) - 1e-9 or (d < tol and after.distance(f.polygon) < tol):
            return False
    return True


def _blockers(scene: PushScene, poses, route: LineString, clear: float) -> list:
    """Movables closer than ``clear`` to the route, in the order of their nearest point along it."""
    placed = scene.with_poses(poses)
    polys = np.asarray([m.polygon for m in placed.movables], dtype=object)
    if len(polys) == 0:
        return []
    d = shapely.distance(polys, route)
    hit = np.nonzero(d < clear)[0]
    along = [route.project(nearest_points(route, polys[k])[0]) for k in hit]
    return [int(hit[i]) for i in np.argsort(along, kind="stable")]


def _displacements(poly, route: LineString, clear: float) -> list:
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


def _moved_polygon(scene: PushScene, poses, m: int, angle: float, dist: float):
    pose = np.array(poses[m], np.float64)
    pose[:2] += dist * np.array([math.cos(angle), math.sin(angle)])
    return dataclasses.replace(scene.movables[m], pose=tuple(float(v) for v in pose)).polygon, pose


# ------------------------------------------------------------------------------------------ SL-Push

def sl_push_offline(scene: PushScene, config: BaselineConfig = BaselineConfig(), world=None, sim=None) -> SearchResult:
    """SL-Push without physics in planning (module docstring), then executed open loop in physics."""
    _check_config(config)
    env = _Env(scene, config, world, sim)
    t0 = time.perf_counter()
    path = _fixed_route(scene, config.route_margin)
    if path is None:
        return _make_result(env, False, [], scene.poses, "no route around the fixed obstacles")
    route = LineString(path)
    clear = 0.5 * scene.width + config.margin
    poses = scene.poses.copy()
    plan = []
    for m in _blockers(scene, poses, route, 0.5 * scene.width):
        # A few rounds: a curved route may still touch the body after one straight shift.
        for _ in range(3):
            poly = scene.with_poses(poses).movables[m].polygon
            if poly.distance(route) >= 0.5 * scene.width:
                break
            angle, dist = _feasible_first(scene, poses, m, _displacements(poly, route, clear))[0]
            plan.append((m, angle, dist))
            _, poses[m] = _moved_polygon(scene, poses, m, angle, dist)
    plan_time = time.perf_counter() - t0
    return _open_loop_result(env, plan, plan_time, "")


def sl_push_sim(scene: PushScene, config: BaselineConfig = BaselineConfig(), world=None, sim=None) -> SearchResult:
    """SL-Push with every displacement validated in physics while planning (module docstring)."""
    _check_config(config)
    env = _Env(scene, config, world, sim)
    path = _fixed_route(scene, config.route_margin)
    if path is None:
        return _make_result(env, False, [], scene.poses, "no route around the fixed obstacles")
    route = LineString(path)
    half, clear = 0.5 * scene.width, 0.5 * scene.width + config.margin
    poses = scene.poses.copy()
    robots = np.asarray(scene.robots, np.float64).copy()
    schedule, tries = [], {}
    while True:
        blockers = _blockers(scene, poses, route, half)
        if not blockers:
            ok = _eq7(scene, poses)
            return _make_result(env, ok, schedule, poses, "" if ok else "corridor clear but Eq. 7 fails")
        if env.elapsed() > config.time_limit_s:
            return _make_result(env, False, schedule, poses, "time limit")
        m = blockers[0]
        tries[m] = tries.get(m, 0) + 1
        if tries[m] > config.max_rounds:
            return _make_result(env, False, schedule, poses, f"movable {m} could not be cleared")
        env.expansions += 1
        poly = scene.with_poses(poses).movables[m].polygon
        side = _displacements(poly, route, clear)
        # Sideways (both sides, minimal and longer) and, as a fallback, along the route both ways.
        along = [(side[0][0] + 0.5 * math.pi, clear), (side[0][0] - 0.5 * math.pi, clear)]
        tasks = [t for angle, dist in side + along for extra in (0.0, 0.25)
                 for t in _push_tasks(env, m, angle, dist + extra, poses)]
        if not tasks:
            return _make_result(env, False, schedule, poses, f"no contact mode for movable {m}")
        st, out, cost = env.simulate(tasks, poses, robots)
        if not np.any(out.valid):
            return _make_result(env, False, schedule, poses, f"no physically valid push for movable {m}")
        left = [len(_blockers(scene, out.poses[k], route, half)) if out.valid[k] else np.inf for k in range(len(cost))]
        k = min(range(len(cost)), key=lambda i: (left[i], cost[i]))
        schedule.append(_scheduled(st, k, cost[k], poses, out, robots))
        poses, robots = out.poses[k].copy(), out.robots[k].copy()


# ------------------------------------------------------------------------------------------ DFS-WCCG

_AXES = (0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi)


def dfs_wccg(scene: PushScene, config: BaselineConfig = BaselineConfig(), world=None, sim=None) -> SearchResult:
    """DFS-WCCG (module docstring): depth-first, four axis-aligned pushes per frontier movable, every
    candidate simulated."""
    _check_config(config)
    env = _Env(scene, config, world, sim)
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
            return _make_result(env, True, schedule, poses, "")
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
                tasks += _push_tasks(env, m, a, config.dfs_distance, poses, teams=(2,)) or \
                    _push_tasks(env, m, a, config.dfs_distance, poses, teams=(1,))
        if not tasks:
            continue
        st, out, cost = env.simulate(tasks, poses, robots)
        children = [k for k in range(len(cost)) if out.valid[k] and out.displacement[k] > env.world.config.move_tol]
        for k in reversed(children):     # first candidate on top of the stack
            stack.append((out.poses[k].copy(), out.robots[k].copy(),
                          schedule + [_scheduled(st, k, cost[k], poses, out, robots)]))
    return _make_result(env, False, best[2], best[0], reason)


# ------------------------------------------------------------------------------------------ Rec-NAMO

def _grid_costs(scene: PushScene, poses, cfg: BaselineConfig, pruned: set):
    """Cell centres f[H, W, 2], per-cell entry cost f[H, W] (inf: impassable) and the movable a cell
    lies within W/2 of (i32[H, W], -1 none; the heaviest when several)."""
    x0, y0, x1, y1 = scene.workspace
    xs = np.arange(x0 + 0.5 * cfg.grid, x1, cfg.grid)
    ys = np.arange(y0 + 0.5 * cfg.grid, y1, cfg.grid)
    gx, gy = np.meshgrid(xs, ys)
    pts = shapely.points(gx.ravel(), gy.ravel())
    r = 0.5 * scene.width
    wall = np.minimum.reduce([gx.ravel() - x0, x1 - gx.ravel(), gy.ravel() - y0, y1 - gy.ravel()])
    blocked = wall < r
    for f in scene.fixed:
        blocked |= shapely.distance(pts, f.polygon) < r
    owner = np.full(len(pts), -1)
    penalty = np.zeros(len(pts))
    placed = scene.with_poses(poses)
    for m, mov in enumerate(placed.movables):
        near = shapely.distance(pts, mov.polygon) < r
        if m in pruned:
            blocked |= near
            continue
        heavier = near & (cfg.mass_penalty * mov.mass > penalty)
        penalty[heavier] = cfg.mass_penalty * mov.mass
        owner[heavier] = m
    cost = np.where(blocked, np.inf, penalty)
    shape = gx.shape
    return np.stack([gx, gy], -1), cost.reshape(shape), owner.reshape(shape)


def _dijkstra(centres, cost, owner, start, goal, grid: float) -> list | None:
    """8-connected Dijkstra from the cell of ``start`` to that of ``goal``: step length plus the entry
    cost of a movable when the path enters its region (once per movable region entered)."""
    h, w = cost.shape
    x0, y0 = centres[0, 0] - 0.5 * grid

    def cell(p):
        return (int(np.clip((p[1] - y0) // grid, 0, h - 1)), int(np.clip((p[0] - x0) // grid, 0, w - 1)))

    s, g = cell(start), cell(goal)
    dist = {s: 0.0}
    prev = {}
    heap = [(0.0, s)]
    steps = [(di, dj, math.hypot(di, dj) * grid) for di in (-1, 0, 1) for dj in (-1, 0, 1) if di or dj]
    while heap:
        d, u = heapq.heappop(heap)
        if u == g:
            break
        if d > dist.get(u, np.inf):
            continue
        for di, dj, ln in steps:
            v = (u[0] + di, u[1] + dj)
            if not (0 <= v[0] < h and 0 <= v[1] < w) or not np.isfinite(cost[v]):
                continue
            # A movable's mass penalty is paid when entering its region from outside it.
            enter = cost[v] if owner[v] >= 0 and owner[u] != owner[v] else 0.0
            nd = d + ln + enter
            if nd < dist.get(v, np.inf):
                dist[v], prev[v] = nd, u
                heapq.heappush(heap, (nd, v))
    if g not in dist:
        return None
    out, u = [g], g
    while u != s:
        u = prev[u]
        out.append(u)
    return [tuple(centres[i, j]) for i, j in reversed(out)]


def _recursive_push(scene: PushScene, poses, m: int, angle: float, dist: float, depth: int, margin: float,
                    moved: set) -> list | None:
    """Geometric push of ``m`` with recursion into movables it would overlap; a list of
    ``(movable, angle, distance)`` (the recursive ones first) applied to ``poses`` in place, or None."""
    poly, pose = _moved_polygon(scene, poses, m, angle, dist)
    if not _sweep_ok(scene, poses, m, angle, dist):
        return None
    plan = []
    placed = scene.with_poses(poses)
    for k, other in enumerate(placed.movables):
        if k == m or k in moved or not poly.intersects(other.polygon):
            continue
        if depth <= 0:
            return None
        # Push the other body on along the same direction by its overlap extent plus the margin.
        d = np.array([math.cos(angle), math.sin(angle)])
        a_ext = np.asarray(poly.exterior.coords)[:, :2] @ d
        b_ext = np.asarray(other.polygon.exterior.coords)[:, :2] @ d
        sub = _recursive_push(scene, poses, k, angle, float(a_ext.max() - b_ext.min()) + margin, depth - 1, margin,
                              moved | {m})
        if sub is None:
            return None
        plan += sub
    poses[m] = pose
    return plan + [(m, angle, dist)]


def rec_namo(scene: PushScene, config: BaselineConfig = BaselineConfig(), world=None, sim=None) -> SearchResult:
    """Rec-NAMO (module docstring): Dijkstra routing through movables, local recursive push
    decomposition, edge pruning; executed open loop in physics."""
    _check_config(config)
    env = _Env(scene, config, world, sim)
    t0 = time.perf_counter()
    half, clear = 0.5 * scene.width, 0.5 * scene.width + config.margin
    pruned: set = set()
    while True:
        if time.perf_counter() - t0 > config.time_limit_s:
            return _make_result(env, False, [], scene.poses, "time limit")
        env.expansions += 1
        centres, cost, owner = _grid_costs(scene, scene.poses, config, pruned)
        cells = _dijkstra(centres, cost, owner, scene.start, scene.goal, config.grid)
        if cells is None:
            return _make_result(env, False, [], scene.poses, "no route after pruning")
        route = LineString([scene.start] + cells + [scene.goal]).simplify(0.5 * config.grid)
        poses = scene.poses.copy()
        plan, failed = [], None
        for m in _blockers(scene, poses, route, half):
            poly = scene.with_poses(poses).movables[m].polygon
            if poly.distance(route) >= half:
                continue    # already moved out by a recursive push
            for angle, dist in _displacements(poly, route, clear):
                trial = poses.copy()
                sub = _recursive_push(scene, trial, m, angle, dist, config.recursion, config.margin, set())
                if sub is not None:
                    plan += sub
                    poses = trial
                    break
            else:
                failed = m
                break
        if failed is None:
            return _open_loop_result(env, plan, time.perf_counter() - t0, "")
        pruned.add(failed)


BASELINES: dict[str, Callable] = {"DFS-WCCG": dfs_wccg, "SL-Push (offline)": sl_push_offline,
                                  "SL-Push (sim)": sl_push_sim, "Rec-NAMO": rec_namo}
