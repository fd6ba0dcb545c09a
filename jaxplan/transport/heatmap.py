"""Propagated mass psi (Eqs. 7-8), the look-back heatmap (Eq. 10, Algorithm 3) and highways (Eq. 11)."""
from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan.core import lattice


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
    pointer = lattice.tree_pointer(path_next, path_next < 0)       # path ends point at a sink
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
    step = (table.next_dir >= 0) & (table.next_dir < lattice.FALLBACK)
    nb = lattice.neighbour_index(table.next_dir)
    state = (nb[..., 0] * w + nb[..., 1]) * k + jnp.maximum(table.next_rank, 0)
    pointer = jnp.append(jnp.where(step, state, n).reshape(-1), n).astype(jnp.int32)
    chosen = occupied[..., None] & (jnp.arange(k) == entry[..., None])
    mass = jnp.append(jnp.where(chosen, table.raw, 0.0).reshape(-1), 0.0)
    return jnp.max(_push_max_down(mass, pointer, max_hops)[:-1].reshape(h, w, k), axis=-1)


def repropagated_mass(psi, value, old_pointer, new_pointer, changed, cells, size: int, max_hops: int):
    """psi after the selected paths of some cells changed, recomputed only where it can change.

    psi: f32[H, W] before; value: f32[H, W] J after (0 off the occupied set); old_pointer,
    new_pointer: i32[H*W] each cell's next cell on its selected path before and after (``H*W`` where
    the path ends), equal outside ``changed``; changed: bool[H, W], the cells whose path or value
    changed, listed in ``cells: i32[C]`` (``H*W`` padding). Returns ``(psi f32[H, W], touched
    i32[C + size], count i32[])``: the cells recomputed (``H*W`` padding) and how many; count >
    C + size means ``size`` was too small and psi is not valid.

    psi changes only on the old and new paths of the changed cells: the changed cells themselves and
    the unchanged cells downstream of them, found by walking the (shared) pointers until the walks
    merge. On that set S the max-propagation runs again by pointer doubling, each cell of S starting
    from its own J and from the old psi of its predecessors outside S (their subtrees did not change).
    """
    h, w = psi.shape
    n = h * w
    lanes = cells.shape[0]
    start = jnp.concatenate([jnp.take(old_pointer, cells, mode="fill", fill_value=n),
                             jnp.take(new_pointer, cells, mode="fill", fill_value=n)])

    def walking(carry):
        pos, _, count, _, _, _ = carry
        return jnp.any(pos < n) & (count <= size)

    def step(carry):
        pos, walked, count, in_s, owner, it = carry
        # walks reaching one cell together continue as one; a walk into S stops (S is ahead of it)
        walked, count, in_s, owner, won = lattice.append_new(walked, count, in_s, owner, it * pos.shape[0], pos)
        nxt = jnp.where(won, jnp.take(new_pointer, pos, mode="fill", fill_value=n), n)
        return nxt, walked, count, in_s, owner, it + 1

    carry = (start, jnp.full(size, n, jnp.int32), jnp.int32(0), jnp.append(changed.reshape(-1), True),
             jnp.full(n + 1, -1, jnp.int32), jnp.int32(0))
    _, walked, count, _, _, _ = jax.lax.while_loop(walking, step, carry)
    touched = jnp.concatenate([cells, walked])
    total = touched.shape[0]
    position = lattice.positions(touched, n, total)
    inside = position < total
    pointer = position[jnp.take(new_pointer, touched, mode="fill", fill_value=n)]
    # a predecessor outside S keeps its subtree, hence its old psi
    pred = lattice.lane_predecessors(touched, (h, w))
    feeds = (jnp.take(new_pointer, pred, mode="fill", fill_value=n) == touched[None]) & ~inside[pred]
    inflow = jnp.max(jnp.where(feeds, lattice.take_cells(psi, pred, 0.0), 0.0), axis=0)
    mass = jnp.maximum(lattice.take_cells(value, touched, 0.0), inflow)
    new = _push_max_down(jnp.append(mass, 0.0), jnp.append(pointer, total).astype(jnp.int32), max_hops)[:-1]
    psi = psi.reshape(-1).at[touched].set(new, mode="drop").reshape(h, w)
    return psi, touched, lanes + count


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
    shape = psi.shape
    # per direction: score every source C, then read the score of X's source by a constant offset
    # (``lattice.pad_flat``; the padded grid scores 0, as psi is 0 there)
    fields = [lattice.pad_flat(a, 0.0) for a in (_source_mass(psi, occupied, hop_len), heading[..., 0], heading[..., 1],
                                                hop_len)]
    best = None
    for d, (dr, dc) in enumerate(lattice.DIRS):
        at_x = lattice.padded_rows(_look_back(d, *fields, cell_size), -dr, -dc, shape)
        best = at_x if best is None else jnp.maximum(best, at_x)
    return jnp.where(target, 0.0, jnp.maximum(lattice.rows_to_grid(best, shape), 0.0))


