"""PushAround (collaborative path clearing): scenes, the W-Clearance Connectivity Graph (Section III-A)
and the ranking of blocking gaps (Section III-B).

::

    from jaxplan.pusharound import nominal_scene, build_wccg, connectivity, w_clear_path, rank_gaps
    scene = nominal_scene(seed=0)
    g = build_wccg(scene)
    conn = connectivity(g, scene.start, scene.goal)      # Eq. 7, frontier loop when blocked
    ranking = rank_gaps(scene, g=g)                      # Eqs. 8-9: ranked gaps + adjacent movables

Physics (Section III-C/D): ``build_push_world`` (the scene in MuJoCo), ``PushTask`` / ``face_contacts``
(candidate pushes), ``quick_pass`` (geometric rejection), ``simulate_pushes`` (one batched rollout on
MJX or the C engine), ``push_cost`` (Eq. 11); see ``jaxplan.pusharound.push``.

See docs/pusharound.md for the definitions and the JSON scene format.
"""
from jaxplan.pusharound.animation import animate_execution, plot_state
from jaxplan.pusharound.baselines import BASELINES
from jaxplan.pusharound.execution import Execution, ExecutionConfig, execute_schedule, load_schedule
from jaxplan.pusharound.modetable import ModeTable
from jaxplan.pusharound.physics import PushPhysicsConfig, PushWorld, build_push_world
from jaxplan.pusharound.push import (
                                     PushOutcome,
                                     PushTask,
                                     QuickPass,
                                     direction_tasks,
                                     face_contacts,
                                     make_push_simulator,
                                     push_cost,
                                     quick_pass,
                                     simulate_pushes,
                                     stack_tasks,
)
from jaxplan.pusharound.ranking import Gap, Ranking, RankingParams, gap_costs, rank_gaps
from jaxplan.pusharound.scenarios import corridor_scene, dense_scene, density_scene, nominal_scene
from jaxplan.pusharound.scene import Fixed, Movable, PushScene
from jaxplan.pusharound.search import ScheduledPush, SearchConfig, SearchResult, SearchStats, plan_pushes
from jaxplan.pusharound.viz import plot_wccg
from jaxplan.pusharound.wccg import (
    WCCG,
    Connectivity,
    build_wccg,
    check_feasible,
    clearance,
    connectivity,
    w_clear_path,
)

__all__ = ["BASELINES", "Execution", "ExecutionConfig", "ModeTable", "ScheduledPush", "SearchConfig", "SearchResult",
           "SearchStats", "animate_execution", "corridor_scene", "dense_scene", "density_scene", "execute_schedule",
           "load_schedule", "plan_pushes", "plot_state", "WCCG", "Connectivity", "Fixed", "Gap", "Movable",
           "PushOutcome", "PushPhysicsConfig", "PushScene",
           "PushTask", "PushWorld", "QuickPass", "Ranking", "RankingParams", "build_push_world", "build_wccg",
           "check_feasible",
           "clearance", "connectivity", "direction_tasks", "face_contacts", "gap_costs", "make_push_simulator",
           "nominal_scene",
           "plot_wccg", "push_cost", "quick_pass", "rank_gaps", "simulate_pushes", "stack_tasks", "w_clear_path"]
