"""The running physical state of one execution (qpos, qvel, tick) and the frames it records."""
from __future__ import annotations

import numpy as np

from jaxplan.pusharound.execution.config import ExecutionConfig
from jaxplan.pusharound.execution.results import Frames
from jaxplan.pusharound.physics import PushWorld, initial_state, movable_poses

__all__ = ["ExecutionState", "recorded_frames"]


class ExecutionState:
    """The running physical state (mutable on purpose: one execution's bookkeeping). qpos, qvel: the
    MuJoCo state; tick: ticks simulated so far; frames: (tick, poses f[M, 3], robots f[N, 2], push
    index, phase) every ``record_every`` ticks; push_index: the push being executed or approached."""

    def __init__(self, world: PushWorld, robots, poses, cfg: ExecutionConfig):
        self.world, self.cfg = world, cfg
        self.qpos, self.qvel = initial_state(world, robots, poses)
        self.tick = 0
        self.frames: list = []
        self.push_index = -1
        self.frames.append((0, self.poses, self.robots, -1, "start"))

    @property
    def poses(self) -> np.ndarray:
        """f64[M, 3] movable poses (x [m], y [m], yaw [rad])."""
        return movable_poses(self.world, self.qpos)[0]

    @property
    def robots(self) -> np.ndarray:
        """f64[N, 2] robot positions [m]."""
        return self.qpos[self.world.robot_adr].astype(np.float64)

    def record(self, traj_qpos: np.ndarray, upto: int, phase: str) -> None:
        """Advance the state to tick ``upto`` of the chunk ``traj_qpos f[T+1, nq]`` and record frames."""
        poses = movable_poses(self.world, traj_qpos[1:upto + 1])[0]
        robots = traj_qpos[1:upto + 1][:, self.world.robot_adr]
        for k in range(upto):
            self.tick += 1
            if self.tick % self.cfg.record_every == 0:
                self.frames.append((self.tick, poses[k], robots[k], self.push_index, phase))


def recorded_frames(state: ExecutionState, world: PushWorld) -> Frames:
    """The frames ``state`` recorded, as :class:`Frames` (time in s)."""
    tick_s = float(world.config.timestep) * world.config.substeps
    m, n = len(world.mov_adr), len(world.robot_adr)
    if not state.frames:
        return Frames(np.zeros(0), np.zeros((0, m, 3)), np.zeros((0, n, 2)), np.zeros(0, np.int32), [])
    tick, poses, robots, push, phase = zip(*state.frames)
    return Frames(np.asarray(tick, np.float64) * tick_s, np.stack(poses), np.stack(robots),
                  np.asarray(push, np.int32), list(phase))
