"""The skeleton of a WCCG (Section III-A): clusters of components joined by bottleneck bridges, and
the rings that bound each cluster's region ``K_c`` and the faces it encloses.

Shared by :mod:`jaxplan.pusharound.wccg` (Eq. 7, frontier tracing, paths), the search's face-graph
presearch and the ranking. Definitions: the module docstring of :mod:`jaxplan.pusharound.wccg`.
Lengths in metres unless a constant says "relative to W".
"""
from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import shapely
from shapely.geometry import Polygon

if TYPE_CHECKING:   # wccg imports this module: the type only, for annotations
    from jaxplan.pusharound.wccg import WCCG

__all__ = ["BRIDGE_EPS", "NODING_GRID", "QUAD_SEGS", "FaceRings", "Ring", "Skeleton", "active_bridges",
           "build_skeleton", "cluster_labels", "cluster_region", "cluster_rings", "face_rings"]

# Half-width of a bridge segment where it is made a polygon [m, relative to W]: the skeleton's
# bridges have zero width; thin strips keep a cluster's outline one polygon, and faces shrunk by it keep
# the rings of two faces that share a bridge apart.
BRIDGE_EPS = 1e-7
# Snap-rounding grid of the noding of a cluster's linework [relative to W] (``face_rings``).
NODING_GRID = 1e-9
# Buffer resolution of the inflated clusters used for paths (segments per quarter circle).
QUAD_SEGS = 32



def active_bridges(g: WCCG, removed) -> np.ndarray:
    """bool[E]: bottleneck bridges not removed. removed: iterable of (body_a, body_b) pairs."""
    act = g.bottleneck.copy()
    if removed:
        bb = g.bridge_bodies
        for a, b in removed:
            lo_, hi_ = min(a, b), max(a, b)
            act &= ~((bb[:, 0] == lo_) & (bb[:, 1] == hi_))
    return act


def cluster_labels(n: int, uv: np.ndarray) -> np.ndarray:
    """Connected-component labels i32[n] of the graph with edges ``uv`` (union-find)."""
    parent = np.arange(n)

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for u, v in uv:
        ru, rv = find(u), find(v)
        if ru != rv:
            parent[max(ru, rv)] = min(ru, rv)
    return np.array([find(i) for i in range(n)], np.int32)


class Ring(NamedTuple):
    """One ring of a cluster's region K_c. cluster: the cluster's label; ring: the LinearRing [m];
    region: the ring's interior with holes ignored, so that containment means "enclosed by the
    ring"; is_hole: the ring bounds a face K_c encloses (else K_c's exterior or an island); islands:
    a hole's islands (``FaceRings``), LinearRings of the obstacle inside its face."""

    cluster: int
    ring: shapely.LinearRing
    region: Polygon
    is_hole: bool
    islands: tuple = ()


class Skeleton(NamedTuple):
    """The skeleton of a WCCG with N components and E bridges. labels: i32[N] the cluster of each
    component; active: bool[E] the bottleneck bridges not removed; regions: a cache, (cluster,
    inflate, quad_segs) -> what :func:`cluster_region` returns, filled on first use (queries that
    share a skeleton share its unions)."""

    labels: np.ndarray
    active: np.ndarray
    regions: dict


def build_skeleton(g: WCCG, removed=()) -> Skeleton:
    """The clusters of ``g`` over its bottleneck bridges, less those between the body pairs
    ``removed`` (iterable of (body_a, body_b))."""
    act = active_bridges(g, removed)
    return Skeleton(cluster_labels(len(g.pieces), g.bridge_uv[act]), act, {})


class FaceRings(NamedTuple):
    """K_c of a cluster as rings, read off the arrangement of its linework (``face_rings``).

    exterior: LinearRing, the cluster's outer boundary; interiors: LinearRings of the faces it
    encloses (K_c's holes); islands: LinearRings around obstacle material that lies inside one of
    those faces, joined to the face's boundary by bridges that close no loop (a hole ring of the
    strip union would detour around it; here it is a ring of its own, which encloses obstacle, not
    a face); island_face: i64[len(islands)], the index in ``interiors`` of the face each lies in.
    """

    exterior: shapely.LinearRing
    interiors: list
    islands: list
    island_face: np.ndarray


