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
   Every list is kept sorted, so ranks are taken by merging lists head by head (``merge_sorted``)
   rather than ranking all their entries again.

Lengths within ``1e-6 s (1 + len)`` are ties, broken by first-step direction, as in the wavefront.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan.core import lattice


def select_top_k(raw, length, key, k: int, tol):
    """The k best of M candidates by ``(raw, -length, key, index)``; lengths within ``tol`` tie.

    raw, length: M candidate planes, each ``f32[...]`` (a sequence, or an array ``[M, ...]``); key:
    M ``i32[...]`` tie-breaks (smaller first), or None when candidates are already in key order (then
    the index decides and one reduction is saved); tol: f32[...] absolute length tolerance. Returns
    ``(raw, length, key, index)``, each a list of k planes (key None when given None); unused entries
    have raw -inf, length +inf, key -1, index 0. A chosen near-tie reports the best length (it differs
    by at most ``tol``). k rounds of a lexicographic argmax: cheaper than a sort for small k.

    Candidates and results stay separate planes: reductions across them fuse with the planes'
    computation (``lattice.lead_max``) instead of reading a stored ``[M, ...]`` array with plane-sized
    strides, and each round's choice is stored once (``lattice.materialize``) so that XLA does not
    recompute the earlier rounds inside every consumer. Both measured on the 2-core CPU: the old
    stacked form was 3-5x slower at 256^2, and without ``materialize`` the rounds cost 10-40x more.
    """
    raw, length = lattice.planes(raw), lattice.planes(length)
    key = None if key is None else lattice.planes(key)
    out_raw, out_len, out_key, out_idx = [], [], [], []
    for _ in range(k):
        best_raw = lattice.lead_max(raw)
        is_best = [r == best_raw for r in raw]
        best_len = lattice.lead_min([jnp.where(b, ln, jnp.inf) for b, ln in zip(is_best, length)])
        near = [b & (ln <= best_len + tol) for b, ln in zip(is_best, length)]
        if key is not None:
            best_key = lattice.lead_min([jnp.where(n, kk, jnp.iinfo(jnp.int32).max) for n, kk in zip(near, key)])
            near = [n & (kk == best_key) for n, kk in zip(near, key)]
        idx = lattice.materialize(lattice.first_true(near))
        used = best_raw > -jnp.inf
        out_raw.append(best_raw)
        out_len.append(jnp.where(used, best_len, jnp.inf))
        out_idx.append(jnp.where(used, idx, 0))
        if key is not None:
            out_key.append(jnp.where(used, best_key, -1))
        raw = [jnp.where(idx == i, -jnp.inf, r) for i, r in enumerate(raw)]
    return out_raw, out_len, (out_key if key is not None else None), out_idx


def merge_sorted(lists, k: int, tol):
    """The k best entries of several sorted lists, as ``select_top_k`` of their concatenation.

    lists: a sequence of ``(raw, length, key)``, each a list of planes (key None in every list, or
    in none), every list already in ``select_top_k`` order (as its own output, or a constant shift of
    it). Each round then only compares the lists' heads and advances the winner's, instead of
    ranking every entry again: with n lists of m entries a round reads n heads, not n*m candidates.
    Ties go to the earlier list, which is ``select_top_k``'s index order on the concatenation.
    Returns ``(raw, length, key, list_index)``, each k planes, unused entries as ``select_top_k``'s.
    """
    lists = [(lattice.planes(r), lattice.planes(ln), None if kk is None else lattice.planes(kk)) for r, ln, kk in lists]
    keyed = lists[0][2] is not None
    taken = [None] * len(lists)           # entries already output from each list (None: none yet)
    out_raw, out_len, out_key, out_idx = [], [], [], []
    for _ in range(k):
        heads = [_head(entries, count) for entries, count in zip(lists, taken)]
        best_raw = lattice.lead_max([h[0] for h in heads])
        is_best = [h[0] == best_raw for h in heads]
        best_len = lattice.lead_min([jnp.where(b, h[1], jnp.inf) for b, h in zip(is_best, heads)])
        near = [b & (h[1] <= best_len + tol) for b, h in zip(is_best, heads)]
        if keyed:
            best_key = lattice.lead_min([jnp.where(n, h[2], jnp.iinfo(jnp.int32).max) for n, h in zip(near, heads)])
            near = [n & (h[2] == best_key) for n, h in zip(near, heads)]
        idx = lattice.materialize(lattice.first_true(near))
        used = best_raw > -jnp.inf
        out_raw.append(best_raw)
        out_len.append(jnp.where(used, best_len, jnp.inf))
        out_idx.append(jnp.where(used, idx, 0))
        if keyed:
            out_key.append(jnp.where(used, best_key, -1))
        taken = [(idx == j).astype(jnp.int32) if count is None else lattice.materialize(count + (idx == j))
                 for j, count in enumerate(taken)]
    return out_raw, out_len, (out_key if keyed else None), out_idx


