"""Executing a pushing schedule in physics with online replanning (Section III-D).

:func:`execute_schedule` takes the schedule of the hybrid search (``SearchResult.schedule``, a list
of scheduled pushes with ``task``, ``poses_after`` f[M, 3], ...) and runs it in ONE continuous
physics state (the MuJoCo world of :func:`build_push_world`; the C engine by default), alternating
the two phases of the paper's hybrid controller:

1. **Transition.** The active robots drive to their push start points (``r + standoff`` behind
   their contacts, as in :func:`simulate_pushes`). Paths: an 8-connected grid A* (``grid`` metres)
   in the instantaneous free space (workspace shrunk, every obstacle at its current pose and every
   robot that does not take part inflated by ``r + transit_margin``), shortcut by line of sight
   against the same free region; short straight escape / approach segments join the robot and the
   start point to the nearest free cells (a robot that has just pushed touches its body). In clutter
   with no clear route (a pocket of the robots' free space, a start point between bodies) the grid
   also holds the cells too close to a movable but clear of fixed obstacles, at a cost growing with
   the depth (``brush_weight``): the robot brushes past or shoves a light body, and a movable that
   ends off its predicted pose fails the push, which replanning then absorbs. Contacts
   are assigned to the active robots so that no robot's path crosses another's start point after
   that robot has arrived there (it would shove it off its contact: a deadlock), then by least total
   path length (:func:`_plan_transit`; the paper swaps contacts on colliding paths). Robots track the
   path at ``transit_speed`` with
   ``u = dp_ref/dt + K_p (p_ref - p)`` (:func:`transit_policy`, same gain and speed limit as the
   push controller); the phase fails after a timeout (1.5 x the path time + ``transit_slack``).
2. **Push.** The task's P-control of the contact references, i.e. :func:`push_policy` of
   ``push.py`` via :func:`make_push_simulator`, from the actual current pose of the target. **Early
   stop** at the first tick where the target is within ``pos_tol`` / ``yaw_tol`` of its planned
   pose, or has stalled (moved less than ``stall_eps`` over ``stall_window`` after
   ``min_push_time``). The rollout is causal, so cutting the trajectory at that tick is the same as
   stopping the robots there.

After each push the outcome is compared with the plan: the push **fails** when it is invalid
(:class:`PushOutcome` checks: fixed-obstacle hit, left the workspace, tipped, not finite) or some
part of a movable ended more than ``deviation_tol`` from where the plan put it (Hausdorff distance
between the outlines at the predicted and the reached pose: a translation counts fully, a rotation
by how far it moves the outline, so a turned cylinder costs nothing and a turned bar its tip's
displacement). On a failure (also a transition timeout, or a schedule that ran out without Eq. 7), control
returns to the planner: ``replan(scene_now) -> SearchResult`` from the current state, at most
``max_replans`` times. With no replanning left (none given, budget used, or a replan that found
nothing) the rest of the schedule runs open loop (``open_loop``; a push whose transition timed out is
skipped), every failure recorded. After every push the WCCG is rebuilt; execution ends as soon as
Eq. 7 holds
after the robots of that push have backed off ``retreat`` (they end pressing on the body): a body
still sliding after the early stop can close a corridor the plan left just W wide, which then counts
as a failure ("corridor closed during the retreat") like a failed push.

Both phases run in chunks of ``config.horizon`` ticks (one compiled program per policy on MJX);
the time offset of a chunk enters through the policy parameters. Units: m, s, rad.
"""
from __future__ import annotations

import dataclasses
import functools
import heapq
import itertools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import LineString, Point

from jaxplan.physics.rollout import Simulator, Trajectory
from jaxplan.pusharound.physics import PushWorld, build_push_world, initial_state, movable_poses
from jaxplan.pusharound.push import (PushTask, _check_tasks, _outcome, _start_positions, make_push_simulator,
                                     stack_tasks)
from jaxplan.pusharound.scene import PushScene
from jaxplan.pusharound.wccg import build_wccg, connectivity, w_clear_path

__all__ = ["ExecutionConfig", "ExecutedPush", "Execution", "Frames", "execute_schedule", "load_schedule",
           "plan_frames", "transit_policy", "transition_path"]


@dataclasses.dataclass(frozen=True)
class ExecutionConfig:
    """Execution constants (all static).

    pos_tol [m], yaw_tol [rad]: early stop when the target is this close to its planned pose;
    stall_window [s], stall_eps [m]: the push stalled when the target moved less than stall_eps
    (translation + 0.3 m x yaw change) over the window; min_push_time [s] before a stall counts;
    deviation_tol [m]: a movable whose outline is this far (Hausdorff) from its predicted outline
    fails the push; max_replans: calls of ``replan`` at most; grid [m]: A* cell size; transit_margin [m]: extra
    clearance of transition paths beyond the robot radius; brush_weight: where no clear route exists, a
    transition path may pass closer than that to a movable (brushing or shoving it; never closer than
    r + 1 cm to a fixed obstacle, the workspace edge or an idle robot), each metre costing
    ``1 + brush_weight * depth / (r + transit_margin)`` for a path ``depth`` metres too close (inf:
    never; the straight segment is driven then); arrive_tol [m]: a robot within this of its
    push start point has arrived; transit_slack [s]: added to 1.5 x the path time for the timeout;
    max_pushes: executed pushes at most (guards a replanner that never converges); None: the
    schedule's own length plus ``EXTRA_PUSHES``, so that a long plan is never cut short; open_loop: when a
    push fails and no replanning is left (no ``replan``, ``max_replans`` used, or a replan found
    nothing), carry on with the rest of the schedule (True) or stop there (False); retreat [m]: at
    the end the robots of the last push back off this far against their push directions (0: not);
    record_every: ticks between recorded frames; backend: "c", "mjx" or "auto" (a single
    element: the C engine is the sensible choice on a CPU).
    """

    pos_tol: float = 0.03
    yaw_tol: float = 0.05
    stall_window: float = 0.5
    stall_eps: float = 0.005
    min_push_time: float = 0.5
    deviation_tol: float = 0.15
    max_replans: int = 3
    grid: float = 0.05
    transit_margin: float = 0.03
    arrive_tol: float = 0.03
    transit_slack: float = 4.0
    brush_weight: float = 10.0
    max_pushes: int | None = None
    open_loop: bool = True
    retreat: float = 0.1
    record_every: int = 4
    backend: str = "c"

    def replace(self, **changes) -> "ExecutionConfig":
        return dataclasses.replace(self, **changes)


