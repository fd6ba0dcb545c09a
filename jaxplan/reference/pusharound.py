"""The exact cross-checks of ``jaxplan.pusharound``: plain shapely, no graph.

- :func:`reference_connected`: free space ``F_W`` = workspace shrunk by W/2 minus the obstacles
  inflated by W/2 (Minkowski sum with the disk, as a shapely buffer); start and goal are connected iff
  both lie in the same connected component of ``F_W`` (Eq. 2 / Eq. 7 without the graph).
- :func:`path_clearance`: the smallest distance from a polyline to any obstacle or to the workspace
  boundary; a path is W-clear iff it lies in the workspace and this is >= W/2.
- :func:`reference_pair_distances`: component distances with one shapely call per pair.
- :func:`swept_polygon`: the region a movable sweeps along a push, placed pose by pose with shapely's
  affine transforms and merged with one union (the peer of ``quickpass.swept_hulls``).
- :func:`reference_gap_costs`: Eq. 9 by exhaustive recursion, with Eq. 8's one-hop terms and the
  dead-end penalty restated here; the WCCG's frontier gaps come from the caller.

This module imports none of the kernels it checks: where a twin needs the WCCG (which gaps lie on the
frontier), the caller computes that with the kernels and passes it in.

Tolerance: shapely buffers approximate the disk by a polygon whose vertices lie on the circle (here 64
per quarter), so ``F_W`` is too large by at most ``W/2 (1 - cos(pi/256)) ~ 4e-5 W``; scenes with a gap
within that of ``W`` are ambiguous to this check.
"""
from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import LineString, Point
from shapely.geometry import box as _box

__all__ = ["DEAD_END_PENALTY", "free_space", "path_clearance", "reference_connected", "reference_gap_costs",
           "reference_pair_distances", "swept_polygon"]

_QUAD_SEGS = 64
DEAD_END_PENALTY = 1e3   # Eq. 9: added to a first-hop gap's cost when every branch after it dead-ends


def free_space(scene):
    """``F_W``: the vehicle centre's free region (a shapely (Multi)Polygon)."""
    r = 0.5 * scene.width
    x0, y0, x1, y1 = scene.workspace
    inner = _box(x0 + r, y0 + r, x1 - r, y1 - r) if (x1 - x0 > 2 * r and y1 - y0 > 2 * r) else None
    if inner is None:
        return shapely.Polygon()
    polys = scene.obstacle_polygons()
    if not polys:
        return inner
    blocked = shapely.union_all([shapely.buffer(p, r, quad_segs=_QUAD_SEGS) for p in polys])
    return inner.difference(blocked)


def reference_connected(scene) -> bool:
    """True iff start and goal lie in one connected component of ``free_space(scene)``."""
    free = free_space(scene)
    s, g = Point(scene.start), Point(scene.goal)
    for part in getattr(free, "geoms", [free]):
        if part.covers(s):
            return bool(part.covers(g))
    return False


def path_clearance(scene, path) -> float:
    """Minimum distance [m] from the polyline ``path: f[P, 2]`` to the obstacles and the workspace
    boundary; ``-inf`` if the path leaves the workspace."""
    path = np.asarray(path, np.float64)
    line = LineString(path) if len(path) > 1 else Point(path[0])
    ws = _box(*scene.workspace)
    if not ws.covers(line):
        return -np.inf
    d = ws.exterior.distance(line)
    for p in scene.obstacle_polygons():
        d = min(d, p.distance(line))
    return float(d)


def reference_pair_distances(pieces) -> np.ndarray:
    """``f64[N, N]`` distance between every pair of shapely polygons (0 when they touch or overlap)."""
    n = len(pieces)
    out = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            out[i, j] = out[j, i] = pieces[i].distance(pieces[j])
    return out


def _one_hop_terms(gap, team, width: float, mass_ref: float) -> tuple:
    """Eq. 8's (C_t, C_p) of crossing ``gap`` with robots at ``team`` f[N, 2]: the farthest robot's
    distance to the gap's insertion point, and the width deficit ``max(W - width, 0)`` times the
    lighter movable's mass over ``mass_ref``."""
    team = np.asarray(team, np.float64).reshape(-1, 2)
    c_t = max((float(np.linalg.norm(p - gap.insertion)) for p in team), default=0.0)
    c_p = max(width - gap.width, 0.0) * gap.mass / mass_ref
    return c_t, c_p


def reference_gap_costs(scene, params, frontier_gaps) -> dict:
    """Eq. 9 by exhaustive recursion (no beam): ``{gap.bodies: Cost(g)}`` for the first-hop gaps.

    Every sequence of at most ``params.depth`` further gaps is enumerated; the minimum runs over the
    sequences that reach the goal's face if any, else over those stopped at the depth limit, else
    (every branch dead-ends) over the dead ends plus :data:`DEAD_END_PENALTY`. Equal to
    :func:`jaxplan.pusharound.ranking.rank_gaps` whenever its beam keeps every state.

    frontier_gaps: the WCCG's answer, computed by the caller with the kernels (``connectivity`` and
    ``candidate_gaps`` on the scene's WCCG): a function of ``removed`` (a frozenset of crossed gaps'
    ``bodies``) returning ``(same_face, gaps)``, whether start and goal share a face once those gaps are
    crossed and, if not, the frontier's candidate gaps (with ``bodies``, ``insertion`` f[2], ``width``
    [m] and ``mass`` [kg]). The costs (Eqs. 8-9) are computed here, with W = ``scene.width``.
    """
    width = float(scene.width)
    lt, lp, eta = float(params.lambda_t), float(params.lambda_p), float(params.eta)

    def tails(removed, team, level):
        """List of (status, cost) of every continuation from this state."""
        same_face, gaps = frontier_gaps(removed)
        if same_face:
            return [(2, 0.0)]
        if level == params.depth:
            return [(1, 0.0)]
        if not gaps:
            return [(0, 0.0)]
        out = []
        for gap in gaps:
            c_t, c_p = _one_hop_terms(gap, team, width, params.mass_ref)
            step = lt * c_t + lp * c_p + eta * float(np.linalg.norm(gap.insertion - np.asarray(scene.goal)))
            out += [(s, step + c) for s, c in tails(removed | {gap.bodies}, gap.insertion, level + 1)]
        return out

    same_face, first = frontier_gaps(frozenset())
    costs = {}
    for gap in first:
        c_t, c_p = _one_hop_terms(gap, scene.robots, width, params.mass_ref)
        leaves = tails(frozenset([gap.bodies]), gap.insertion, 0)
        for status, penalty in ((2, 0.0), (1, 0.0), (0, DEAD_END_PENALTY)):
            pool = [c for s, c in leaves if s == status]
            if pool:
                costs[gap.bodies] = lt * c_t + lp * c_p + min(pool) + penalty
                break
    return costs


def swept_polygon(movable, pose0, velocity, duration: float, samples: int = 8):
    """The union over consecutive poses (``samples`` evenly spaced along ``pose0 + velocity t``,
    ``t`` in [0, duration]) and pieces of the convex hull of the piece placed at both poses."""
    ts = np.linspace(0.0, float(duration), samples)
    placed = [movable.world_pieces(tuple(np.asarray(pose0, np.float64) + np.asarray(velocity, np.float64) * t))
              for t in ts]
    return shapely.union_all([shapely.union_all([a, b]).convex_hull
                              for k in range(samples - 1) for a, b in zip(placed[k], placed[k + 1])])
