"""jaxplan: planning how robots move bulk material and clear paths, as jit-compiled JAX kernels.

Public API::

    import jaxplan
    scene = jaxplan.builtin_scene()
    fabric = jaxplan.build_fabric(scene, jaxplan.FabricParams(theta_tol_deg=60.0))
    episode = jaxplan.run_episode(scene)      # plan, push, spill, rebuild until delivered
"""
from jaxplan._compile import limit_malloc_arenas, single_cpu
from jaxplan.connectors import Connectors, plan_connectors
from jaxplan.episode import Episode, EpisodeParams, EpisodeState, StepRecord, reset, run_episode, step
from jaxplan.execute import Push, Route
from jaxplan.fabric import Fabric, Paths, Table, build_fabric, extract_paths
from jaxplan.params import FabricParams
from jaxplan.rebuild import Affected, refresh_connectors, selective_rebuild
from jaxplan.scene import BUILTIN_SCENES, DEFAULT_SCENE, Scene, box, builtin_scene, circle
from jaxplan.selection import Selection, reselect, select_routes
from jaxplan.soft import SoftFabric
from jaxplan.spillage import SpillParams

# PushAround, the team model, sweeps and tuning load on first use: each pulls in libraries (MuJoCo,
# optax) that planning on a grid does not need, so ``import jaxplan`` stays quick and small.
_LAZY = {
    **{name: "jaxplan.pusharound" for name in ("PushScene", "RankingParams", "SearchConfig", "build_wccg",
                                                "connectivity", "nominal_scene", "plan_pushes", "rank_gaps")},
    **{name: "jaxplan.teams" for name in ("SiteParams", "TeamsConfig", "paper_scenario", "random_sites",
                                           "run_sites", "simulate_site")},
}
_LAZY_MODULES = ("sweep", "tune", "pusharound", "teams", "physics", "reference")

__all__ = [
    "BUILTIN_SCENES", "DEFAULT_SCENE", "Affected", "Connectors", "Episode", "EpisodeParams", "EpisodeState", "Fabric",
    "FabricParams", "Paths", "Push", "PushScene", "RankingParams", "SearchConfig", "Route", "Scene", "Selection",
    "SiteParams", "SoftFabric", "SpillParams", "StepRecord", "Table", "TeamsConfig", "box", "build_fabric", "build_wccg", "builtin_scene",
    "circle", "connectivity", "extract_paths", "limit_malloc_arenas", "nominal_scene", "paper_scenario", "plan_connectors", "plan_pushes",
    "random_sites", "rank_gaps", "refresh_connectors", "reselect", "reset", "run_episode", "run_sites", "select_routes", "selective_rebuild",
    "simulate_site", "single_cpu", "step", "sweep", "tune",
]
__version__ = "0.1.0"


def __getattr__(name: str):
    import importlib

    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
    elif name in _LAZY_MODULES:
        value = importlib.import_module(f"jaxplan.{name}")
    else:
        raise AttributeError(f"module 'jaxplan' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY) | set(_LAZY_MODULES))