class Frames(NamedTuple):
    """Recorded states every ``record_every`` ticks. time: f[K] seconds since the start; poses:
    f[K, M, 3] movable (x, y, yaw); robots: f[K, N, 2] robot positions; push: i32[K] index into
    ``Execution.executed`` of the push being executed or approached (-1 before the first);
    phase: list of K strings ("start" / "transit" / "push" / "retreat" / "planned")."""

    time: np.ndarray
    poses: np.ndarray
    robots: np.ndarray
    push: np.ndarray
    phase: list


class ExecutedPush(NamedTuple):
    """One executed push. task: the :class:`PushTask` as executed (contacts possibly swapped);
    planned: f[M, 3] predicted poses after it; poses_before / poses_after: f[M, 3] actual;
    robots_after: f[N, 2]; stop: "reached" | "stalled" | "horizon" | "transit_timeout";
    valid: the physics checks passed (else ``invalid`` names the failed ones: "hit_fixed",
    "left_workspace", "tipped", "not_finite"); deviation: f[] largest Hausdorff distance of a movable
    outline from its predicted one [m]; ok: the push counts as succeeded; transit_s, push_s: simulated seconds of both phases;
    plan: which plan it came from (0 the original, k the k-th replan)."""

    task: PushTask
    planned: np.ndarray
    poses_before: np.ndarray
    poses_after: np.ndarray
    robots_after: np.ndarray
    stop: str
    valid: bool
    deviation: float
    ok: bool
    transit_s: float
    push_s: float
    plan: int
    invalid: str = ""


class Execution(NamedTuple):
    """Result of :func:`execute_schedule`.

    success: Eq. 7 holds at the end and a W-clear path was constructed; connectivity: Eq. 7 at the
    end; w_clear_path: f64[P, 2] or None; final_scene: the scene at the final physical state
    (movable poses, robot positions); executed: list of :class:`ExecutedPush`; frames:
    :class:`Frames`; execution_time_s: simulated seconds; replans: calls of ``replan``; reason: why
    execution stopped ("connected", "schedule exhausted", "push failed", ...)."""

    success: bool
    connectivity: bool
    w_clear_path: np.ndarray | None
    final_scene: PushScene
    executed: list
    frames: Frames
    execution_time_s: float
    replans: int
    reason: str


# --------------------------------------------------------------------------------- transition paths

def _free_region(scene: PushScene, poses, clearance: float, extra=()):
    """Where a robot centre may be: the workspace shrunk by ``clearance`` minus every obstacle at
    ``poses`` (and the ``extra`` polygons) inflated by it."""
    obstacles = scene.with_poses(poses).obstacle_polygons() + list(extra)
    blocked = shapely.union_all([o.buffer(clearance, 8) for o in obstacles]) if obstacles else None
    free = scene.workspace_polygon.buffer(-clearance)
    return free.difference(blocked) if blocked is not None else free


class _Roadmap:
    """The free region of :func:`_free_region` and its grid, built once and queried for many paths.

    With ``brush_weight`` finite, a cell that is within ``clearance`` of a movable but clear of the
    fixed obstacles, the workspace edge and the ``extra`` polygons by ``hard_clearance`` is passable
    at a cost (``_cell_costs``): in clutter where no clear route exists the robot brushes past, or
    shoves, a light movable rather than drive straight into a wall. Clear cells cost 1, so a detour
    through them is taken while it is cheaper than the brush. ``brush_weight`` inf (this class's
    default; ``ExecutionConfig``'s is 10): clear cells only, and the straight segment when they hold no route.
    """

    def __init__(self, scene: PushScene, poses, clearance: float, grid: float, extra=(),
                 hard_clearance: float | None = None, brush_weight: float = math.inf):
        if not grid > 0:
            raise ValueError(f"grid: must be > 0 m; got {grid!r}.")
        self.free = _free_region(scene, poses, clearance, extra)
        shapely.prepare(self.free)
        x0, y0, x1, y1 = (float(v) for v in scene.workspace)
        nx, ny = max(1, int(math.ceil((x1 - x0) / grid))), max(1, int(math.ceil((y1 - y0) / grid)))
        self.xs, self.ys = x0 + (np.arange(nx) + 0.5) * grid, y0 + (np.arange(ny) + 0.5) * grid
        self.cx, self.cy = np.meshgrid(self.xs, self.ys, indexing="ij")           # [nx, ny]
        self.ok = shapely.contains_xy(self.free, self.cx, self.cy)
        self.passable, self.cost = self.ok, None
        if math.isfinite(brush_weight) and hard_clearance is not None:
            self.cost = _cell_costs(scene, poses, self.cx, self.cy, self.ok, clearance, hard_clearance,
                                    brush_weight, extra)
            self.passable = np.isfinite(self.cost)

    def _nearest(self, p, mask):
        d = np.where(mask, (self.cx - p[0]) ** 2 + (self.cy - p[1]) ** 2, np.inf)
        return np.unravel_index(int(np.argmin(d)), d.shape)

    def path(self, start, goal) -> np.ndarray:
        s, gl = np.asarray(start, np.float64).reshape(2), np.asarray(goal, np.float64).reshape(2)
        if self.free.covers(LineString([s, gl])) or not self.passable.any():
            return np.stack([s, gl])
        cells = _astar(self.passable, self._nearest(s, self.passable), self._nearest(gl, self.passable), self.cost)
        if cells is None:
            return np.stack([s, gl])
        pts = np.stack([self.xs[[c[0] for c in cells]], self.ys[[c[1] for c in cells]]], -1)
        pts = np.concatenate([s[None], _turning_points(pts), gl[None]])
        return _shortcut(pts, self.free)


