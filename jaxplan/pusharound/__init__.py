"""PushAround (collaborative path clearing): scenes, the W-Clearance Connectivity Graph (Section III-A)
and the ranking of blocking gaps (Section III-B).

::

    from jaxplan.pusharound import nominal_scene, build_wccg, connectivity, w_clear_path, rank_gaps
    scene = nominal_scene(seed=0)
    g = build_wccg(scene)
    conn = connectivity(g, scene.start, scene.goal)      # Eq. 7, frontier loop when blocked
    ranking = rank_gaps(scene, g=g)                      # Eqs. 8-9: ranked gaps + adjacent movables

See docs/pusharound.md for the definitions and the JSON scene format.
"""
from jaxplan.pusharound.ranking import Gap, Ranking, RankingParams, gap_costs, rank_gaps
from jaxplan.pusharound.scenarios import nominal_scene
from jaxplan.pusharound.scene import Fixed, Movable, PushScene
from jaxplan.pusharound.viz import plot_wccg
from jaxplan.pusharound.wccg import WCCG, Connectivity, build_wccg, clearance, connectivity, w_clear_path

__all__ = ["WCCG", "Connectivity", "Fixed", "Gap", "Movable", "PushScene", "Ranking", "RankingParams",
           "build_wccg", "clearance", "connectivity", "gap_costs", "nominal_scene", "plot_wccg",
           "rank_gaps", "w_clear_path"]
