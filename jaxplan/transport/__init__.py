"""Environment-first aggregate transport (paper 1): a trajectory fabric over a grid of aggregate
counts, and the push loop that plans on it.

Data flows one way (docs/architecture.md): ``scene`` -> ``visibility`` (successor graph) ->
``fabric`` (K-best DP, ``kbest``; values, table, psi) -> ``heatmap`` (heat, highways) ->
``connectors`` (anchors) -> ``selection`` (Eq. 6 with ``spillage``) -> ``execute`` (push) ->
``rebuild`` (selective, ``compact``) -> ``episode`` (``reset`` / ``step`` / ``run_episode``).
``soft`` is the differentiable relaxation of the fabric; ``rover`` checks routes in MuJoCo; ``viz``
draws fabrics and episodes.
"""
from jaxplan.transport.connectors import Connectors, plan_connectors
from jaxplan.transport.episode import Episode, EpisodeParams, EpisodeState, StepRecord, reset, run_episode, step
from jaxplan.transport.execute import Push, Route
from jaxplan.transport.fabric import (
    Fabric,
    Paths,
    Table,
    build_fabric,
    check_build_memory,
    estimate_build_bytes,
    extract_paths,
)
from jaxplan.transport.params import FabricParams
from jaxplan.transport.rebuild import Affected, refresh_connectors, selective_rebuild
from jaxplan.transport.scene import Scene, box, circle
from jaxplan.transport.scenes import BUILTIN_SCENES, DEFAULT_SCENE, builtin_scene, random_scene
from jaxplan.transport.selection import Selection, reselect, select_routes
from jaxplan.transport.soft import SoftFabric
from jaxplan.transport.spillage import SpillParams

__all__ = ["BUILTIN_SCENES", "DEFAULT_SCENE", "Affected", "Connectors", "Episode", "EpisodeParams", "EpisodeState",
           "Fabric", "FabricParams", "Paths", "Push", "Route", "Scene", "Selection", "SoftFabric", "SpillParams",
           "StepRecord", "Table", "box", "build_fabric", "builtin_scene", "check_build_memory", "circle",
           "estimate_build_bytes", "extract_paths",
           "plan_connectors", "random_scene", "refresh_connectors", "reselect", "reset", "run_episode",
           "select_routes", "selective_rebuild", "step"]