def _cell_costs(scene: PushScene, poses, cx, cy, ok, clearance: float, hard_clearance: float,
                brush_weight: float, extra=()) -> np.ndarray:
    """f[nx, ny] cost per metre of driving through each grid cell (centres ``cx, cy``): 1 on clear
    cells (``ok``); ``1 + brush_weight * depth / clearance`` where the cell is ``depth`` metres deeper
    than ``clearance`` towards the nearest movable but at least ``hard_clearance`` from every fixed
    obstacle, the workspace edge and the ``extra`` polygons; inf elsewhere."""
    hard = [f.polygon for f in scene.fixed] + list(extra)
    room = scene.workspace_polygon.buffer(-hard_clearance)
    if hard:
        room = room.difference(shapely.union_all([o.buffer(hard_clearance, 8) for o in hard]))
    cost = np.where(ok, 1.0, np.inf)
    tight = ~ok & shapely.contains_xy(room, cx, cy)
    movables = [m.polygon for m in scene.with_poses(poses).movables]
    if tight.any() and movables:
        d = shapely.distance(shapely.union_all(movables), shapely.points(cx[tight], cy[tight]))
        cost[tight] = 1.0 + brush_weight * np.clip(clearance - d, 0.0, None) / clearance
    return cost


def transition_path(scene: PushScene, start, goal, *, poses=None, clearance: float | None = None,
                    grid: float = 0.05, extra=()) -> np.ndarray:
    """A collision-free path ``f64[P, 2]`` for a robot centre from ``start`` to ``goal`` (both (x, y)).

    Grid A* (8-connected, cell ``grid`` m) over the free region of :func:`_free_region` (obstacles at
    ``poses`` f[M, 3], default the scene's, inflated by ``clearance``, default ``robot_radius + 0.03``;
    ``extra``: more shapely polygons to avoid), then line-of-sight shortcuts. ``start`` and ``goal``
    may lie inside the inflated region (a robot at a contact): they are joined straight to their
    nearest free cells. When no grid route exists the straight segment is returned (the physics and
    the transition timeout then decide).
    """
    poses = scene.poses if poses is None else np.asarray(poses, np.float64)
    clearance = float(scene.robot_radius) + 0.03 if clearance is None else float(clearance)
    return _Roadmap(scene, poses, clearance, grid, extra).path(start, goal)


