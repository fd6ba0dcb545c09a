"""Grid helpers shared by every kernel: the 8 neighbour directions and neighbour gathers.

Direction order (see docs/transport.md) is fixed everywhere: index ``i`` of ``DIRS`` is the step
``(dr, dc)``; ``8`` marks a boundary fallback in continuation tables.
"""
from __future__ import annotations

import functools
import math

import jax
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
ALIGN_TIE_EPS = 1e-6     # fallback-hop alignments (cosines) this close are ties (to the lower direction index)


def planes(a) -> list:
    """A sequence of same-shaped planes as a list; an array ``[M, ...]`` is split along axis 0."""
    if isinstance(a, (list, tuple)):
        return list(a)
    return [a[i] for i in range(a.shape[0])]


def lead_max(a):
    """Elementwise max of M planes (a sequence, or an array ``[M, ...]``).

    A reduction over a freshly stacked axis: XLA turns it into an elementwise chain fused with the
    planes' computation. Reducing a stored ``[M, H, W]`` array instead reads it with plane-sized
    strides, unvectorised (5-10x slower at 256^2 on the CPU, measured).
    """
    return jnp.max(jnp.stack(planes(a)), axis=0)


def lead_min(a):
    """Elementwise min of M planes (see ``lead_max``)."""
    return jnp.min(jnp.stack(planes(a)), axis=0)


def materialize(index):
    """``index`` (non-negative i32) unchanged, computed once and stored rather than re-fused.

    XLA's CPU fusion copies cheap elementwise producers into every consumer; a selection round
    consumed by many planes would then be recomputed per plane (and per later round). XLA counts a
    remainder as expensive and does not duplicate it (seen in the compiled HLO: the largest fusion
    of the K-best table at 65^2 went from 979 to 369 instructions); by a modulus above any index it
    changes nothing.
    """
    return jax.lax.rem(index, jnp.int32(2**31 - 1))


def all_equal(a, b):
    """``bool[]`` whether two pytrees of arrays (e.g. tuples of planes) are equal everywhere."""
    pairs = zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b))
    return functools.reduce(jnp.logical_and, [jnp.array_equal(x, y) for x, y in pairs])


def first_true(masks):
    """``i32[...]`` index of the first true plane of M boolean planes, M where none is."""
    masks = planes(masks)
    return lead_min([jnp.where(m, jnp.int32(i), jnp.int32(len(masks))) for i, m in enumerate(masks)])


def shift(a, dr: int, dc: int, fill):
    """``out[r, c] = a[r + dr, c + dc]``, ``fill`` outside the grid. ``a: [H, W, ...]``."""
    h, w = a.shape[:2]
    pad = [(1, 1), (1, 1)] + [(0, 0)] * (a.ndim - 2)
    padded = jnp.pad(a, pad, constant_values=fill)
    return padded[1 + dr:1 + dr + h, 1 + dc:1 + dc + w]


def pad_flat(a, fill):
    """``a: [H, W]`` with a border of ``fill``, flattened: ``[(H + 2) * (W + 2)]``.

    On this layout every neighbour is a constant offset away, so the 8 neighbour reads of a stencil
    are plain slices of one array (``padded_rows``) with no bounds test per element, which XLA's
    CPU code vectorises, unlike ``shift``'s pad-and-slice per direction.
    """
    return jnp.pad(a, 1, constant_values=fill).reshape(-1)


def padded_rows(flat, dr: int, dc: int, shape):
    """The value at ``(r + dr, c + dc)`` for every position from cell (0, 0) to cell (H-1, W-1) of
    ``pad_flat``'s layout, the border columns between them included: ``[H * (W + 2) - 2]``, the
    "rows layout". Its border positions hold no cell: ``rows_to_grid`` drops them."""
    h, w = shape
    start = (w + 3) + dr * (w + 2) + dc
    return jax.lax.slice(flat, (start,), (start + h * (w + 2) - 2,))


def rows_to_grid(rows, shape):
    """The cells ``[H, W]`` of an array in the rows layout (``padded_rows``)."""
    h, w = shape
    return jnp.pad(rows, 1).reshape(h, w + 2)[:, 1:-1]


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