def _head(entries, taken):
    """``(raw, length, key)`` planes of a sorted list's first entry not yet output (``taken`` i32
    planes, None for none); raw -inf, length +inf, key 0 past its end."""
    raw, length, key = entries
    if taken is None:
        return raw[0], length[0], None if key is None else key[0]
    head_raw, head_len, head_key = jnp.full_like(raw[0], -jnp.inf), jnp.full_like(length[0], jnp.inf), None
    if key is not None:
        head_key = jnp.zeros_like(key[0])
    for r in reversed(range(len(raw))):
        here = taken == r
        head_raw, head_len = jnp.where(here, raw[r], head_raw), jnp.where(here, length[r], head_len)
        if key is not None:
            head_key = jnp.where(here, key[r], head_key)
    return head_raw, head_len, head_key


def length_tolerance(length, cell_size):
    """Absolute tie tolerance for lengths near ``length`` (world units)."""
    return lattice.LENGTH_TIE_EPS * cell_size * (1.0 + jnp.where(jnp.isfinite(length), length, 0.0))


# ------------------------------------------------------------------------------------ policy iteration

def grid_neighbours(raw, length):
    """``neighbour(d, r) -> (raw, len)``: entry r of every cell's direction-d neighbour, read from K
    planes ``f32[H, W]`` of the whole grid by a shift (-inf / +inf off the grid)."""
    def neighbour(d, r):
        dr, dc = lattice.DIRS[d]
        return lattice.shift(raw[r], dr, dc, -jnp.inf), lattice.shift(length[r], dr, dc, jnp.inf)
    return neighbour


def step_candidates(raw, length, g, neighbour=None):
    """Every cell's 8*K + 1 candidate paths as two lists of ``f32[H, W]`` planes: a first step in
    each direction followed by each of the neighbour's K table entries (direction-major, then rank),
    then the fallback. raw, length: the table, K planes ``f32[H, W]`` each (list or ``[K, H, W]``);
    g: a ``visibility.SuccessorGraph`` (or anything with its fields, per cell); neighbour: how a
    neighbour's entry is read (default ``grid_neighbours(raw, length)``)."""
    raw, length = lattice.planes(raw), lattice.planes(length)
    neighbour = grid_neighbours(raw, length) if neighbour is None else neighbour
    cand_raw, cand_len = [], []
    for d in range(lattice.N_DIRS):
        via_cell = g.feasible[d] & ~g.enters_goal[d]
        for r in range(len(raw)):
            nb_raw, nb_len = neighbour(d, r)
            via_goal = g.enters_goal[d] if r == 0 else False
            cand_raw.append(jnp.where(via_cell, g.obj + nb_raw, jnp.where(via_goal, g.obj, -jnp.inf)))
            cand_len.append(g.step_len[d] + (jnp.where(via_goal, 0.0, nb_len) if r == 0 else nb_len))
    cand_raw.append(jnp.where(g.fallback, g.obj, -jnp.inf))
    cand_len.append(g.fallback_len)
    return cand_raw, cand_len