_STEPS = [(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy]


def _astar(ok: np.ndarray, a, b, cost: np.ndarray | None = None):
    """Cells (i, j) from ``a`` to ``b`` through ``ok`` (bool[nx, ny]), 8-connected, corners not cut;
    None when unreachable. ``cost`` f[nx, ny] >= 1: per-cell cost per unit length (a step costs its
    length times the mean of its two cells'; default 1 everywhere, the heuristic stays admissible)."""
    nx, ny = ok.shape
    a, b = (int(a[0]), int(a[1])), (int(b[0]), int(b[1]))

    def h(c):
        dx, dy = abs(c[0] - b[0]), abs(c[1] - b[1])
        return max(dx, dy) + (math.sqrt(2) - 1) * min(dx, dy)

    g = {a: 0.0}
    parent = {a: None}
    heap = [(h(a), 0.0, a)]
    while heap:
        _, gc, c = heapq.heappop(heap)
        if c == b:
            out = []
            while c is not None:
                out.append(c)
                c = parent[c]
            return out[::-1]
        if gc > g[c]:
            continue
        for dx, dy in _STEPS:
            n = (c[0] + dx, c[1] + dy)
            if not (0 <= n[0] < nx and 0 <= n[1] < ny) or not ok[n]:
                continue
            if dx and dy and not (ok[c[0] + dx, c[1]] and ok[c[0], c[1] + dy]):
                continue                      # no corner cutting past a blocked cell
            step = math.sqrt(2) if dx and dy else 1.0
            ng = gc + (step if cost is None else step * 0.5 * (cost[c] + cost[n]))
            if ng < g.get(n, math.inf):
                g[n] = ng
                parent[n] = c
                heapq.heappush(heap, (ng + h(n), ng, n))
    return None


def _turning_points(pts: np.ndarray) -> np.ndarray:
    """Keep the first, last and every point where the grid path changes direction."""
    if len(pts) <= 2:
        return pts
    d = np.diff(pts, axis=0)
    turn = np.any(np.abs(d[1:] - d[:-1]) > 1e-12, axis=1)
    keep = np.r_[True, turn, True]
    return pts[keep]


def _shortcut(pts: np.ndarray, free) -> np.ndarray:
    """Greedy line-of-sight shortening: from each kept point jump to the farthest point visible in
    ``free`` (the first and last legs, which may start inside the inflated region, stay as they are)."""
    out = [pts[0]]
    i, n = 1, len(pts)
    if n > 2:
        out.append(pts[1])
    while i < n - 2:
        j = n - 2
        while j > i + 1 and not free.covers(LineString([pts[i], pts[j]])):
            j -= 1
        out.append(pts[j])
        i = j
    out.append(pts[-1])
    path = np.asarray(out)
    keep = np.r_[True, np.linalg.norm(np.diff(path, axis=0), axis=1) > 1e-9]
    return path[keep]


# ----------------------------------------------------------------------------------- policies

def transit_policy(robot_adr: tuple, kp: float, vmax: float, params, pstate, qpos, qvel, time):
    """Path tracking as a rollout policy (bind the first three with ``functools.partial``).

    params: dict with path f[N, K, 2] waypoints per robot [m] (padded by repeating the last),
    arclen f[N, K] strictly increasing cumulative length [m], speed f[] [m/s], t0 f[] time offset of
    this chunk [s]. The reference runs along each path at ``speed`` and stops at its end:
    ``u = dp_ref/dt + kp (p_ref - p)``, clipped to ``vmax``. Returns ``(ctrl f[2N], pstate)``.
    """
    adr = jnp.asarray(robot_adr)
    pos = qpos[adr].reshape(-1, 2)

    def ref(t):
        s = params["speed"] * (t + params["t0"])
        one = lambda p, lens: jnp.stack([jnp.interp(s, lens, p[:, 0]), jnp.interp(s, lens, p[:, 1])])  # noqa: E731
        return jax.vmap(one)(params["path"], params["arclen"])

    p_ref, v_ff = jax.jvp(ref, (time,), (jnp.ones_like(time),))
    u = v_ff + kp * (p_ref - pos)
    speed = jnp.linalg.norm(u, axis=-1, keepdims=True)
    u = u * jnp.minimum(1.0, vmax / jnp.maximum(speed, 1e-9))
    return u.reshape(-1).astype(qpos.dtype), pstate


def _pack_paths(paths: list) -> tuple[np.ndarray, np.ndarray]:
    """Pad per-robot paths to ``path f[N, K, 2]`` and ``arclen f[N, K]`` (strictly increasing)."""
    k = max(2, max(len(p) for p in paths))
    out, lens = np.zeros((len(paths), k, 2)), np.zeros((len(paths), k))
    for i, p in enumerate(paths):
        p = np.asarray(p, np.float64).reshape(-1, 2)
        if len(p) == 1:
            p = np.concatenate([p, p])
        cum = np.r_[0.0, np.cumsum(np.maximum(np.linalg.norm(np.diff(p, axis=0), axis=1), 1e-9))]
        pad = k - len(p)
        out[i] = np.concatenate([p, np.repeat(p[-1:], pad, 0)])
        # jnp.interp needs increasing abscissae: the padding steps on by 1 um and the point repeats.
        lens[i] = np.r_[cum, cum[-1] + 1e-6 * np.arange(1, pad + 1)]
    return out, lens


# ---------------------------------------------------------------------------------- execution

class _State:
    """The running physical state (mutable on purpose: one execution's bookkeeping)."""

    def __init__(self, world: PushWorld, robots, poses, cfg: ExecutionConfig):
        self.world, self.cfg = world, cfg
        self.qpos, self.qvel = initial_state(world, robots, poses)
        self.tick = 0
        self.frames: list = []
        self.push_index = -1
        self.frames.append((0, self.poses, self.robots, -1, "start"))

    @property
    def poses(self) -> np.ndarray:
        return movable_poses(self.world, self.qpos)[0]

    @property
    def robots(self) -> np.ndarray:
        return self.qpos[self.world.robot_adr].astype(np.float64)

    def record(self, traj_qpos: np.ndarray, upto: int, phase: str) -> None:
        """Advance the state to tick ``upto`` of the chunk ``traj_qpos f[T+1, nq]`` and record frames."""
        poses = movable_poses(self.world, traj_qpos[1:upto + 1])[0]
        robots = traj_qpos[1:upto + 1][:, self.world.robot_adr]
        for k in range(upto):
            self.tick += 1
            if self.tick % self.cfg.record_every == 0:
                self.frames.append((self.tick, poses[k], robots[k], self.push_index, phase))


# Pushes that replanning may add to a schedule before execution gives up (ExecutionConfig.max_pushes).
EXTRA_PUSHES = 40
_HARD_MARGIN = 0.01  # m: transit paths keep at least r + this from fixed obstacles, walls and idle robots
_MEET_SLACK = 0.02   # m: robots that start touching (after a joint push) do not count as meeting


def _positions(path: np.ndarray, arclen: np.ndarray) -> np.ndarray:
    """``f[T, 2]``: where a robot driving ``path`` f[K, 2] is at arc lengths ``arclen`` f[T] (it waits
    at the end)."""
    seg = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    return np.stack([np.interp(arclen, seg, path[:, 0]), np.interp(arclen, seg, path[:, 1])], -1)


def _meet(path_a: np.ndarray, path_b: np.ndarray, speed: float, radius: float, dt: float = 0.05) -> bool:
    """Whether two robots driving their paths at ``speed`` from the same instant come closer than
    ``2 radius - _MEET_SLACK`` at some moment after they were at least that far apart."""
    total = max(float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))) if len(p) > 1 else 0.0
                for p in (path_a, path_b))
    s = np.arange(0.0, total + speed * dt, speed * dt)
    gap = np.linalg.norm(_positions(path_a, s) - _positions(path_b, s), axis=-1)
    close = gap < 2 * radius - _MEET_SLACK
    return bool(np.any(close[np.argmax(~close):])) if (~close).any() else False


