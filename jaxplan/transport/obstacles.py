"""Blocked cells: the obstacle-aware distance and direction to the target, and the corner rule.

A scene's ``blocked: bool[H, W]`` marks buildings, parked equipment and no-go zones. No route,
rover or spill enters them. :func:`obstacle_geometry` turns the straight-line geometry of
:func:`jaxplan.transport.geometry.target_geometry` into one that goes around them
(``docs/transport.md``, "Blocked cells"):

- a free cell is **clear** when its *digital ray* reaches the target (or leaves the grid) without
  entering a blocked cell or cutting a blocked corner. The ray steps from a cell to the neighbour
  ``(row + floor(t_y + 1/2), col + floor(t_x + 1/2))``, ``t`` the cell's unit vector to its closest
  boundary point, so it follows the straight segment to that point within a cell;
- clear cells keep the straight-line ``d(C, T)`` and ``t(C)``;
- every other free cell gets the geodesic ``d(C, T) = min over open steps of d(N, T) + |step|``
  (the shortest chain of open steps to a clear cell, plus that cell's straight distance), its
  ``t(C)`` is the unit vector of the best such step (ties to the lower direction index), and
  ``detour`` holds that step's direction: a route that falls back from such a cell drives the
  chain of detour steps to the first clear cell, and goes straight from there;
- free cells with no open chain to the target are **cut off**: ``d = inf``, ``t = 0``. Their material
  cannot be planned; ``Scene.unreachable_mass`` counts it.

A step is **open** when it stays on the grid, enters no blocked cell and, if diagonal, cuts no
blocked cell's corner (neither of the two cells it passes between is blocked). Without blocked
cells every cell is clear and nothing changes. The serial twin is
:func:`jaxplan.reference.obstacles.reference_obstacle_geometry`.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.core import grid_jit, lattice

__all__ = ["NO_DETOUR", "corner_free", "corner_free_of", "count_detour_hops", "detour_hops", "jump_clear",
           "obstacle_geometry", "open_steps", "ray_direction"]

NO_DETOUR = -1
"""``Scene.detour`` of a cell that needs no detour (clear, target, blocked or cut-off cells)."""

_DIRS = list(lattice.DIRS)

# DIRS index of the step (dr, dc), at [(dr + 1) * 3 + (dc + 1)]; -1 for (0, 0)
_DIR_OF_OFFSET = np.full(9, -1, np.int32)
for _d, (_dr, _dc) in enumerate(lattice.DIRS):
    _DIR_OF_OFFSET[(_dr + 1) * 3 + (_dc + 1)] = _d


def corner_free(blocked):
    """``bool[8, H, W]``: the step in each direction cuts no blocked corner (always True for the four
    straight steps; a diagonal needs both cells it passes between unblocked). blocked: bool[H, W]."""
    return corner_free_of(lattice.neighbours(jnp.asarray(blocked, bool), False))


def corner_free_of(neighbour_blocked):
    """``corner_free`` from the 8 neighbours' blocked flags, ``bool[8, ...]`` in ``DIRS`` order (off
    the grid: False), for the grid or a list of cells."""
    ones = jnp.ones(neighbour_blocked.shape[1:], bool)
    return jnp.stack([~neighbour_blocked[_DIRS.index((dr, 0))] & ~neighbour_blocked[_DIRS.index((0, dc))]
                      if dr and dc else ones for dr, dc in lattice.DIRS])


def open_steps(blocked):
    """``bool[8, H, W]``: the step from each cell in each direction is open (in the grid, into an
    unblocked cell, cutting no blocked corner). blocked: bool[H, W]."""
    blocked = jnp.asarray(blocked, bool)
    return jnp.asarray(lattice.in_grid(blocked.shape)) & ~lattice.neighbours(blocked, True) & corner_free(blocked)


def ray_direction(tvec):
    """``i32[...]``: direction index (0-7) of the digital ray's step, ``(floor(t_y + 1/2), floor(t_x +
    1/2))`` as (dr, dc); -1 where ``t = 0``. tvec: f32[..., 2] unit (x, y) vectors."""
    step = jnp.floor(jnp.asarray(tvec, jnp.float32) + 0.5).astype(jnp.int32)
    return jnp.asarray(_DIR_OF_OFFSET)[(step[..., 1] + 1) * 3 + (step[..., 0] + 1)]


def _chain_pointer(direction, stop):
    """``i32[H W + 1]``: the flat index of the neighbour ``direction`` points to, or the sink ``H W``
    where ``stop``, where ``direction < 0`` or where the neighbour is off the grid."""
    h, w = stop.shape
    safe = jnp.maximum(direction, 0)
    offset = jnp.asarray(lattice.DIRS_ARRAY)[safe]
    rows, cols = jnp.meshgrid(jnp.arange(h), jnp.arange(w), indexing="ij")
    r, c = rows + offset[..., 0], cols + offset[..., 1]
    inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
    go = ~stop & (direction >= 0) & inside
    return jnp.append(jnp.where(go, r * w + c, h * w).reshape(-1), h * w).astype(jnp.int32)


def _clear_cells(blocked, target, tvec, steps_open):
    """``bool[H, W]``: free non-target cells whose digital ray meets no blocked cell or corner."""
    direction = ray_direction(tvec)
    open_ray = jnp.take_along_axis(steps_open, jnp.maximum(direction, 0)[None], axis=0)[0]
    h, w = blocked.shape
    rows, cols = jnp.meshgrid(jnp.arange(h), jnp.arange(w), indexing="ij")
    offset = jnp.asarray(lattice.DIRS_ARRAY)[jnp.maximum(direction, 0)]
    r, c = rows + offset[..., 0], cols + offset[..., 1]
    leaves_grid = (r < 0) | (r >= h) | (c < 0) | (c >= w)
    # a ray step that leaves the grid ends the ray (nothing beyond it can block); a ray cycling
    # among free cells beside the target meets no blocked cell either
    bad = ~target & (direction >= 0) & ~leaves_grid & ~open_ray
    pointer = _chain_pointer(direction, target)
    (n_bad,) = lattice.sum_to_sink((jnp.append(bad.astype(jnp.int32).reshape(-1), 0),), pointer)
    return ~blocked & ~target & (n_bad[:-1].reshape(h, w) == 0)


def _relax(start, update, steps_open, step_len):
    """Least fixed point of ``G(C) = min(G(C), min over open steps d of G(N_d) + step_len[d])`` on the
    ``update`` cells, from ``start`` (synchronous rounds until nothing changes)."""
    def candidates(g):
        return jnp.stack([jnp.where(steps_open[d], lattice.shift(g, dr, dc, jnp.inf) + step_len[d], jnp.inf)
                          for d, (dr, dc) in enumerate(lattice.DIRS)])

    def body(carry):
        g, _ = carry
        new = jnp.where(update, jnp.minimum(g, jnp.min(candidates(g), axis=0)), g)
        return new, jnp.any(new != g)

    g, _ = jax.lax.while_loop(lambda carry: carry[1], body, (start, jnp.bool_(True)))
    return g, candidates(g)


@grid_jit
def obstacle_geometry(blocked, target_mask, dist, tvec, cell_size):
    """Distance, direction and detour of every cell around blocked cells (module docstring).

    blocked: bool[H, W]; target_mask: bool[H, W] (no cell both); dist: f32[H, W] world units and
    tvec: f32[H, W, 2] unit (x, y), the straight-line geometry of ``target_geometry``;
    cell_size: f32[], world units.

    Returns
      dist: f32[H, W], world units: straight on clear cells, geodesic on detour cells, 0 on target
        cells, +inf on blocked and cut-off cells;
      tvec: f32[H, W, 2]: straight on clear cells, the detour step's unit vector on detour cells,
        (0, 0) elsewhere;
      detour: i32[H, W], the detour step's direction (0-7) on detour cells, ``NO_DETOUR`` elsewhere.
    """
    blocked = jnp.asarray(blocked, bool)
    target = jnp.asarray(target_mask, bool)
    dist = jnp.asarray(dist, jnp.float32)
    tvec = jnp.asarray(tvec, jnp.float32)
    steps_open = open_steps(blocked)
    clear = _clear_cells(blocked, target, tvec, steps_open)
    step_len = jnp.asarray(lattice.STEP_CELLS) * jnp.asarray(cell_size, jnp.float32)
    start = jnp.where(target, 0.0, jnp.where(clear, dist, jnp.inf))
    shadow = ~blocked & ~target & ~clear
    geo, cand = _relax(start, shadow, steps_open, step_len)
    # the first direction reaching the minimum: ties to the lower index
    best = jnp.argmin(cand, axis=0).astype(jnp.int32)
    detour = shadow & jnp.isfinite(geo)
    new_tvec = jnp.where(clear[..., None], tvec,
                         jnp.where(detour[..., None], jnp.asarray(lattice.STEP_UNIT)[best], 0.0))
    return geo, new_tvec, jnp.where(detour, best, NO_DETOUR)


def jump_clear(blocked, a, b):
    """bool[]: the straight jump from cell ``a`` to cell ``b`` (i32[2] each, (row, col)) is open: every
    cell of its Chebyshev walk ``a + round(k (b - a) / D)``, k = 0..D (D = max(|b - a|), halves
    rounded up), is unblocked and no step between two of them cuts a blocked corner. A connector
    that ends with such a jump to its anchor may be driven only when it is clear. blocked: bool[H, W]."""
    h, w = blocked.shape
    a, b = jnp.asarray(a, jnp.int32), jnp.asarray(b, jnp.int32)
    d = jnp.maximum(jnp.max(jnp.abs(b - a)), 1)
    k = jnp.arange(max(h, w) + 1, dtype=jnp.int32)
    cells = a[None] + jnp.floor_divide(2 * k[:, None] * (b - a)[None] + d, 2 * d)
    cells = jnp.where((k <= d)[:, None], cells, b[None])                        # past the end: stay on b
    at = lambda r, c: blocked[jnp.clip(r, 0, h - 1), jnp.clip(c, 0, w - 1)]  # noqa: E731
    prev = jnp.concatenate([cells[:1], cells[:-1]])
    cut = at(prev[:, 0], cells[:, 1]) | at(cells[:, 0], prev[:, 1])              # the two cells a diagonal passes
    return ~jnp.any(at(cells[:, 0], cells[:, 1]) | cut)


def count_detour_hops(detour):
    """``i32[H, W]``: steps of each cell's detour chain to its first clear (or target) cell; 0 where
    ``detour`` is ``NO_DETOUR``. Pointer doubling."""
    h, w = detour.shape
    pointer = _chain_pointer(detour, jnp.zeros(detour.shape, bool))
    (hops,) = lattice.sum_to_sink((jnp.append((detour >= 0).astype(jnp.int32).reshape(-1), 0),), pointer)
    return hops[:-1].reshape(h, w)


detour_hops = grid_jit(count_detour_hops)
