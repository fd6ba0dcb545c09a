"""K-best selection helpers: merging sorted lists equals ranking their concatenation."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxplan.transport import kbest

TOL = 1e-3
SHAPE = (3, 4)   # a small plane: every cell is an independent instance


def _sorted_lists(rng, n_lists: int, m: int, keyed: bool):
    """n_lists lists of m entries, each put in ``select_top_k`` order by ``select_top_k`` itself.

    Raw counts and lengths come from small sets (ties are common); lengths are whole numbers, some
    moved by a fraction of the tolerance (near-ties); some entries are unused (raw -inf)."""
    lists = []
    for _ in range(n_lists):
        raw = rng.integers(0, 4, (m, *SHAPE)).astype(np.float32)
        raw[rng.random((m, *SHAPE)) < 0.2] = -np.inf
        length = (rng.integers(1, 4, (m, *SHAPE)) + TOL * 0.3 * rng.integers(0, 2, (m, *SHAPE))).astype(np.float32)
        key = rng.integers(0, 8, (m, *SHAPE)).astype(np.int32) if keyed else None
        r, ln, kk, _ = kbest.select_top_k(jnp.asarray(raw), jnp.asarray(length),
                                           None if key is None else jnp.asarray(key), m, jnp.float32(TOL))
        lists.append((r, ln, kk))
    return lists


def _merge_and_rank(lists, k: int):
    merged = kbest.merge_sorted(lists, k, jnp.float32(TOL))
    keyed = lists[0][2] is not None
    ranked = kbest.select_top_k([r for lst in lists for r in lst[0]], [ln for lst in lists for ln in lst[1]],
                                 [kk for lst in lists for kk in lst[2]] if keyed else None, k, jnp.float32(TOL))
    return merged, ranked


@settings(max_examples=40, deadline=None)
@given(n_lists=st.integers(1, 8), m=st.integers(1, 4), k=st.integers(1, 5), keyed=st.booleans(),
       seed=st.integers(0, 2**31 - 1))
def test_merge_sorted_equals_select_top_k_of_the_concatenation(n_lists, m, k, keyed, seed):
    lists = _sorted_lists(np.random.default_rng(seed), n_lists, m, keyed)
    (raw, length, key, which), (want_raw, want_len, want_key, want_index) = _merge_and_rank(lists, k)
    np.testing.assert_array_equal(np.stack(raw), np.stack(want_raw))
    np.testing.assert_array_equal(np.stack(length), np.stack(want_len))
    if keyed:
        np.testing.assert_array_equal(np.stack(key), np.stack(want_key))
    used = np.stack(want_raw) > -np.inf
    # the concatenation is list-major: entry r of list j sits at index j * m + r
    np.testing.assert_array_equal(np.where(used, np.stack(which), 0), np.where(used, np.stack(want_index) // m, 0))


def test_merge_sorted_jitted_equals_unjitted():
    lists = _sorted_lists(np.random.default_rng(0), 3, 3, True)
    eager = kbest.merge_sorted(lists, 4, jnp.float32(TOL))
    jitted = jax.jit(lambda lists: kbest.merge_sorted(lists, 4, jnp.float32(TOL)))(lists)
    for a, b in zip(jax.tree_util.tree_leaves(eager), jax.tree_util.tree_leaves(jitted)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