def _plan_transit(roadmap: _Roadmap, robots: np.ndarray, starts: np.ndarray, active: np.ndarray, speed: float,
                  radius: float) -> tuple:
    """Which active robot takes which contact, and the paths. Returns ``(perm i32[N], paths)``: robot
    i takes contact perm[i]; paths: one f[K, 2] per robot (inactive robots: their position).

    Every assignment of the active robots to the contacts (N <= 3; more keep the plan's) is scored by
    (conflicts, total path length): a conflict is a robot whose path passes over another robot's start
    point (closer than 2 r) after that robot should have arrived there (arc length / speed, 1 s
    margin): the later robot would shove the earlier one off its contact, a deadlock in physics; or
    two robots that meet on the way (closer than 2 r - ``_MEET_SLACK`` at the same time, both driving
    at ``speed``): head-on they block each other. This is the paper's swap of contacts on colliding
    paths, decided on the planned paths and their timing.
    """
    n = len(robots)
    act = [int(i) for i in np.nonzero(active)[0]]
    cache: dict = {}

    def path(i, k):
        if (i, k) not in cache:
            cache[i, k] = roadmap.path(robots[i], starts[k])
        return cache[i, k]

    def length(p):
        return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))

    best, best_key = np.arange(n), None
    for p in (itertools.permutations(act) if len(act) <= 3 else [tuple(act)]):
        perm = np.arange(n)
        perm[act] = p
        lens = {i: length(path(i, perm[i])) for i in act}
        conflicts = 0
        for i in act:
            line = LineString(path(i, perm[i]))
            for j in act:
                slot = Point(*starts[perm[j]])
                if j != i and line.distance(slot) < 2 * radius - 1e-3 and \
                        line.project(slot) / speed > lens[j] / speed - 1.0:
                    conflicts += 1
        conflicts += sum(_meet(path(i, perm[i]), path(j, perm[j]), speed, radius)
                         for a, i in enumerate(act) for j in act[a + 1:])
        key = (conflicts, sum(lens.values()))
        if best_key is None or key < best_key:
            best, best_key = perm, key
    paths = [path(i, best[i]) if active[i] else robots[i][None] for i in range(n)]
    return best, paths


def _swap(task: PushTask, perm: np.ndarray) -> PushTask:
    return task._replace(contacts=np.asarray(task.contacts)[perm], directions=np.asarray(task.directions)[perm],
                         active=np.asarray(task.active)[perm])


def _scheduled(obj) -> list:
    if obj is None:
        return []
    return list(obj.schedule) if hasattr(obj, "schedule") else list(obj)


def _run_transit(state: _State, sim: Simulator, scene: PushScene, task: PushTask, starts: np.ndarray) -> tuple:
    """Assign contacts, plan paths and drive the active robots to their push start points ``starts
    f[N, 2]``. Returns (task with contacts possibly swapped, arrived, simulated seconds)."""
    cfg = state.cfg
    r = float(scene.robot_radius)
    robots, poses = state.robots, state.poses
    active = np.asarray(task.active, bool)
    # Inactive robots stay where they are: obstacles for the others.
    idle = [Point(*robots[i]).buffer(r, 8) for i in np.nonzero(~active)[0]]
    roadmap = _Roadmap(scene, poses, r + cfg.transit_margin, cfg.grid, idle, r + _HARD_MARGIN, cfg.brush_weight)
    perm, paths = _plan_transit(roadmap, robots, starts, active, float(state.world.config.transit_speed), r)
    task, starts = _swap(task, perm), starts[perm]
    arrived, seconds = _track(state, sim, paths, starts, np.asarray(task.active, bool), "transit")
    return task, arrived, seconds


