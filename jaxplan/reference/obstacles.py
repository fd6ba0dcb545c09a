"""Serial reference for blocked cells: digital rays walked cell by cell, Dijkstra for the detours.

The plain twin of :func:`jaxplan.transport.obstacles.obstacle_geometry` (docs/transport.md,
"Blocked cells"). Distances are float32 sums, as in the kernel, so that the two agree exactly:
Dijkstra and the kernel's synchronous rounds reach the same fixed point ``G(C) = min over open steps
of G(N) + |step|``.
"""
from __future__ import annotations

import heapq
import math

import numpy as np

from jaxplan.reference.visibility import DIRS

__all__ = ["open_step", "reference_obstacle_geometry", "reference_detour_hops"]


def _inside(r, c, h, w):
    return 0 <= r < h and 0 <= c < w


def open_step(blocked, r, c, d) -> bool:
    """Whether the step from (r, c) in direction ``d`` stays on the grid, enters no blocked cell and,
    if diagonal, passes between two unblocked cells."""
    h, w = blocked.shape
    dr, dc = DIRS[d]
    if not _inside(r + dr, c + dc, h, w) or blocked[r + dr, c + dc]:
        return False
    return not (dr and dc and (blocked[r + dr, c] or blocked[r, c + dc]))


def _ray_step(t):
    """(dr, dc) of the digital ray from a cell with unit vector ``t = (x, y)`` (float32 rounding)."""
    tx, ty = np.float32(t[0]), np.float32(t[1])
    return int(math.floor(ty + np.float32(0.5))), int(math.floor(tx + np.float32(0.5)))


def _is_clear(blocked, target, tvec, r, c) -> bool:
    h, w = blocked.shape
    for _ in range(h * w + 1):                       # a ray that cycles among free cells is clear
        if target[r, c]:
            return True
        dr, dc = _ray_step(tvec[r, c])
        if (dr, dc) == (0, 0) or not _inside(r + dr, c + dc, h, w):
            return True
        if not open_step(blocked, r, c, DIRS.index((dr, dc))):
            return False
        r, c = r + dr, c + dc
    return True


def reference_obstacle_geometry(blocked, target_mask, dist, tvec, cell_size):
    """``(dist f32[H, W], tvec f32[H, W, 2], detour i32[H, W])`` as ``obstacle_geometry``.

    blocked, target_mask: bool[H, W]; dist: [H, W] and tvec: [H, W, 2], the straight-line geometry
    (the kernel's own, so that the comparison is exact); cell_size: world units.
    """
    blocked = np.asarray(blocked, bool)
    target = np.asarray(target_mask, bool)
    dist = np.asarray(dist, np.float32)
    tvec = np.asarray(tvec, np.float32)
    h, w = blocked.shape
    step_len = [np.float32(np.float32(math.hypot(*DIRS[d])) * np.float32(cell_size)) for d in range(8)]
    clear = np.zeros((h, w), bool)
    geo = np.full((h, w), np.inf, np.float32)
    for r in range(h):
        for c in range(w):
            if target[r, c]:
                geo[r, c] = 0.0
            elif not blocked[r, c] and _is_clear(blocked, target, tvec, r, c):
                clear[r, c] = True
                geo[r, c] = dist[r, c]
    shadow = ~blocked & ~target & ~clear
    heap = [(float(geo[r, c]), r, c) for r in range(h) for c in range(w) if np.isfinite(geo[r, c])]
    heapq.heapify(heap)
    done = np.zeros((h, w), bool)
    while heap:
        g, r, c = heapq.heappop(heap)
        if done[r, c] or g > geo[r, c]:
            continue
        done[r, c] = True
        for d, (dr, dc) in enumerate(DIRS):          # open steps are symmetric between free cells
            nr, nc = r + dr, c + dc
            if _inside(nr, nc, h, w) and shadow[nr, nc] and open_step(blocked, r, c, d):
                cand = np.float32(geo[r, c] + step_len[d])
                if cand < geo[nr, nc]:
                    geo[nr, nc] = cand
                    heapq.heappush(heap, (float(cand), nr, nc))
    out_tvec = np.where(clear[..., None], tvec, 0.0).astype(np.float32)
    detour = np.full((h, w), -1, np.int32)
    for r, c in zip(*np.nonzero(shadow & np.isfinite(geo))):
        best, best_d = np.float32(np.inf), -1
        for d, (dr, dc) in enumerate(DIRS):
            if open_step(blocked, r, c, d):
                cand = np.float32(geo[r + dr, c + dc] + step_len[d])
                if cand < best:
                    best, best_d = cand, d
        detour[r, c] = best_d
        dr, dc = DIRS[best_d]
        norm = math.hypot(dr, dc)
        out_tvec[r, c] = (np.float32(dc / norm), np.float32(dr / norm))
    return geo, out_tvec, detour


def reference_detour_hops(detour):
    """``int[H, W]``: steps along each cell's detour chain until a cell without one."""
    detour = np.asarray(detour)
    h, w = detour.shape
    hops = np.zeros((h, w), np.int64)
    for r in range(h):
        for c in range(w):
            rr, cc, n = r, c, 0
            while detour[rr, cc] >= 0 and n <= h * w:
                dr, dc = DIRS[detour[rr, cc]]
                rr, cc, n = rr + dr, cc + dc, n + 1
            hops[r, c] = n
    return hops
