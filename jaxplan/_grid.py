"""Grid helpers shared by every kernel: the 8 neighbour directions and neighbour gathers.

Direction order (see docs/conventions.md) is fixed everywhere: index ``i`` of ``DIRS`` is the step
``(dr, dc)``; ``8`` marks a boundary fallback in continuation tables.
"""
from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

DIRS: tuple[tuple[int, int], ...] = (
    (-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1),
)
FALLBACK = 8
N_DIRS = 8

# Unit step vectors in world (x, y) = (dc, dr) / |(dc, dr)|, and step lengths in cells.
STEP_UNIT = np.array([(dc / math.hypot(dr, dc), dr / math.hypot(dr, dc)) for dr, dc in DIRS],
                     dtype=np.float32)
STEP_CELLS = np.array([math.hypot(dr, dc) for dr, dc in DIRS], dtype=np.float32)
DIRS_ARRAY = np.array(DIRS, dtype=np.int32)

CONE_EPS = 1e-6          # absolute slack on the cone test (Eq. 1)
MONOTONE_EPS = 1e-5      # strict-decrease margin of the monotone rule, in cell sizes
LENGTH_TIE_EPS = 1e-6  # path lengths this close (relative, in cell sizes) are ties
GATE_EPS = 1e-6          # near-field / forward-facing slack of the heatmap, in cell sizes


def shift(a, dr: int, dc: int, fill):
    """``out[r, c] = a[r + dr, c + dc]``, ``fill`` outside the grid. ``a: [H, W, ...]``."""
    h, w = a.shape[:2]
    pad = [(1, 1), (1, 1)] + [(0, 0)] * (a.ndim - 2)
    padded = jnp.pad(a, pad, constant_values=fill)
    return padded[1 + dr:1 + dr + h, 1 + dc:1 + dc + w]


def shift_planes(a, dr: int, dc: int, fill):
    """``out[..., r, c] = a[..., r + dr, c + dc]``, ``fill`` outside. ``a: [..., H, W]`` (no transposes)."""
    h, w = a.shape[-2:]
    pad = [(0, 0)] * (a.ndim - 2) + [(1, 1), (1, 1)]
    padded = jnp.pad(a, pad, constant_values=fill)
    return padded[..., 1 + dr:1 + dr + h, 1 + dc:1 + dc + w]


def neighbours(a, fill):
    """All 8 neighbour gathers stacked on a leading axis: ``[8, H, W, ...]`` (``DIRS`` order)."""
    return jnp.stack([shift(a, dr, dc, fill) for dr, dc in DIRS])


def sources_of(a, fill):
    """For each cell X and direction i, the value at the cell C with ``X = C + DIRS[i]``.

    The heatmap looks back from X to the sources that step toward it: ``[8, H, W, ...]``.
    """
    return jnp.stack([shift(a, -dr, -dc, fill) for dr, dc in DIRS])


def in_grid(shape) -> np.ndarray:
    """``bool[8, H, W]``: whether the neighbour in each direction lies inside the grid."""
    h, w = shape
    ones = np.ones((h, w), dtype=bool)
    out = np.zeros((N_DIRS, h, w), dtype=bool)
    for i, (dr, dc) in enumerate(DIRS):
        padded = np.pad(ones, 1, constant_values=False)
        out[i] = padded[1 + dr:1 + dr + h, 1 + dc:1 + dc + w]
    return out


def cell_centers(shape, cell_size, origin):
    """``f32[H, W, 2]`` world (x, y) centre of every cell."""
    h, w = shape
    cols = (jnp.arange(w, dtype=jnp.float32) + 0.5) * cell_size + origin[0]
    rows = (jnp.arange(h, dtype=jnp.float32) + 0.5) * cell_size + origin[1]
    x, y = jnp.meshgrid(cols, rows)
    return jnp.stack([x, y], axis=-1)