def _track(state: _State, sim: Simulator, paths: list, targets: np.ndarray, active: np.ndarray, phase: str) -> tuple:
    """Drive the robots along ``paths`` (one f[K, 2] per robot) until the ``active`` ones are within
    ``arrive_tol`` of ``targets f[N, 2]`` after their reference ended, or the timeout. Returns
    (arrived, simulated seconds)."""
    cfg, world = state.cfg, state.world
    path, lens = _pack_paths(paths)
    speed = float(world.config.transit_speed)
    length = float(np.max(lens[:, -1]))
    timeout = 1.5 * length / speed + cfg.transit_slack
    horizon, tick_s = int(world.config.horizon), sim.tick_seconds
    spent, t0 = 0, 0.0
    while True:
        params = {"path": jnp.asarray(path[None], jnp.float32), "arclen": jnp.asarray(lens[None], jnp.float32),
                  "speed": jnp.full((1,), speed, jnp.float32), "t0": jnp.full((1,), t0, jnp.float32)}
        traj = sim.run(state.qpos[None], state.qvel[None], params, jnp.zeros((1,), jnp.float32), horizon)
        qp = np.asarray(traj.qpos[0], np.float64)
        err = np.linalg.norm(qp[:, world.robot_adr] - targets[None], axis=-1)[:, active].max(-1)    # [T+1]
        ref_done = (np.arange(horizon + 1) * tick_s + t0) * speed >= length
        hit = np.nonzero(ref_done & (err < cfg.arrive_tol))[0]
        hit = hit[hit > 0]
        stop = int(hit[0]) if len(hit) else horizon
        if not bool(traj.finite[0]):
            stop = min(stop, max(1, int(traj.first_bad[0]) - 1))
        state.record(qp, stop, phase)
        state.qpos, state.qvel = qp[stop], np.asarray(traj.qvel[0, stop], np.float64)
        spent += stop
        t0 += stop * tick_s
        if len(hit) or not bool(traj.finite[0]):
            return bool(len(hit)), spent * tick_s
        if spent * tick_s >= timeout:
            return False, spent * tick_s


def _retreat(state: _State, sim: Simulator, task: PushTask) -> float:
    """The robots of the last push back off ``retreat`` metres against their push directions (they
    end pressing on the body). Returns the simulated seconds."""
    dist = float(state.cfg.retreat)
    active = np.asarray(task.active, bool)
    if not dist > 0 or not active.any():
        return 0.0
    psi = float(state.poses[int(np.asarray(task.movable)), 2])
    rot = np.array([[np.cos(psi), -np.sin(psi)], [np.sin(psi), np.cos(psi)]])
    robots = state.robots
    back = robots - dist * (np.asarray(task.directions, np.float64) @ rot.T)
    x0, y0, x1, y1 = state.world.scene.workspace
    r = float(state.world.scene.robot_radius)
    back = np.clip(back, [x0 + r, y0 + r], [x1 - r, y1 - r])
    targets = np.where(active[:, None], back, robots)
    paths = [np.stack([robots[i], targets[i]]) if active[i] else robots[i][None] for i in range(len(robots))]
    return _track(state, sim, paths, targets, active, "retreat")[1]


def _run_push(state: _State, sim: Simulator, task: PushTask, planned: np.ndarray) -> tuple:
    """One P-controlled push with early stop. Returns (outcome of 1, stop reason, simulated seconds)."""
    cfg, world = state.cfg, state.world
    tasks = _check_tasks(world, stack_tasks([task]))
    m = int(tasks.movable[0])
    poses0, robots0 = state.poses, state.robots
    params = {"pose0": jnp.asarray(poses0[[m]], jnp.float32),
              "velocity": jnp.asarray(tasks.velocity, jnp.float32),
              "contacts": jnp.asarray(tasks.contacts, jnp.float32),
              "directions": jnp.asarray(tasks.directions, jnp.float32),
              "active": jnp.asarray(tasks.active, jnp.float32),
              "hold": jnp.asarray(robots0[None], jnp.float32),
              "duration": jnp.asarray(tasks.duration, jnp.float32)}
    horizon = int(world.config.horizon)
    traj = sim.run(state.qpos[None], state.qvel[None], params, jnp.zeros((1,), jnp.float32), horizon)
    tick_s = sim.tick_seconds
    pose_t = movable_poses(world, np.asarray(traj.qpos[0], np.float64))[0][:, m]          # [T+1, 3]
    dxy = np.linalg.norm(pose_t[:, :2] - planned[m, :2], axis=-1)
    dyaw = np.abs(np.angle(np.exp(1j * (pose_t[:, 2] - planned[m, 2]))))
    reached = (dxy < cfg.pos_tol) & (dyaw < cfg.yaw_tol)
    w = max(1, int(round(cfg.stall_window / tick_s)))
    move = np.full(horizon + 1, np.inf)
    move[w:] = (np.linalg.norm(pose_t[w:, :2] - pose_t[:-w, :2], axis=-1)
                + 0.3 * np.abs(np.angle(np.exp(1j * (pose_t[w:, 2] - pose_t[:-w, 2])))))
    t = np.arange(horizon + 1) * tick_s
    stalled = (move < cfg.stall_eps) & (t >= cfg.min_push_time)
    stop, why = horizon, "horizon"
    for k in range(1, horizon + 1):
        if reached[k] or stalled[k]:
            stop, why = k, "reached" if reached[k] else "stalled"
            break
    first_bad = int(traj.first_bad[0])
    finite = first_bad < 0 or first_bad > stop
    cut = Trajectory(traj.qpos[:, :stop + 1], traj.qvel[:, :stop + 1], traj.ctrl[:, :stop], traj.time[:stop + 1],
                     np.array([finite]), np.array([first_bad if not finite else -1], np.int32),
                     traj.ncon[:, :stop + 1], traj.pstate, traj.backend)
    out = _outcome(world, tasks, cut, poses0, 4)
    qp = np.asarray(traj.qpos[0], np.float64)
    state.record(qp, stop, "push")
    state.qpos, state.qvel = qp[stop], np.asarray(traj.qvel[0, stop], np.float64)
    return out, why, stop * tick_s


