"""The W-Clearance Connectivity Graph (Section III-A): construction, Eq. 7, frontier tracing, paths.

Definitions (exact forms in ``docs/pusharound.md``):

- **Components**: the convex pieces of every movable and fixed obstacle, plus four wall boxes just
  outside the workspace (the RA-L version of the paper includes the workspace boundary; without it a
  gap between an obstacle and a wall would never count). Each has a centroid node.
- **Bridges**: for every pair of components at distance ``w < W`` (or ``< bridge_range * W``, to
  draw near-misses too), bridge nodes at the closest points ``p_u, p_v`` and a bridge-bridge edge of
  width ``w = |p_u - p_v|``; ``bottleneck = w < W``. Pieces of one body touch, so they are always
  bridged (``internal``).
- **Skeleton**: the union of the components and the bottleneck bridge segments. Every bridge segment
  lies in the union of the two inflated components (each of its points is within ``w/2 < W/2`` of an
  end), so no W-clear path crosses the skeleton.
- **Clusters**: connected components of the skeleton (union-find over bottleneck bridges). A
  cluster's region ``K_c`` has rings: one exterior and its holes (the bounded faces of the planar
  arrangement of its pieces' boundaries and bridge segments, :func:`faces.face_rings`); **faces** are the
  components of the plane minus all clusters. Two points lie in the same face iff no ring encloses
  exactly one of them (Janiszewski's theorem: disjoint clusters separate independently).
- **Eq. 7**: connected iff start and goal are in the same face and both disks ``B(s, W/2)`` are
  free (clearance >= W/2 from every component, walls included).
- **Frontier tracing** (BugPlanner): walk the segment start -> goal; at the first ring hit, either
  that ring separates (return it: the frontier loop) or go around it along the ring to the last
  crossing and continue. The walk stays on the start's face, so the first separating ring it meets
  bounds that face.
- **Skeleton to path**: the same walk over the clusters inflated by ``W/2 + delta`` gives an explicit
  polyline whose ``W/2``-disk sweep stays free.

Bridges can be removed (``removed``: a set of body pairs) to ask "what if this gap were widened":
the ranking's presearch does that.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import jax
import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry import box as _box

from jaxplan.pusharound.budget import MemoryEstimate, check_pieces_memory, estimate_pieces_bytes, pair_bucket
from jaxplan.pusharound.faces import (
    BRIDGE_EPS,
    QUAD_SEGS,
    Skeleton,
    active_bridges,
    build_skeleton,
    cluster_region,
    cluster_rings,
)
from jaxplan.pusharound.kernels import aabb_gaps, pack_polygons, pair_distances, point_distances
from jaxplan.pusharound.scene import PushScene

__all__ = ["MOVABLE", "FIXED", "WALL", "WCCG", "Connectivity", "Frontier", "build_wccg", "check_feasible",
           "check_memory", "clearance", "connectivity", "estimate_memory_bytes", "frontier_bridges", "w_clear_path"]

MOVABLE, FIXED, WALL = 0, 1, 2

# Buffer resolution of the inflated clusters used for paths when the default (``faces.QUAD_SEGS``)
# closes a passage within ~3e-4 W of W [segments per quarter circle].
_FINE_QUAD_SEGS = 512


class WCCG(NamedTuple):
    """The graph of Eq. 6 plus what queries need. N components, E bridges, B bodies.

    width: W [m]. workspace: (x0, y0, x1, y1).
    pieces: tuple of N convex Polygons (world); verts f64[N, V, 2] / nverts i32[N]: packed pieces.
    comp_body: i32[N] body of each component; centroids: f64[N, 2] (centroid nodes).
    body_kind: i32[B] MOVABLE / FIXED / WALL; body_index: i32[B] index in scene.movables / .fixed
      (-1 for the wall body); body_mass: f64[B] (0 for fixed bodies and walls).
    bridge_uv: i32[E, 2] components; bridge_pts: f64[E, 2, 2] bridge nodes p_u, p_v;
      bridge_width: f64[E] w_uv; bottleneck: bool[E] w < W; internal: bool[E] same body.
    Bodies: movables 0..M-1, then fixed M..M+F-1, then the wall body M+F.
    """

    width: float
    workspace: tuple
    pieces: tuple
    verts: np.ndarray
    nverts: np.ndarray
    comp_body: np.ndarray
    centroids: np.ndarray
    body_kind: np.ndarray
    body_index: np.ndarray
    body_mass: np.ndarray
    bridge_uv: np.ndarray
    bridge_pts: np.ndarray
    bridge_width: np.ndarray
    bottleneck: np.ndarray
    internal: np.ndarray

    @property
    def bridge_bodies(self) -> np.ndarray:
        """i32[E, 2] the bodies of each bridge's two components, sorted (a <= b)."""
        return np.sort(self.comp_body[self.bridge_uv], axis=1)


