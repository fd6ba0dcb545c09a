"""jaxplan: planning how robots move bulk material and clear paths, as jit-compiled JAX kernels.

Public API::

    import jaxplan
    scene = jaxplan.builtin_scene()
    fabric = jaxplan.build_fabric(scene, jaxplan.FabricParams(theta_tol_deg=60.0))
    episode = jaxplan.run_episode(scene)      # plan, push, spill, rebuild until delivered

Each system is a package (``jaxplan.transport``, ``jaxplan.fleet``, ``jaxplan.pusharound``,
``jaxplan.teams``) whose entry points are re-exported here; docs/architecture.md is the map. Names
that only make sense inside one system (the transport episode's ``reset`` and ``step``, its ``Push``
and ``Route`` records) stay in that system's package.
"""
# Every name loads on first use, so that ``import jaxplan`` imports neither JAX nor MuJoCo: the
# command line installs its signal handlers before those imports (``jaxplan.cli.entry``), and a
# program that only plans on a grid never loads MuJoCo or optax.
_TRANSPORT = ("BUILTIN_SCENES", "DEFAULT_SCENE", "Connectors", "Episode", "EpisodeParams", "EpisodeState", "Fabric",
              "FabricParams", "Paths", "Scene", "Selection", "SoftFabric", "SpillParams", "box", "build_fabric",
              "builtin_scene", "circle", "extract_paths", "plan_connectors", "random_scene", "refresh_connectors",
              "reselect", "run_episode", "select_routes", "selective_rebuild")
_LAZY = {
    **{name: "jaxplan.core" for name in ("limit_malloc_arenas", "single_cpu")},
    **{name: "jaxplan.transport" for name in _TRANSPORT},
    **{name: "jaxplan.pusharound" for name in ("PushScene", "RankingParams", "SearchConfig", "build_wccg",
                                                "connectivity", "nominal_scene", "plan_pushes", "rank_gaps")},
    **{name: "jaxplan.teams" for name in ("SiteParams", "TeamsConfig", "paper_scenario", "random_sites",
                                           "run_sites", "simulate_site")},
    **{name: "jaxplan.fleet" for name in ("FleetConfig", "FleetRun", "run_fleet")},
}
_LAZY_MODULES = ("core", "transport", "sweep", "tune", "pusharound", "teams", "physics", "reference", "cli", "fleet")

__all__ = [
    # shared
    "limit_malloc_arenas", "single_cpu", "sweep", "tune",
    # transport
    "BUILTIN_SCENES", "DEFAULT_SCENE", "Connectors", "Episode", "EpisodeParams", "EpisodeState", "Fabric",
    "FabricParams", "Paths", "Scene", "Selection", "SoftFabric", "SpillParams", "box", "build_fabric",
    "builtin_scene", "circle", "extract_paths", "plan_connectors", "random_scene", "refresh_connectors", "reselect",
    "run_episode", "select_routes", "selective_rebuild",
    # fleet
    "FleetConfig", "FleetRun", "run_fleet",
    # PushAround
    "PushScene", "RankingParams", "SearchConfig", "build_wccg", "connectivity", "nominal_scene", "plan_pushes",
    "rank_gaps",
    # teams
    "SiteParams", "TeamsConfig", "paper_scenario", "random_sites", "run_sites", "simulate_site",
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