def _outline_deviation(scene: PushScene, poses, planned) -> np.ndarray:
    """f[M]: per movable, the Hausdorff distance [m] between its outline at ``poses f[M, 3]`` and at
    ``planned f[M, 3]`` (0 where the poses agree to 1e-9)."""
    out = np.zeros(len(scene.movables))
    for i, m in enumerate(scene.movables):
        if np.max(np.abs(np.asarray(poses[i]) - np.asarray(planned[i]))) > 1e-9:
            # The body-frame union moved rigidly, as Movable.polygon: a union of separately moved pieces
            # may split or keep slivers, which the Hausdorff distance would report as a deviation.
            body = shapely.union_all(m.pieces)
            a, b = (affinity.translate(affinity.rotate(body, float(p[2]), origin=(0, 0), use_radians=True),
                                       float(p[0]), float(p[1])) for p in (poses[i], planned[i]))
            out[i] = float(shapely.hausdorff_distance(a, b, densify=0.25))
    return out


def _connected(scene: PushScene) -> bool:
    return bool(connectivity(build_wccg(scene), scene.start, scene.goal).connected)


def execute_schedule(scene: PushScene, result_or_schedule, *, world: PushWorld | None = None, replan=None,
                     config: ExecutionConfig | None = None, record_every: int | None = None) -> Execution:
    """Execute a pushing schedule in physics from ``scene``'s state (module docstring).

    result_or_schedule: a ``SearchResult`` (its ``schedule``) or a list of scheduled pushes, each
    with ``task`` (a single :class:`PushTask`) and ``poses_after`` f[M, 3] (the prediction).
    world: :func:`build_push_world` of ``scene`` (built when None; only its model and config are used,
    the state comes from ``scene``). replan: ``replan(scene_now) -> SearchResult`` called with the
    current poses and robot positions when a push fails or the schedule ends without Eq. 7 (None: no
    replanning). config: :class:`ExecutionConfig`; record_every overrides its frame interval [ticks].
    """
    cfg = ExecutionConfig() if config is None else config
    if record_every is not None:
        cfg = cfg.replace(record_every=int(record_every))
    if cfg.record_every < 1:
        raise ValueError(f"record_every: must be an int >= 1 tick; got {cfg.record_every!r}.")
    if not cfg.brush_weight >= 0:
        raise ValueError(f"config.brush_weight: must be >= 0 (inf: transit paths never brush a movable); "
                         f"got {cfg.brush_weight!r}.")
    if cfg.max_replans < 0:
        raise ValueError(f"config.max_replans: must be >= 0; got {cfg.max_replans!r}.")
    if cfg.max_pushes is not None and cfg.max_pushes < 1:
        raise ValueError(f"config.max_pushes: must be >= 1, or None (the schedule's length + {EXTRA_PUSHES}); "
                         f"got {cfg.max_pushes!r}.")
    if not isinstance(scene, PushScene):
        raise ValueError(f"scene: expected a PushScene; got {type(scene).__name__}.")
    schedule = _scheduled(result_or_schedule)
    max_pushes = len(schedule) + EXTRA_PUSHES if cfg.max_pushes is None else cfg.max_pushes
    world = build_push_world(scene) if world is None else world
    if len(world.mov_adr) != len(scene.movables) or len(world.robot_adr) != len(scene.robots):
        raise ValueError("world: built for another scene (movable or robot count differs); "
                         "use build_push_world(scene).")
    push_sim = make_push_simulator(world, cfg.backend)
    wcfg = world.config
    transit_sim = Simulator(world.model,
                            functools.partial(transit_policy, tuple(int(a) for a in world.robot_adr.reshape(-1)),
                                              float(wcfg.kp), float(wcfg.vmax)),
                            substeps=wcfg.substeps, bounds=world.bounds, backend=push_sim.backend)
    state = _State(world, np.asarray(scene.robots, np.float64), scene.poses, cfg)
    executed, replans, plan_id, queue = [], 0, 0, list(schedule)

    def now() -> PushScene:
        return scene.with_poses(state.poses).replace(robots=state.robots)

    reason, notes, can_replan, retreated = "schedule exhausted", [], replan is not None, False
    connected = _connected(scene)
    if connected:
        reason = "connected"
    while not connected:
        failed = None
        if not queue:
            failed = "schedule exhausted"
        elif len(executed) >= max_pushes:
            reason = f"max_pushes ({max_pushes}) reached"
            break
        else:
            item = queue.pop(0)
            retreated = False
            planned = np.asarray(item.poses_after, np.float64)
            task = PushTask(*(np.asarray(getattr(item.task, f)) for f in PushTask._fields))
            state.push_index = len(executed)
            poses_before = state.poses
            tasks1 = _check_tasks(world, stack_tasks([task]))
            starts = _start_positions(world._replace(scene=scene.replace(robots=state.robots)), tasks1, poses_before)[0]
            task, arrived, transit_s = _run_transit(state, transit_sim, scene, task, starts)
            if not arrived:
                executed.append(ExecutedPush(task, planned, poses_before, state.poses, state.robots,
                                             "transit_timeout", False, math.nan, False, transit_s, 0.0, plan_id))
                failed = "transition timed out"
            else:
                out, why, push_s = _run_push(state, push_sim, task, planned)
                after = state.poses
                dev = _outline_deviation(scene, after, planned)
                valid = bool(out.valid[0])
                ok = valid and float(dev.max()) <= cfg.deviation_tol
                flags = {"hit_fixed": out.hit_fixed[0], "left_workspace": out.left_workspace[0],
                         "tipped": out.tipped[0], "not_finite": not out.finite[0]}
                executed.append(ExecutedPush(task, planned, poses_before, after, state.robots, why, valid,
                                             float(dev.max()), ok, transit_s, push_s, plan_id,
                                             ",".join(k for k, v in flags.items() if v)))
                connected = _connected(now())
                if connected and cfg.retreat > 0:
                    # The corridor the vehicle meets is the one after the robots back off: a body still
                    # sliding from the early stop can close a corridor the plan left just W wide.
                    _retreat(state, transit_sim, task)
                    retreated = True
                    connected = _connected(now())
                    if not connected:
                        failed = "corridor closed during the retreat"
                if connected:
                    reason = "connected" + (f" (after: {'; '.join(dict.fromkeys(notes))})" if notes else "")
                    break
                if not ok and failed is None:
                    failed = "push failed" if valid else "push invalid in physics"
        if failed is None:
            continue
        if can_replan and replans < cfg.max_replans:
            replans += 1
            res = replan(now())
            if res is not None and getattr(res, "success", True):
                plan_id += 1
                queue = _scheduled(res)
                continue
            notes.append(f"{failed}; replan {replans} failed" + (f" ({res.reason})" if getattr(res, "reason", "") else ""))
            can_replan = False          # a replanner that found nothing from here will not from a later state
        elif replan is not None and can_replan:
            notes.append(f"{failed} (replans exhausted: {replans})")
            can_replan = False
        else:
            notes.append(failed)
        # No replanning left: finish the schedule open loop (or stop), the failure recorded in ``executed``.
        if failed == "schedule exhausted" or not cfg.open_loop:
            reason = "; ".join(dict.fromkeys(notes))
            break
    if executed and cfg.retreat > 0 and not retreated:
        _retreat(state, transit_sim, executed[-1].task)
    final = now()
    g = build_wccg(final)
    conn = bool(connectivity(g, final.start, final.goal).connected)
    path = w_clear_path(g, final.start, final.goal) if conn else None
    frames = _frames(state, world)
    tick_s = float(wcfg.timestep) * wcfg.substeps
    return Execution(conn and path is not None, conn, path, final, executed, frames, state.tick * tick_s, replans,
                     reason)


