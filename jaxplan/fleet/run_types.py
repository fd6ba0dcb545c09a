"""What a fleet run returns (``run_fleet``): the record the report, the CLI and the benchmark read."""
from __future__ import annotations

import dataclasses

import numpy as np

from jaxplan.transport.scene import Scene

__all__ = ["FleetRun"]


@dataclasses.dataclass
class FleetRun:
    """One fleet run, on the host (numpy arrays and plain Python values). T = steps, N = rovers.

    scene: the initial scene (counts as given, quantized). final_scene: the scene after the last step.
    n_rovers: N. strategy: the strategy's name. steps: T, steps simulated.
    pos: i32[T+1, N, 2], (row, col) of every rover at every step (index 0 = the start).
    delivered: f64[T+1], mass inside the targets (objects). outside: f64[T+1], mass outside them.
    initial_mass: the total mass. initial_outside: ``outside[0]``.
    pushes: one dict per push: rover, first_step, last_step, cells ``[[r, c], ...]``, collected,
      delivered, spilled (objects), mode ("deliver" / "rearrange").
    rover_pushes: i32[N], pushes per rover. idle_steps: i32[N], steps each rover had no task.
    plan_ms: wall ms of each step in which an assignment happened (the planning events).
    conflicts: invariant violations found by the serial checker (must be 0).
    stop_reason: one of ``STOP_REASONS``. message: the stop in words.
    frames: with ``record=True``, one dict per step: obj f32[H, W], heat f32[H, W], highways
      bool[H, W], routes (a list of N: the rover's route cells i32[k, 2], or None without a task);
      else None.
    """

    scene: Scene
    final_scene: Scene
    n_rovers: int
    strategy: str
    steps: int
    pos: np.ndarray
    delivered: np.ndarray
    outside: np.ndarray
    initial_mass: float
    initial_outside: float
    pushes: list
    rover_pushes: np.ndarray
    idle_steps: np.ndarray
    plan_ms: list
    conflicts: int
    stop_reason: str
    message: str
    frames: list | None
