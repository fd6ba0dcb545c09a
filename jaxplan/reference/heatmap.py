"""Serial reference for psi (Eqs. 7-8), the look-back heatmap (Eq. 10, Algorithm 3) and highways (Eq. 11).

Plain Python loops, float64, following docs/transport.md ("Propagated mass", "Heatmap", "Highways").
"""
from __future__ import annotations

import math

import numpy as np

from jaxplan.reference.visibility import DIRS, FALLBACK, GATE_EPS, in_grid

__all__ = ["psi_map", "table_path", "heat_map", "smooth", "ridge", "highway_mask"]


def psi_map(paths: dict, value: np.ndarray) -> np.ndarray:
    """``psi: f64[H, W]`` (objects): Eqs. 7-8, walking every selected path.

    paths: ``{source (r, c): [cells of P*(source)]}`` (source first; the target cell the path ends in
    included). value: f64[H, W], ``J`` (objects). Every cell on the path of source ``R`` gets
    ``psi <- max(psi, J(R))``; cells on no path keep 0.
    """
    psi = np.zeros(value.shape, dtype=np.float64)
    for source, cells in paths.items():
        phi = float(value[source])        # Eq. 7: Phi(R) = raw(P*(R)) = J(R)
        for cell in cells:
            psi[cell] = max(psi[cell], phi)   # Eq. 8
    return psi


def table_path(next_dir, next_rank, source, entry) -> list:
    """The cells of the path that entry ``entry`` of ``source``'s continuation table describes.

    next_dir, next_rank: int[H, W, K] (``fabric.Table`` fields). A plain walk: from the current
    (cell, entry) take the step ``next_dir`` and continue with the next cell's entry ``next_rank``;
    stop at a fallback or an unused entry (no step), or after a step whose ``next_rank`` is -1 (it
    entered a goal cell, which is listed). Source first.
    """
    (r, c), e = source, int(entry)
    cells = [(r, c)]
    for _ in range(next_dir.size):   # a path never repeats a (cell, entry) state
        d = int(next_dir[r, c, e])
        if d < 0 or d == FALLBACK:
            return cells
        rank = int(next_rank[r, c, e])
        r, c = r + DIRS[d][0], c + DIRS[d][1]
        cells.append((r, c))
        if rank < 0:
            return cells
        e = rank
    raise ValueError("table_path: the table's pointers form a cycle")


def heat_map(occupied, first_hop, heading, psi, target_mask, cell_size) -> np.ndarray:
    """``H: f64[H, W]`` (objects), Algorithm 3 with the conventions' ``1e-6 s`` slacks.

    occupied, target_mask: bool[H, W]. first_hop: int[H, W, 2], ``(row, col)`` of ``u(C)``, -1 where
    undefined. heading: f64[H, W, 2], unit ``(x, y)`` vector ``v(C)``. psi: f64[H, W].
    cell_size: world units.

    For every non-target cell X: ``H(X) = max a(C, X) * psi(C)`` over occupied sources ``C != X`` with
    ``u(C)`` defined, ``|x - c| <= |c1 - c| + 1e-6 s`` (near-field gate) and
    ``v(C) . (x - c) > 1e-6 s`` (forward-facing), ``a = v(C) . (x - c) / |x - c|``; 0 if none.
    """
    h, w = occupied.shape
    s = float(cell_size)
    eps = GATE_EPS * s
    out = np.zeros((h, w), dtype=np.float64)
    for xr in range(h):
        for xc in range(w):
            if target_mask[xr, xc]:
                continue   # H is defined on G \ T only; 0 on target cells
            best = 0.0
            # Algorithm 3 loops over every source C. The near-field gate needs |x - c| <= |c1 - c|
            # (+1e-6 s), and |c1 - c| <= s*sqrt(2) because u(C) is an 8-neighbour of C, so a source
            # more than s*sqrt(2) + eps away can never pass it: only the 3x3 block around X is visited.
            for cr in range(xr - 1, xr + 2):
                for cc in range(xc - 1, xc + 2):
                    if not in_grid(cr, cc, (h, w)) or (cr, cc) == (xr, xc):
                        continue
                    if not occupied[cr, cc]:
                        continue
                    ur, uc = int(first_hop[cr, cc, 0]), int(first_hop[cr, cc, 1])
                    if ur < 0:
                        continue   # u(C) undefined: no cached path / velocity
                    # World (x, y) offsets: x is the column, y the row.
                    dx, dy = (xc - cc) * s, (xr - cr) * s
                    dist_x = math.hypot(dx, dy)
                    dist_hop = math.hypot((uc - cc) * s, (ur - cr) * s)
                    if dist_x > dist_hop + eps:
                        continue   # near-field gate: X lies within the first hop
                    vx, vy = float(heading[cr, cc, 0]), float(heading[cr, cc, 1])
                    forward = vx * dx + vy * dy
                    if forward <= eps:
                        continue   # forward-only: no back-flow
                    a = forward / dist_x
                    best = max(best, a * float(psi[cr, cc]))
            out[xr, xc] = best
    return out


def smooth(heat: np.ndarray) -> np.ndarray:
    """``f64[H, W]``: mean of ``heat`` over the in-grid cells of the 3x3 block around each cell."""
    h, w = heat.shape
    out = np.zeros((h, w), dtype=np.float64)
    for r in range(h):
        for c in range(w):
            vals = [heat[rr, cc] for rr in range(r - 1, r + 2) for cc in range(c - 1, c + 2)
                    if in_grid(rr, cc, (h, w))]
            out[r, c] = sum(vals) / len(vals)
    return out


# The 4 axes of the non-max suppression, each as its two opposite (dr, dc) neighbours.
_AXES = (((0, -1), (0, 1)), ((-1, 0), (1, 0)), ((-1, -1), (1, 1)), ((-1, 1), (1, -1)))


def ridge(hs: np.ndarray) -> np.ndarray:
    """``bool[H, W]``: non-max suppression; kept if ``>=`` both neighbours along at least one axis.

    Out-of-grid neighbours count as 0.
    """
    h, w = hs.shape

    def at(r, c):
        return hs[r, c] if in_grid(r, c, (h, w)) else 0.0

    out = np.zeros((h, w), dtype=bool)
    for r in range(h):
        for c in range(w):
            out[r, c] = any(hs[r, c] >= at(r + a[0], c + a[1]) and hs[r, c] >= at(r + b[0], c + b[1])
                            for a, b in _AXES)
    return out


def highway_mask(heat, target_mask, tau_h, *, relative=True, smoothing=False, nms=False) -> np.ndarray:
    """``bool[H, W]`` highway cells (Eq. 11).

    heat: f64[H, W] (objects); target_mask: bool[H, W]; tau_h: a fraction of ``max H_s`` (the
    maximum over the whole grid) when ``relative``, else objects. ``smoothing``: use the 3x3 mean
    ``H_s``; ``nms``: keep only ridge cells. Highway cells are non-target with ``H_s > 0`` and
    ``H_s >= threshold``.
    """
    hs = smooth(heat) if smoothing else np.asarray(heat, dtype=np.float64)
    threshold = float(tau_h) * float(hs.max()) if relative else float(tau_h)
    keep = ~np.asarray(target_mask, bool) & (hs > 0) & (hs >= threshold)
    if nms:
        keep &= ridge(hs)
    return keep
