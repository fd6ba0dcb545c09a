"""Environment-first aggregate transport (paper 1): a trajectory fabric over a grid of aggregate
counts, and the push loop that plans on it.

Data flows one way (docs/architecture.md): ``scene`` -> ``visibility`` (successor graph) ->
``fabric`` (K-best DP, ``kbest``; values, table, psi) -> ``heatmap`` (heat, highways) ->
``connectors`` (anchors) -> ``selection`` (Eq. 6 with ``spillage``) -> ``execute`` (push) ->
``rebuild`` (selective, ``compact``). ``plan`` makes one tick's push; ``episode`` is the pure state
machine (``reset`` / ``step`` / ``rollout``); ``run`` its host driver (``run_episode``).
``soft`` is the differentiable relaxation of the fabric; ``physics`` checks routes with a rover in MuJoCo; ``viz``
draws fabrics and episodes.
"""
from jaxplan.transport.connectors import Connectors, plan_connectors, slot_anchors
from jaxplan.transport.episode import (
    BUDGET,
    CLEARED,
    DONE,
    MAX_PUSHES,
    NO_MATERIAL,
    NO_ROUTE,
    RUNNING,
    SELECTIVE_MIN_CELLS,
    STOP_REASONS,
    WALK_CAP,
    EpisodeParams,
    EpisodeState,
    StepRecord,
    act,
    default_walk_cap,
    outside_mass,
    plan_code,
    rebuild_mode,
    require_hard,
    reset,
    rollout_scenes_jit,
    step,
    validate_episode_params,
)
from jaxplan.transport.execute import (
    SPLINE_CHUNK,
    Push,
    Route,
    execute_jit,
    execute_push,
    quantize,
    route_from_path,
    routes_from_paths,
    spill_cells,
    waypoint_pickup,
    waypoints,
)
from jaxplan.transport.fabric import (
    Fabric,
    Paths,
    Table,
    build_fabric,
    check_build_memory,
    count_table_hops,
    estimate_build_bytes,
    extract_paths,
    fabric_of,
    walk_table,
)
from jaxplan.transport.generators import BUILTIN_SCENES, DEFAULT_SCENE, builtin_scene, random_scene
from jaxplan.transport.heatmap import highways
from jaxplan.transport.maps import read_movingai_map, site_from_map
from jaxplan.transport.obstacles import NO_DETOUR, corner_free, detour_hops, jump_clear, obstacle_geometry
from jaxplan.transport.params import K_MAX, FabricParams, validate_params
from jaxplan.transport.plan import (
    FabricChanges,
    Plan,
    PlanReads,
    anchor_connector,
    choose_source,
    connector_walk,
    fabric_changes,
    plan_episode_tick,
    plan_for_source,
    plan_reads,
    plan_tick,
    plan_with_connector,
    plans_unchanged,
    source_anchor,
    source_anchors,
)
from jaxplan.transport.rebuild import Affected, refresh_connectors, selective_rebuild
from jaxplan.transport.run import Episode, run_episode
from jaxplan.transport.scene import MAX_FILE_SIDE, Scene, box, circle, stack_scenes
from jaxplan.transport.selection import Selection, reselect, reselect_jit, select_routes
from jaxplan.transport.soft import SoftFabric
from jaxplan.transport.spillage import SpillParams
from jaxplan.transport.viz import (
    PALETTE,
    animate_episode,
    blocked_handle,
    blocked_of,
    cell_edges,
    draw_blocked,
    finite_max,
    plot_episode,
    plot_fabric,
    polygon_rings,
)

__all__ = ["Affected", "BUDGET", "BUILTIN_SCENES", "CLEARED", "Connectors", "DEFAULT_SCENE", "DONE", "Episode",
           "EpisodeParams", "EpisodeState", "Fabric", "FabricChanges", "FabricParams", "K_MAX", "MAX_FILE_SIDE",
           "MAX_PUSHES", "NO_DETOUR", "NO_MATERIAL", "NO_ROUTE", "PALETTE", "Paths", "Plan", "PlanReads", "Push",
           "RUNNING", "Route", "SELECTIVE_MIN_CELLS", "SPLINE_CHUNK", "STOP_REASONS", "Scene", "Selection",
           "SoftFabric", "SpillParams", "StepRecord", "Table", "WALK_CAP", "act", "anchor_connector", "animate_episode",
           "blocked_handle", "blocked_of", "box", "build_fabric", "builtin_scene", "cell_edges", "check_build_memory",
           "choose_source", "circle", "connector_walk", "corner_free", "count_table_hops", "default_walk_cap",
           "detour_hops", "draw_blocked", "estimate_build_bytes", "execute_jit", "execute_push", "extract_paths",
           "fabric_changes", "fabric_of", "finite_max", "highways", "jump_clear", "obstacle_geometry", "outside_mass",
           "plan_code", "plan_connectors", "plan_episode_tick", "plan_for_source", "plan_reads", "plan_tick",
           "plan_with_connector", "plans_unchanged", "plot_episode", "plot_fabric", "polygon_rings", "quantize",
           "random_scene", "read_movingai_map", "rebuild_mode", "refresh_connectors", "require_hard", "reselect",
           "reselect_jit", "reset", "rollout_scenes_jit", "route_from_path", "routes_from_paths", "run_episode",
           "select_routes", "selective_rebuild", "site_from_map", "slot_anchors", "source_anchor", "source_anchors",
           "spill_cells", "stack_scenes", "step", "validate_episode_params", "validate_params", "walk_table",
           "waypoint_pickup", "waypoints"]
