"""A fleet of rovers on one shared fabric (docs/fleet.md): tasks are pushes the fabric offers, each
reserving its footprint; idle rovers get tasks by a strategy (``coordinated``, ``independent``,
``partitioned``); rovers approach and push one cell per step without colliding.

Modules: ``footprint`` (a task's cells and push path), ``motion`` (distance fields, the one-step
move), ``assign`` (the strategies), ``make_way`` (parked rovers leave a task's footprint),
``set_aside`` (sources whose tasks met a running task, kept out of the candidates),
``state`` (``FleetConfig``, ``FleetState`` with its ``Rovers`` and ``Totals``, ``reset``, ``step``,
``rollout``), ``run`` (``run_fleet``, the host driver, and ``FleetRun``), ``generators`` (the
built-in sites ``site128``, ``site256``, ``site512``, ``site1024``), ``report`` (a run's summary,
files, figure and animation), ``physics`` (concurrent pushes in one MuJoCo world).
"""
from jaxplan.fleet import assign, footprint, motion, set_aside
from jaxplan.fleet.generators import SITES, site
from jaxplan.fleet.physics import (
    TOLERANCE,
    check_concurrent_pushes,
    check_first_round,
    disjoint_routes,
    route_footprint,
    within_tolerance,
)
from jaxplan.fleet.report import FLEET_OUTPUTS, plot_fleet, summary_of, write_fleet_outputs
from jaxplan.fleet.run import FleetRun, check_fleet_memory, run_fleet, validate_fleet_inputs
from jaxplan.fleet.state import (
    STOP_REASONS,
    STRATEGIES,
    FleetConfig,
    FleetRecord,
    FleetState,
    Rovers,
    Totals,
    advance,
    keep_tasks,
    max_rovers,
    reset,
    rollout,
    route_slots,
    step,
)

__all__ = ["FLEET_OUTPUTS", "FleetConfig", "FleetRecord", "FleetRun", "FleetState", "Rovers", "SITES",
           "STOP_REASONS", "STRATEGIES", "TOLERANCE", "Totals", "advance", "assign", "check_concurrent_pushes",
           "check_first_round", "check_fleet_memory", "disjoint_routes", "footprint", "keep_tasks", "max_rovers",
           "motion", "plot_fleet", "reset", "rollout", "route_footprint", "route_slots", "run_fleet", "set_aside",
           "site", "step", "summary_of", "validate_fleet_inputs", "within_tolerance", "write_fleet_outputs"]
