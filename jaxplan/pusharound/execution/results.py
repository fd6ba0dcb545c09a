"""What an execution returns: :class:`Frames` (recorded states), :class:`ExecutedPush` (one push as
executed), :class:`Execution` (the whole run), and :func:`plan_frames` (key frames of a plan that
was not executed). Units: m, s, rad."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxplan.pusharound.push import PushTask
from jaxplan.pusharound.scene import PushScene

__all__ = ["ExecutedPush", "Execution", "Frames", "plan_frames", "schedule_of"]


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
    outline from its predicted one [m]; ok: the push counts as succeeded; transit_s, push_s: simulated
    seconds of both phases; plan: which plan it came from (0 the original, k the k-th replan)."""

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


def schedule_of(obj) -> list:
    """The scheduled pushes of a ``SearchResult`` (its ``schedule``), of a list of them, or [] for None."""
    if obj is None:
        return []
    return list(obj.schedule) if hasattr(obj, "schedule") else list(obj)


def plan_frames(scene: PushScene, result_or_schedule) -> Frames:
    """Key frames of a schedule as planned (no physics): the start state, then every push's predicted
    ``poses_after`` / ``robots_after``; time is the cumulative push duration [s]. For drawing a plan
    that is not executed (``--no-execute``, or a failed search's partial schedule)."""
    schedule = schedule_of(result_or_schedule)
    poses = [scene.poses] + [np.asarray(s.poses_after, np.float64) for s in schedule]
    robots = [np.asarray(scene.robots, np.float64)] + [np.asarray(s.robots_after, np.float64) for s in schedule]
    time = np.r_[0.0, np.cumsum([float(np.asarray(s.task.duration)) for s in schedule])]
    return Frames(time, np.stack(poses), np.stack(robots), np.arange(-1, len(schedule), dtype=np.int32),
                  ["start"] + ["planned"] * len(schedule))