def best_candidate(raw, length, cell_size):
    """The best of M candidate planes by ``(raw, -length)``, near-tied lengths to the lower index:
    ``(raw, length, index)``, each a plane."""
    top_raw = lattice.lead_max(raw)
    is_top = [r == top_raw for r in raw]
    top_len = lattice.lead_min([jnp.where(t, ln, jnp.inf) for t, ln in zip(is_top, length)])
    tol = length_tolerance(top_len, cell_size)
    return top_raw, top_len, lattice.first_true([t & (ln <= top_len + tol) for t, ln in zip(is_top, length)])


def _best_step(best_raw, best_len, g, cell_size):
    return best_candidate(*step_candidates([best_raw], [best_len], g), cell_size)


def _policy_pointer(policy, g, occupied):
    """``i32[H*W + 1]`` successor of each cell under ``policy``; the sink where the path ends
    (off the occupied set, a fallback, or a step into a goal cell)."""
    into_goal = jnp.take_along_axis(g.enters_goal, jnp.clip(policy, 0, 7)[None], axis=0)[0]
    return lattice.tree_pointer(policy, ~occupied | (policy == lattice.FALLBACK) | into_goal)


def _evaluate(policy, g, occupied):
    """Raw and length ``f32[H, W]`` of following ``policy`` (0-7 step, 8 fallback) from every cell."""
    h, w = occupied.shape
    step_len = jnp.where(policy == lattice.FALLBACK, g.fallback_len, g.step_len[jnp.clip(policy, 0, 7)])
    raw = jnp.append(jnp.where(occupied, g.obj, 0.0).reshape(-1), 0.0)
    length = jnp.append(jnp.where(occupied, step_len, 0.0).reshape(-1), 0.0)
    raw, length = lattice.sum_to_sink((raw, length), _policy_pointer(policy, g, occupied))
    raw = jnp.where(occupied, raw[:-1].reshape(h, w), -jnp.inf)
    return raw, jnp.where(occupied, length[:-1].reshape(h, w), jnp.inf)


def improve_policy(start, evaluate, best_step, occupied, cell_size, max_iterations: int):
    """Policy iteration from ``start``: ``(J, L, policy, iterations)``.

    evaluate(policy) -> (raw, length) of following it; best_step(raw, length) -> (top raw, top
    length, step) against those values (``best_candidate`` of the step candidates). A final pass
    re-picks the lowest-index step among exact ties, as the wavefront does.
    """
    def improving(carry):
        return carry[2] & (carry[1] < max_iterations)

    def improve(carry):
        policy, it, _, _, _, _ = carry
        raw, length = evaluate(policy)
        top_raw, top_len, step = best_step(raw, length)
        better = (top_raw > raw) | ((top_raw == raw) & (top_len < length - length_tolerance(length, cell_size)))
        new = jnp.where(occupied & better, step, policy)
        return new, it + 1, jnp.any(new != policy), raw, length, step

    def final_pass(policy):
        raw, length = evaluate(policy)
        return raw, length, best_step(raw, length)[2]

    # the entry's values are placeholders: the loop body runs at least once
    start_carry = (start, jnp.int32(0), jnp.bool_(True), jnp.zeros(start.shape, jnp.float32),
                   jnp.zeros(start.shape, jnp.float32), start)
    policy, iterations, changed, raw, length, step = jax.lax.while_loop(improving, improve, start_carry)
    # converged: the last round already evaluated ``policy`` and picked its steps, so reuse them;
    # stopped at max_iterations with changes pending: evaluate the new policy once more
    raw, length, policy = jax.lax.cond(changed, final_pass, lambda p: (raw, length, step), policy)
    policy = lattice.materialize(policy)   # stored once: its consumers would each recompute the selection
    return raw, length, jnp.where(occupied, policy, -1), iterations


