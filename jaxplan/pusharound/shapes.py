"""Obstacle shapes as convex pieces, plus the rigid-body properties the physics will need.

Every constructor returns a :class:`Shape`: the outline (a shapely ``Polygon``, possibly with holes)
and its convex pieces, both in the **body frame** with the area centroid at the origin. The pieces
cover the outline exactly (their union is the outline; they share edges but do not overlap), and every
piece is a convex polygon with counter-clockwise vertices: what a physics engine collides (boxes,
convex meshes). Units: metres.

The menu is the paper's nominal one (Section IV-A): rings, ellipses, X/T/L/diamond, arrows, rectangles
and cylinders. Curved shapes are regular polygons (``n`` vertices on the curve).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import Polygon
from shapely.geometry import box as _box

__all__ = ["Shape", "arrow", "convex_decomposition", "cylinder", "diamond", "ellipse", "is_convex",
           "l_shape", "polygon_inertia", "rectangle", "ring", "shape_from_pieces", "t_shape",
           "x_shape", "SHAPE_KINDS"]

# Relative tolerance of the convexity test (hull area vs area).
_CONVEX_RTOL = 1e-9


class Shape(NamedTuple):
    """outline: Polygon (body frame, centroid at the origin); pieces: tuple of convex Polygons that
    tile it; kind / params: how it was made (``{"kind": "ring", "r_out": ...}``), for the physics
    builder, which may prefer a native primitive (a cylinder) to the polygon."""

    outline: Polygon
    pieces: tuple
    kind: str
    params: dict


def is_convex(poly: Polygon) -> bool:
    """True for a valid hole-free polygon equal (within 1e-9 relative area) to its convex hull."""
    if poly.is_empty or not poly.is_valid or len(poly.interiors) > 0 or poly.area <= 0:
        return False
    return poly.convex_hull.area - poly.area <= _CONVEX_RTOL * poly.area


def _ccw(poly: Polygon) -> Polygon:
    return shapely.orient_polygons(poly, exterior_cw=False)


def shape_from_pieces(pieces, kind: str = "polygon", params: dict | None = None) -> Shape:
    """A :class:`Shape` from convex pieces given in any frame: recentred on the area centroid.

    pieces: iterable of Polygons or ``[[x, y], ...]`` vertex lists. Raises ``ValueError`` when a piece
    is not convex or the pieces do not form one connected polygon.
    """
    polys = [p if isinstance(p, Polygon) else Polygon(p) for p in pieces]
    for i, p in enumerate(polys):
        if not is_convex(p):
            raise ValueError(f"pieces[{i}]: not a convex polygon; split it into convex pieces "
                             "(see jaxplan.pusharound.shapes.convex_decomposition).")
    outline = shapely.union_all(polys)
    if not isinstance(outline, Polygon):
        raise ValueError("pieces: they do not form one connected polygon; pieces of one body must "
                         "touch along edges.")
    c = outline.centroid
    shift = lambda g: affinity.translate(g, -c.x, -c.y)  # noqa: E731
    return Shape(_ccw(shift(outline)), tuple(_ccw(shift(p)) for p in polys), kind, dict(params or {}))


def rectangle(width: float, height: float) -> Shape:
    """A ``width x height`` box (one piece)."""
    _positive(width=width, height=height)
    return shape_from_pieces([_box(0, 0, width, height)], "rectangle",
                             {"width": width, "height": height})


def _regular(n: int, rx: float, ry: float) -> np.ndarray:
    # A half-step angular offset keeps no vertex on an axis (fewer exact ties with boxes).
    ang = 2.0 * np.pi * (np.arange(n) + 0.5) / n
    return np.stack([rx * np.cos(ang), ry * np.sin(ang)], axis=1)


def cylinder(radius: float, n: int = 12) -> Shape:
    """A disk of ``radius`` as a regular ``n``-gon (one piece; vertices on the circle)."""
    _positive(radius=radius)
    return shape_from_pieces([Polygon(_regular(_count(n, 3), radius, radius))], "cylinder",
                             {"radius": radius, "n": n})


def ellipse(a: float, b: float, n: int = 16) -> Shape:
    """An ellipse with semi-axes ``a`` (x) and ``b`` (y) as an ``n``-gon (one piece)."""
    _positive(a=a, b=b)
    return shape_from_pieces([Polygon(_regular(_count(n, 3), a, b))], "ellipse", {"a": a, "b": b, "n": n})


def ring(r_out: float, r_in: float, n: int = 12) -> Shape:
    """An annulus as ``n`` trapezoids (annular sectors with straight sides)."""
    _positive(r_out=r_out, r_in=r_in)
    if not r_in < r_out:
        raise ValueError(f"ring: r_in must be < r_out; got r_in={r_in!r}, r_out={r_out!r}.")
    n = _count(n, 3)
    ang = 2.0 * np.pi * np.arange(n + 1) / n
    cos, sin = np.cos(ang), np.sin(ang)
    pieces = [Polygon([(r_in * cos[k], r_in * sin[k]), (r_out * cos[k], r_out * sin[k]),
                       (r_out * cos[k + 1], r_out * sin[k + 1]), (r_in * cos[k + 1], r_in * sin[k + 1])])
              for k in range(n)]
    return shape_from_pieces(pieces, "ring", {"r_out": r_out, "r_in": r_in, "n": n})


def l_shape(width: float, height: float, thickness: float) -> Shape:
    """An L: a ``width x thickness`` foot and a ``thickness``-wide leg up to ``height`` (two boxes)."""
    _bars(width=width, height=height, thickness=thickness)
    return shape_from_pieces([_box(0, 0, width, thickness), _box(0, thickness, thickness, height)],
                             "l", {"width": width, "height": height, "thickness": thickness})


def t_shape(width: float, height: float, thickness: float) -> Shape:
    """A T: a ``width x thickness`` top bar on a centred stem of total height ``height`` (two boxes)."""
    _bars(width=width, height=height, thickness=thickness)
    x0 = 0.5 * (width - thickness)
    return shape_from_pieces([_box(0, height - thickness, width, height),
                              _box(x0, 0, x0 + thickness, height - thickness)],
                             "t", {"width": width, "height": height, "thickness": thickness})


def x_shape(width: float, height: float, thickness: float) -> Shape:
    """A plus-shaped X (rotate it for a cross): a horizontal bar and two vertical stubs (three boxes)."""
    _bars(width=width, height=height, thickness=thickness)
    xa, ya = 0.5 * (width - thickness), 0.5 * (height - thickness)
    return shape_from_pieces([_box(0, ya, width, ya + thickness),
                              _box(xa, 0, xa + thickness, ya),
                              _box(xa, ya + thickness, xa + thickness, height)],
                             "x", {"width": width, "height": height, "thickness": thickness})


def diamond(width: float, height: float) -> Shape:
    """A rhombus with diagonals ``width`` (x) and ``height`` (y) (one piece)."""
    _positive(width=width, height=height)
    w, h = 0.5 * width, 0.5 * height
    return shape_from_pieces([Polygon([(w, 0), (0, h), (-w, 0), (0, -h)])], "diamond",
                             {"width": width, "height": height})


def arrow(length: float, shaft_width: float, head_length: float, head_width: float) -> Shape:
    """An arrow along +x: a box shaft and a triangular head (two pieces)."""
    _positive(length=length, shaft_width=shaft_width, head_length=head_length, head_width=head_width)
    if not (head_length < length and shaft_width < head_width):
        raise ValueError("arrow: need head_length < length and shaft_width < head_width; got "
                         f"{length!r}, {shaft_width!r}, {head_length!r}, {head_width!r}.")
    xs = length - head_length
    hw, sw = 0.5 * head_width, 0.5 * shaft_width
    return shape_from_pieces([_box(0, -sw, xs, sw), Polygon([(xs, -hw), (length, 0), (xs, hw)])],
                             "arrow", {"length": length, "shaft_width": shaft_width,
                                       "head_length": head_length, "head_width": head_width})


SHAPE_KINDS = {"rectangle": rectangle, "cylinder": cylinder, "ellipse": ellipse, "ring": ring,
               "l": l_shape, "t": t_shape, "x": x_shape, "diamond": diamond, "arrow": arrow}


def convex_decomposition(poly: Polygon) -> list[Polygon]:
    """Convex pieces tiling a valid polygon (holes allowed).

    A constrained Delaunay triangulation, then greedy merging: two pieces sharing an edge are merged
    while their union stays convex (a Hertel-Mehlhorn-style pass). Not minimal, but few pieces for the
    shapes one meets (an L gives 2-3). A convex polygon is returned as itself.
    """
    if not isinstance(poly, Polygon) or not poly.is_valid or poly.area <= 0:
        raise ValueError("convex_decomposition: expected a valid Polygon with positive area.")
    if is_convex(poly):
        return [_ccw(poly)]
    tris = [t for t in shapely.constrained_delaunay_triangles(poly).geoms if t.area > 0]
    pieces = list(tris)
    merged = True
    while merged:
        merged = False
        for i in range(len(pieces)):
            for j in range(i + 1, len(pieces)):
                shared = pieces[i].boundary.intersection(pieces[j].boundary)
                if shared.length <= 0:
                    continue  # touching at a point only: merging would not be convex anyway
                u = shapely.union_all([pieces[i], pieces[j]])
                if isinstance(u, Polygon) and is_convex(u):
                    pieces[i] = shapely.simplify(u, 0.0)
                    del pieces[j]
                    merged = True
                    break
            if merged:
                break
    return [_ccw(p) for p in pieces]


def polygon_inertia(poly: Polygon, mass: float) -> float:
    """Moment of inertia [kg m^2] about the area centroid of a uniform lamina of ``mass`` [kg].

    Green's theorem over every ring: ``J_O = 1/12 sum (x_i y_j - x_j y_i)(x_i^2 + x_i x_j + x_j^2 +
    y_i^2 + y_i y_j + y_j^2)`` with the exterior counter-clockwise and holes clockwise, then the parallel
    axis theorem ``J_c = J_O - A |c|^2`` and ``I = mass * J_c / A``.
    """
    poly = shapely.orient_polygons(poly, exterior_cw=False)
    area, j_o = 0.0, 0.0
    for ring_ in [poly.exterior, *poly.interiors]:
        xy = np.asarray(ring_.coords)[:, :2]
        x0, y0, x1, y1 = xy[:-1, 0], xy[:-1, 1], xy[1:, 0], xy[1:, 1]
        cross = x0 * y1 - x1 * y0
        area += 0.5 * cross.sum()
        j_o += (cross * (x0 * x0 + x0 * x1 + x1 * x1 + y0 * y0 + y0 * y1 + y1 * y1)).sum() / 12.0
    c = poly.centroid
    j_c = j_o - area * (c.x ** 2 + c.y ** 2)
    return float(mass * j_c / area)


def _positive(**values):
    for name, v in values.items():
        if not (isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name}: must be a finite number > 0 (metres); got {v!r}.")


def _bars(width, height, thickness):
    _positive(width=width, height=height, thickness=thickness)
    if not (thickness < width and thickness < height):
        raise ValueError(f"thickness: must be < width and < height; got thickness={thickness!r}, "
                         f"width={width!r}, height={height!r}.")


def _count(n, lo: int) -> int:
    if not isinstance(n, (int, np.integer)) or n < lo:
        raise ValueError(f"n: the number of vertices must be an int >= {lo}; got {n!r}.")
    return int(n)