def _wall_pieces(workspace, thickness: float) -> list:
    x0, y0, x1, y1 = workspace
    t = thickness
    return [_box(x0 - t, y0 - t, x0, y1 + t), _box(x1, y0 - t, x1 + t, y1 + t),
            _box(x0, y0 - t, x1, y0), _box(x0, y1, x1, y1 + t)]


def _components(scene: PushScene) -> tuple:
    """The WCCG's components: (pieces: list of N world Polygons, comp_body i32[N], body kinds, body
    indices, body masses [kg]); movables first, then fixed obstacles, then the four wall boxes."""
    pieces, comp_body, kinds, index, mass = [], [], [], [], []
    for i, m in enumerate(scene.movables):
        pieces += m.world_pieces()
        comp_body += [len(kinds)] * len(m.pieces)
        kinds.append(MOVABLE), index.append(i), mass.append(m.mass)
    for i, f in enumerate(scene.fixed):
        pieces += f.pieces
        comp_body += [len(kinds)] * len(f.pieces)
        kinds.append(FIXED), index.append(i), mass.append(0.0)
    walls = _wall_pieces(scene.workspace, max(float(scene.width), 1.0))
    pieces += walls
    comp_body += [len(kinds)] * len(walls)
    kinds.append(WALL), index.append(-1), mass.append(0.0)
    return pieces, np.asarray(comp_body, np.int32), kinds, index, mass


def estimate_memory_bytes(scene: PushScene, search: bool = False, bridge_range: float = 1.0) -> MemoryEstimate:
    """Estimated peak memory of the pairwise geometry kernels on ``scene`` (``jaxplan.pusharound.budget``):
    of :func:`build_wccg` at ``bridge_range``, or with ``search`` of :func:`plan_pushes` (its contact test
    against fixed obstacles too). Returns a ``MemoryEstimate`` (``.bytes``, ``.total_vertices``, ...)."""
    pieces = _components(scene)[0]
    return estimate_pieces_bytes(pieces, bridge_range * float(scene.width), touch=_touches(scene, search))


def _touches(scene: PushScene, search: bool) -> bool:
    """Whether the search runs the fixed-obstacle contact test: pushes (movables, robots) and fixed obstacles."""
    return search and bool(scene.fixed) and bool(scene.movables) and np.asarray(scene.robots).size > 0


def check_memory(scene: PushScene, search: bool = False, available: int | None = None) -> MemoryEstimate:
    """Raise ``ValueError`` before any work when :func:`estimate_memory_bytes` exceeds the memory
    available (``jaxplan.core.available_memory_bytes``, or ``available`` bytes), naming the total vertex
    count, the bytes needed, the memory available and the largest vertex count per piece that fits.
    ``check_feasible`` (so ``plan_pushes`` and the CLI) and ``build_wccg`` call it."""
    what = "planning pushes (plan_pushes)" if search else "building the W-clearance graph"
    return check_pieces_memory(_components(scene)[0], float(scene.width), touch=_touches(scene, search),
                               what=what, available=available)


def _bridges(verts: np.ndarray, reach: float) -> tuple:
    """Every component pair closer than ``reach`` [m]: (iu i[P], iv i[P], d f64[P], pa f64[P, 2], pb f64[P, 2])."""
    lo, hi = verts.min(axis=1), verts.max(axis=1)
    with jax.enable_x64(True):
        gaps = np.asarray(aabb_gaps(lo, hi))
        iu, iv = np.nonzero(np.triu(gaps < reach, k=1))
        n_pairs = len(iu)
        pad = pair_bucket(n_pairs) - n_pairs
        a = np.concatenate([verts[iu], np.repeat(verts[:1], pad, 0)])
        b = np.concatenate([verts[iv], np.repeat(verts[:1], pad, 0)])
        d, pa, pb = (np.asarray(x)[:n_pairs] for x in pair_distances(a, b))
    return iu, iv, d, pa, pb


