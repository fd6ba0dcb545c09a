"""Serial reference for visibility (Section 3.1, Algorithm 1): occupied successors and the fallback hop.

Plain Python over one cell at a time, float64. Definitions follow docs/transport.md, "Visibility":

- candidates of an occupied cell ``C`` are its in-grid 8-neighbours that are occupied or target cells;
- cone rule (Eq. 1): ``t(C) . step_unit >= cos(theta_tol) - 1e-6``;
- monotone rule (Eq. 2, made strict): ``d(N, T) < d(C, T) - 1e-5 * s``;
- ``Vis(C)`` empty means a boundary fallback; its heatmap hop is the in-grid neighbour whose step
  direction best aligns with ``t(C)`` (ties to the lower direction index).

Everything here is also used, with a different forward vector and distance, for connectors
(``jaxplan.reference.connectors``), so the cone and monotone tests are small separate functions.
"""
from __future__ import annotations

import math

__all__ = [
    "DIRS", "FALLBACK", "CONE_EPS", "MONOTONE_EPS", "GATE_EPS",
    "step_unit", "step_cells", "in_grid", "cone_ok", "cos_tol", "successors", "fallback_alignments", "fallback_hop",
]

# The 8 neighbour directions as (dr, dc), in the one order used everywhere (docs/transport.md).
DIRS: tuple[tuple[int, int], ...] = (
    (-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1),
)
# Direction index that marks a boundary fallback at the end of a path (sorts after all real steps).
FALLBACK = 8

CONE_EPS = 1e-6       # absolute slack on the cone test, so exact 45-degree cases stay feasible
MONOTONE_EPS = 1e-5   # strict-decrease margin of the monotone rule, in cell sizes
GATE_EPS = 1e-6       # slack of the heatmap's near-field and forward-facing tests, in cell sizes
ALIGN_TIE_EPS = 1e-6  # fallback-hop alignments this close are ties, won by the lower direction index


def step_cells(k: int) -> float:
    """Length of step ``k`` in cells: 1 for a straight step, sqrt(2) for a diagonal one."""
    dr, dc = DIRS[k]
    return math.hypot(dr, dc)


def step_unit(k: int) -> tuple[float, float]:
    """Unit world ``(x, y)`` vector of step ``k``: ``(dc, dr) / |(dc, dr)|`` (x is the column)."""
    dr, dc = DIRS[k]
    n = math.hypot(dr, dc)
    return (dc / n, dr / n)


def in_grid(r: int, c: int, shape) -> bool:
    """Whether cell ``(r, c)`` lies inside a grid of ``shape = (H, W)``."""
    return 0 <= r < shape[0] and 0 <= c < shape[1]


def cos_tol(theta_tol_deg: float) -> float:
    """``cos(theta_tol)`` for a cone half-angle in degrees (Eq. 1's right side, before the slack)."""
    return math.cos(math.radians(float(theta_tol_deg)))


def cone_ok(forward_xy, k: int, cos_theta: float) -> bool:
    """Cone rule (Eq. 1) for step ``k`` from a cell whose forward unit vector is ``forward_xy``.

    forward_xy: ``(x, y)`` unit vector (``t(C)`` for target paths, the direction to the anchor for
    connectors). cos_theta: ``cos(theta_tol)``. The ``1e-6`` slack keeps exact boundary cases feasible.
    """
    ux, uy = step_unit(k)
    return forward_xy[0] * ux + forward_xy[1] * uy >= cos_theta - CONE_EPS


def successors(r, c, occupied, target_mask, dist, tvec, cell_size, cos_theta, monotone=True, blocked=None):
    """``Vis(C)`` for cell ``C = (r, c)`` (Algorithm 1), as a list of ``(direction, (row, col))``.

    occupied: bool[H, W] (non-target cells with obj > 0); target_mask: bool[H, W];
    dist: f64[H, W], world units, d(., T) (0 on target cells); tvec: f64[H, W, 2], unit (x, y) vector
    to the closest boundary point; cell_size: world units; cos_theta: ``cos(theta_tol)``;
    monotone: apply the strict monotone rule. blocked: optional bool[H, W]; a diagonal step may not
    pass between a blocked cell and another cell (cut its corner).

    The list is in direction order (0..7). Only occupied cells have successors; an empty list means
    the boundary fallback (see ``fallback_hop``).
    """
    shape = occupied.shape
    if not occupied[r, c]:
        return []
    forward = (float(tvec[r, c, 0]), float(tvec[r, c, 1]))
    out = []
    for k, (dr, dc) in enumerate(DIRS):
        nr, nc = r + dr, c + dc
        if not in_grid(nr, nc, shape):
            continue
        # Candidates are occupied or target cells: planning expands only through occupied cells.
        if not (occupied[nr, nc] or target_mask[nr, nc]):
            continue
        if not cone_ok(forward, k, cos_theta):
            continue
        if blocked is not None and dr and dc and (blocked[r + dr, c] or blocked[r, c + dc]):
            continue
        # Strictly closer: makes the successor graph acyclic (every step lowers d by > 1e-5 s).
        if monotone and not (dist[nr, nc] < dist[r, c] - MONOTONE_EPS * cell_size):
            continue
        out.append((k, (nr, nc)))
    return out


def fallback_alignments(r, c, forward_xy, shape) -> list:
    """``[(dot, direction, (row, col)), ...]`` for every in-grid 8-neighbour of (r, c), in direction
    order: how well each step direction aligns with ``forward_xy``."""
    out = []
    for k, (dr, dc) in enumerate(DIRS):
        nr, nc = r + dr, c + dc
        if in_grid(nr, nc, shape):
            ux, uy = step_unit(k)
            out.append((forward_xy[0] * ux + forward_xy[1] * uy, k, (nr, nc)))
    return out


def fallback_hop(r, c, forward_xy, shape):
    """Heatmap first hop of a fallback cell: ``(direction, (row, col))`` or ``None``.

    The in-grid 8-neighbour whose step direction best aligns with ``forward_xy`` (largest dot
    product; the scan in direction order keeps the first of alignments within ``ALIGN_TIE_EPS``).
    ``None`` when the grid has no neighbour (1x1 grid).
    """
    best = None
    best_dot = -math.inf
    for dot, k, cell in fallback_alignments(r, c, forward_xy, shape):
        if dot > best_dot + ALIGN_TIE_EPS:
            best, best_dot = (k, cell), dot
    return best

