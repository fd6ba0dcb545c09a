"""The execution loop (:func:`execute_schedule`): transition, push, compare with the plan, replan
or go on open loop, until Eq. 7 holds (module docstring of :mod:`jaxplan.pusharound.execution`)."""
from __future__ import annotations

import functools
import math

import numpy as np
import shapely
from shapely import affinity

from jaxplan.physics import Simulator
from jaxplan.pusharound.execution.config import ExecutionConfig
from jaxplan.pusharound.execution.control import retreat, run_push, transit_policy
from jaxplan.pusharound.execution.results import ExecutedPush, Execution, schedule_of
from jaxplan.pusharound.execution.state import ExecutionState, recorded_frames
from jaxplan.pusharound.execution.transit import run_transit
from jaxplan.pusharound.physics import PushWorld, build_push_world
from jaxplan.pusharound.push import PushTask, check_tasks, make_push_simulator, stack_tasks, start_positions
from jaxplan.pusharound.scene import PushScene
from jaxplan.pusharound.wccg import build_wccg, connectivity, w_clear_path

__all__ = ["EXTRA_PUSHES", "execute_schedule"]

# Pushes that replanning may add to a schedule before execution gives up (ExecutionConfig.max_pushes).
EXTRA_PUSHES = 40


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
    """Execute a pushing schedule in physics from ``scene``'s state (docstring of
    :mod:`jaxplan.pusharound.execution`).

    result_or_schedule: a ``SearchResult`` (its ``schedule``) or a list of scheduled pushes, each
    with ``task`` (a single :class:`PushTask`) and ``poses_after`` f[M, 3] (the prediction).
    world: :func:`build_push_world` of ``scene`` (built when None; only its model and config are used,
    the state comes from ``scene``). replan: ``replan(scene_now) -> SearchResult`` called with the
    current poses and robot positions when a push fails or the schedule ends without Eq. 7 (None: no
    replanning). config: :class:`ExecutionConfig`; record_every overrides its frame interval [ticks].
    """
    cfg = _checked_config(config, record_every)
    if not isinstance(scene, PushScene):
        raise ValueError(f"scene: expected a PushScene; got {type(scene).__name__}.")
    schedule = schedule_of(result_or_schedule)
    max_pushes = len(schedule) + EXTRA_PUSHES if cfg.max_pushes is None else cfg.max_pushes
    world = _checked_world(scene, world)
    push_sim, transit_sim = _simulators(world, cfg.backend)
    state = ExecutionState(world, np.asarray(scene.robots, np.float64), scene.poses, cfg)
    ex = _Progress(scene, state, push_sim, transit_sim, replan, list(schedule))
    reason = "connected" if _connected(scene) else _run_until_connected(ex, max_pushes)
    if ex.executed and cfg.retreat > 0 and not ex.retreated:
        retreat(state, transit_sim, ex.executed[-1].task)
    return _execution(ex, reason)


def _checked_config(config: ExecutionConfig | None, record_every: int | None) -> ExecutionConfig:
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
    return cfg


def _checked_world(scene: PushScene, world: PushWorld | None) -> PushWorld:
    world = build_push_world(scene) if world is None else world
    if len(world.mov_adr) != len(scene.movables) or len(world.robot_adr) != len(scene.robots):
        raise ValueError("world: built for another scene (movable or robot count differs); "
                         "use build_push_world(scene).")
    return world


def _simulators(world: PushWorld, backend: str) -> tuple:
    """(push simulator, transit simulator) of ``world``, on the same engine."""
    push_sim = make_push_simulator(world, backend)
    wcfg = world.config
    transit_sim = Simulator(world.model,
                            functools.partial(transit_policy, tuple(int(a) for a in world.robot_adr.reshape(-1)),
                                              float(wcfg.kp), float(wcfg.vmax)),
                            substeps=wcfg.substeps, bounds=world.bounds, backend=push_sim.backend)
    return push_sim, transit_sim


class _Progress:
    """One execution's bookkeeping (mutable on purpose): the pushes executed, the schedule left, the
    replanning budget used, and the notes of the failures absorbed on the way."""

    def __init__(self, scene: PushScene, state: ExecutionState, push_sim: Simulator, transit_sim: Simulator,
                 replan, queue: list):
        self.scene, self.state, self.push_sim, self.transit_sim = scene, state, push_sim, transit_sim
        self.replan, self.queue = replan, queue
        self.executed: list = []
        self.replans = 0
        self.plan_id = 0
        self.notes: list = []
        self.can_replan = replan is not None
        self.retreated = False

    def now(self) -> PushScene:
        """The scene at the current physical state."""
        return self.scene.with_poses(self.state.poses).replace(robots=self.state.robots)


