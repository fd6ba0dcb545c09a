"""The "graph" presearch: Eq. 9's continuation cost of every gap, minimised exactly by Dijkstra over
the faces of the WCCG skeleton (:func:`face_graph`)."""
from __future__ import annotations

import heapq
import math
from typing import NamedTuple

import numpy as np
import shapely

from jaxplan.pusharound.faces import BRIDGE_EPS, Skeleton, build_skeleton, cluster_region, cluster_rings
from jaxplan.pusharound.ranking import RankingParams
from jaxplan.pusharound.wccg import MOVABLE, WCCG

__all__ = ["FaceGraph", "face_graph"]


class FaceGraph(NamedTuple):
    """The faces of the WCCG skeleton and the gaps between them (the "graph" presearch).

    faces: per gap (body pair with a movable) the set of face ids its bottleneck bridges border;
    start_face, goal_face: the faces of the endpoints (-1: outside every ring, -2: inside an
    obstacle cluster); tail: per gap, the least cost of the gap sequence after crossing it to reach
    the goal face (Eq. 9's continuation, minimised by Dijkstra instead of a beam of limited depth;
    inf when no sequence reaches the goal); final: per gap, crossing it reaches the goal face;
    terms: None unless asked for (``face_graph(..., terms=True)``), else per gap the Eq. 8-9 terms
    of its least tail, f64[3] = (sum of ``|m - m'|`` [m], sum of ``C_p``, sum of ``|m' - goal|`` [m]):
    ``tail = lambda_t t[0] + lambda_p t[1] + eta t[2]`` plus the ``extra`` costs on the way (zeros
    where the tail is 0 or inf).
    """

    faces: dict
    start_face: int
    goal_face: int
    tail: dict
    final: dict
    terms: dict | None = None


def face_graph(g: WCCG, goal, params: RankingParams, extra: dict | None = None, *,
               skeleton: Skeleton | None = None, terms: bool = False) -> FaceGraph:
    """Eq. 9's continuation costs for every gap of the scene, without beam or depth limit.

    Faces are the rings of the skeleton's clusters (a point lies in the face of the smallest ring
    polygon containing it when that ring is a hole; in an obstacle when it is a cluster's exterior).
    A gap (a body pair with at least one movable and bottleneck bridges) borders the faces found a
    hair off each of its bridges, on both sides. Two gaps are neighbours when they border a common
    face (crossing one then the other is a gap sequence; crossed gaps stay open, so the region only
    grows). Costs follow Eqs. 8-9 after the first gap: moving the team from gap to gap
    ``lambda_t |m - m'|`` (bridge midpoints, straight line), widening ``lambda_p C_p(g')`` and the
    goal term ``eta |m' - goal|``; ``tail(g)`` is the least sum over sequences from ``g`` to a gap
    bordering the goal face (0 if ``g`` borders it). One union per cluster (the same as Eq. 7's
    query) and a point location per bridge side. ``extra``: an added
    cost per gap (body pair), e.g. the search's penalty for gaps its pushes failed to widen.
    skeleton: :func:`faces.build_skeleton` of ``g`` to reuse (built when None). goal: (x, y) [m].
    terms: also return each tail's decomposition into Eq. 8-9 terms (``FaceGraph.terms``; the search's
    gap recorder asks for it). The tails are the same either way.
    """
    lt, lp, eta = (float(np.asarray(v)) for v in (params.lambda_t, params.lambda_p, params.eta))
    goal = np.asarray(goal, np.float64)
    # A connectivity query's skeleton already holds the cluster unions.
    sk = skeleton if skeleton is not None else build_skeleton(g)
    locate = _face_locator(g, sk)
    goal_face = int(locate(goal[None])[0])
    faces, narrowest = _gap_faces(g, sk, locate)
    where, parts = {}, ({} if terms else None)
    for pair, (width_p, m) in narrowest.items():
        mass = min(g.body_mass[b] for b in pair if g.body_kind[b] == MOVABLE)
        where[pair] = (m, lp * max(float(g.width) - width_p, 0.0) * mass / params.mass_ref
                       + eta * float(np.linalg.norm(m - goal)) + (extra or {}).get(pair, 0.0))
        if terms:
            parts[pair] = np.array([0.0, max(float(g.width) - width_p, 0.0) * mass / params.mass_ref,
                                    float(np.linalg.norm(m - goal))])
    tail, sums = _tails_to_goal(faces, where, goal_face, lt, parts)
    final = {pair: goal_face in fs for pair, fs in faces.items()}
    return FaceGraph(faces, -1, goal_face, tail, final, sums)