def _frames(state: _State, world: PushWorld) -> Frames:
    tick_s = float(world.config.timestep) * world.config.substeps
    m, n = len(world.mov_adr), len(world.robot_adr)
    if not state.frames:
        return Frames(np.zeros(0), np.zeros((0, m, 3)), np.zeros((0, n, 2)), np.zeros(0, np.int32), [])
    tick, poses, robots, push, phase = zip(*state.frames)
    return Frames(np.asarray(tick, np.float64) * tick_s, np.stack(poses), np.stack(robots),
                  np.asarray(push, np.int32), list(phase))


def plan_frames(scene: PushScene, result_or_schedule) -> Frames:
    """Key frames of a schedule as planned (no physics): the start state, then every push's predicted
    ``poses_after`` / ``robots_after``; time is the cumulative push duration [s]. For drawing a plan
    that is not executed (``--no-execute``, or a failed search's partial schedule)."""
    schedule = _scheduled(result_or_schedule)
    poses = [scene.poses] + [np.asarray(s.poses_after, np.float64) for s in schedule]
    robots = [np.asarray(scene.robots, np.float64)] + [np.asarray(s.robots_after, np.float64) for s in schedule]
    time = np.r_[0.0, np.cumsum([float(np.asarray(s.task.duration)) for s in schedule])]
    return Frames(time, np.stack(poses), np.stack(robots), np.arange(-1, len(schedule), dtype=np.int32),
                  ["start"] + ["planned"] * len(schedule))


def load_schedule(result) -> list:
    """The schedule of a ``jaxplan pusharound`` result.json (a path or the parsed dict) as a list of
    ``search.ScheduledPush``, ready for :func:`execute_schedule` (e.g. to replay a ``--no-execute``
    plan). Values carry the file's rounding (1e-6)."""
    import json  # noqa: PLC0415
    from pathlib import Path  # noqa: PLC0415

    from jaxplan.pusharound.search import ScheduledPush  # noqa: PLC0415 (search is heavier; load on use)

    data = json.loads(Path(result).read_text()) if not isinstance(result, dict) else result
    if not isinstance(data, dict) or data.get("format") != "jaxplan.pusharound.result":
        raise ValueError("result: not a jaxplan pusharound result.json (format 'jaxplan.pusharound.result').")
    out = []
    for k, p in enumerate(data.get("schedule", [])):
        try:
            task = PushTask(int(p["movable"]), np.asarray(p["contacts_body"], np.float64),
                            np.asarray(p["directions_body"], np.float64), np.asarray(p["active"], bool),
                            np.asarray(p["velocity"], np.float64), float(p["duration_s"]))
            out.append(ScheduledPush(task, tuple(p["gap"]) if p.get("gap") is not None else None, float(p["cost"]),
                                     np.asarray(p["poses_before"], np.float64), np.asarray(p["poses_after"], np.float64),
                                     np.asarray(p["robots_before"], np.float64), np.asarray(p["robots_after"], np.float64)))
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"schedule[{k}]: malformed push record ({type(e).__name__}: {e}).") from None
    return out