def best_paths(g, occupied, cell_size, max_iterations: int):
    """Policy iteration: ``(J f32[H,W], L f32[H,W], policy i32[H,W], iterations i32[])``.

    policy: first-step direction 0-7 of P*(C), 8 for a fallback, -1 off the occupied set.
    """
    # any successor ends somewhere, so any choice is a valid start; valuing each neighbour at its
    # own count (a one-step look-ahead, free here) starts closer to the optimum: fewer iterations
    look_ahead = jnp.where(occupied, g.obj, -jnp.inf), jnp.where(occupied, 0.0, jnp.inf)
    _, _, start = _best_step(*look_ahead, g, cell_size)
    return improve_policy(start, lambda policy: _evaluate(policy, g, occupied),
                          lambda raw, length: _best_step(raw, length, g, cell_size), occupied, cell_size,
                          max_iterations)


# ------------------------------------------------------------------------------------ K-best table

def _sidetracks_into_entry(neighbour, best_raw, best_len, policy, g, r: int, count: int, tol):
    """The ``count`` best non-tree first steps at every cell whose continuation is the neighbour's
    entry r, as losses against the cell's own best path.

    neighbour(d, r): the neighbours' entry r (exact). Returns loss raw / length and first-step
    direction, lists of ``count`` planes.
    """
    raw, length = [], []
    # off the occupied set J = -inf; keep the subtraction finite there (nothing is feasible anyway)
    occupied = best_raw > -jnp.inf
    base_raw, base_len = jnp.where(occupied, best_raw, 0.0), jnp.where(occupied, best_len, 0.0)
    for d in range(lattice.N_DIRS):
        off_tree = g.feasible[d] & (policy != d)
        via_cell = off_tree & ~g.enters_goal[d]
        nb_raw, nb_len = neighbour(d, r)
        via_goal = (off_tree & g.enters_goal[d]) if r == 0 else False
        raw.append(jnp.where(via_cell, g.obj + nb_raw, jnp.where(via_goal, g.obj, -jnp.inf)) - base_raw)
        length.append(g.step_len[d] + (jnp.where(via_goal, 0.0, nb_len) if r == 0 else nb_len) - base_len)
    # candidates in direction order, so the index is the direction tie-break
    loss_raw, loss_len, _, direction = select_top_k(raw, length, None, count, tol)
    return loss_raw, loss_len, [jnp.where(x > -jnp.inf, d, -1) for x, d in zip(loss_raw, direction)]


def _sidetrack_losses(by_entry, k: int, tol):
    """The k best non-tree first steps at every cell (losses, lists of k planes), from
    ``by_entry[r]``: the best such steps into the neighbours' entry r, for r < k.

    A step into entry r ranks behind the same step into entries 0..r-1, so it can only hold
    position r or later: the k best need only the k - r best of each ``by_entry[r]``. Merged keyed
    by direction, the earlier entry first among one direction's ties: the direction-major order of
    ranking all 8k steps at once.
    """
    if k == 1:
        return [p[:1] for p in by_entry[0]]
    lists = [tuple(p[:k - r] for p in by_entry[r]) for r in range(k)]
    loss_raw, loss_len, loss_dir, _ = merge_sorted(lists, k, tol)
    return loss_raw, loss_len, loss_dir


