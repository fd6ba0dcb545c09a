"""Serial reference of the affected sets of a selective rebuild (``jaxplan.transport.rebuild``)."""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from jaxplan.reference.visibility import DIRS


def upstream_closure(seed, feasible_old, feasible_new):
    """Cells that reach a ``seed`` cell through successor steps of either graph (breadth-first).

    seed: bool[H, W]; feasible_old, feasible_new: bool[H, W, 8] (direction k of the cell is a successor).
    """
    h, w = seed.shape
    edges = np.asarray(feasible_old) | np.asarray(feasible_new)
    out = np.array(seed, bool)
    queue = deque(zip(*np.nonzero(out)))
    while queue:
        r, c = queue.popleft()
        for k, (dr, dc) in enumerate(DIRS):
            pr, pc = r - dr, c - dc   # the predecessor that steps by (dr, dc) onto (r, c)
            if 0 <= pr < h and 0 <= pc < w and not out[pr, pc] and edges[pr, pc, k]:
                out[pr, pc] = True
                queue.append((pr, pc))
    return out


def a_vis(changed, occupied, tvec, cell_size, origin, theta_tol_deg):
    """Eq. 13: occupied cells C with a changed cell X such that t(C) . unit(x - c) >= cos(theta)."""
    h, w = changed.shape
    cos_t = math.cos(math.radians(theta_tol_deg)) - 1e-6
    changed_cells = list(zip(*np.nonzero(changed)))
    out = np.zeros((h, w), bool)
    for r in range(h):
        for c in range(w):
            if not occupied[r, c]:
                continue
            for xr, xc in changed_cells:
                dx, dy = (xc - c) * cell_size, (xr - r) * cell_size
                norm = math.hypot(dx, dy)
                if norm > 0 and (tvec[r, c, 0] * dx + tvec[r, c, 1] * dy) / norm >= cos_t:
                    out[r, c] = True
                    break
    return out