def heat_at(cells, psi, occupied, heading, hop_len, target, cell_size):
    """``heat`` at a list of cells (``cells: i32[C]`` flat, ``H*W`` for padding): ``f32[C]``, the
    same values, each reading only its 8 neighbours."""
    source = lattice.lane_predecessors(cells, psi.shape)
    best = jnp.zeros(cells.shape, psi.dtype)
    for d in range(lattice.N_DIRS):
        at = lambda a, fill: lattice.take_cells(a, source[d], fill)  # noqa: E731, B023
        heading_at, hop_at = at(heading, 0.0), at(hop_len, 0.0)
        score = _look_back(d, _source_mass(at(psi, 0.0), at(occupied, False), hop_at), heading_at[..., 0],
                           heading_at[..., 1], hop_at, cell_size)
        best = jnp.maximum(best, score)
    return jnp.where(lattice.take_cells(target, cells, True), 0.0, best)


def _source_mass(psi, occupied, hop_len):
    """psi(C) where C can be a source of the look-back (occupied, with a first hop), else 0."""
    return jnp.where(occupied & (hop_len > 0), psi, 0.0)


def _look_back(d: int, mass, heading_x, heading_y, hop_len, cell_size):
    """What a source C (fields elementwise: ``_source_mass``, the components of v(C), the first
    hop's length) gives the neighbour it steps onto by ``DIRS[d]``: align * psi(C) when that
    neighbour is within its first hop and ahead of it (Eq. 10), else 0."""
    eps = lattice.GATE_EPS * cell_size
    ux, uy = (float(u) for u in lattice.STEP_UNIT[d])
    step = float(lattice.STEP_CELLS[d]) * cell_size                       # |x - c|
    align = heading_x * ux + heading_y * uy                             # v(C) . unit(x - c)
    gate = (step <= hop_len + eps) & (align * step > eps)               # forward-facing
    return jnp.where(gate, align * mass, 0.0)


def smooth_3x3(h):
    """Mean over the in-grid cells of each 3x3 block."""
    ones = jnp.ones_like(h)
    total = h + jnp.sum(lattice.neighbours(h, 0.0), axis=0)
    count = ones + jnp.sum(lattice.neighbours(ones, 0.0), axis=0)
    return total / count


def _ridge(h):
    """Non-max suppression: X survives if it is >= both neighbours along at least one of 4 axes."""
    nb = lattice.neighbours(h, 0.0)
    axes = ((3, 4), (1, 6), (0, 7), (2, 5))          # horizontal, vertical, diagonal, anti-diagonal
    return jnp.any(jnp.stack([(h >= nb[a]) & (h >= nb[b]) for a, b in axes]), axis=0)


def highways(heat_map, target, tau_h, *, relative: bool = True, smoothing: bool = False, nms: bool = False):
    """``bool[H, W]`` highway cells (Eq. 11): non-target, positive heat at or above the threshold.

    heat_map: f32[H, W] objects; target: bool[H, W]; tau_h: f32[], fraction of max heat when
    ``relative`` (static) else objects. ``smoothing`` / ``nms`` (static) as in docs/transport.md.
    """
    h = smooth_3x3(heat_map) if smoothing else heat_map
    threshold = tau_h * jnp.max(h) if relative else tau_h
    keep = ~target & (h > 0) & (h >= threshold)
    return keep & _ridge(h) if nms else keep