def build_wccg(scene: PushScene, poses=None, bridge_range: float = 1.0) -> WCCG:
    """Build the WCCG of ``scene`` (with movable ``poses: f[M, 3]`` if given).

    bridge_range: bridges are kept for pairs closer than ``bridge_range * W`` (>= 1; 1 = the paper's
    graph, where every bridge is a bottleneck).
    Cost: one quick pass (bounding boxes) over all pairs, then one batched exact distance call over
    the surviving pairs, both in float64. Memory: refused with a ``ValueError`` before any work when the
    pairwise kernels would not fit (:func:`check_memory`; ``jaxplan.pusharound.budget``).
    """
    if poses is not None:
        scene = scene.with_poses(poses)
    w = float(scene.width)
    if not bridge_range >= 1.0:
        raise ValueError(f"bridge_range: must be >= 1 (a multiple of W); got {bridge_range!r}.")
    pieces, comp_body, kinds, index, mass = _components(scene)
    reach = bridge_range * w
    check_pieces_memory(pieces, reach)
    verts, nverts = pack_polygons(pieces)
    iu, iv, d, pa, pb = _bridges(verts, reach)
    keep = d < reach
    uv = np.stack([iu[keep], iv[keep]], axis=1).astype(np.int32).reshape(-1, 2)
    pts = np.stack([pa[keep], pb[keep]], axis=1).reshape(-1, 2, 2)
    width = d[keep]
    return WCCG(width=w, workspace=tuple(scene.workspace), pieces=tuple(pieces), verts=verts,
                nverts=nverts, comp_body=comp_body,
                centroids=np.array([[p.centroid.x, p.centroid.y] for p in pieces]).reshape(-1, 2),
                body_kind=np.asarray(kinds, np.int32), body_index=np.asarray(index, np.int32),
                body_mass=np.asarray(mass, np.float64), bridge_uv=uv, bridge_pts=pts,
                bridge_width=width, bottleneck=width < w,
                internal=comp_body[uv[:, 0]] == comp_body[uv[:, 1]])


def clearance(g: WCCG, points) -> np.ndarray:
    """Distance ``f64[P]`` from ``points: f[P, 2]`` to the nearest component (walls included)."""
    pts = np.asarray(points, np.float64).reshape(-1, 2)
    with jax.enable_x64(True):
        return np.asarray(point_distances(pts, g.verts)).min(axis=1)


def _segment_hits(seg: LineString, rings: list, s: np.ndarray, d: np.ndarray) -> list:
    """For each ring, the sorted crossing parameters ``t in [0, 1]`` along ``s + t d``."""
    dd = float(d @ d)
    if not rings:
        return []
    # One vectorised intersection over all rings (bounding boxes first: most rings miss the segment).
    arr = np.asarray([r.ring for r in rings], dtype=object)
    hit = np.nonzero(shapely.intersects(arr, seg))[0]
    out = [np.zeros(0)] * len(rings)
    if len(hit):
        xy, idx = shapely.get_coordinates(shapely.intersection(arr[hit], seg), return_index=True)
        t = (xy - s) @ d / dd
        for j, k in enumerate(hit):
            out[k] = np.sort(t[idx == j])
    return out


# ---------------------------------------------------------------------------------------------------
# Connectivity (Eq. 7) by frontier tracing
# ---------------------------------------------------------------------------------------------------

class Frontier(NamedTuple):
    """The blocking loop L: ``ring`` f64[K, 2] (closed, counter-clockwise), the ``cluster`` it bounds,
    and ``encloses_start`` (True: the start is trapped inside L; False: L encloses the goal).
    islands: tuple of f64[K_i, 2] rings of the obstacle lying inside L's face, hanging off L by bridges
    that close no loop; they and those bridges count as part of L (the loop walks around them)."""

    ring: np.ndarray
    cluster: int
    encloses_start: bool
    islands: tuple = ()

    def region(self) -> Polygon:
        """L's face: the polygon inside the ring, less its islands."""
        return Polygon(self.ring, list(self.islands))


