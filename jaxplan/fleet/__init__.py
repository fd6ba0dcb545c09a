"""A fleet of rovers on one shared fabric (issue 34): built-in sites, the run record and its report.

``sites`` holds the built-in sites (``site128``, ``site256``, ``site512``); ``run_types.FleetRun``
is what a fleet run returns; ``report`` turns a run into its files (summary, trajectory, pushes,
figure, animation).
"""
from jaxplan.fleet.run_types import FleetRun
from jaxplan.fleet.sites import SITES, site

__all__ = ["SITES", "FleetRun", "site"]
