"""Grid helpers: listing the true cells of a mask, cell positions, neighbour lists and the padded flat layout."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxplan.core import lattice

_true_indices = jax.jit(lattice.true_indices, static_argnums=1)


@settings(max_examples=30, deadline=None)
@given(n=st.sampled_from((1, 31, 32, 33, 100, 1000)), density=st.sampled_from((0.0, 0.01, 0.3, 1.0)),
       size=st.sampled_from((1, 5, 64, 1100)), seed=st.integers(0, 2**31 - 1))
def test_true_indices_equal_nonzero(n, density, size, seed):
    mask = np.random.default_rng(seed).random(n) < density
    want = np.full(size, n)
    found = np.flatnonzero(mask)[:size]
    want[: found.size] = found
    np.testing.assert_array_equal(np.asarray(_true_indices(jnp.asarray(mask), size)), want)
    np.testing.assert_array_equal(np.asarray(lattice.true_indices(jnp.asarray(mask), size)), want)   # un-jitted


def test_positions_ignore_padding():
    cells = jnp.array([4, 7, 9, 10], jnp.int32)    # 10 = H*W: padding
    got = np.asarray(lattice.positions(cells, 10, 99))
    want = np.full(11, 99)
    want[[4, 7, 9]] = [0, 1, 2]
    np.testing.assert_array_equal(got, want)


def test_lane_neighbours_match_the_grid_shift():
    h, w = 4, 5
    index = jnp.arange(h * w, dtype=jnp.int32).reshape(h, w)
    lanes = np.asarray(lattice.lane_neighbours(jnp.append(index.reshape(-1), h * w), (h, w)))
    for d, (dr, dc) in enumerate(lattice.DIRS):
        want = np.asarray(lattice.shift(index, dr, dc, h * w)).reshape(-1)
        np.testing.assert_array_equal(lanes[d, :-1], want)
    assert (lanes[:, -1] == h * w).all()


@settings(max_examples=20, deadline=None)
@given(h=st.integers(1, 7), w=st.integers(1, 7), seed=st.integers(0, 2**31 - 1))
def test_padded_rows_equal_the_grid_shift(h, w, seed):
    a = jnp.asarray(np.random.default_rng(seed).random((h, w)), jnp.float32)
    flat = lattice.pad_flat(a, -1.0)
    assert flat.shape == ((h + 2) * (w + 2),)
    for dr, dc in lattice.DIRS + ((0, 0),):
        rows = lattice.padded_rows(flat, dr, dc, (h, w))
        np.testing.assert_array_equal(np.asarray(lattice.rows_to_grid(rows, (h, w))),
                                      np.asarray(lattice.shift(a, dr, dc, -1.0)))
