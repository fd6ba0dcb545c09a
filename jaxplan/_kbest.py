"""The fast exact solver for the monotone fabric: policy iteration for P*, then the K-best table.

The plain wavefront (``fabric._wavefront_dp``) needs as many full-grid rounds as the longest path has
hops, and each round ranks 8K + 1 candidates per cell. With the monotone rule the successor graph is
a DAG, which allows two shortcuts that give the same table in far fewer grid passes:

1. **Policy iteration** for the selected paths. A policy (one successor per cell) is evaluated by
   pointer doubling along its forest (log2(hops) gathers), then every cell switches to a strictly
   better successor given those values. Values only grow, so it terminates, typically after a few
   to a few dozen iterations where the wavefront needs one round per hop of the longest path
   (``Fabric.rounds`` holds the count for either solver). A final pass re-picks the lowest-index
   successor among exact ties, as the wavefront does.
2. **Sidetracks** for the other K-1 entries (the idea of Eppstein's k-shortest paths). Every path
   from C follows the selected tree for a while, leaves it at some cell X by a non-tree step (a
   sidetrack) and continues with any path from there. Its value is J(C) plus the sidetrack's loss
   relative to J(X). The r-th best path has at most r sidetracks, so K-1 levels suffice: level m
   ranks, at every cell, the sidetracks into the neighbours' first m table entries, then takes the
   best m losses along each cell's tree path by pointer doubling (log2(hops) merges of two m-lists).

Lengths within ``1e-6 s (1 + len)`` are ties, broken by first-step direction, as in the wavefront.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan import _grid


def select_top_k(raw, length, key, k: int, tol):
    """The k best of M candidates by ``(raw, -length, key, index)``; lengths within ``tol`` tie.

    raw, length: f32[M, ...]; key: i32[M, ...] tie-break (smaller first), or None when candidates
    are already in key order (then the index decides and one reduction is saved); tol: f32[...]
    absolute length tolerance. Returns ``(raw, length, key, index)``, each ``[k, ...]`` (key None
    when given None); unused entries have raw -inf, length +inf, key -1, index 0. A chosen near-tie
    reports the best length (it differs by at most ``tol``). k rounds of a lexicographic argmax over
    whole planes: cheaper than a sort for small k, and every reduction is elementwise across cells.
    """
    m = raw.shape[0]
    positions = jnp.arange(m, dtype=jnp.int32).reshape((m,) + (1,) * (raw.ndim - 1))
    out_raw, out_len, out_key, out_idx = [], [], [], []
    for _ in range(k):
        best_raw = jnp.max(raw, axis=0)
        is_best = raw == best_raw
        best_len = jnp.min(jnp.where(is_best, length, jnp.inf), axis=0)
        near = is_best & (length <= best_len + tol)
        if key is not None:
            best_key = jnp.min(jnp.where(near, key, jnp.iinfo(jnp.int32).max), axis=0)
            near = near & (key == best_key)
        idx = jnp.min(jnp.where(near, positions, m), axis=0)
        used = best_raw > -jnp.inf
        out_raw.append(best_raw)
        out_len.append(jnp.where(used, best_len, jnp.inf))
        out_idx.append(jnp.where(used, idx, 0))
        if key is not None:
            out_key.append(jnp.where(used, best_key, -1))
        raw = jnp.where(positions == idx, -jnp.inf, raw)
    stacked_key = jnp.stack(out_key) if key is not None else None
    return jnp.stack(out_raw), jnp.stack(out_len), stacked_key, jnp.stack(out_idx)


def length_tolerance(length, cell_size):
    """Absolute tie tolerance for lengths near ``length`` (world units)."""
    return _grid.LENGTH_TIE_EPS * cell_size * (1.0 + jnp.where(jnp.isfinite(length), length, 0.0))


# ------------------------------------------------------------------------------------ policy iteration

def step_candidates(raw, length, g):
    """Every cell's 8*K + 1 candidate paths, ``f32[8K + 1, H, W]``: a first step in each direction
    followed by each of the neighbour's K table entries (direction-major, then rank), then the
    fallback. raw, length: the table, ``[K, H, W]``; g: a ``visibility.SuccessorGraph``."""
    k = raw.shape[0]
    first_rank = (jnp.arange(k) == 0)[:, None, None]
    cand_raw, cand_len = [], []
    for d, (dr, dc) in enumerate(_grid.DIRS):
        via_cell = g.feasible[d] & ~g.enters_goal[d]
        via_goal = g.enters_goal[d] & first_rank
        nb_raw = _grid.shift_planes(raw, dr, dc, -jnp.inf)
        nb_len = _grid.shift_planes(length, dr, dc, jnp.inf)
        cand_raw.append(jnp.where(via_cell, g.obj + nb_raw, jnp.where(via_goal, g.obj, -jnp.inf)))
        cand_len.append(g.step_len[d] + jnp.where(via_goal, 0.0, nb_len))
    cand_raw.append(jnp.where(g.fallback, g.obj, -jnp.inf)[None])
    cand_len.append(g.fallback_len[None])
    return jnp.concatenate(cand_raw), jnp.concatenate(cand_len)


def _best_step(best_raw, best_len, g, cell_size):
    raw, length = step_candidates(best_raw[None], best_len[None], g)
    top_raw = jnp.max(raw, axis=0)
    top_len = jnp.min(jnp.where(raw == top_raw, length, jnp.inf), axis=0)
    key = jnp.arange(9, dtype=jnp.int32)[:, None, None]
    tie = (raw == top_raw) & (length <= top_len + length_tolerance(top_len, cell_size))
    return top_raw, top_len, jnp.min(jnp.where(tie, key, 9), axis=0)


def _policy_pointer(policy, g, occupied):
    """``i32[H*W + 1]`` successor of each cell under ``policy``; the sink where the path ends
    (off the occupied set, a fallback, or a step into a goal cell)."""
    into_goal = jnp.take_along_axis(g.enters_goal, jnp.clip(policy, 0, 7)[None], axis=0)[0]
    return _grid.tree_pointer(policy, ~occupied | (policy == _grid.FALLBACK) | into_goal)


def _evaluate(policy, g, occupied):
    """Raw and length ``f32[H, W]`` of following ``policy`` (0-7 step, 8 fallback) from every cell."""
    h, w = occupied.shape
    step_len = jnp.where(policy == _grid.FALLBACK, g.fallback_len, g.step_len[jnp.clip(policy, 0, 7)])
    raw = jnp.append(jnp.where(occupied, g.obj, 0.0).reshape(-1), 0.0)
    length = jnp.append(jnp.where(occupied, step_len, 0.0).reshape(-1), 0.0)
    raw, length = _grid.sum_to_sink((raw, length), _policy_pointer(policy, g, occupied))
    raw = jnp.where(occupied, raw[:-1].reshape(h, w), -jnp.inf)
    return raw, jnp.where(occupied, length[:-1].reshape(h, w), jnp.inf)


def best_paths(g, occupied, cell_size, max_iterations: int):
    """Policy iteration: ``(J f32[H,W], L f32[H,W], policy i32[H,W], iterations i32[])``.

    policy: first-step direction 0-7 of P*(C), 8 for a fallback, -1 off the occupied set.
    """
    empty = jnp.where(occupied, 0.0, -jnp.inf), jnp.where(occupied, 0.0, jnp.inf)
    _, _, start = _best_step(*empty, g, cell_size)   # any successor ends somewhere: a valid policy

    def improving(carry):
        return carry[2] & (carry[1] < max_iterations)

    def improve(carry):
        policy, it, _ = carry
        raw, length = _evaluate(policy, g, occupied)
        top_raw, top_len, step = _best_step(raw, length, g, cell_size)
        better = (top_raw > raw) | ((top_raw == raw) & (top_len < length - length_tolerance(length, cell_size)))
        new = jnp.where(occupied & better, step, policy)
        return new, it + 1, jnp.any(new != policy)

    policy, iterations, _ = jax.lax.while_loop(improving, improve, (start, jnp.int32(0), jnp.bool_(True)))
    raw, length = _evaluate(policy, g, occupied)
    _, _, policy = _best_step(raw, length, g, cell_size)   # lowest direction among exact ties
    return raw, length, jnp.where(occupied, policy, -1), iterations


# ------------------------------------------------------------------------------------ K-best table

def _sidetrack_losses(table_raw, table_len, best_raw, best_len, policy, g, k: int, cell_size):
    """The k best non-tree first steps at every cell, as losses against its own best path.

    table_raw, table_len: f32[k, H, W], the neighbours' first k entries (exact at level k). Returns
    loss raw / length and first-step direction, ``[k, H, W]`` each.
    """
    raw, length = [], []
    rank = jnp.arange(k)[:, None, None]
    # off the occupied set J = -inf; keep the subtraction finite there (nothing is feasible anyway)
    occupied = best_raw > -jnp.inf
    base_raw, base_len = jnp.where(occupied, best_raw, 0.0), jnp.where(occupied, best_len, 0.0)
    for d, (dr, dc) in enumerate(_grid.DIRS):
        off_tree = g.feasible[d] & (policy != d)
        via_cell = off_tree & ~g.enters_goal[d]
        via_goal = off_tree & g.enters_goal[d] & (rank == 0)
        nb_raw = _grid.shift_planes(table_raw, dr, dc, -jnp.inf)
        nb_len = _grid.shift_planes(table_len, dr, dc, jnp.inf)
        raw.append(jnp.where(via_cell, g.obj + nb_raw, jnp.where(via_goal, g.obj, -jnp.inf)) - base_raw)
        length.append(g.step_len[d] + jnp.where(via_goal, 0.0, nb_len) - base_len)
    tol = length_tolerance(best_len, cell_size)
    # candidates are direction-major, so index order is the direction tie-break
    loss_raw, loss_len, _, index = select_top_k(jnp.concatenate(raw), jnp.concatenate(length), None, k, tol)
    return loss_raw, loss_len, jnp.where(loss_raw > -jnp.inf, index // k, -1)


def _best_along_tree(loss_raw, loss_len, loss_dir, pointer, tree_dir, tol, k: int):
    """Top-k losses over each cell's tree path (itself, its successor, ...), by pointer doubling.

    loss_*: [k, H, W]; pointer: i32[H*W + 1] (sink last); tree_dir: i32[H, W] the first step of P*,
    which is the first step of any path that leaves the tree further down. Returns ``[k, H, W]``.
    """
    h, w = tree_dir.shape
    flat = lambda a, fill: jnp.concatenate(  # noqa: E731
        [a.reshape(k, -1), jnp.full((k, 1), fill, a.dtype)], axis=1)
    raw, length, direction = flat(loss_raw, -jnp.inf), flat(loss_len, jnp.inf), flat(loss_dir, -1)
    own_dir = jnp.broadcast_to(jnp.append(tree_dir.reshape(-1), -1), raw.shape)
    tol = jnp.append(tol.reshape(-1), 0.0)

    def unfinished(carry):
        return jnp.any(carry[3][:-1] != h * w)

    def merge(carry):
        raw, length, direction, pointer = carry
        cand_raw = jnp.concatenate([raw, raw[:, pointer]])
        cand_len = jnp.concatenate([length, length[:, pointer]])
        cand_dir = jnp.concatenate([direction, own_dir])   # downstream exits start with P*'s step
        raw, length, direction, _ = select_top_k(cand_raw, cand_len, cand_dir, k, tol)
        return raw, length, direction, pointer[pointer]

    raw, length, direction, _ = jax.lax.while_loop(unfinished, merge, (raw, length, direction, pointer))
    unflat = lambda a: a[:, :-1].reshape(k, h, w)  # noqa: E731
    return unflat(raw), unflat(length), unflat(direction)


def kbest_tables(best_raw, best_len, policy, g, occupied, k: int, cell_size):
    """The exact K-best table ``(raw, length, first_dir)``, each ``[k, H, W]``, from P*.

    Level m makes entries 0..m exact: the r-th best path has at most r sidetracks, and its sidetrack
    continues with one of the neighbour's r best paths, so level m needs only the neighbours' first m
    entries and keeps m losses per cell. That makes level m cost O(m^2) per cell, not O(K^2).
    """
    pointer = _policy_pointer(policy, g, occupied)
    tol = length_tolerance(best_len, cell_size)
    table_raw, table_len, table_dir = best_raw[None], best_len[None], jnp.where(occupied, policy, -1)[None]
    for m in range(1, k):
        losses = _sidetrack_losses(table_raw, table_len, best_raw, best_len, policy, g, m, cell_size)
        loss_raw, loss_len, loss_dir = _best_along_tree(*losses, pointer, policy, tol, m)
        zero = jnp.zeros((1,) + policy.shape)
        loss_raw, loss_len, table_dir, _ = select_top_k(
            jnp.concatenate([zero, loss_raw]), jnp.concatenate([zero, loss_len]),
            jnp.concatenate([policy[None], loss_dir]), m + 1, tol)
        table_raw = jnp.where(occupied, best_raw + loss_raw, -jnp.inf)
        table_len = jnp.where(table_raw > -jnp.inf, best_len + loss_len, jnp.inf)
        table_dir = jnp.where(table_raw > -jnp.inf, table_dir, -1)
    return table_raw, table_len, table_dir
