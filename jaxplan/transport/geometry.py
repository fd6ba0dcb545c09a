"""A scene's geometry: target shapes and the kernel that measures every cell against the target.

:func:`target_geometry` finds which cells are target cells, the distance ``d(C, T)`` and the unit vector
``t(C)`` toward the target boundary (Section 3.1; ``docs/transport.md``, "Grid and geometry"), in one of
two ways with the same result:

- brute force: every (cell, boundary segment) pair, with array operations in row blocks and segment
  chunks so that memory stays bounded;
- tiled, for large grids: the even-odd parity from (row, segment) pairs only (a segment that straddles a
  row crosses it at one x; a binary search counts the centres left of it, and a histogram of those counts
  summed from the right gives every centre's crossings), and the closest segment of each square tile of
  cells among its candidates, the few segments that pass two necessary tests for being closest to one
  of its cells (:func:`_cull_tiles`). Where some tile keeps more than K candidates the brute force
  measures the distances instead, so the result never depends on the culling.

Both evaluate a (cell, segment) pair with the same float32 arithmetic (:func:`_pair_terms`, every product
rounded so that any program gets the same bits) and let the lowest segment index win ties, so they agree
exactly. The serial twin, with one shapely call per cell, is
:func:`jaxplan.reference.geometry.reference_geometry`.
"""
from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry import box as _shapely_box

from jaxplan.core import grid_jit, traced

__all__ = ["ON_BOUNDARY_EPS", "box", "circle", "segment_bucket", "target_geometry", "target_segments"]

# A centre this close to the boundary (in cell sizes) is "on" it and therefore covered.
ON_BOUNDARY_EPS = 1e-9

# Memory bounds of the geometry kernel: at most this many (cell, segment) pairs (or (row, segment),
# (tile, segment) pairs in the tiled kernel) are live at once, and the brute force consumes segments in
# chunks of at most this many (a block always holds >= 1 row or tile).
_PAIR_BUDGET = 1 << 20
_SEG_CHUNK = 1024
# The tiled kernel. Tile side in cells and K, the most candidate segments a tile may keep (beyond that
# the brute force takes over), measured on the fleet sites: 16 x 16 tiles keep 7 segments on average and
# at most 71 on site1024 (8 x 8 tiles keep fewer, but culling them costs four times as much).
_TILE = 16
_MAX_CANDIDATES = 128
# Candidates are evaluated this many at a time, in blocks of at most this many cells: a block stops after
# the chunks its busiest tile needs (tiles go in order of their count), so small chunks and blocks waste
# few pairs on padding; larger ones take fewer loop steps.
_CANDIDATE_CHUNK = 4
_EVAL_BLOCK_CELLS = 1 << 15
# "auto" takes the tiled kernel from this many (cell, segment) pairs on. It compiles 0.5 to 1.5 s longer
# than the brute force: under the test suite's XLA flags the brute force's run time (~30M pairs/s on 2
# cores) makes up for that from about this size, with XLA's defaults (~200M pairs/s) only near 2^28 pairs
# for a single call; every further call on the shape is faster at any size.
_TILED_MIN_PAIRS = 1 << 25
# Culling margin, a fraction of the largest local coordinate: float32 distances and projections are off
# by a few ulps of it, so 2^-16 (>= 100 ulps) keeps every segment whose computed distance could win.
_CULL_MARGIN = 2.0 ** -16



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


def _rounded(x, zero):
    """``x: f32[...]`` unchanged, but rounded to float32 before any sum it enters.

    XLA:CPU may fuse ``a * b + c`` into one fused multiply-add, rounded once instead of twice, and
    whether it does depends on the surrounding program. An identity the compiler cannot see through
    (xor of the bits with ``zero``, an i32 that is 0 at run time) keeps every product a product, so
    any program that evaluates a pair gets the same bits and the same closest segment.
    """
    return lax.bitcast_convert_type(lax.bitcast_convert_type(x, jnp.int32) ^ zero, jnp.float32)