class Connectivity(NamedTuple):
    """Result of :func:`connectivity`.

    connected: Eq. 7 holds. same_face: start and goal in one face. start_clear / goal_clear: the
    endpoint disks ``B(., W/2)`` are free. frontier: the blocking loop when not ``same_face``, else None.
    skeleton: when ``same_face``, the ordered pieces of the traced route: ``("line", p, q)`` and
    ``("arc", ring f64[K, 2], p, q)`` (along a cluster ring from p to q).
    """

    connected: bool
    same_face: bool
    start_clear: bool
    goal_clear: bool
    frontier: Frontier | None
    skeleton: tuple


def _trace(seg_start, seg_goal, rings, separates):
    """The BugPlanner walk along the segment. Returns (skeleton pieces, blocking ring index or None)."""
    s, gl = np.asarray(seg_start, np.float64), np.asarray(seg_goal, np.float64)
    d = gl - s
    hits = _segment_hits(LineString([s, gl]), rings, s, d)
    pieces, t, pos = [], 0.0, s
    while True:
        # The next ring the walk meets: the smallest crossing beyond the current position.
        nxt = [(h[h > t + 1e-12][0], k) for k, h in enumerate(hits) if np.any(h > t + 1e-12)]
        if not nxt:
            pieces.append(("line", pos, gl))
            return pieces, None
        t_hit, k = min(nxt)
        if separates[k]:
            return pieces, k
        t_leave = float(hits[k][-1])
        p_hit, p_leave = s + t_hit * d, s + t_leave * d
        pieces.append(("line", pos, p_hit))
        pieces.append(("arc", np.asarray(rings[k].ring.coords), p_hit, p_leave))
        t, pos = t_leave, p_leave


def _relevant_clusters(g: WCCG, sk: Skeleton, seg: LineString) -> np.ndarray:
    """Clusters whose skeleton touches the segment (the others cannot be crossed by the walk)."""
    hit_comp = np.nonzero(shapely.intersects(np.asarray(g.pieces, dtype=object), seg))[0]
    act = np.nonzero(sk.active)[0]
    if len(act):
        # Vectorised: segments for the bridges of positive width, points for touching pairs.
        pts = g.bridge_pts[act]
        pos = g.bridge_width[act] > 0
        lines = np.empty(len(act), dtype=object)
        if np.any(pos):
            lines[pos] = shapely.linestrings(pts[pos])
        if np.any(~pos):
            lines[~pos] = shapely.points(pts[~pos, 0])
        hit_br = act[shapely.intersects(lines, seg)]
    else:
        hit_br = act
    return np.unique(np.concatenate([sk.labels[hit_comp], sk.labels[g.bridge_uv[hit_br, 0]]]))


def connectivity(g: WCCG, start, goal, removed=(), *, skeleton: Skeleton | None = None) -> Connectivity:
    """Eq. 7 for the vehicle from ``start`` to ``goal`` (both (x, y) in the workspace [m]).

    removed: body pairs ``(a, b)`` whose bridges are ignored (a virtually widened gap). skeleton:
    :func:`faces.build_skeleton` of ``g`` and ``removed`` to reuse (its cached cluster regions then
    serve later queries on the same graph, e.g. the search's face graph); built here when None.
    """
    sk = skeleton if skeleton is not None else build_skeleton(g, removed)
    s, gl = np.asarray(start, np.float64), np.asarray(goal, np.float64)
    clr = clearance(g, np.stack([s, gl]))
    r = 0.5 * g.width
    seg = LineString([s, gl])
    rings = []
    for c in _relevant_clusters(g, sk, seg):
        rings += cluster_rings(cluster_region(g, sk, int(c)), int(c))
    regions = np.asarray([rg.region for rg in rings], dtype=object)
    enc_s = [bool(v) for v in shapely.contains_xy(regions, *s)] if rings else []
    enc_g = [bool(v) for v in shapely.contains_xy(regions, *gl)] if rings else []
    separates = [a != b for a, b in zip(enc_s, enc_g)]
    pieces, blocking = _trace(s, gl, rings, separates)
    start_clear, goal_clear = bool(clr[0] >= r), bool(clr[1] >= r)
    if blocking is None:
        return Connectivity(start_clear and goal_clear, True, start_clear, goal_clear, None, tuple(pieces))
    rg = rings[blocking]
    ring = np.asarray(shapely.orient_polygons(rg.region, exterior_cw=False).exterior.coords)
    islands = tuple(np.asarray(island.coords) for island in rg.islands)
    return Connectivity(False, False, start_clear, goal_clear,
                        Frontier(ring, rg.cluster, enc_s[blocking], islands), ())


