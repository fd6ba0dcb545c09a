"""The shovel rover in MuJoCo: its MJCF world built from a Scene (``model``), the 3D <-> 2D bridge
that drives planned routes and scores them (``bridge``), and its report (``report``). See
docs/physics.md."""
from jaxplan.transport.rover.bridge import Check, PursuitParams, RouteOutcome, check_routes, plan_routes
from jaxplan.transport.rover.model import RoverConfig, World, build_world

__all__ = ["Check", "PursuitParams", "RouteOutcome", "RoverConfig", "World", "build_world", "check_routes",
           "plan_routes"]
