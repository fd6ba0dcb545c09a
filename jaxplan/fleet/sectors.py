"""Where rovers start and which cells each may work: the ``partitioned`` strategy's sectors and the
default start cells (docs/fleet.md, "Strategies").

``sectors`` cuts the grid into near-square bands, one per rover; ``sector_starts`` puts rover i in
sector i, ``spread_starts`` spreads the rovers along the grid's border for the other strategies.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["band_counts", "sector_grid", "sector_starts", "sectors", "spread_starts"]


def sector_grid(n: int) -> tuple[int, int]:
    """``(rows, cols)`` of the sector grid for n rovers: rows = the largest divisor of n that is at
    most sqrt(n), so the sectors are as near square as n allows (a prime n gives vertical strips)."""
    rows = max(d for d in range(1, int(np.sqrt(n)) + 1) if n % d == 0)
    return rows, n // rows


def band_counts(shape, n: int) -> list[int]:
    """Sectors in each horizontal band of the grid, top to bottom (they sum to n).

    ``sector_grid(n)`` when its bands and columns fit the grid (``rows <= H``, ``cols <= W``): equal
    bands of equal sectors. Otherwise (a prime n wider than the grid, say) the bands are as many as
    keep the sectors near square, at least ``ceil(n / W)`` and at most H and n, and their sector counts
    differ by at most one, so that every sector holds a cell. n must be in [1, H W]."""
    h, w = shape
    if not 1 <= n <= h * w:
        raise ValueError(f"n_rovers: {n} sectors cannot be cut from a {h} x {w} grid; use at most {h * w} rovers.")
    rows, cols = sector_grid(n)
    if rows <= h and cols <= w:
        return [cols] * rows
    rows = int(min(h, n, max(-(-n // w), round(np.sqrt(n * h / w)))))
    return [n // rows + (i < n % rows) for i in range(rows)]


def sectors(shape, n: int) -> np.ndarray:
    """i32[H, W]: the sector of every cell for ``partitioned`` with n rovers, numbered row-major:
    ``band_counts`` bands of equal height (up to one cell), each cut into its count of sectors of equal
    width (up to one cell). Every sector holds at least one cell."""
    h, w = shape
    counts = band_counts(shape, n)
    band_of_row = (np.arange(h) * len(counts)) // h
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out = np.empty((h, w), np.int32)
    for r in range(h):
        b = band_of_row[r]
        out[r] = first[b] + (np.arange(w) * counts[b]) // w
    return out


def _border_order(shape) -> np.ndarray:
    """i32[H W]: flat cell indices, the border clockwise from (0, 0) first, then the rest row-major."""
    h, w = shape
    ring = [(0, c) for c in range(w)] + [(r, w - 1) for r in range(1, h)]
    ring += [(h - 1, c) for c in range(w - 2, -1, -1)] if h > 1 else []
    ring += [(r, 0) for r in range(h - 2, 0, -1)] if w > 1 else []
    seen, order = set(), []
    for r, c in ring:
        if (r, c) not in seen:
            seen.add((r, c))
            order.append(r * w + c)
    order += [i for i in range(h * w) if (i // w, i % w) not in seen]
    return np.asarray(order, np.int32)


def spread_starts(target_mask, n: int):
    """i32[N, 2]: n distinct cells outside ``target_mask`` (bool[H, W]: the targets, and any other cell
    a rover may not start on), spread evenly along the grid's border (clockwise from the top-left
    corner; the interior row-major where the border has too few). The grid must have at least n
    cells outside the mask."""
    h, w = target_mask.shape
    order = jnp.asarray(_border_order((h, w)))
    border = jnp.arange(h * w) < (2 * (h + w) - 4 if h > 1 and w > 1 else h * w)
    ok = ~target_mask.reshape(-1)[order]
    listed = order[jnp.nonzero(ok, size=h * w, fill_value=0)[0]]
    k_border = jnp.sum(ok & border)
    k = jnp.where(k_border >= n, k_border, jnp.sum(ok))
    pick = (jnp.arange(n) * k) // n
    flat = listed[pick]
    return jnp.stack([flat // w, flat % w], -1).astype(jnp.int32)


def sector_starts(target_mask, region: np.ndarray):
    """i32[N, 2]: for each sector i of ``region`` (a concrete i32[H, W], ``sectors``), the cell outside
    ``target_mask`` (as in ``spread_starts``) nearest the sector's centre (ties: row-major), chosen
    in sector order among cells not yet taken; a sector with no such cell takes the nearest free cell
    outside it."""
    h, w = target_mask.shape
    region = np.asarray(region)
    n = int(region.max()) + 1
    rows, cols = np.meshgrid(np.arange(h, dtype=np.float32), np.arange(w, dtype=np.float32), indexing="ij")
    centres = np.asarray([(rows[region == i].mean(), cols[region == i].mean()) for i in range(n)], np.float32)
    inside = region[None] == np.arange(n)[:, None, None]
    cost = (rows[None] - centres[:, 0, None, None]) ** 2 + (cols[None] - centres[:, 1, None, None]) ** 2
    cost = jnp.asarray(np.where(inside, cost, cost + 1e9), jnp.float32)

    def one(i, carry):
        taken, out = carry
        flat = jnp.argmin(jnp.where(target_mask | taken, jnp.inf, cost[i]).reshape(-1))
        cell = jnp.stack([flat // w, flat % w]).astype(jnp.int32)
        return taken.at[cell[0], cell[1]].set(True), out.at[i].set(cell)

    _, out = jax.lax.fori_loop(0, n, one, (jnp.zeros((h, w), bool), jnp.zeros((n, 2), jnp.int32)))
    return out