def cluster_region(g: WCCG, sk: Skeleton, c: int, inflate: float = 0.0, quad_segs: int = QUAD_SEGS):
    """Cluster ``c``'s region K_c: its rings (inflate = 0, a ``FaceRings``) or K_c inflated by
    ``inflate`` [m] (a Polygon of ``quad_segs`` segments per quarter circle; the bridges are inside it
    then). Cached in ``sk.regions``."""
    key = (c, inflate, quad_segs)
    if key not in sk.regions:
        comps = np.nonzero(sk.labels == c)[0]
        if inflate > 0:
            region = shapely.union_all([shapely.buffer(g.pieces[i], inflate, quad_segs=quad_segs) for i in comps])
            if not isinstance(region, Polygon):  # numerically split: keep the largest part
                region = max(getattr(region, "geoms", [region]), key=lambda p: p.area)
        else:
            bridges = np.nonzero(sk.active & np.isin(g.bridge_uv[:, 0], comps))[0]
            region = face_rings(g, comps, bridges)
        sk.regions[key] = region
    return sk.regions[key]


def face_rings(g: WCCG, comps: np.ndarray, bridges: np.ndarray) -> FaceRings:
    """The rings of the skeleton of components ``comps`` i64[K] and bridges ``bridges`` i64[E']
    (indices into ``g``'s components and bridges).

    The faces K_c encloses are the bounded faces of the planar arrangement of the pieces' boundaries
    and the bridge segments that lie outside every piece: the linework is noded once (a union of
    lines) and polygonized. That is the zero-width skeleton itself. Unioning the pieces with a thin
    polygon per bridge instead gives the same faces up to the strips' width (1e-7 W), but crossing
    strips make it several times slower where bridges cross by the hundred (dense clutter). The
    exterior is the outline of all
    faces together with the strips of the bridges that are not inside them (bridges that close no
    loop on the outside, and touching pieces).
    """
    pieces = np.asarray([g.pieces[i] for i in comps], dtype=object)
    has_length = g.bridge_width[bridges] > 0
    segments = shapely.linestrings(g.bridge_pts[bridges[has_length]]) if np.any(has_length) else []
    # snap-rounded: a bridge end computed a rounding error off its piece's edge still meets the edge
    linework = shapely.union_all(np.concatenate([shapely.get_exterior_ring(pieces), segments]),
                                 grid_size=NODING_GRID * g.width)
    faces = shapely.get_parts(shapely.polygonize([linework]))   # one multi-line input: no per-line objects
    inside = np.zeros(len(faces), bool)
    pi, _ = shapely.STRtree(pieces).query(shapely.point_on_surface(faces), predicate="within")
    inside[pi] = True
    free = faces[~inside]
    filled = shapely.coverage_union_all(faces)
    eps = BRIDGE_EPS * g.width
    skeleton = np.empty(len(bridges), dtype=object)
    skeleton[has_length] = segments
    skeleton[~has_length] = shapely.points(g.bridge_pts[bridges[~has_length], 0])
    outside = ~shapely.contains(filled, skeleton) if len(bridges) else np.zeros(0, bool)
    strips = shapely.buffer(skeleton[outside], eps, quad_segs=1)
    outline = shapely.union_all(np.concatenate([[filled], strips])) if len(strips) else filled
    if not isinstance(outline, Polygon):  # numerically split: keep the largest part
        outline = max(getattr(outline, "geoms", [outline]), key=lambda p: p.area)
    # Adjacent faces share their bridges: shrunk by the strip half-width, their rings stay apart as
    # the strip union's do, so a walk meets the ring it leaves before the one it enters.
    holes = shapely.get_parts(shapely.buffer(free, -eps, quad_segs=1, join_style="mitre"))
    holes = holes[~shapely.is_empty(holes)]
    n_islands = shapely.get_num_interior_rings(holes)
    with_k = [np.nonzero(n_islands > k)[0] for k in range(int(n_islands.max(initial=0)))]
    islands = [ring for k, faces_k in enumerate(with_k) for ring in shapely.get_interior_ring(holes[faces_k], k)]
    island_face = np.concatenate([np.zeros(0, np.int64), *with_k])
    return FaceRings(outline.exterior, list(shapely.get_exterior_ring(holes)), islands, island_face)


def cluster_rings(region, c: int) -> list:
    """The ``Ring``s of cluster ``c``'s region (a ``FaceRings``, or a Polygon: its exterior and
    holes): the exterior first, then the holes, then the islands."""
    holes = list(region.interiors)
    islands = list(getattr(region, "islands", []))
    in_face = [[] for _ in holes]
    for ring, face in zip(islands, getattr(region, "island_face", [])):
        in_face[face].append(ring)
    rings = [region.exterior] + holes + islands
    # One vectorised call builds every ring's interior (a cluster may have hundreds of sliver holes).
    polys = shapely.polygons(np.asarray(rings, dtype=object))
    return [Ring(c, r, p, 0 < k <= len(holes), tuple(in_face[k - 1]) if 0 < k <= len(holes) else ())
            for k, (r, p) in enumerate(zip(rings, polys))]
