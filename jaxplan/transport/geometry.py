"""A scene's geometry: target shapes and the kernel that measures every cell against the target.

:func:`target_geometry` evaluates every (cell, boundary segment) pair with array operations, in row
blocks and segment chunks so that memory stays bounded on large grids: which cells are target cells,
the distance ``d(C, T)`` and the unit vector ``t(C)`` toward the target boundary (Section 3.1;
``docs/transport.md``, "Grid and geometry"). Its serial twin, with one shapely call per cell, is
:func:`jaxplan.reference.geometry.reference_geometry`.
"""
from __future__ import annotations

import functools
import math

import jax.numpy as jnp
import numpy as np
from jax import lax
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry import box as _shapely_box

from jaxplan.core import grid_jit

__all__ = ["ON_BOUNDARY_EPS", "box", "circle", "target_geometry", "target_segments"]

# A centre this close to the boundary (in cell sizes) is "on" it and therefore covered.
ON_BOUNDARY_EPS = 1e-9

# Memory bounds of the geometry kernel: at most this many (cell, segment) pairs are live at once,
# and segments are consumed in chunks of at most this many (a row block always holds >= 1 row).
_PAIR_BUDGET = 1 << 20
_SEG_CHUNK = 1024



# --------------------------------------------------------------------------------------------------
# Shapes
# --------------------------------------------------------------------------------------------------

def circle(center, radius, resolution: int = 64) -> Polygon:
    """A circle as a regular polygon with ``resolution`` vertices on the circle (inscribed).

    The vertices sit at angles ``2 pi (k + 0.5) / resolution``: the half-step offset keeps vertices
    off the axis-aligned points ``center +- (radius, 0)``, which often coincide with cell centres.

    center: (x, y), world units; radius: world units, > 0; resolution: int >= 3.
    """
    cx, cy = (float(v) for v in center)
    radius = float(radius)
    if not (math.isfinite(cx) and math.isfinite(cy)):
        raise ValueError(f"circle: center must be two finite numbers, got {center!r}.")
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"circle: radius must be finite and > 0, got {radius!r}.")
    if int(resolution) < 3:
        raise ValueError(f"circle: resolution must be >= 3 vertices, got {resolution!r}.")
    n = int(resolution)
    ang = 2.0 * np.pi * (np.arange(n) + 0.5) / n
    return Polygon(np.stack([cx + radius * np.cos(ang), cy + radius * np.sin(ang)], axis=1))


def box(x0: float, y0: float, x1: float, y1: float) -> Polygon:
    """Axis-aligned rectangle ``[x0, x1] x [y0, y1]`` in world units (shapely's ``box``)."""
    return _shapely_box(x0, y0, x1, y1)


# --------------------------------------------------------------------------------------------------
# Geometry kernel
# --------------------------------------------------------------------------------------------------

def _polygons(target):
    return list(target.geoms) if isinstance(target, MultiPolygon) else [target]


def target_segments(target) -> np.ndarray:
    """All boundary segments of ``target``: ``f32[M, 2, 2]``, ``[m, 0]`` = start, ``[m, 1]`` = end.

    Order (the tie-break order of ``t(C)``): polygon by polygon, exterior ring then interior rings,
    each ring in its stored vertex order. World units, (x, y).
    """
    parts = []
    for poly in _polygons(target):
        for ring in [poly.exterior, *poly.interiors]:
            xy = np.asarray(ring.coords, dtype=np.float64)[:, :2]  # closed ring: last == first
            parts.append(np.stack([xy[:-1], xy[1:]], axis=1))
    if not parts:
        return np.zeros((0, 2, 2), np.float32)
    return np.concatenate(parts, axis=0).astype(np.float32)


def _pair_terms(px, py, seg):
    """Closest-point offsets and ray crossings for every (cell, segment) pair.

    px: f32[1, W, 1], py: f32[R, 1, 1] local cell centres; seg: f32[Mc, 2, 2] local segments.
    Returns ex, ey (closest point minus centre) and d2 (squared distance), each f32[R, W, Mc], and
    cross: bool[R, W, Mc], whether the +x ray from the centre crosses the segment.
    """
    ax, ay, bx, by = seg[:, 0, 0], seg[:, 0, 1], seg[:, 1, 0], seg[:, 1, 1]
    dx, dy = bx - ax, by - ay
    dd = dx * dx + dy * dy
    # Degenerate (zero-length) segments project onto their start point.
    t = ((px - ax) * dx + (py - ay) * dy) / jnp.where(dd > 0, dd, 1.0)
    t = jnp.clip(t, 0.0, 1.0)
    # Use the exact end points at t = 0 / 1 so a vertex shared by two segments gives equal distances
    # (then the first segment wins, as the conventions require).
    qx = jnp.where(t <= 0, ax, jnp.where(t >= 1, bx, ax + t * dx))
    qy = jnp.where(t <= 0, ay, jnp.where(t >= 1, by, ay + t * dy))
    ex, ey = qx - px, qy - py
    d2 = ex * ex + ey * ey
    # Even-odd rule, half-open in y so a ray through a vertex counts it exactly once.
    straddle = (ay > py) != (by > py)
    x_cross = ax + (py - ay) * dx / jnp.where(straddle, dy, 1.0)
    cross = straddle & (px < x_cross)
    return ex, ey, d2, cross


