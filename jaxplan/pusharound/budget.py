"""Memory bound of PushAround's pairwise geometry kernels, checked before any work starts.

The exact polygon distance (:func:`jaxplan.pusharound.kernels.pair_distances`) compares every vertex
of one convex piece with every edge of the other, on pieces packed and padded to the largest piece's
vertex count ``V``: it holds about ``PAIR_BYTES`` = 124 bytes per pair and per ``V^2`` (XLA's memory
analysis on the CPU backend, float64: 122-126 bytes for 8 to 4096 pairs and V = 16 to 1024). So
memory grows with the square of the largest piece's vertex count, and a 100,000-vertex outline would
need about 9.7 TB. The estimate (bytes):

- the W-clearance graph (:func:`jaxplan.pusharound.build_wccg`): ``16 N V`` (packing) ``+ 24 N^2``
  (the bounding-box quick pass over all N pieces) ``+ 124 P' V^2``, where ``P'`` is the number of
  piece pairs whose bounding boxes are within ``bridge_range * W`` (the pairs the exact kernel
  sees), rounded up to a power of two >= 8 as the kernel's batches are;
- the search (:func:`jaxplan.pusharound.plan_pushes`) with fixed obstacles adds the fixed-obstacle
  contact test of every simulated batch: ``124 C V'^2`` with ``V'`` the vertex count rounded up to a
  power of two >= 16 and ``C`` = :func:`touch_chunk` pairs per call (4096, halved while a call would
  take more than ``TOUCH_BYTES`` = 256 MiB, down to 8); the larger of the two counts.

:func:`check_pieces_memory` compares that with ``jaxplan.core.available_memory_bytes`` and raises a
``ValueError`` naming the total vertex count, the bytes needed, the memory available and the largest
vertex count per piece that fits.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import shapely

from jaxplan.core import available_memory_bytes

__all__ = ["PAIR_BYTES", "TOUCH_CHUNK", "MemoryEstimate", "check_pieces_memory", "estimate_pieces_bytes",
           "pair_bucket", "touch_chunk"]

PAIR_BYTES = 124    # bytes per polygon pair and per V^2 in pair_distances (measured, module docstring)
BOX_BYTES = 24      # bytes per N^2 in the bounding-box quick pass (device result, host mask and triangle)
PACK_BYTES = 16     # bytes per padded vertex (x, y in float64)
TOUCH_CHUNK = 4096  # polygon pairs per exact-distance call in the search's fixed-obstacle contact test (at most)
TOUCH_BYTES = 1 << 28   # memory one such call may take when its pieces are large [bytes]


class MemoryEstimate(NamedTuple):
    """total_vertices: vertices of all convex pieces (walls included); n_pieces: N; v_max: the largest
    piece's vertex count V; n_pairs: piece pairs within reach; bytes: the estimated peak [bytes]."""

    total_vertices: int
    n_pieces: int
    v_max: int
    n_pairs: int
    bytes: int


def pair_bucket(n: int) -> int:
    """Batch size of ``n`` polygon pairs: a power of two >= 8, so that jit compiles few shapes."""
    return max(8, 1 << (max(int(n), 1) - 1).bit_length())


def touch_chunk(v: int) -> int:
    """Polygon pairs per exact-distance call of the contact test for pieces padded to ``v`` vertices:
    ``TOUCH_CHUNK``, halved while a call would need more than ``TOUCH_BYTES``, at least 8."""
    chunk = TOUCH_CHUNK
    while chunk > 8 and PAIR_BYTES * chunk * v * v > TOUCH_BYTES:
        chunk //= 2
    return chunk


def _vertex_counts(pieces) -> np.ndarray:
    """i64[N] vertex count of each Polygon's exterior (the closing vertex not counted)."""
    if not pieces:
        return np.zeros(0, np.int64)
    rings = shapely.get_exterior_ring(np.asarray(pieces, dtype=object))
    return shapely.get_num_coordinates(rings).astype(np.int64) - 1


