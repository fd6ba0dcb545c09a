"""The K-best table of a few cells, the others' tables known: the solver of the selective rebuild.

With the monotone rule a cell's table depends only on its own count, its successor steps and its
successors' tables. After a push only the *dirty* cells (``rebuild.upstream_closure``) can change;
the others keep their old, exact tables. This module recomputes the dirty rows on a compact buffer of
``capacity`` cells with the same two steps as the full build (``jaxplan.transport.kbest``), so that its cost
grows with log(path length) passes over the buffer rather than one pass per hop:

1. **Policy iteration** for P* on the dirty cells. A step into a clean cell ends the chain there
   with that cell's old J and L, so pointer doubling runs over the buffer only. It starts from the
   old first steps, which are mostly still optimal.
2. **Sidetracks** for the other entries, level by level: the best non-tree steps of each dirty cell
   (into dirty neighbours' new entries or clean neighbours' old ones), merged along the dirty part
   of its tree path; where that path enters a clean cell X, X's own entries 1..m (as losses against
   its J) stand for every exit further down, since X's table already ranks them.

The result equals the full build's rows (tests hold rebuild and full build equal).
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.core import lattice
from jaxplan.transport import kbest
from jaxplan.transport.fabric import make_table, ranks_from_directions


class Buffer(NamedTuple):
    """The dirty cells' inputs, gathered once. C = capacity, K = table entries.

    idx: i32[C] flat cell index, H*W for padding. occupied: bool[C]. obj: f32[C] objects.
    fallback: bool[C]; fallback_len: f32[C] world units. feasible, enters_goal: bool[8, C]
    (enters_goal implies feasible). step_len: f32[8] world units. nb_dirty: bool[8, C] the neighbour
    is in the buffer, at nb_pos: i32[8, C] (clipped to the buffer). clean_raw, clean_len: f32[8, K, C]
    the old table of a clean neighbour (-inf / +inf where the neighbour is dirty or off the grid).
    Fields a ``visibility.SuccessorGraph`` also has carry its names, so ``jaxplan.transport.kbest`` reads both.
    """

    idx: jax.Array
    occupied: jax.Array
    obj: jax.Array
    fallback: jax.Array
    fallback_len: jax.Array
    feasible: jax.Array
    enters_goal: jax.Array
    step_len: jax.Array
    nb_dirty: jax.Array
    nb_pos: jax.Array
    clean_raw: jax.Array
    clean_len: jax.Array


def gather(g, cells, table_raw, table_len) -> Buffer:
    """The ``Buffer`` of the dirty cells ``cells: i32[C]`` (flat indices, ``H*W`` for padding).

    g: their rows of the new successor graph (``visibility.successor_lanes`` or ``graph_at``, fields
    ``[C]`` / ``[8, C]``); table_raw, table_len: f32[H, W, K] the old table.
    """
    h, w, k = table_raw.shape
    n = h * w
    capacity = cells.shape[0]
    nb = lattice.lane_neighbours(cells, (h, w))                            # [8, C], n = off grid
    position = lattice.positions(cells, n, capacity)
    nb_pos = position[nb]                                                # capacity = clean or off grid
    nb_dirty = nb_pos < capacity
    clean = lambda a, fill: jnp.where(nb_dirty[:, None], fill,            # noqa: E731
                                      jnp.moveaxis(lattice.take_cells(a, nb, fill), -1, 1))
    return Buffer(cells, jnp.any(g.feasible, axis=0) | g.fallback, g.obj, g.fallback, g.fallback_len, g.feasible,
                  g.enters_goal, jnp.asarray(g.step_len), nb_dirty, jnp.minimum(nb_pos, capacity - 1),
                  clean(table_raw, -jnp.inf), clean(table_len, jnp.inf))


def closed_buffer(g, cells, nb_pos, k: int) -> Buffer:
    """The ``Buffer`` of cells ``cells: i32[C]`` (flat, ``H*W`` for padding) closed under successor
    steps: every feasible step enters a listed cell or a goal cell, so no table outside is read.
    g: their successor rows (fields ``[C]`` / ``[8, C]``); nb_pos: i32[8, C] where each neighbour
    is listed, C where it is not; k: table entries."""
    capacity = cells.shape[0]
    nb_dirty = nb_pos < capacity
    return Buffer(cells, jnp.any(g.feasible, axis=0) | g.fallback, g.obj, g.fallback, g.fallback_len, g.feasible,
                  g.enters_goal, jnp.asarray(g.step_len), nb_dirty, jnp.minimum(nb_pos, capacity - 1),
                  jnp.full((lattice.N_DIRS, k, capacity), -jnp.inf), jnp.full((lattice.N_DIRS, k, capacity), jnp.inf))


def _neighbours(b: Buffer):
    """``(raw, length) -> neighbour(d, r)``: entry r of each buffer cell's direction-d neighbour, from
    the buffer's planes ``f32[C]`` when that neighbour is dirty, from its old table when not (the
    buffer's counterpart of ``kbest.grid_neighbours``)."""
    def reader(raw, length):
        def neighbour(d, r):
            pos = b.nb_pos[d]
            return (jnp.where(b.nb_dirty[d], raw[r][pos], b.clean_raw[d, r]),
                    jnp.where(b.nb_dirty[d], length[r][pos], b.clean_len[d, r]))
        return neighbour
    return reader


