"""The controllers of both phases as rollouts in chunks of ``config.horizon`` ticks: path tracking
(:func:`transit_policy`, driven by :func:`drive_along`; also the final :func:`retreat`) and the
P-controlled push with early stop (:func:`run_push`). Each advances an :class:`ExecutionState` and
records its frames. Units: m, s, rad."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.physics import Simulator, Trajectory
from jaxplan.pusharound.execution.state import ExecutionState
from jaxplan.pusharound.physics import movable_poses
from jaxplan.pusharound.push import PushTask, check_tasks, rollout_outcome, stack_tasks

__all__ = ["drive_along", "pack_paths", "retreat", "run_push", "transit_policy"]


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


def pack_paths(paths: list) -> tuple[np.ndarray, np.ndarray]:
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


def drive_along(state: ExecutionState, sim: Simulator, paths: list, targets: np.ndarray, active: np.ndarray,
                phase: str) -> tuple:
    """Drive the robots along ``paths`` (one f[K, 2] per robot) until the ``active`` ones are within
    ``arrive_tol`` of ``targets f[N, 2]`` after their reference ended, or the timeout. Returns
    (arrived, simulated seconds)."""
    cfg, world = state.cfg, state.world
    path, lens = pack_paths(paths)
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


def retreat(state: ExecutionState, sim: Simulator, task: PushTask) -> float:
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
    return drive_along(state, sim, paths, targets, active, "retreat")[1]


def run_push(state: ExecutionState, sim: Simulator, task: PushTask, planned: np.ndarray) -> tuple:
    """One P-controlled push with early stop. Returns (outcome of 1, stop reason, simulated seconds)."""
    world = state.world
    tasks = check_tasks(world, stack_tasks([task]))
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
    stop, why = _early_stop(state.cfg, pose_t, planned[m], tick_s)
    first_bad = int(traj.first_bad[0])
    finite = first_bad < 0 or first_bad > stop
    cut = Trajectory(traj.qpos[:, :stop + 1], traj.qvel[:, :stop + 1], traj.ctrl[:, :stop], traj.time[:stop + 1],
                     np.array([finite]), np.array([first_bad if not finite else -1], np.int32),
                     traj.ncon[:, :stop + 1], traj.pstate, traj.backend)
    out = rollout_outcome(world, tasks, cut, poses0, 4)
    qp = np.asarray(traj.qpos[0], np.float64)
    state.record(qp, stop, "push")
    state.qpos, state.qvel = qp[stop], np.asarray(traj.qvel[0, stop], np.float64)
    return out, why, stop * tick_s


def _early_stop(cfg, pose_t: np.ndarray, planned: np.ndarray, tick_s: float) -> tuple:
    """The tick to stop the push at, and why: the first tick (>= 1) where the target's pose ``pose_t``
    f[T+1, 3] is within ``pos_tol`` / ``yaw_tol`` of ``planned`` f[3] ("reached") or moved less than
    ``stall_eps`` over ``stall_window`` after ``min_push_time`` ("stalled"); else T ("horizon")."""
    horizon = len(pose_t) - 1
    dxy = np.linalg.norm(pose_t[:, :2] - planned[:2], axis=-1)
    dyaw = np.abs(np.angle(np.exp(1j * (pose_t[:, 2] - planned[2]))))
    reached = (dxy < cfg.pos_tol) & (dyaw < cfg.yaw_tol)
    w = max(1, int(round(cfg.stall_window / tick_s)))
    move = np.full(horizon + 1, np.inf)
    move[w:] = (np.linalg.norm(pose_t[w:, :2] - pose_t[:-w, :2], axis=-1)
                + 0.3 * np.abs(np.angle(np.exp(1j * (pose_t[w:, 2] - pose_t[:-w, 2])))))
    t = np.arange(horizon + 1) * tick_s
    stalled = (move < cfg.stall_eps) & (t >= cfg.min_push_time)
    for k in range(1, horizon + 1):
        if reached[k] or stalled[k]:
            return k, "reached" if reached[k] else "stalled"
    return horizon, "horizon"
