"""PushAround (collaborative path clearing): scenes, the W-Clearance Connectivity Graph (Section III-A)
and the ranking of blocking gaps (Section III-B).

::

    from jaxplan.pusharound import nominal_scene, build_wccg, connectivity, w_clear_path, rank_gaps
    scene = nominal_scene(seed=0)
    g = build_wccg(scene)
    conn = connectivity(g, scene.start, scene.goal)      # Eq. 7, frontier loop when blocked
    ranking = rank_gaps(scene, g=g)                      # Eqs. 8-9: ranked gaps + adjacent movables

Physics (Section III-C/D): ``build_push_world`` (the scene in MuJoCo), ``PushTask`` / ``face_contacts``
(candidate pushes), ``simulate_pushes`` (one batched rollout on MJX or the C engine), ``push_cost``
(Eq. 11); see ``jaxplan.pusharound.push``. ``quick_pass`` (geometric rejection before physics) is in
``jaxplan.pusharound.quickpass``; the seeded scene generators (``nominal_scene``, ...) in
``jaxplan.pusharound.generators``; the Table I baselines (``BASELINES``, ``BaselineConfig``) in the
package ``jaxplan.pusharound.baselines``.

Memory: ``check_memory`` / ``estimate_memory_bytes`` bound the pairwise geometry kernels before any work
(``check_feasible``, ``build_wccg`` and ``plan_pushes`` call it; ``jaxplan.pusharound.budget``).

See docs/pusharound.md for the definitions and docs/scene-files.md for the JSON scene format.
"""
from jaxplan.pusharound.animation import animate_execution, plot_state, save_final_png
from jaxplan.pusharound.baselines import BASELINES, BaselineConfig
from jaxplan.pusharound.execution import Execution, ExecutionConfig, execute_schedule, load_schedule
from jaxplan.pusharound.generators import corridor_scene, dense_scene, density_scene, nominal_scene
from jaxplan.pusharound.modetable import ModeTable
from jaxplan.pusharound.physics import PushPhysicsConfig, PushWorld, build_push_world
from jaxplan.pusharound.push import (
    PushOutcome,
    PushTask,
    direction_tasks,
    face_contacts,
    make_push_simulator,
    push_cost,
    simulate_pushes,
    stack_tasks,
)
from jaxplan.pusharound.quickpass import QuickPass, quick_pass
from jaxplan.pusharound.ranking import (
    Gap,
    PresearchFeatures,
    Ranking,
    RankingParams,
    gap_costs,
    rank_gaps,
    validate_ranking_params,
)
from jaxplan.pusharound.scene import Fixed, Movable, PushScene
from jaxplan.pusharound.search import ScheduledPush, SearchConfig, SearchResult, SearchStats, plan_pushes
from jaxplan.pusharound.viz import plot_wccg
from jaxplan.pusharound.wccg import (
    WCCG,
    Connectivity,
    build_wccg,
    check_feasible,
    check_memory,
    clearance,
    connectivity,
    estimate_memory_bytes,
    w_clear_path,
)

__all__ = ["BASELINES", "BaselineConfig", "Connectivity", "Execution", "ExecutionConfig", "Fixed", "Gap",
           "ModeTable", "Movable", "PresearchFeatures", "PushOutcome", "PushPhysicsConfig", "PushScene", "PushTask",
           "PushWorld", "QuickPass", "Ranking", "RankingParams", "ScheduledPush", "SearchConfig", "SearchResult",
           "SearchStats", "WCCG", "animate_execution", "build_push_world", "build_wccg", "check_feasible",
           "check_memory", "clearance", "connectivity", "corridor_scene", "dense_scene", "density_scene",
           "direction_tasks", "estimate_memory_bytes", "execute_schedule", "face_contacts", "gap_costs",
           "load_schedule", "make_push_simulator", "nominal_scene", "plan_pushes", "plot_state", "plot_wccg",
           "push_cost", "quick_pass", "rank_gaps", "save_final_png", "simulate_pushes", "stack_tasks",
           "validate_ranking_params", "w_clear_path"]