def _best_step(b: Buffer, raw, length, cell_size):
    """The best first step of every buffer cell given the current J and L ``f32[C]``."""
    return kbest.best_candidate(*kbest.step_candidates([raw], [length], b, _neighbours(b)([raw], [length])),
                                 cell_size)


def _along(a, policy):
    """``a[policy]`` per cell for ``a: [8, C]`` (policy clipped to 0-7)."""
    return jnp.take_along_axis(a, jnp.clip(policy, 0, 7)[None], axis=0)[0]


def _chain(b: Buffer, policy):
    """Where the policy's step leads: ``(pointer i32[C + 1], ends_clean bool[C])``. The pointer is
    the next buffer cell, the sink (C) where the path ends (fallback, goal, a clean cell, or none)."""
    capacity = policy.shape[0]
    step = b.occupied & (policy >= 0) & (policy < lattice.FALLBACK) & ~_along(b.enters_goal, policy)
    dirty_next = step & _along(b.nb_dirty, policy)
    pointer = jnp.append(jnp.where(dirty_next, _along(b.nb_pos, policy), capacity), capacity)
    return pointer.astype(jnp.int32), step & ~dirty_next


def _evaluate(b: Buffer, policy):
    """J and L ``f32[C]`` of following ``policy`` (0-7 step, 8 fallback) from every buffer cell."""
    pointer, ends_clean = _chain(b, policy)
    step_len = jnp.where(policy == lattice.FALLBACK, b.fallback_len, b.step_len[jnp.clip(policy, 0, 7)])
    tail_raw = jnp.where(ends_clean, _along(b.clean_raw[:, 0], policy), 0.0)
    tail_len = jnp.where(ends_clean, _along(b.clean_len[:, 0], policy), 0.0)
    raw = jnp.append(jnp.where(b.occupied, b.obj + tail_raw, 0.0), 0.0)
    length = jnp.append(jnp.where(b.occupied, step_len + tail_len, 0.0), 0.0)
    raw, length = lattice.sum_to_sink((raw, length), pointer)
    return jnp.where(b.occupied, raw[:-1], -jnp.inf), jnp.where(b.occupied, length[:-1], jnp.inf)


def best_paths(b: Buffer, warm_policy, cell_size, max_iterations: int):
    """Policy iteration on the buffer: ``(J f32[C], L f32[C], policy i32[C], iterations i32[])``.

    warm_policy: i32[C] a first guess (the old first steps); a step that is no longer allowed is
    replaced by the first allowed one, or the fallback where none is. Any valid policy will do, and
    the few cells that need it (next to the push) are not worth an evaluation and best-step pass.
    """
    still_ok = (warm_policy >= 0) & jnp.where(warm_policy == lattice.FALLBACK, b.fallback,
                                               _along(b.feasible, warm_policy))
    guess = lattice.first_true(list(b.feasible))          # 8 = FALLBACK where no step is allowed
    start = jnp.where(b.occupied, jnp.where(still_ok, warm_policy, guess), -1)
    return kbest.improve_policy(start, lambda policy: _evaluate(b, policy),
                                 lambda raw, length: _best_step(b, raw, length, cell_size), b.occupied, cell_size,
                                 max_iterations)


def kbest_rows(b: Buffer, best_raw, best_len, policy, k: int, cell_size):
    """The K-best rows of the buffer ``(raw, length, first_dir)``, each ``[K, C]``: the full build's
    levels, with a clean cell X entered by the tree path standing in, by its entries 1.. as losses
    against J(X), for every exit beyond it."""
    pointer, ends_clean = _chain(b, policy)
    beyond_raw = [jnp.where(ends_clean, _along(b.clean_raw[:, r] - b.clean_raw[:, 0], policy), -jnp.inf)
                  for r in range(1, k)]
    beyond_len = [jnp.where(ends_clean, _along(b.clean_len[:, r] - b.clean_len[:, 0], policy), jnp.inf)
                  for r in range(1, k)]
    return kbest.kbest_levels(best_raw, best_len, policy, b, b.occupied, pointer, _neighbours(b), k, cell_size,
                               downstream=(beyond_raw, beyond_len))


def solve_rows(b: Buffer, warm_policy, k: int, cell_size, max_iterations: int):
    """``(rows, iterations)``: the buffer cells' K-best table rows, a ``Table`` of fields ``[C, K]``
    (``best_paths`` from ``warm_policy``, then ``kbest_rows``), and the policy iterations run."""
    best_raw, best_len, policy, iterations = best_paths(b, warm_policy, cell_size, max_iterations)
    raw, length, direction = kbest_rows(b, best_raw, best_len, policy, k, cell_size)
    rank = ranks_from_directions(direction[..., None])[..., 0]
    return make_table(raw, length, direction, rank, b.enters_goal), iterations