def _run_until_connected(ex: _Progress, max_pushes: int) -> str:
    """Execute the queue, replanning on failures, until Eq. 7 holds or nothing is left to do.
    Returns why execution stopped."""
    while True:
        if not ex.queue:
            failed = "schedule exhausted"
        elif len(ex.executed) >= max_pushes:
            return f"max_pushes ({max_pushes}) reached"
        else:
            connected, failed = _execute_next(ex)
            if connected:
                return "connected" + (f" (after: {'; '.join(dict.fromkeys(ex.notes))})" if ex.notes else "")
        if failed is None:
            continue
        if _replanned(ex, failed):
            continue
        # No replanning left: finish the schedule open loop (or stop), the failure recorded in ``executed``.
        if failed == "schedule exhausted" or not ex.state.cfg.open_loop:
            return "; ".join(dict.fromkeys(ex.notes))


def _execute_next(ex: _Progress) -> tuple:
    """Transition and push of the next scheduled push, recorded in ``ex.executed``. Returns
    (Eq. 7 holds after it, why it failed or None)."""
    state, cfg = ex.state, ex.state.cfg
    item = ex.queue.pop(0)
    ex.retreated = False
    planned = np.asarray(item.poses_after, np.float64)
    task = PushTask(*(np.asarray(getattr(item.task, f)) for f in PushTask._fields))
    state.push_index = len(ex.executed)
    poses_before = state.poses
    world = state.world
    tasks1 = check_tasks(world, stack_tasks([task]))
    starts = start_positions(world._replace(scene=ex.scene.replace(robots=state.robots)), tasks1, poses_before)[0]
    task, arrived, transit_s = run_transit(state, ex.transit_sim, ex.scene, task, starts)
    if not arrived:
        ex.executed.append(ExecutedPush(task, planned, poses_before, state.poses, state.robots,
                                        "transit_timeout", False, math.nan, False, transit_s, 0.0, ex.plan_id))
        return False, "transition timed out"
    out, why, push_s = run_push(state, ex.push_sim, task, planned)
    after = state.poses
    dev = _outline_deviation(ex.scene, after, planned)
    valid = bool(out.valid[0])
    ok = valid and float(dev.max()) <= cfg.deviation_tol
    flags = {"hit_fixed": out.hit_fixed[0], "left_workspace": out.left_workspace[0],
             "tipped": out.tipped[0], "not_finite": not out.finite[0]}
    ex.executed.append(ExecutedPush(task, planned, poses_before, after, state.robots, why, valid,
                                    float(dev.max()), ok, transit_s, push_s, ex.plan_id,
                                    ",".join(k for k, v in flags.items() if v)))
    failed = None
    connected = _connected(ex.now())
    if connected and cfg.retreat > 0:
        # The corridor the vehicle meets is the one after the robots back off: a body still sliding
        # from the early stop can close a corridor the plan left just W wide.
        retreat(state, ex.transit_sim, task)
        ex.retreated = True
        connected = _connected(ex.now())
        if not connected:
            failed = "corridor closed during the retreat"
    if not connected and not ok and failed is None:
        failed = "push failed" if valid else "push invalid in physics"
    return connected, failed


def _replanned(ex: _Progress, failed: str) -> bool:
    """After a failure: replan from the current state if the budget allows; a new schedule replaces
    the queue. Returns whether it did; otherwise the failure is noted and replanning ends."""
    if ex.can_replan and ex.replans < ex.state.cfg.max_replans:
        ex.replans += 1
        res = ex.replan(ex.now())
        if res is not None and getattr(res, "success", True):
            ex.plan_id += 1
            ex.queue = schedule_of(res)
            return True
        why = f" ({res.reason})" if getattr(res, "reason", "") else ""
        ex.notes.append(f"{failed}; replan {ex.replans} failed{why}")
        ex.can_replan = False          # a replanner that found nothing from here will not from a later state
    elif ex.replan is not None and ex.can_replan:
        ex.notes.append(f"{failed} (replans exhausted: {ex.replans})")
        ex.can_replan = False
    else:
        ex.notes.append(failed)
    return False


def _execution(ex: _Progress, reason: str) -> Execution:
    """The :class:`Execution` at the current state: Eq. 7 and a W-clear path, frames, simulated time."""
    state, world = ex.state, ex.state.world
    final = ex.now()
    g = build_wccg(final)
    conn = bool(connectivity(g, final.start, final.goal).connected)
    path = w_clear_path(g, final.start, final.goal) if conn else None
    tick_s = float(world.config.timestep) * world.config.substeps
    return Execution(conn and path is not None, conn, path, final, ex.executed, recorded_frames(state, world),
                     state.tick * tick_s, ex.replans, reason)
