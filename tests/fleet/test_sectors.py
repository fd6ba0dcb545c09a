"""Sectors and start cells (``jaxplan.fleet.sectors``): every allowed rover count on every grid shape
gets n non-empty sectors, one start cell each, all distinct and outside the targets."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxplan import builtin_scene
from jaxplan.fleet import FleetConfig, reset
from jaxplan.fleet.sectors import band_counts, sector_starts, sectors


@st.composite
def grids(draw):
    h, w = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    return (h, w), draw(st.integers(1, h * w))


@settings(max_examples=200, deadline=None)
@given(grids())
def test_every_rover_count_gets_its_own_non_empty_sector(grid):
    shape, n = grid
    region = sectors(shape, n)
    assert region.shape == shape and region.dtype == np.int32
    assert np.array_equal(np.unique(region), np.arange(n))
    counts = band_counts(shape, n)
    assert sum(counts) == n and 1 <= len(counts) <= shape[0] and min(counts) >= 1 and max(counts) <= shape[1]


@settings(max_examples=60, deadline=None)
@given(grids(), st.integers(0, 2**16))
def test_start_cells_are_distinct_and_outside_the_targets(grid, seed):
    shape, n = grid
    target = np.random.default_rng(seed).random(shape) < 0.3
    free = int((~target).sum())
    if free < n:
        target[:] = False
    starts = np.asarray(sector_starts(target, sectors(shape, n)))
    assert starts.shape == (n, 2)
    assert len({tuple(c) for c in starts}) == n
    assert not target[starts[:, 0], starts[:, 1]].any()


def test_factorable_rover_counts_keep_the_equal_grid():
    assert band_counts((25, 25), 12) == [4, 4, 4]
    np.testing.assert_array_equal(sectors((4, 4), 4), np.repeat(np.repeat([[0, 1], [2, 3]], 2, 0), 2, 1))


def test_more_sector_columns_than_grid_columns_is_not_a_crash():
    """The defect: 31 partitioned rovers on the 25 x 25 default scene (a prime n, one band of 31
    columns) ended in a TypeError, shapes (30, 2) vs (31, 2)."""
    state = reset(builtin_scene("default"), config=FleetConfig(31, "partitioned"), max_steps=5)
    pos = np.asarray(state.rovers.pos)
    assert pos.shape == (31, 2) and len({tuple(c) for c in pos}) == 31


def test_more_sectors_than_cells_is_a_named_error():
    with pytest.raises(ValueError, match="n_rovers: 10 sectors"):
        sectors((3, 3), 10)
