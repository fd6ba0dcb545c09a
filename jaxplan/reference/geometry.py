"""Serial reference for the scene geometry: one shapely query per cell, float64.

This is the obviously-correct twin of :func:`jaxplan.transport.scene._geometry` (docs/transport.md, "Grid and
geometry"). It is slow (a Python double loop) and meant for tests on small grids only.
"""
from __future__ import annotations

import numpy as np
from shapely.geometry import Point
from shapely.ops import nearest_points

__all__ = ["reference_geometry"]

# A centre this close to the boundary (in cell sizes) counts as on it, hence covered.
_ON_BOUNDARY_EPS = 1e-9


def reference_geometry(shape, cell_size, origin, target):
    """Target mask, distance and boundary direction of every cell, by per-cell shapely calls.

    shape: (H, W); cell_size: world units; origin: world (x, y) of the grid corner;
    target: shapely Polygon/MultiPolygon, world units.

    Returns numpy arrays
      target_mask: bool[H, W], centre covered by the target (or within 1e-9 s of its boundary);
      dist: f64[H, W], world units, distance from the centre to the target (0 on target cells);
      tvec: f64[H, W, 2], unit (x, y) vector from the centre to the closest boundary point
        (shapely's choice when several are equally close); (0, 0) on target cells.
    """
    h, w = (int(v) for v in shape)
    s = float(cell_size)
    ox, oy = (float(v) for v in origin)
    boundary = target.boundary
    mask = np.zeros((h, w), bool)
    dist = np.zeros((h, w), np.float64)
    tvec = np.zeros((h, w, 2), np.float64)
    for r in range(h):
        for c in range(w):
            p = Point(ox + (c + 0.5) * s, oy + (r + 0.5) * s)
            if boundary.distance(p) <= _ON_BOUNDARY_EPS * s or target.covers(p):
                mask[r, c] = True
                continue
            dist[r, c] = target.distance(p)
            q = nearest_points(boundary, p)[0]
            v = np.array([q.x - p.x, q.y - p.y])
            tvec[r, c] = v / np.linalg.norm(v)
    return mask, dist, tvec