def _face_locator(g: WCCG, sk: Skeleton):
    """A function from points f[P, 2] [m] to their face ids i64[P]: the index of the smallest ring
    containing the point when that ring is a hole, -2 when it is a cluster's exterior (inside an
    obstacle), -1 outside every ring."""
    rings = []
    for c in np.unique(sk.labels):
        rings += cluster_rings(cluster_region(g, sk, int(c)), int(c))
    polys = np.asarray([r.region for r in rings], dtype=object)
    areas = shapely.area(polys)
    hole = np.asarray([r.is_hole for r in rings], bool)
    tree = shapely.STRtree(polys)

    def locate(points):
        points = np.asarray(points, np.float64).reshape(-1, 2)
        pi, ri = tree.query(shapely.points(points), predicate="within")
        face = np.full(len(points), -1, np.int64)
        best = np.full(len(points), np.inf)
        for p, r in zip(pi, ri):
            if areas[r] < best[p]:
                best[p] = areas[r]
                face[p] = r if hole[r] else -2
        return face

    return locate


def _gap_faces(g: WCCG, sk: Skeleton, locate) -> tuple:
    """The crossable gaps (bottleneck bridges between two bodies, one of them movable) and the faces
    each borders, found a hair off each of its bridges on both sides. Returns (gap bodies -> set of
    face ids, gap bodies -> (narrowest bridge width [m], its midpoint f[2]))."""
    w = float(g.width)
    bb = g.bridge_bodies
    kinds = g.body_kind[bb]
    ok = sk.active & (bb[:, 0] != bb[:, 1]) & np.any(kinds == MOVABLE, axis=1)
    edges = np.nonzero(ok)[0]
    pu, pv = g.bridge_pts[edges, 0], g.bridge_pts[edges, 1]
    mid = 0.5 * (pu + pv)
    d = pv - pu
    touch = np.linalg.norm(d, axis=1) < 10 * BRIDGE_EPS * w
    if np.any(touch):   # touching bodies: across the line of their components' centroids
        uv = g.bridge_uv[edges[touch]]
        d[touch] = g.centroids[uv[:, 1]] - g.centroids[uv[:, 0]]
    n = np.stack([-d[:, 1], d[:, 0]], 1) / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    tau = np.where(touch, 0.05 * w, 3.0 * BRIDGE_EPS * w)[:, None]
    side = locate(np.concatenate([mid + tau * n, mid - tau * n])).reshape(2, -1)
    faces, narrowest = {}, {}
    for k, e in enumerate(edges):
        pair = (int(bb[e, 0]), int(bb[e, 1]))
        faces.setdefault(pair, set()).update(int(f) for f in side[:, k] if f >= -1)
        if pair not in narrowest or g.bridge_width[e] < narrowest[pair][0]:
            narrowest[pair] = (float(g.bridge_width[e]), mid[k])
    return faces, narrowest


def _tails_to_goal(faces: dict, where: dict, goal_face: int, lt: float, parts: dict | None = None) -> tuple:
    """Reverse Dijkstra from the gaps bordering the goal face: gap -> least cost of a gap sequence
    after it (``where``: gap -> (midpoint f[2], widening + goal cost); ``lt`` per metre between
    midpoints); inf where none reaches the goal face. ``parts``: gap -> f[3] its own (0, C_p,
    distance to the goal) or None; returns (tails, None or gap -> f[3] the summed terms of each least
    tail, the metres between midpoints in slot 0)."""
    by_face: dict = {}
    for pair, fs in faces.items():
        for f in fs:
            by_face.setdefault(f, []).append(pair)
    tail = {pair: math.inf for pair in faces}
    sums = None if parts is None else {pair: np.zeros(3) for pair in faces}
    heap = []
    for pair in by_face.get(goal_face, []):
        tail[pair] = 0.0
        heap.append((0.0, pair))
    heapq.heapify(heap)
    while heap:
        dist, pair = heapq.heappop(heap)
        if dist > tail[pair]:
            continue
        m, c = where[pair]
        for f in faces[pair]:
            for q in by_face[f]:
                step = float(np.linalg.norm(where[q][0] - m))
                nd = dist + c + lt * step
                if nd < tail[q] - 1e-12:
                    tail[q] = nd
                    if sums is not None:
                        sums[q] = sums[pair] + parts[pair] + np.array([step, 0.0, 0.0])
                    heapq.heappush(heap, (nd, q))
    return tail, sums
