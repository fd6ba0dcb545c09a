"""The transition phase: which active robot takes which contact (no deadlock on another robot's
start point, no head-on meeting, then the least total length), the robots' paths over one
:class:`Roadmap`, and driving them there. Units: m, s."""
from __future__ import annotations

import itertools

import numpy as np
from shapely.geometry import LineString, Point

from jaxplan.physics import Simulator
from jaxplan.pusharound.execution.control import drive_along
from jaxplan.pusharound.execution.roadmap import Roadmap
from jaxplan.pusharound.execution.state import ExecutionState
from jaxplan.pusharound.push import PushTask
from jaxplan.pusharound.scene import PushScene

__all__ = ["HARD_MARGIN", "MEET_SLACK", "paths_meet", "plan_transit", "run_transit"]

HARD_MARGIN = 0.01  # m: transit paths keep at least r + this from fixed obstacles, walls and idle robots
MEET_SLACK = 0.02   # m: robots that start touching (after a joint push) do not count as meeting


def _positions(path: np.ndarray, arclen: np.ndarray) -> np.ndarray:
    """``f[T, 2]``: where a robot driving ``path`` f[K, 2] is at arc lengths ``arclen`` f[T] (it waits
    at the end)."""
    seg = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    return np.stack([np.interp(arclen, seg, path[:, 0]), np.interp(arclen, seg, path[:, 1])], -1)


def paths_meet(path_a: np.ndarray, path_b: np.ndarray, speed: float, radius: float, dt: float = 0.05) -> bool:
    """Whether two robots driving their paths at ``speed`` from the same instant come closer than
    ``2 radius - MEET_SLACK`` at some moment after they were at least that far apart."""
    total = max(float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))) if len(p) > 1 else 0.0
                for p in (path_a, path_b))
    s = np.arange(0.0, total + speed * dt, speed * dt)
    gap = np.linalg.norm(_positions(path_a, s) - _positions(path_b, s), axis=-1)
    close = gap < 2 * radius - MEET_SLACK
    return bool(np.any(close[np.argmax(~close):])) if (~close).any() else False


def plan_transit(roadmap: Roadmap, robots: np.ndarray, starts: np.ndarray, active: np.ndarray, speed: float,
                  radius: float) -> tuple:
    """Which active robot takes which contact, and the paths. Returns ``(perm i32[N], paths)``: robot
    i takes contact perm[i]; paths: one f[K, 2] per robot (inactive robots: their position).

    Every assignment of the active robots to the contacts (N <= 3; more keep the plan's) is scored by
    (conflicts, total path length): a conflict is a robot whose path passes over another robot's start
    point (closer than 2 r) after that robot should have arrived there (arc length / speed, 1 s
    margin): the later robot would shove the earlier one off its contact, a deadlock in physics; or
    two robots that meet on the way (closer than 2 r - ``MEET_SLACK`` at the same time, both driving
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
        conflicts += sum(paths_meet(path(i, perm[i]), path(j, perm[j]), speed, radius)
                         for a, i in enumerate(act) for j in act[a + 1:])
        key = (conflicts, sum(lens.values()))
        if best_key is None or key < best_key:
            best, best_key = perm, key
    paths = [path(i, best[i]) if active[i] else robots[i][None] for i in range(n)]
    return best, paths


def _swap_contacts(task: PushTask, perm: np.ndarray) -> PushTask:
    return task._replace(contacts=np.asarray(task.contacts)[perm], directions=np.asarray(task.directions)[perm],
                         active=np.asarray(task.active)[perm])


def run_transit(state: ExecutionState, sim: Simulator, scene: PushScene, task: PushTask, starts: np.ndarray) -> tuple:
    """Assign contacts, plan paths and drive the active robots to their push start points ``starts
    f[N, 2]``. Returns (task with contacts possibly swapped, arrived, simulated seconds)."""
    cfg = state.cfg
    r = float(scene.robot_radius)
    robots, poses = state.robots, state.poses
    active = np.asarray(task.active, bool)
    # Inactive robots stay where they are: obstacles for the others.
    idle = [Point(*robots[i]).buffer(r, 8) for i in np.nonzero(~active)[0]]
    roadmap = Roadmap(scene, poses, r + cfg.transit_margin, cfg.grid, idle, r + HARD_MARGIN, cfg.brush_weight)
    perm, paths = plan_transit(roadmap, robots, starts, active, float(state.world.config.transit_speed), r)
    task, starts = _swap_contacts(task, perm), starts[perm]
    arrived, seconds = drive_along(state, sim, paths, starts, np.asarray(task.active, bool), "transit")
    return task, arrived, seconds