def frontier_bridges(g: WCCG, frontier: Frontier, removed=()) -> np.ndarray:
    """Indices of the active bottleneck bridges that lie on the frontier loop (i32[K]).

    A bridge lies on L when L or one of its islands passes within 3 strip half-widths of its
    midpoint (a face's ring runs 1e-7 W inside its bridges), or when its midpoint lies inside L's face:
    a bridge that hangs an island off L, or a spur into the face (a walk around L goes along both).
    """
    act = np.nonzero(active_bridges(g, removed))[0]
    if not len(act):
        return act
    mid = shapely.points(g.bridge_pts[act].mean(axis=1))
    tol = 3.0 * BRIDGE_EPS * g.width
    near = shapely.distance(shapely.LinearRing(frontier.ring), mid) <= tol
    for island in frontier.islands:
        near |= shapely.distance(shapely.LinearRing(island), mid) <= tol
    if frontier.islands:
        near |= shapely.contains(frontier.region(), mid)
    return act[near]


# ---------------------------------------------------------------------------------------------------
# Skeleton to path
# ---------------------------------------------------------------------------------------------------

def _ring_arc(coords: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The shorter of the two arcs of the closed ring ``coords: f[K+1, 2]`` from p to q (both on it)."""
    ring = LineString(coords)
    length = ring.length
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(coords, axis=0), axis=1))])[:-1]
    verts = coords[:-1]
    # Vertex positions over two laps, so that an arc that wraps past the seam is one window.
    pos2, verts2 = np.concatenate([cum, cum + length]), np.concatenate([verts, verts])

    def forward(a, b):
        if b < a:
            b += length
        inner = verts2[(pos2 > a) & (pos2 < b)]
        return np.vstack([np.asarray(ring.interpolate(a % length).coords), inner,
                          np.asarray(ring.interpolate(b % length).coords)])

    dp, dq = ring.project(Point(p)), ring.project(Point(q))
    fwd, bwd = forward(dp, dq), forward(dq, dp)[::-1]
    arc_len = lambda xy: float(np.sum(np.linalg.norm(np.diff(xy, axis=0), axis=1)))  # noqa: E731
    return fwd if arc_len(fwd) <= arc_len(bwd) else bwd


def w_clear_path(g: WCCG, start, goal, delta: float | None = None, shorten: bool = True) -> np.ndarray | None:
    """An explicit W-clear path (Section III-A.3): ``f64[P, 2]`` from start to goal, or None.

    The frontier walk of :func:`connectivity`, run over the clusters inflated by
    ``rho = (W/2 + delta) / cos(pi / (4 * quad_segs))`` (the division makes the polygonal buffer, whose
    vertices lie on the circle, contain the true disk): straight pieces where the segment is free,
    arcs along an inflated cluster's ring around each cluster it meets. Every point is then at least
    ``W/2 + delta`` from its own cluster and at least ``gap - rho >= W/2`` from the others when the
    non-bottleneck gaps exceed ``W + (rho - W/2)`` (~1e-4 W): the exactness limit of this construction.
    ``delta`` defaults to ``1e-4 W`` (shrunk so that the endpoint disks stay outside the inflation),
    then ``1e-2 W/2`` if the first path fails the exact clearance check (GEOS may simplify a buffer),
    then ``1e-6 W`` over buffers of 512 segments per quarter circle (a passage within ~3e-4 W of W,
    which the 32-segment polygons close; slower, so only when the others fail). The returned path
    always passes that check (shapely distance >= W/2 to every component, walls
    included). None when Eq. 7 fails or no margin gives a clear path (near-ties only).
    ``shorten``: then cut the walk's detours by line of sight (:func:`_shorten`; same exact check).
    """
    conn = connectivity(g, start, goal)
    if not conn.connected:
        return None
    r = 0.5 * g.width
    s, gl = np.asarray(start, np.float64), np.asarray(goal, np.float64)
    clr = float(clearance(g, np.stack([s, gl])).min())
    pieces = np.asarray(g.pieces, dtype=object)
    for quad_segs, margins in ((QUAD_SEGS, (1e-4 * g.width, 1e-2 * r)), (_FINE_QUAD_SEGS, (1e-6 * g.width,))):
        cos = math.cos(math.pi / (4 * quad_segs))
        # GEOS may simplify a buffer's input by ~1% of the distance, so a path along it can dip a
        # little: every candidate is checked exactly and the next, wider margin is tried when it dips.
        # Every margin stays below half the endpoints' spare clearance, so start and goal stay
        # outside the inflated obstacles whatever the margin.
        room = 0.5 * (clr * cos - r)
        for d in [delta] if delta is not None else [min(m, room) for m in margins]:
            path = _inflated_walk(g, s, gl, (r + max(d, 0.0)) / cos, quad_segs)
            if path is not None and float(shapely.distance(pieces, LineString(path)).min()) >= r:
                return _shorten(path, shapely.union_all(pieces), r) if shorten else path
        if delta is not None:
            break
    return None


def _shorten(path: np.ndarray, obstacles, r: float, max_tries: int = 128) -> np.ndarray:
    """Greedy line-of-sight shortening of a W-clear polyline ``f64[P, 2]``: from each kept point jump
    to the farthest later point whose straight segment stays at least ``r`` from ``obstacles`` (the
    exact check of :func:`w_clear_path`). The frontier walk follows cluster rings, so it loops around
    a cluster where a straight run would do; every accepted segment is itself W-clear. At most
    ``max_tries`` later points are tried per jump (evenly spaced, the next one always among them), so
    that a walk along finely resolved arcs (thousands of points) stays cheap."""
    out, i, n = [path[0]], 0, len(path)
    while i < n - 1:
        later = np.arange(i + 1, n)
        if len(later) > max_tries:
            later = np.unique(np.r_[i + 1, later[np.linspace(0, len(later) - 1, max_tries - 1).astype(int)]])
        segs = shapely.linestrings(np.stack([np.broadcast_to(path[i], (len(later), 2)), path[later]], 1))
        clear = np.nonzero(shapely.distance(obstacles, segs) >= r)[0]
        i = int(later[clear[-1]]) if len(clear) else i + 1
        out.append(path[i])
    return np.asarray(out)


def _inflated_walk(g: WCCG, s: np.ndarray, gl: np.ndarray, rho: float,
                   quad_segs: int = QUAD_SEGS) -> np.ndarray | None:
    """The frontier walk over the clusters inflated by ``rho`` (buffers of ``quad_segs`` segments per
    quarter circle): the polyline f64[P, 2] or None."""
    sk = build_skeleton(g)
    seg = LineString([s, gl])
    # The inflated clusters the segment meets: those with a component within rho of it.
    near = np.nonzero(shapely.distance(np.asarray(g.pieces, dtype=object), seg) < rho)[0]
    rings = []
    for c in np.unique(sk.labels[near]):
        rings += cluster_rings(cluster_region(g, sk, int(c), inflate=rho, quad_segs=quad_segs), int(c))
    separates = [bool(shapely.contains_xy(rg.region, *s)) != bool(shapely.contains_xy(rg.region, *gl))
                 for rg in rings]
    pieces, blocking = _trace(s, gl, rings, separates)
    if blocking is not None:  # only within the tolerance above (a gap within ~1e-4 W of W)
        return None
    pts = [s]
    for piece in pieces:
        if piece[0] == "line":
            pts.append(piece[2])
        else:
            pts.extend(_ring_arc(piece[1], piece[2], piece[3])[1:])
    path = np.asarray(pts)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(path, axis=0), axis=1) > 1e-12])
    return path[keep]


# ---------------------------------------------------------------------------------------------------
# Feasibility: what no pushing can change
# ---------------------------------------------------------------------------------------------------

def check_feasible(scene: PushScene) -> None:
    """Raise ``ValueError`` naming the scene field and the fix when no pushing schedule can open a
    W-clear corridor (Eq. 7) from ``start`` to ``goal``; ``plan_pushes`` and the CLI call it before
    any search. Only what pushing cannot change is checked (workspace walls and fixed obstacles never
    move), in this order:

    - ``vehicle_width``: W below the workspace's narrow side;
    - ``robots.radius``: a robot disk fits across the workspace;
    - ``start`` / ``goal``: at least W/2 from every workspace wall and from every fixed obstacle (Eq. 7
      needs the disk ``B(s, W/2)`` free);
    - ``fixed``: start and goal connected for the vehicle with every movable removed (the WCCG of the
      fixed obstacles and walls alone; ``connectivity``);
    - ``robots``: a scene without robots must already hold a W-clear corridor (nothing can push).

    Before all of these, ``check_memory(scene, search=True)``: the pairwise kernels of the graph and of the
    search's contact test must fit in memory.
    Milliseconds on scenes of a few fixed obstacles (one WCCG of the fixed pieces and the walls).
    """
    check_memory(scene, search=True)
    x0, y0, x1, y1 = (float(v) for v in scene.workspace)
    w, r = float(scene.width), 0.5 * float(scene.width)
    narrow = min(x1 - x0, y1 - y0)
    if not w < narrow:
        raise ValueError(f"vehicle_width: {w:g} m is not narrower than the workspace's narrow side ({narrow:g} m "
                         f"of {scene.workspace}), so no W-clear path fits; use a width below {narrow:g} m or "
                         "enlarge the workspace.")
    if not 2.0 * float(scene.robot_radius) < narrow:
        raise ValueError(f"robots.radius: a robot of radius {float(scene.robot_radius):g} m does not fit across "
                         f"the workspace's narrow side ({narrow:g} m); use a radius below {narrow / 2:g} m.")
    for name, pt in (("start", scene.start), ("goal", scene.goal)):
        _check_endpoint(scene, name, (float(pt[0]), float(pt[1])), r, (x0, y0, x1, y1))
    fixed_only = scene.replace(movables=())
    if not connectivity(build_wccg(fixed_only), scene.start, scene.goal).connected:
        raise ValueError(f"fixed: the fixed obstacles and walls alone leave no W-clear corridor from start to goal "
                         f"for W = {w:g} m (even with every movable pushed away); widen the openings between "
                         "fixed obstacles, move the start or goal, or use a smaller vehicle_width.")
    no_robots = np.asarray(scene.robots).reshape(-1, 2).shape[0] == 0
    if no_robots and scene.movables and not connectivity(build_wccg(scene), scene.start, scene.goal).connected:
        raise ValueError("robots: the scene has no robot, and its movables block every W-clear corridor from "
                         "start to goal; add robots (robots.positions) to push them.")


def _check_endpoint(scene: PushScene, name: str, pt: tuple, r: float, ws: tuple) -> None:
    """``start`` / ``goal`` at ``pt``: inside the workspace, its W/2 disk clear of the walls and fixed obstacles."""
    x0, y0, x1, y1 = ws
    x, y = pt
    to_wall = min(x - x0, x1 - x, y - y0, y1 - y)
    if to_wall < 0:
        raise ValueError(f"{name}: {pt} is outside the workspace {scene.workspace}; give a point at least "
                         f"W/2 = {r:g} m inside it.")
    if to_wall < r:
        raise ValueError(f"{name}: {pt} is {to_wall:g} m from a workspace wall, closer than W/2 = {r:g} m, so the "
                         f"vehicle does not fit there; move the {name} at least {r:g} m inside the workspace or "
                         "use a smaller vehicle_width.")
    p = Point(pt)
    for i, f in enumerate(scene.fixed):
        d = float(f.polygon.distance(p))
        if d < r:
            raise ValueError(f"{name}: {pt} is {d:g} m from fixed[{i}] ({f.name}), closer than W/2 = {r:g} m, and "
                             f"fixed obstacles are never pushed; move the {name} or use a smaller vehicle_width.")