def _opaque_zero(x):
    """i32[...], 0 where ``x`` is a number (its NaN flag): for run-time data ``x``, a 0 that the compiler
    cannot fold to a constant (which would let it drop :func:`_rounded`'s identity)."""
    return jnp.isnan(x).astype(jnp.int32)


def _pair_terms(px, py, seg):
    """Closest-point offsets and ray crossings for every (cell, segment) pair.

    px: f32[1, W, 1], py: f32[R, 1, 1] local cell centres; seg: f32[Mc, 2, 2] local segments.
    Returns ex, ey (closest point minus centre) and d2 (squared distance), each f32[R, W, Mc], and
    cross: bool[R, W, Mc], whether the +x ray from the centre crosses the segment.
    Plain float32 arithmetic, every product rounded (:func:`_rounded`): bit-identical in every program.
    """
    ax, ay, bx, by = seg[:, 0, 0], seg[:, 0, 1], seg[:, 1, 0], seg[:, 1, 1]
    zero = _opaque_zero(ax)
    dx, dy = bx - ax, by - ay
    dd = _rounded(dx * dx, zero) + _rounded(dy * dy, zero)
    # Degenerate (zero-length) segments project onto their start point. The reciprocal is explicit and
    # opaque: XLA turns a division by a broadcast into a product with its reciprocal, and a product with a
    # reciprocal into a division, each in some programs and not others.
    inv_dd = _rounded(1.0 / jnp.where(dd > 0, dd, 1.0), zero)
    t = (_rounded((px - ax) * dx, zero) + _rounded((py - ay) * dy, zero)) * inv_dd
    t = jnp.clip(t, 0.0, 1.0)
    # Use the exact end points at t = 0 / 1 so a vertex shared by two segments gives equal distances
    # (then the first segment wins, as the conventions require).
    qx = jnp.where(t <= 0, ax, jnp.where(t >= 1, bx, ax + _rounded(t * dx, zero)))
    qy = jnp.where(t <= 0, ay, jnp.where(t >= 1, by, ay + _rounded(t * dy, zero)))
    ex, ey = qx - px, qy - py
    d2 = _rounded(ex * ex, zero) + _rounded(ey * ey, zero)
    straddle, x_cross = _row_crossing(ax, ay, by, dx, dy, py)
    return ex, ey, d2, straddle & (px < x_cross)


def _row_crossing(ax, ay, by, dx, dy, py):
    """``(straddle, x_cross)``: whether each segment crosses the line y = ``py`` and at which x.

    Even-odd rule, half-open in y so a ray through a vertex counts it exactly once. Every kernel takes
    the crossing from this one expression, so they agree to the bit.
    """
    straddle = (ay > py) != (by > py)
    return straddle, ax + (py - ay) * dx / jnp.where(straddle, dy, 1.0)


def _centres(index, cell_size):
    """Local cell-centre coordinate ``(index + 0.5) * cell_size`` (f32, world units) of integer ``index``.

    Every path computes centres with this one expression, rounded (:func:`_rounded`, or the product
    could fuse with the difference ``px - ax`` that follows it), so they all see bit-identical centres.
    """
    return _rounded((index.astype(jnp.float32) + 0.5) * cell_size, _opaque_zero(cell_size))


def _closest_update(best, px, py, seg, valid):
    """Fold one chunk of segments into the closest boundary offsets found so far.

    best: (d2, ex, ey), each f32[R, Wb]; px: f32[1, Wb, 1], py: f32[R, 1, 1] local centres;
    seg: f32[Mc, 2, 2] local; valid: bool[Mc]. Returns the new best and cross: bool[R, Wb, Mc].
    Within the chunk the first smallest d2 wins; across chunks only a strictly smaller one, so with
    chunks in segment order the lowest segment index wins exact ties.
    """
    best_d2, best_ex, best_ey = best
    ex, ey, d2, cross = _pair_terms(px, py, seg)
    d2 = jnp.where(valid, d2, jnp.inf)
    k = jnp.argmin(d2, axis=-1)[..., None]
    c_d2 = jnp.take_along_axis(d2, k, axis=-1)[..., 0]
    c_ex = jnp.take_along_axis(ex, k, axis=-1)[..., 0]
    c_ey = jnp.take_along_axis(ey, k, axis=-1)[..., 0]
    better = c_d2 < best_d2
    best = (jnp.where(better, c_d2, best_d2), jnp.where(better, c_ex, best_ex), jnp.where(better, c_ey, best_ey))
    return best, cross