def centers_at(cells, shape, cell_size, origin):
    """``f32[..., 2]`` world (x, y) centre of the cells at flat indices ``cells: i32[...]``, rounded as
    ``cell_centers`` rounds them."""
    w = shape[1]
    x = ((cells % w).astype(jnp.float32) + 0.5) * cell_size + origin[0]
    y = ((cells // w).astype(jnp.float32) + 0.5) * cell_size + origin[1]
    return jnp.stack([x, y], axis=-1)


def norm_and_unit(delta):
    """Length ``[...]`` and unit vector ``[..., 2]`` of ``delta: [..., 2]`` (zero vector for zero length)."""
    norm = jnp.linalg.norm(delta, axis=-1)
    return norm, jnp.where(norm[..., None] > 0, delta / jnp.maximum(norm, 1e-30)[..., None], 0.0)


def neighbour_index(direction):
    """``i32[..., 2]`` (row, col) of the neighbour in ``direction`` (i32[H, W, ...], 0-7; other
    values give the cell itself shifted by direction 0 and must be masked by the caller)."""
    h, w = direction.shape[:2]
    extra = (1,) * (direction.ndim - 2)
    rows = jnp.arange(h).reshape((h, 1) + extra)
    cols = jnp.arange(w).reshape((1, w) + extra)
    step = jnp.asarray(DIRS_ARRAY)[jnp.clip(direction, 0, 7)]
    return jnp.stack([rows + step[..., 0], cols + step[..., 1]], -1).astype(jnp.int32)


def lane_neighbours(cells, shape):
    """``i32[8, C]`` flat index of each listed cell's neighbour in every direction; ``H*W`` off the
    grid and for padding cells (``cells: i32[C]`` flat indices, ``H*W`` for padding)."""
    h, w = shape
    rows, cols = cells // w, cells % w
    step = jnp.asarray(DIRS_ARRAY)
    nr, nc = rows[None] + step[:, 0:1], cols[None] + step[:, 1:2]
    inside = (cells[None] < h * w) & (nr >= 0) & (nr < h) & (nc >= 0) & (nc < w)
    # stored once: its many consumers would each recompute it (a smaller, faster program)
    return materialize(jnp.where(inside, nr * w + nc, h * w).astype(jnp.int32))


def lane_predecessors(cells, shape):
    """``i32[8, C]``: row d holds, for each listed cell, the neighbour that steps onto it by
    ``DIRS[d]`` (``H*W`` off the grid and for padding). DIRS is symmetric (``DIRS[7 - d] = -DIRS[d]``),
    so that is its neighbour in direction 7 - d."""
    return lane_neighbours(cells, shape)[::-1]


def append_new(listed, count, in_set, owner, stamp, found):
    """Append the distinct cells of ``found`` that are not yet in ``in_set`` to the list ``listed``.

    listed: i32[L] the list, ``count`` entries filled (slots past L are dropped; the caller compares
    the new count with L); in_set: bool[N + 1] membership, the sink N set; owner: i32[N + 1] scratch
    for the deduplication, which must only grow: ``stamp`` (i32[]) must exceed every earlier call's
    ``stamp + found.size``; found: i32[M] candidate cells, N for none. Of the lanes holding one new
    cell, the last wins. Returns ``(listed, count, in_set, owner, won: bool[M])``.
    """
    n = in_set.shape[0] - 1
    fresh = (found < n) & ~in_set[found]
    ids = stamp + jnp.arange(found.shape[0], dtype=jnp.int32)
    owner = owner.at[jnp.where(fresh, found, n)].max(ids)
    won = fresh & (owner[found] == ids)
    slot = count + jnp.cumsum(won, dtype=jnp.int32) - 1
    listed = listed.at[jnp.where(won, slot, listed.shape[0])].set(found, mode="drop")
    in_set = in_set.at[jnp.where(won, found, n)].set(True)
    return listed, count + jnp.sum(won, dtype=jnp.int32), in_set, owner, won


def positions(cells, n: int, missing: int):
    """``i32[n + 1]``: where each flat cell index sits in the list ``cells: i32[C]`` (``n`` marks
    padding), ``missing`` for cells not listed and for the padding index ``n`` itself."""
    listed = jnp.where(cells < n, cells, n + 1)           # padding would overwrite index n: drop it
    return jnp.full(n + 1, missing, jnp.int32).at[listed].set(jnp.arange(cells.shape[0], dtype=jnp.int32),
                                                              mode="drop")


def take_cells(a, cells, fill):
    """``a``'s entries at flat cell indices (``a: [H, W, ...]``, ``cells: i32[...]``), ``fill`` for
    the index ``H*W`` (padding, off the grid): ``[*cells.shape, ...]``."""
    h, w = a.shape[:2]
    return jnp.take(a.reshape((h * w,) + a.shape[2:]), cells, axis=0, mode="fill", fill_value=fill)


def true_indices(mask, size: int):
    """``i32[size]``: the indices of the first ``size`` true entries of ``mask: bool[N]``, in order,
    ``N`` where there are fewer (``jnp.nonzero(mask, size=size, fill_value=N)``).

    For sparse masks of large grids: ``jnp.nonzero`` runs a prefix sum over all N entries, which
    XLA's CPU backend makes slow (about 1 ms at N = 65,536, measured); here the prefix sum runs
    over N / 32 bit-packed words, and each output finds its word by binary search and its bit by
    halving the word five times.
    """
    n = mask.shape[0]
    bits = jnp.arange(32, dtype=jnp.uint32)
    words = jnp.sum(jnp.pad(mask, (0, (-n) % 32)).reshape(-1, 32).astype(jnp.uint32) << bits, axis=1,
                    dtype=jnp.uint32)
    count = jax.lax.population_count(words).astype(jnp.int32)
    ends = jnp.cumsum(count)                                         # true entries up to each word's end
    rank = jnp.arange(size, dtype=jnp.int32)
    word = jnp.minimum(jnp.searchsorted(ends, rank, side="right"), words.shape[0] - 1)
    within = rank - (ends[word] - count[word])                       # rank among the word's set bits
    w, bit = words[word], jnp.zeros(size, jnp.uint32)
    for half in (16, 8, 4, 2, 1):        # the wanted bit lies in the upper half when the lower is too short
        low = jax.lax.population_count((w >> bit) & jnp.uint32((1 << half) - 1)).astype(jnp.int32)
        upper = within >= low
        bit = jnp.where(upper, bit + half, bit)
        within = jnp.where(upper, within - low, within)
    return jnp.where(rank < ends[-1], word.astype(jnp.int32) * 32 + bit.astype(jnp.int32), n)


def tree_pointer(direction, stops):
    """``i32[H*W + 1]`` flat index of each cell's successor; ``H*W`` (a sink) where ``stops``.

    direction: i32[H, W] step index 0-7 (ignored where ``stops``); stops: bool[H, W].
    """
    h, w = direction.shape
    nb = neighbour_index(direction)
    sink = h * w
    return jnp.append(jnp.where(stops, sink, nb[..., 0] * w + nb[..., 1]).reshape(-1), sink).astype(jnp.int32)


def sum_to_sink(values, pointer):
    """Sum each array of ``values`` along ``pointer`` chains up to the sink (the last index).

    values: tuple of [N + 1] arrays (the sink's entry 0); pointer: i32[N + 1], the sink pointing to
    itself. Pointer doubling: log2(chain length) gather-and-add passes. Capped at enough passes for
    any simple chain, so a cyclic pointer (possible only in an unconverged table) cannot hang it.
    """
    sink = pointer.shape[0] - 1
    max_passes = max(1, sink).bit_length() + 1

    def unfinished(carry):
        return jnp.any(carry[1][:-1] != sink) & (carry[2] < max_passes)

    def double(carry):
        values, pointer, passes = carry
        return tuple(v + v[pointer] for v in values), pointer[pointer], passes + 1

    values, _, _ = jax.lax.while_loop(unfinished, double, (tuple(values), pointer, jnp.int32(0)))
    return values