def _block_geometry(rows, seg_chunks, valid_chunks, width: int, cell_size):
    """Closest-boundary offset, squared distance and crossing parity for one block of rows.

    rows: i32[R]; seg_chunks: f32[C, Mc, 2, 2] (local frame); valid_chunks: bool[C, Mc].
    Returns (d2, ex, ey, parity), each [R, W].
    """
    py = ((rows.astype(jnp.float32) + 0.5) * cell_size)[:, None, None]
    px = ((jnp.arange(width, dtype=jnp.float32) + 0.5) * cell_size)[None, :, None]
    shape = (rows.shape[0], width)

    def step(carry, chunk):
        best_d2, best_ex, best_ey, parity = carry
        seg, valid = chunk
        ex, ey, d2, cross = _pair_terms(px, py, seg)
        d2 = jnp.where(valid, d2, jnp.inf)
        k = jnp.argmin(d2, axis=-1)[..., None]  # first index wins ties
        c_d2 = jnp.take_along_axis(d2, k, axis=-1)[..., 0]
        c_ex = jnp.take_along_axis(ex, k, axis=-1)[..., 0]
        c_ey = jnp.take_along_axis(ey, k, axis=-1)[..., 0]
        # Strictly better only: an earlier chunk (lower segment index) keeps exact ties.
        better = c_d2 < best_d2
        n_cross = jnp.sum(cross & valid, axis=-1)
        carry = (
            jnp.where(better, c_d2, best_d2),
            jnp.where(better, c_ex, best_ex),
            jnp.where(better, c_ey, best_ey),
            parity ^ (n_cross % 2 == 1),
        )
        return carry, None

    init = (
        jnp.full(shape, jnp.inf, jnp.float32),
        jnp.zeros(shape, jnp.float32),
        jnp.zeros(shape, jnp.float32),
        jnp.zeros(shape, bool),
    )
    out, _ = lax.scan(step, init, (seg_chunks, valid_chunks))
    return out


def _chunk_segments(seg, seg_chunk: int):
    """Pad ``seg: f32[M, 2, 2]`` to whole chunks: ``f32[C, Mc, 2, 2]`` and a validity ``bool[C, Mc]``."""
    m = seg.shape[0]
    mc = max(1, min(m, seg_chunk))
    n_chunks = -(-m // mc)
    pad = n_chunks * mc - m
    seg = jnp.pad(seg, ((0, pad), (0, 0), (0, 0)))
    valid = jnp.arange(n_chunks * mc) < m
    return seg.reshape(n_chunks, mc, 2, 2), valid.reshape(n_chunks, mc)


def _geometry_cells(segments, shape, *args, **kwargs) -> int:
    return int(shape[0]) * int(shape[1])


# the process's first compilation, usually: on the paper's grids the older code generator keeps the
# newer one's compiler (and its memory) out of the process
@functools.partial(grid_jit, static_argnames=("shape", "pair_budget", "seg_chunk"), cells_of=_geometry_cells)
def target_geometry(segments, shape, cell_size, origin, pair_budget: int = _PAIR_BUDGET,
                    seg_chunk: int = _SEG_CHUNK):
    """Target mask, distance and boundary direction of every cell (conventions, "Grid and geometry").

    segments: f32[M, 2, 2] from :func:`target_segments`, world units (M >= 1).
    shape: static (H, W). cell_size: f32[], world units. origin: f32[2], world (x, y) of the grid corner.
    pair_budget / seg_chunk: static memory bounds (pairs live at once; segments per chunk).

    Returns
      target_mask: bool[H, W], centre covered by the target (even-odd rule, or within 1e-9 s of ∂T);
      dist: f32[H, W], world units, distance to the closest boundary segment, 0 on target cells;
      tvec: f32[H, W, 2], unit (x, y) vector to the closest boundary point, (0, 0) on target cells.

    Compiles once per (H, W, M) (and memory bounds); cell_size and origin are traced.
    """
    h, w = (int(v) for v in shape)
    cell_size = jnp.asarray(cell_size, jnp.float32)
    origin = jnp.asarray(origin, jnp.float32)
    # Work relative to the grid corner: small coordinates keep float32 rounding small.
    seg = jnp.asarray(segments, jnp.float32) - origin
    seg_chunks, valid_chunks = _chunk_segments(seg, seg_chunk)
    mc = seg_chunks.shape[1]
    rows_per_block = int(min(h, max(1, pair_budget // max(1, w * mc))))
    n_blocks = -(-h // rows_per_block)
    row_blocks = jnp.arange(n_blocks * rows_per_block, dtype=jnp.int32).reshape(n_blocks, -1)

    def block(rows):
        return _block_geometry(rows, seg_chunks, valid_chunks, w, cell_size)

    _, ex, ey, parity = (a.reshape(-1, w)[:h] for a in lax.map(block, row_blocks))
    # Distance and direction both come from the selected offset, so tvec has unit norm even where
    # XLA evaluated the argmin's squared distances with different rounding (e.g. fused multiply-add).
    dist = jnp.sqrt(ex * ex + ey * ey)
    mask = parity | (dist <= ON_BOUNDARY_EPS * cell_size)
    safe = jnp.where(dist > 0, dist, 1.0)
    tvec = jnp.stack([ex / safe, ey / safe], axis=-1)
    tvec = jnp.where(mask[..., None], 0.0, tvec)
    dist = jnp.where(mask, 0.0, dist)
    return mask, dist, tvec
