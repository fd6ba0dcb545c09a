"""Top-view plot of a PushAround scene with its WCCG (the style of the paper's Figs. 3-4).

Draws the workspace, fixed obstacles (grey), movables (tan, with their convex pieces outlined),
centroid nodes (blue squares), bridge nodes (red dots), bottleneck bridge-bridge edges (red dashed,
annotated with the width), the frontier loop (orange), ranked gaps (numbers at ``o_g``), the robots,
the endpoint disks ``B(., W/2)`` and the W-clear path (green). Never selects a matplotlib backend.
"""
from __future__ import annotations

import numpy as np

__all__ = ["plot_wccg"]


def plot_wccg(scene, g=None, ax=None, path=None, frontier=None, ranking=None, annotate: bool = True):
    """Draw ``scene`` with its WCCG ``g`` on ``ax`` (a new figure when None); returns the axes.

    path: f[P, 2] W-clear path; frontier: ``Frontier`` (or taken from ``ranking``); ranking:
    ``Ranking``, whose gaps are numbered in ranked order.
    """
    import matplotlib.pyplot as plt  # noqa: PLC0415 (keep matplotlib optional at import time)
    from matplotlib.patches import Circle  # noqa: PLC0415
    from matplotlib.patches import Polygon as MplPolygon  # noqa: PLC0415

    if ax is None:
        _, ax = plt.subplots(figsize=(8, 5.5))
    x0, y0, x1, y1 = scene.workspace
    ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="k", lw=1.5)

    def draw(poly, face, edge, lw=0.8, alpha=1.0):
        ax.add_patch(MplPolygon(np.asarray(poly.exterior.coords), closed=True, fc=face, ec=edge,
                                lw=lw, alpha=alpha))
        for hole in poly.interiors:
            ax.add_patch(MplPolygon(np.asarray(hole.coords), closed=True, fc="white", ec=edge, lw=lw))

    for f in scene.fixed:
        draw(f.polygon, "#9ca3af", "#374151")
    for m in scene.movables:
        draw(m.polygon, "#fcd9a8", "#b45309")
        for p in m.world_pieces():
            ax.plot(*np.asarray(p.exterior.coords).T, color="#b45309", lw=0.3)
    if g is not None:
        inside = [k for k, c in enumerate(g.centroids) if x0 <= c[0] <= x1 and y0 <= c[1] <= y1]
        ax.scatter(g.centroids[inside, 0], g.centroids[inside, 1], marker="s", s=10, c="#2563eb", zorder=3)
        for e in np.nonzero(g.bottleneck & ~g.internal)[0]:
            (ux, uy), (vx, vy) = g.bridge_pts[e]
            cu, cv = g.centroids[g.bridge_uv[e]]
            ax.plot([cu[0], ux], [cu[1], uy], color="#2563eb", lw=0.4)
            ax.plot([cv[0], vx], [cv[1], vy], color="#2563eb", lw=0.4)
            ax.plot([ux, vx], [uy, vy], "--", color="#dc2626", lw=1.0)
            ax.scatter([ux, vx], [uy, vy], s=8, c="#dc2626", zorder=4)
            if annotate and g.bridge_width[e] > 0:
                ax.text(0.5 * (ux + vx), 0.5 * (uy + vy), f"{g.bridge_width[e]:.2f}", fontsize=5,
                        color="#7f1d1d")
    if frontier is None and ranking is not None:
        frontier = ranking.frontier
    if frontier is not None:
        ax.plot(*frontier.ring.T, color="#f97316", lw=1.5, label="frontier loop")
    if ranking is not None:
        for rank, k in enumerate(ranking.order):
            o = ranking.gaps[k].insertion
            ax.annotate(str(rank + 1), o, color="#1d4ed8", fontsize=9, weight="bold", ha="center")
    r = 0.5 * scene.width
    for name, pt, col in (("start", scene.start, "#16a34a"), ("goal", scene.goal, "#7c3aed")):
        ax.add_patch(Circle(pt, r, fc="none", ec=col, lw=1.2))
        ax.text(pt[0], pt[1], name[0].upper(), ha="center", va="center", color=col, weight="bold")
    for p in np.asarray(scene.robots).reshape(-1, 2):
        ax.add_patch(Circle(p, scene.robot_radius, fc="#111827", ec="none"))
    if path is not None:
        ax.plot(*np.asarray(path).T, color="#16a34a", lw=2.0, label="W-clear path")
    ax.set_xlim(x0 - 0.1, x1 + 0.1)
    ax.set_ylim(y0 - 0.1, y1 + 0.1)
    ax.set_aspect("equal")
    ax.set_title(f"WCCG, W = {scene.width:g} m")
    return ax
