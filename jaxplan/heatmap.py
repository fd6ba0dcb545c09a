"""Propagated mass psi (Eqs. 7-8), the look-back heatmap (Eq. 10, Algorithm 3) and highways (Eq. 11)."""
from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan import _grid


def propagated_mass(value, occupied, path_next, max_hops: int):
    """``psi: f32[H, W]``, the max of J(R) over sources R whose selected path visits each cell.

    value: f32[H, W] J, objects. occupied: bool[H, W]. path_next: i32[H, W], direction (0-7) of the
    selected path's next cell, -1 where the path ends (goal entered next step counts: the goal cell is
    the next cell) or for non-sources. max_hops: static bound on path length.

    The selected paths form a forest (P*(C) = C + P*(u(C))), so instead of walking every path we push
    maxima down the forest by pointer doubling: after level k every cell holds the max over sources at
    most 2^k - 1 steps upstream. log2(longest path) scatter-max passes (capped by ``max_hops``).
    """
    h, w = value.shape
    pointer = _grid.tree_pointer(path_next, path_next < 0)       # path ends point at a sink
    mass = jnp.append(jnp.where(occupied, value, 0.0).reshape(-1), 0.0)
    return _push_max_down(mass, pointer, max_hops)[:-1].reshape(h, w)


def propagated_mass_of_entries(table, entry, occupied, max_hops: int):
    """``psi: f32[H, W]`` (Eqs. 7-8) when each source's selected path is table entry ``entry``.

    table: the K-best ``fabric.Table``; entry: i32[H, W], the selected entry of each source (Eq. 6);
    occupied: bool[H, W], the sources. Phi(R) = raw of R's selected entry. A path is a chain of
    (cell, entry) states (``next_dir``, ``next_rank``), so the chains of all states form a forest
    and the same pointer doubling as ``propagated_mass`` pushes each source's Phi down its chain;
    psi(U) is the max over U's K states. The goal cell a path steps into is its last state (entry 0
    of that cell, which no source uses). With ``entry = 0`` everywhere this equals ``propagated_mass``.
    """
    h, w, k = table.raw.shape
    n = h * w * k
    step = (table.next_dir >= 0) & (table.next_dir < _grid.FALLBACK)
    nb = _grid.neighbour_index(table.next_dir)
    state = (nb[..., 0] * w + nb[..., 1]) * k + jnp.maximum(table.next_rank, 0)
    pointer = jnp.append(jnp.where(step, state, n).reshape(-1), n).astype(jnp.int32)
    chosen = occupied[..., None] & (jnp.arange(k) == entry[..., None])
    mass = jnp.append(jnp.where(chosen, table.raw, 0.0).reshape(-1), 0.0)
    return jnp.max(_push_max_down(mass, pointer, max_hops)[:-1].reshape(h, w, k), axis=-1)


def _push_max_down(mass, pointer, max_hops: int):
    """Every node's max over the masses of the nodes upstream of it (itself included) in the forest
    ``pointer`` (i32[N + 1], the sink last and pointing to itself), by pointer doubling: after level
    k every node holds the max over nodes at most 2^k - 1 steps upstream. log2(longest chain)
    scatter-max passes, capped by ``max_hops``."""
    sink = pointer.shape[0] - 1
    levels = max(1, int(max_hops).bit_length())

    def unfinished(carry):   # stop once every chain has reached the sink (usually far below the cap)
        _, pointer, level = carry
        return jnp.any(pointer[:-1] != sink) & (level < levels)

    def level(carry):
        mass, pointer, level = carry
        mass = mass.at[pointer].max(mass)
        return mass, pointer[pointer], level + 1

    mass, _, _ = jax.lax.while_loop(unfinished, level, (mass, pointer, jnp.int32(0)))
    return mass


def heat(psi, occupied, heading, hop_len, target, cell_size):
    """``H: f32[H, W]`` look-back heatmap (Eq. 10) as an 8-neighbour stencil.

    psi: f32[H, W] objects; occupied: bool[H, W]; heading: f32[H, W, 2] unit (x, y) v(C), zero where
    u(C) is undefined; hop_len: f32[H, W] |c1 - c| world units (0 where undefined); target: bool[H, W].
    The near-field gate |x - c| <= |c1 - c| <= s*sqrt(2) means only the 8 neighbours of X can
    contribute, so each X looks back along the 8 directions at the source C = X - step.
    """
    eps = _grid.GATE_EPS * cell_size
    hx, hy = heading[..., 0], heading[..., 1]
    source_ok = occupied & (hop_len > 0)
    best = jnp.zeros_like(psi)
    # per direction: score every source C for the neighbour X = C + step, then shift the plane onto X
    # (one scalar plane per direction instead of gathering [8, H, W, 2] headings)
    for (dr, dc), (ux, uy), cells in zip(_grid.DIRS, _grid.STEP_UNIT, _grid.STEP_CELLS):
        step = float(cells) * cell_size                                     # |x - c|
        align = hx * float(ux) + hy * float(uy)                             # v(C) . unit(x - c)
        gate = source_ok & (step <= hop_len + eps) & (align * step > eps)   # forward-facing
        score = jnp.where(gate, align * psi, 0.0)
        best = jnp.maximum(best, _grid.shift(score, -dr, -dc, 0.0))
    return jnp.where(target, 0.0, best)


def _smooth(h):
    """Mean over the in-grid cells of each 3x3 block."""
    ones = jnp.ones_like(h)
    total = h + jnp.sum(_grid.neighbours(h, 0.0), axis=0)
    count = ones + jnp.sum(_grid.neighbours(ones, 0.0), axis=0)
    return total / count


def _ridge(h):
    """Non-max suppression: X survives if it is >= both neighbours along at least one of 4 axes."""
    nb = _grid.neighbours(h, 0.0)
    axes = ((3, 4), (1, 6), (0, 7), (2, 5))          # horizontal, vertical, diagonal, anti-diagonal
    return jnp.any(jnp.stack([(h >= nb[a]) & (h >= nb[b]) for a, b in axes]), axis=0)


def highways(heat_map, target, tau_h, *, relative: bool = True, smoothing: bool = False, nms: bool = False):
    """``bool[H, W]`` highway cells (Eq. 11): non-target, positive heat at or above the threshold.

    heat_map: f32[H, W] objects; target: bool[H, W]; tau_h: f32[], fraction of max heat when
    ``relative`` (static) else objects. ``smoothing`` / ``nms`` (static) as in docs/conventions.md.
    """
    h = _smooth(heat_map) if smoothing else heat_map
    threshold = tau_h * jnp.max(h) if relative else tau_h
    keep = ~target & (h > 0) & (h >= threshold)
    return keep & _ridge(h) if nms else keep
