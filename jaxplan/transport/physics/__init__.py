"""The shovel rover in MuJoCo: its MJCF world built from a Scene (``model``), the 3D <-> 2D bridge
that drives planned routes and scores them (``bridge``), its report (``report``), and episodes
closed through physics (``closed_loop``). See docs/physics.md."""
from jaxplan.transport.physics.bridge import (
           PUSH_IN,
           Check,
           PursuitParams,
           RouteOutcome,
           cells_of,
           check_routes,
           friction_fields,
           pad_paths,
           particle_fates,
           plan_routes,
           projected_obj,
           pursuit_params,
           pursuit_policy,
           route_mask,
           route_path,
           world_for_routes,
)
from jaxplan.transport.physics.closed_loop import (
           ClosedLoop,
           animate_closed_loop,
           grid_episode,
           plot_closed_loop,
           run_closed_loop,
)
from jaxplan.transport.physics.model import (
           RoverConfig,
           World,
           build_world,
           initial_qpos,
           particle_layout,
           rover_geometry,
           rover_prefix,
           rover_qpos_adr,
)
from jaxplan.transport.physics.report import plot_check, render_frames, table_markdown

__all__ = ["Check", "ClosedLoop", "PUSH_IN", "PursuitParams", "RouteOutcome", "RoverConfig", "World", "build_world",
           "cells_of",
           "check_routes", "friction_fields", "initial_qpos", "pad_paths", "particle_fates", "particle_layout",
           "plan_routes", "plot_check", "projected_obj", "pursuit_params", "pursuit_policy", "render_frames",
           "route_mask", "route_path", "rover_geometry", "rover_prefix", "rover_qpos_adr", "table_markdown",
           "world_for_routes", "animate_closed_loop", "grid_episode", "plot_closed_loop", "run_closed_loop"]
