"""Random scenes for property tests (hypothesis strategies) and a bridge to the serial reference."""
from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from shapely import affinity
from shapely.geometry import MultiPolygon, Polygon

from jaxplan import Scene, circle
from jaxplan.reference import reference_fabric

ANGLES = (30.0, 45.0, 60.0, 75.0, 90.0, 120.0)
TARGET_KINDS = ("circle", "box", "triangle", "multipolygon")


def _target(kind: str, h: int, w: int, rng: np.random.Generator):
    """A target that covers at least the centre of one random cell (unit cells, origin 0)."""
    r, c = rng.integers(h), rng.integers(w)
    cx, cy = c + 0.5, r + 0.5
    size = rng.uniform(0.6, max(0.7, min(h, w) / 3))
    if kind == "circle":
        return circle((cx, cy), size, resolution=24)
    if kind == "box":
        return Polygon([(cx - size, cy - size * 0.7), (cx + size * 0.8, cy - size * 0.7),
                        (cx + size * 0.8, cy + size), (cx - size, cy + size)])
    if kind == "triangle":
        tri = Polygon([(cx - size, cy - size), (cx + size * 1.2, cy - size * 0.5), (cx, cy + size * 1.3)])
        return affinity.rotate(tri, rng.uniform(0, 360), origin=(cx, cy))
    first = circle((cx, cy), min(size, 1.2), resolution=16)
    r2, c2 = rng.integers(h), rng.integers(w)
    second = circle((c2 + 0.5, r2 + 0.5), 0.6, resolution=16)
    if first.intersects(second):
        return first
    return MultiPolygon([first, second])


# Grid shapes from 1x1 to 30x30. A fixed menu rather than any (H, W): every new shape compiles the
# kernels again, and a handful of shapes keeps the suite fast while covering the edge sizes.
SHAPES = ((1, 1), (1, 6), (6, 1), (2, 3), (5, 5), (7, 12), (13, 9), (16, 16), (30, 30))


@st.composite
def scenes(draw, max_side: int = 30, integer_counts: bool = True, blocked: bool = False):
    """A random Scene: size, density, target shape and counts; with ``blocked``, random blocked cells
    (single cells and walls) off the target, and no material on them."""
    h, w = draw(st.sampled_from([s for s in SHAPES if max(s) <= max_side]))
    density = draw(st.sampled_from((0.2, 0.5, 0.8, 1.0)))
    kind = draw(st.sampled_from(TARGET_KINDS))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    if integer_counts:
        counts = rng.integers(1, 6, (h, w)).astype(np.float32)
    else:  # distinct-ish real counts, so exact ties between paths are rare
        counts = np.round(rng.uniform(0.5, 5.0, (h, w)), 3).astype(np.float32)
    obj = np.where(rng.random((h, w)) < density, counts, 0.0).astype(np.float32)
    target = _target(kind, h, w, rng)
    if not blocked:
        return Scene.from_arrays(obj, target, cell_size=1.0)
    mask = random_blocked((h, w), rng) & ~np.asarray(Scene.from_arrays(obj, target).target_mask)
    return Scene.from_arrays(np.where(mask, 0.0, obj), target, cell_size=1.0, blocked=mask)


def random_blocked(shape, rng: np.random.Generator) -> np.ndarray:
    """bool[H, W]: scattered blocked cells plus a few straight walls (buildings' sides)."""
    h, w = shape
    mask = rng.random((h, w)) < rng.choice((0.05, 0.15, 0.3))
    for _ in range(rng.integers(0, 3)):
        r, c = rng.integers(h), rng.integers(w)
        if rng.random() < 0.5:
            mask[r, c:c + rng.integers(2, max(3, w))] = True
        else:
            mask[r:r + rng.integers(2, max(3, h)), c] = True
    return mask


def reference_of(scene: Scene, params, **kw):
    """The serial reference on exactly the scene's geometry arrays (float64 copies)."""
    kw.setdefault("blocked", np.asarray(scene.blocked) if bool(np.asarray(scene.blocked).any()) else None)
    return reference_fabric(
        np.asarray(scene.obj, np.float64), np.asarray(scene.target_mask),
        np.asarray(scene.dist, np.float64), np.asarray(scene.tvec, np.float64),
        float(scene.cell_size), float(params.theta_tol_deg), monotone=params.monotone, k=params.k,
        max_hops=params.max_hops, tau_h=float(params.tau_h), highway_relative=params.highway_relative,
        highway_smoothing=params.highway_smoothing, highway_nms=params.highway_nms,
        anchor_lambda=float(params.anchor_lambda), **kw)


def has_borderline_step(scene: Scene, theta_tol_deg: float, margin: float = 5e-7) -> bool:
    """Whether any cone or monotone test of the scene lies within ``margin`` of its threshold.

    The kernels decide those in float32 (rounding ~1e-7) and the reference in float64, so such a step may be
    feasible in one and not the other; tests comparing the two skip such scenes.
    """
    from jaxplan.core import lattice

    tvec = np.asarray(scene.tvec, np.float64)
    dist = np.asarray(scene.dist, np.float64)
    s = float(scene.cell_size)
    h, w = dist.shape
    cos_t = np.cos(np.deg2rad(theta_tol_deg)) - lattice.CONE_EPS
    for _i, (dr, dc) in enumerate(lattice.DIRS):
        unit = np.array([dc, dr], np.float64) / np.hypot(dr, dc)
        cone = tvec @ unit - cos_t
        nb = np.full((h, w), np.nan)
        rs, cs = slice(max(0, -dr), h - max(0, dr)), slice(max(0, -dc), w - max(0, dc))
        nb[rs, cs] = dist[max(0, dr):h + min(0, dr), max(0, dc):w + min(0, dc)]
        with np.errstate(invalid="ignore"):   # inf - inf beside blocked cells: not a step either way
            mono = (dist - lattice.MONOTONE_EPS * s) - nb
        if np.any(np.abs(cone) < margin) or np.any(np.abs(mono[np.isfinite(mono)]) < 2 * margin * s):
            return True
    return False
