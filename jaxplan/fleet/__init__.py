"""A fleet of rovers on one shared fabric (docs/fleet.md): tasks are pushes the fabric offers, each
reserving its footprint; idle rovers get tasks by a strategy (``coordinated``, ``independent``,
``partitioned``); rovers approach and push one cell per step without colliding.

Modules: ``footprint`` (a task's cells and push path), ``motion`` (distance fields, the one-step
move), ``assign`` (the strategies), ``state`` (``FleetConfig``, ``FleetState``, ``reset``, ``step``,
``rollout``), ``run`` (``run_fleet``, the host driver, and ``FleetRun``).
"""
from jaxplan.fleet.run import FleetRun, run_fleet
from jaxplan.fleet.state import (
    STOP_REASONS,
    STRATEGIES,
    FleetConfig,
    FleetRecord,
    FleetState,
    reset,
    rollout,
    step,
)

__all__ = ["STOP_REASONS", "STRATEGIES", "FleetConfig", "FleetRecord", "FleetRun", "FleetState", "reset",
           "rollout", "run_fleet", "step"]
