"""jaxplan: environment-first planning for aggregate transport, as jit-compiled JAX kernels.

Public API::

    from jaxplan import Scene, FabricParams, build_fabric
    scene = jaxplan.builtin_scene()
    fabric = build_fabric(scene, FabricParams(theta_tol_deg=60.0))
"""
from jaxplan.connectors import Connectors, plan_connectors
from jaxplan.fabric import Fabric, Paths, Table, build_fabric, extract_paths
from jaxplan.params import FabricParams
from jaxplan.scene import BUILTIN_SCENES, DEFAULT_SCENE, Scene, box, builtin_scene, circle
from jaxplan.teams import (SiteParams, TeamsConfig, paper_scenario, random_sites, run_sites,
                           simulate_site)

__all__ = [
    "BUILTIN_SCENES", "DEFAULT_SCENE", "Connectors", "Fabric", "FabricParams", "Paths", "Scene",
    "Table", "box", "build_fabric", "builtin_scene", "circle", "extract_paths", "plan_connectors",
    "SiteParams", "TeamsConfig", "paper_scenario", "random_sites", "run_sites", "simulate_site",
]
__version__ = "0.1.0"