def _near_pairs(pieces, reach: float) -> int:
    """Number of piece pairs (i < j) whose bounding boxes are within ``reach`` [m] of each other."""
    if len(pieces) < 2:
        return 0
    b = shapely.bounds(np.asarray(pieces, dtype=object))
    boxes = shapely.box(b[:, 0], b[:, 1], b[:, 2], b[:, 3])
    i, j = shapely.STRtree(boxes).query(boxes, predicate="dwithin", distance=float(reach))
    return int(np.count_nonzero(i < j))


def _bytes(n: int, pairs: int, v: int, touch: bool) -> int:
    """The estimate of the module docstring for N pieces, P' pairs, V vertices per piece."""
    v = max(int(v), 3)
    wccg = PACK_BYTES * n * v + BOX_BYTES * n * n + PAIR_BYTES * pair_bucket(pairs) * v * v
    if not touch:
        return wccg
    vp = max(16, 1 << (v - 1).bit_length())
    return max(wccg, PAIR_BYTES * touch_chunk(vp) * vp * vp)


def estimate_pieces_bytes(pieces, reach: float, touch: bool = False) -> MemoryEstimate:
    """Estimated peak memory of the pairwise kernels on convex ``pieces`` (Polygons, walls included).

    reach: the bridge range ``bridge_range * W`` [m]; touch: add the search's fixed-obstacle contact
    test (module docstring). Cheap: vertex counts and an STRtree over the bounding boxes.
    """
    counts = _vertex_counts(pieces)
    n, v = len(counts), int(counts.max()) if len(counts) else 3
    if BOX_BYTES * n * n > 2 ** 40:   # the quick pass alone is beyond any machine: skip the pair count
        pairs = n * (n - 1) // 2
    else:
        pairs = _near_pairs(pieces, reach)
    return MemoryEstimate(int(counts.sum()), n, v, pairs, _bytes(n, pairs, v, touch))


def _size(n: int) -> str:
    for unit, scale in (("TB", 1e12), ("GB", 1e9)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n / 1e6:.0f} MB"


def _largest_fit(est: MemoryEstimate, room: int, touch: bool) -> int:
    """The largest vertex count per piece (>= 3) whose estimate fits in ``room`` bytes; 0 if none."""
    lo, hi = 2, est.v_max   # invariant: lo fits (2 means "none"), hi does not
    if _bytes(est.n_pieces, est.n_pairs, 3, touch) > room:
        return 0
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if _bytes(est.n_pieces, est.n_pairs, mid, touch) <= room else (lo, mid)
    return max(lo, 3)


def check_pieces_memory(pieces, reach: float, *, touch: bool = False, what: str = "building the W-clearance graph",
                        available: int | None = None) -> MemoryEstimate:
    """Raise ``ValueError`` when :func:`estimate_pieces_bytes` exceeds ``available`` bytes (default
    ``jaxplan.core.available_memory_bytes()``; no check when that is unknown). Returns the estimate."""
    est = estimate_pieces_bytes(pieces, reach, touch)
    room = available_memory_bytes() if available is None else int(available)
    if room is None or est.bytes <= room:
        return est
    fit = _largest_fit(est, room, touch)
    fix = (f"the largest piece that fits has {fit:,} vertices: simplify the outlines to at most {fit:,} vertices "
           "a piece (e.g. shapely.simplify at a tolerance well below the vehicle width W), or free memory"
           if fit else f"even with 3-vertex pieces it would need about "
           f"{_size(_bytes(est.n_pieces, est.n_pairs, 3, touch))}: free memory, or split the site into smaller "
           "workspaces with fewer obstacles")
    raise ValueError(f"scene: its obstacles have {est.total_vertices:,} vertices in total ({est.n_pieces:,} convex "
                     f"pieces, walls included; every piece is padded to the largest, {est.v_max:,} vertices), and "
                     f"{what} would need about {_size(est.bytes)} ({est.bytes:,} bytes), more than the "
                     f"{_size(room)} of memory available; {fix}.")