def _no_best(shape):
    """No closest segment yet: (d2, ex, ey), each f32[*shape], d2 = inf."""
    return jnp.full(shape, jnp.inf, jnp.float32), jnp.zeros(shape, jnp.float32), jnp.zeros(shape, jnp.float32)


def _block_geometry(rows, cols, seg_chunks, valid_chunks, cell_size):
    """Closest-boundary offset, squared distance and crossing parity for one block of cells.

    rows: i32[R], cols: i32[Wb] (the block is rows x cols); seg_chunks: f32[C, Mc, 2, 2] (local frame);
    valid_chunks: bool[C, Mc]. Returns (d2, ex, ey, parity), each [R, Wb].
    """
    py = _centres(rows, cell_size)[:, None, None]
    px = _centres(cols, cell_size)[None, :, None]
    shape = (rows.shape[0], cols.shape[0])

    def step(carry, chunk):
        seg, valid = chunk
        best, cross = _closest_update(carry[:3], px, py, seg, valid)
        n_cross = jnp.sum(cross & valid, axis=-1)
        return (*best, carry[3] ^ (n_cross % 2 == 1)), None

    out, _ = lax.scan(step, (*_no_best(shape), jnp.zeros(shape, bool)), (seg_chunks, valid_chunks))
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


def _in_blocks(fn, n: int, per_block: int):
    """``fn`` over ``arange(n)`` in blocks of ``per_block`` indices (``lax.map``); outputs ``[n, ...]``.

    The last block is padded with indices >= n (``fn`` must accept them), whose outputs are dropped.
    """
    per_block = int(max(1, min(n, per_block)))
    n_blocks = -(-n // per_block)
    idx = jnp.arange(n_blocks * per_block, dtype=jnp.int32).reshape(n_blocks, per_block)
    out = lax.map(fn, idx)
    return tuple(a.reshape(n_blocks * per_block, *a.shape[2:])[:n] for a in out)


def _brute_geometry(seg, h: int, w: int, cell_size, pair_budget: int, seg_chunk: int):
    """Every (cell, segment) pair: closest offsets ``ex, ey: f32[H, W]`` and crossing parity ``bool[H, W]``."""
    seg_chunks, valid_chunks = _chunk_segments(seg, seg_chunk)
    rows_per_block = pair_budget // max(1, w * seg_chunks.shape[1])

    def block(rows):
        return _block_geometry(rows, jnp.arange(w), seg_chunks, valid_chunks, cell_size)

    _, ex, ey, parity = _in_blocks(block, h, rows_per_block)
    return ex, ey, parity


def _prefix_counts(x):
    """Inclusive prefix sums ``i32[..., N]`` along the last axis of counts ``x: int/bool[..., N]``.

    As two small matrix products (within groups of 32, then of the group totals) instead of a scan:
    XLA's scans compile and run slowly on CPUs. Exact while the sums stay below 2^24 (float32).
    """
    n = x.shape[-1]
    g = min(n, 32)
    n_groups = -(-n // g)
    x = jnp.pad(x.astype(jnp.float32), [(0, 0)] * (x.ndim - 1) + [(0, n_groups * g - n)])
    x = x.reshape(*x.shape[:-1], n_groups, g)
    within = x @ jnp.triu(jnp.ones((g, g), jnp.float32))   # [..., n_groups, g]
    before = within[..., -1] @ jnp.triu(jnp.ones((n_groups, n_groups), jnp.float32), 1)
    out = (within + before[..., None]).reshape(*x.shape[:-2], n_groups * g)[..., :n]
    return out.astype(jnp.int32)


def _crossing_parity(seg, h: int, w: int, cell_size, pair_budget: int):
    """Even-odd parity ``bool[H, W]`` of the +x rays' crossings, from (row, segment) pairs only.

    A segment that straddles row ``h`` crosses it at ``x_cross`` (:func:`_row_crossing`, as in
    :func:`_pair_terms`), and the rays of the centres with ``px < x_cross`` cross it: the first
    ``searchsorted(px, x_cross)`` centres of the row. A histogram of those counts per row, summed from
    the right, gives each centre's number of crossings.
    """
    m = seg.shape[0]
    ax, ay, bx, by = seg[:, 0, 0], seg[:, 0, 1], seg[:, 1, 0], seg[:, 1, 1]
    dx, dy = bx - ax, by - ay
    px = _centres(jnp.arange(w), cell_size)

    def block(rows):
        py = _centres(rows, cell_size)[:, None]
        straddle, x_cross = _row_crossing(ax, ay, by, dx, dy, py)
        n_left = jnp.searchsorted(px, x_cross, side="left")   # centres with px < x_cross
        hist = jnp.zeros((rows.shape[0], w + 1), jnp.int32)
        hist = hist.at[jnp.arange(rows.shape[0])[:, None], n_left].add(straddle.astype(jnp.int32))
        from_right = _prefix_counts(hist[:, ::-1])[:, ::-1]
        return (from_right[:, 1:] % 2 == 1,)   # centre w: the crossings counted right of it

    (parity,) = _in_blocks(block, h, pair_budget // m)
    return parity


def _cull_tiles(seg, busy, tile: int, h: int, w: int, cell_size, margin, pair_budget: int, slots: int):
    """Candidate segments of every tile: those that may be closest to one of its cells.

    seg: f32[M, 2, 2] local; busy: bool[nT], tiles (row-major, ``tile`` x ``tile`` cells) with a cell that
    needs a distance; margin: f32[], world units, covers float32 rounding. Returns cand: i32[nT, slots],
    the first ``slots`` kept segment indices in increasing order (0 past them), and count: i32[nT], how
    many segments were kept (0 for an idle tile).

    The tile's cell centres lie in a box with centre c and half diagonal r. With q the boundary point
    closest to c, f(p) the distance from a centre p to the boundary and d(p, m) to segment m, f(p) <= |q - p|
    <= f(c) + r, and m can be p's closest segment only if d(p, m) <= f(p). So m is kept only if it passes
    two tests, each necessary for that at some p of the box (``margin`` added to every bound):
    - band: LB_m <= f(c) + r, for LB_m the distance between m's bounding box and the box, and for
      LB_m = d(c, m) - r;
    - slab: min(a.u, b.u) <= q.u + H, with a, b m's end points, u the unit vector from c to q and H the
      largest |q - v| - (q - v).u over the box's corners v (a convex function of v, so H bounds it over the
      box): d(p, m) >= min(a.u, b.u) - p.u, and f(p) <= |q - p| <= (q - p).u + H. Segments behind the
      nearest boundary as seen from the tile fail it, which the band keeps on tiles far from the target.
    """
    m, n_tiles, n_cols = seg.shape[0], busy.shape[0], -(-w // tile)
    ax, ay, bx, by = seg[:, 0, 0], seg[:, 0, 1], seg[:, 1, 0], seg[:, 1, 1]
    dx, dy = bx - ax, by - ay
    dd = dx * dx + dy * dy
    inv_dd = 1.0 / jnp.where(dd > 0, dd, 1.0)
    sx0, sx1 = jnp.minimum(ax, bx), jnp.maximum(ax, bx)
    sy0, sy1 = jnp.minimum(ay, by), jnp.maximum(ay, by)

    def offset(px, py, k):
        """Closest point of segments k minus p (plain arithmetic: the margin covers its rounding)."""
        wx, wy = ax[k] - px, ay[k] - py
        t = jnp.clip(-(wx * dx[k] + wy * dy[k]) * inv_dd[k], 0.0, 1.0)
        return wx + t * dx[k], wy + t * dy[k]

    def block(tiles):
        tiles = jnp.minimum(tiles, n_tiles - 1)   # the padding of the last block repeats a tile
        row0, col0 = (tiles // n_cols)[:, None] * tile, (tiles % n_cols)[:, None] * tile
        # The box of the tile's centres on the grid.
        x0, x1 = _centres(col0, cell_size), _centres(jnp.minimum(col0 + tile, w) - 1, cell_size)
        y0, y1 = _centres(row0, cell_size), _centres(jnp.minimum(row0 + tile, h) - 1, cell_size)
        cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        rad = 0.5 * jnp.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2)
        ex, ey = offset(cx, cy, slice(None))   # [nb, M]
        d2 = ex * ex + ey * ey
        k = jnp.argmin(d2, axis=1)[:, None]
        reach = jnp.sqrt(jnp.take_along_axis(d2, k, axis=1)) + rad + margin   # f(c) + r, and the margin
        gx = jnp.maximum(0.0, jnp.maximum(sx0 - x1, x0 - sx1))
        gy = jnp.maximum(0.0, jnp.maximum(sy0 - y1, y0 - sy1))
        keep = (gx * gx + gy * gy <= reach * reach) & (d2 <= (reach + rad) ** 2)

        rx, ry = offset(cx, cy, k)   # [nb, 1] c -> q
        norm = jnp.sqrt(rx * rx + ry * ry)
        # c on the boundary gives u = 0, and the slab test keeps every segment.
        ux, uy = rx / jnp.where(norm > 0, norm, 1.0), ry / jnp.where(norm > 0, norm, 1.0)
        qx, qy = cx + rx, cy + ry
        vx = qx - jnp.concatenate([x0, x1, x0, x1], axis=1)   # [nb, 4] q - corner
        vy = qy - jnp.concatenate([y0, y0, y1, y1], axis=1)
        h_max = jnp.max(jnp.sqrt(vx * vx + vy * vy) - (vx * ux + vy * uy), axis=1, keepdims=True)
        front = jnp.minimum(ax * ux + ay * uy, bx * ux + by * uy)
        keep = keep & (front <= qx * ux + qy * uy + h_max + margin) & busy[tiles][:, None]

        count = jnp.sum(keep, axis=1, dtype=jnp.int32)
        slot = _prefix_counts(keep) - 1
        slot = jnp.where(keep & (slot < slots), slot, slots)   # out of range: dropped
        cand = jnp.zeros((tiles.shape[0], slots), jnp.int32)
        cand = cand.at[jnp.arange(tiles.shape[0])[:, None], slot].set(
            jnp.broadcast_to(jnp.arange(m, dtype=jnp.int32), slot.shape), mode="drop")
        return cand, count

    return _in_blocks(block, n_tiles, pair_budget // m)


def _tiled_offsets(seg, cand, count, tile: int, n_rows: int, n_cols: int, cell_size, pair_budget: int,
                   chunk: int):
    """Closest offsets ``ex, ey: f32[n_rows * tile, n_cols * tile]`` from each tile's candidates only.

    cand: i32[nT, K] increasing segment indices, the first ``count[t]`` valid (K a multiple of ``chunk``).
    The (cell, candidate) pairs go through :func:`_closest_update` in chunks of ``chunk`` candidates, as
    the brute force's (cell, segment) pairs, so the first smallest wins as over all segments. Tiles are
    processed in order of their count, so that a block stops after the chunks its busiest tile needs.
    """
    n_tiles = cand.shape[0]
    offs = jnp.arange(tile, dtype=jnp.int32)
    order = jnp.argsort(count)
    update = jax.vmap(_closest_update)

    def block(pos):
        tiles = order[jnp.minimum(pos, n_tiles - 1)]
        n = count[tiles][:, None]
        px = _centres((tiles % n_cols)[:, None] * tile + offs, cell_size)[:, None, :, None]
        py = _centres((tiles // n_cols)[:, None] * tile + offs, cell_size)[:, :, None, None]
        ids = cand[tiles]

        def body(i, best):
            first = i * chunk
            idx = lax.dynamic_slice_in_dim(ids, first, chunk, axis=1)
            best, _ = update(best, px, py, seg[idx], first + jnp.arange(chunk) < n)
            return best

        n_chunks = (jnp.max(n) + chunk - 1) // chunk
        _, ex, ey = lax.fori_loop(0, n_chunks, body, _no_best((tiles.shape[0], tile, tile)))
        return ex, ey

    # A block runs as many chunks as its busiest tile needs: small blocks waste few pairs on tiles with fewer
    # candidates, large ones take few loop steps.
    ex, ey = _in_blocks(block, n_tiles, min(pair_budget // chunk, _EVAL_BLOCK_CELLS) // (tile * tile))

    def grid(a):   # [nT, tile, tile] in count order -> [n_rows * tile, n_cols * tile]
        a = jnp.zeros_like(a).at[order].set(a)
        return a.reshape(n_rows, n_cols, tile, tile).transpose(0, 2, 1, 3).reshape(n_rows * tile, n_cols * tile)

    return grid(ex), grid(ey)


def _geometry_cells(segments, n_segments, shape, *args, **kwargs) -> int:
    return int(shape[0]) * int(shape[1])


def segment_bucket(m: int) -> int:
    """The padded segment count the geometry kernel compiles for ``m`` segments: a power of two from 16
    up to ``_SEG_CHUNK``, then whole chunks, so that targets with other vertex counts share programs."""
    if m <= _SEG_CHUNK:
        return max(16, 1 << (max(m, 1) - 1).bit_length())
    return -(-m // _SEG_CHUNK) * _SEG_CHUNK


def target_geometry(segments, shape, cell_size, origin, pair_budget: int = _PAIR_BUDGET,
                    seg_chunk: int = _SEG_CHUNK, method: str = "auto", tile: int = _TILE,
                    max_candidates: int = _MAX_CANDIDATES):
    """Target mask, distance and boundary direction of every cell (conventions, "Grid and geometry").

    segments: f32[M, 2, 2] from :func:`target_segments`, world units (M >= 1).
    shape: static (H, W). cell_size: f32[], world units. origin: f32[2], world (x, y) of the grid corner.
    pair_budget: static, the most (cell, segment), (row, segment) or (tile, segment) pairs live at once;
      seg_chunk: static, segments per chunk of the brute force.
    method: static, "brute", "tiled" or "auto" (module docstring): "auto" (default) is "tiled" from
      ``_TILED_MIN_PAIRS`` (cell, segment) pairs on, else "brute". All give the same result.
    tile: static, the tiles' side in cells; max_candidates: static, K, the most candidate segments a tile
      may keep before the tiled kernel measures distances by brute force (both only for "tiled").

    Returns
      target_mask: bool[H, W], centre covered by the target (even-odd rule, or within 1e-9 s of ∂T);
      dist: f32[H, W], world units, distance to the closest boundary segment, 0 on target cells;
      tvec: f32[H, W, 2], unit (x, y) vector to the closest boundary point, (0, 0) on target cells.

    Compiles once per (H, W), segment bucket (``segment_bucket(M)``) and static options; cell_size and
    origin are traced.
    """
    if method not in ("auto", "tiled", "brute"):
        raise ValueError(f"target_geometry: method must be 'auto', 'tiled' or 'brute', got {method!r}.")
    if int(tile) < 1 or int(max_candidates) < 1:
        raise ValueError(f"target_geometry: tile and max_candidates must be >= 1, got {tile!r}, {max_candidates!r}.")
    m = int(segments.shape[0])
    padded = segment_bucket(m)
    if traced(segments):
        segments = jnp.pad(jnp.asarray(segments, jnp.float32), ((0, padded - m), (0, 0), (0, 0)))
    else:   # on the host: no small program compiled per segment count
        segments = np.pad(np.asarray(segments, np.float32), ((0, padded - m), (0, 0), (0, 0)))
    return _target_geometry(segments, np.int32(m), shape, cell_size, origin, pair_budget=pair_budget,
                            seg_chunk=seg_chunk, method=method, tile=tile, max_candidates=max_candidates)


# the process's first compilation, usually: on the paper's grids the older code generator keeps the
# newer one's compiler (and its memory) out of the process
@functools.partial(grid_jit, static_argnames=("shape", "pair_budget", "seg_chunk", "method", "tile",
                                              "max_candidates"), cells_of=_geometry_cells)
def _target_geometry(segments, n_segments, shape, cell_size, origin, pair_budget: int, seg_chunk: int,
                     method: str, tile: int, max_candidates: int):
    """:func:`target_geometry` on ``segments: f32[B, 2, 2]`` padded to a bucket, the first ``n_segments``
    (i32[]) real."""
    h, w = (int(v) for v in shape)
    cell_size = jnp.asarray(cell_size, jnp.float32)
    origin = jnp.asarray(origin, jnp.float32)
    # Work relative to the grid corner: small coordinates keep float32 rounding small.
    seg = jnp.asarray(segments, jnp.float32) - origin
    m = seg.shape[0]
    real = jnp.arange(m) < n_segments
    span = jnp.maximum(jnp.max(jnp.where(real[:, None, None], jnp.abs(seg), 0.0)), max(h, w) * cell_size)
    # the padding: zero-length segments far outside the grid, which no ray crosses and no cell has closest
    seg = jnp.where(real[:, None, None], seg, -10.0 * span)
    if method == "auto":
        method = "tiled" if h * w * m >= _TILED_MIN_PAIRS else "brute"

    if method == "brute":
        ex, ey, parity = _brute_geometry(seg, h, w, cell_size, pair_budget, seg_chunk)
    else:
        parity = _crossing_parity(seg, h, w, cell_size, pair_budget)
        n_rows, n_cols = -(-h // tile), -(-w // tile)
        # Target cells need no distance: a tile of target cells only is idle.
        busy = jnp.pad(~parity, ((0, n_rows * tile - h), (0, n_cols * tile - w)))
        busy = busy.reshape(n_rows, tile, n_cols, tile).any(axis=(1, 3)).reshape(-1)
        margin = span * _CULL_MARGIN
        chunk = min(_CANDIDATE_CHUNK, max_candidates)
        slots = -(-max_candidates // chunk) * chunk
        cand, count = _cull_tiles(seg, busy, tile, h, w, cell_size, margin, pair_budget, slots)

        def tiled(_):
            ex, ey = _tiled_offsets(seg, cand, count, tile, n_rows, n_cols, cell_size, pair_budget, chunk)
            return ex[:h, :w], ey[:h, :w]

        def brute(_):
            ex, ey, _ = _brute_geometry(seg, h, w, cell_size, pair_budget, seg_chunk)
            return ex, ey

        ex, ey = lax.cond(jnp.max(count) <= max_candidates, tiled, brute, None)

    # Distance and direction both come from the selected offset (products rounded as in _pair_terms, so
    # every method gives the same bits), and tvec has unit norm.
    zero = _opaque_zero(ex)
    dist = jnp.sqrt(_rounded(ex * ex, zero) + _rounded(ey * ey, zero))
    mask = parity | (dist <= ON_BOUNDARY_EPS * cell_size)
    safe = jnp.where(dist > 0, dist, 1.0)
    tvec = jnp.stack([ex / safe, ey / safe], axis=-1)
    tvec = jnp.where(mask[..., None], 0.0, tvec)
    dist = jnp.where(mask, 0.0, dist)
    return mask, dist, tvec