def _best_along_tree(loss_raw, loss_len, loss_dir, pointer, tree_dir, tol, k: int):
    """Top-k losses over each cell's tree path (itself, its successor, ...), by pointer doubling.

    loss_*: k planes ``[H, W]`` (any plane shape); pointer: i32[H*W + 1] (sink last); tree_dir:
    i32[H, W] the first step of P*, which is the first step of any path that leaves the tree further
    down. Returns lists of k planes ``[H, W]``.
    """
    shape = tree_dir.shape
    sink = tree_dir.size
    flat = lambda planes: tuple(p.reshape(-1) for p in planes)  # noqa: E731
    raw, length, direction = flat(loss_raw), flat(loss_len), flat(loss_dir)
    own_dir = [tree_dir.reshape(-1)] * k
    tol = tol.reshape(-1)
    pointer = pointer[:-1]
    # the sink (index H*W) is past the end: gathers fill it with "no loss" rather than appending an
    # entry to every plane (a concatenation would pull the selection into one fusion per output)

    def unfinished(carry):
        return jnp.any(carry[2] != sink)

    def merge(carry):
        # the loop carries raw and length as one stacked array (and directions as another), not 3k
        # planes: fewer loop buffers to copy each turn
        scores, direction, pointer = carry
        # a filled (sink) entry has raw -inf, so its length is never read
        down = [jnp.take(row, pointer, mode="fill", fill_value=-jnp.inf) for row in scores]
        # downstream exits start with P*'s step
        raw, length, direction, _ = merge_sorted([(scores[:k], scores[k:], direction),
                                                  (down[:k], down[k:], own_dir)], k, tol)
        return (jnp.stack([*raw, *length]), jnp.stack(direction),
                jnp.take(pointer, pointer, mode="fill", fill_value=sink))

    scores, direction, _ = jax.lax.while_loop(unfinished, merge, (jnp.stack([*raw, *length]), jnp.stack(direction),
                                                                   pointer))
    raw, length = scores[:k], scores[k:]
    unflat = lambda planes: [p.reshape(shape) for p in planes]  # noqa: E731
    return unflat(raw), unflat(length), unflat(direction)


def kbest_levels(best_raw, best_len, policy, g, occupied, pointer, neighbours, k: int, cell_size,
                 downstream=None):
    """The exact K-best ``(raw, length, first_dir)``, each ``[k, ...]``, from P* (module docstring).

    Level m makes entries 0..m exact: the r-th best path has at most r sidetracks, and its sidetrack
    continues with one of the neighbour's r best paths, so level m needs only the neighbours' first m
    entries and keeps m losses per cell. That makes level m cost O(m^2) per cell, not O(K^2).
    pointer: i32[N + 1] each cell's tree successor (sink last); neighbours(raw, length) -> a
    ``neighbour(d, r)`` reader of the current table (``grid_neighbours``); downstream: optional k - 1
    planes of raw and of length losses beyond the pointer's chain (entered after P*'s first step).
    """
    tol = length_tolerance(best_len, cell_size)
    table_raw, table_len, table_dir = [best_raw], [best_len], [jnp.where(occupied, policy, -1)]
    zero = jnp.zeros(policy.shape)
    by_entry = []
    for m in range(1, k):
        by_entry.append(_sidetracks_into_entry(neighbours(table_raw, table_len), best_raw, best_len, policy, g,
                                               m - 1, k - m, tol))
        loss_raw, loss_len, loss_dir = _sidetrack_losses(by_entry, m, tol)
        if downstream is not None:
            beyond_raw, beyond_len = downstream[0][:m], downstream[1][:m]
            loss_raw, loss_len, loss_dir, _ = merge_sorted(
                [(loss_raw, loss_len, loss_dir), (beyond_raw, beyond_len, [policy] * m)], m, tol)
        loss_raw, loss_len, loss_dir = _best_along_tree(loss_raw, loss_len, loss_dir, pointer, policy, tol, m)
        loss_raw, loss_len, loss_dir, _ = merge_sorted(
            [([zero], [zero], [policy]), (loss_raw, loss_len, loss_dir)], m + 1, tol)
        table_raw = [jnp.where(occupied, best_raw + r, -jnp.inf) for r in loss_raw]
        table_len = [jnp.where(r > -jnp.inf, best_len + ln, jnp.inf) for r, ln in zip(table_raw, loss_len)]
        table_dir = [jnp.where(r > -jnp.inf, d, -1) for r, d in zip(table_raw, loss_dir)]
    return jnp.stack(table_raw), jnp.stack(table_len), jnp.stack(table_dir)


def kbest_tables(best_raw, best_len, policy, g, occupied, k: int, cell_size):
    """The exact K-best table ``(raw, length, first_dir)``, each ``[k, H, W]``, from P*."""
    return kbest_levels(best_raw, best_len, policy, g, occupied, _policy_pointer(policy, g, occupied),
                        grid_neighbours, k, cell_size)
