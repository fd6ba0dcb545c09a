"""THE random-scene generator (``jaxplan.random_scene``): reproducible, as specified, named errors."""
from __future__ import annotations

import numpy as np
import pytest

from jaxplan import random_scene
from jaxplan.transport.generators import LAYOUTS


@pytest.mark.parametrize("layout", LAYOUTS)
def test_same_arguments_give_the_same_scene(layout):
    a, b = random_scene(3, (12, 15), 0.4, layout=layout), random_scene(3, (12, 15), 0.4, layout=layout)
    np.testing.assert_array_equal(np.asarray(a.obj), np.asarray(b.obj))
    np.testing.assert_array_equal(np.asarray(a.target_mask), np.asarray(b.target_mask))
    assert a.name == b.name and a.shape == (12, 15)
    c = random_scene(4, (12, 15), 0.4, layout=layout)
    assert not np.array_equal(np.asarray(a.obj), np.asarray(c.obj))


@pytest.mark.parametrize("layout", LAYOUTS)
def test_counts_are_integers_up_to_max_count_and_none_on_the_target(layout):
    scene = random_scene(0, (20, 20), 0.5, layout=layout, max_count=4)
    obj = np.asarray(scene.obj)
    assert np.all(obj == np.round(obj)) and obj.min() >= 0 and obj.max() <= 4 and obj.max() > 0
    assert not np.any(obj[np.asarray(scene.target_mask)])
    assert np.asarray(scene.target_mask).any()


def test_uniform_layout_fills_about_density_of_the_cells_around_a_central_target():
    scene = random_scene(1, (60, 60), 0.3)
    mask = np.asarray(scene.target_mask)
    occupied = np.asarray(scene.obj) > 0
    assert abs(occupied[~mask].mean() - 0.3) < 0.03
    rows, cols = np.nonzero(mask)
    assert abs(rows.mean() - 29.5) < 1 and abs(cols.mean() - 29.5) < 1
    assert mask.sum() == pytest.approx(np.pi * 6.0 ** 2, rel=0.15)   # radius max(2.5, 0.1 * 60) cells


@pytest.mark.parametrize(("kwargs", "field"), [
    (dict(shape=(2, 9)), "shape"), (dict(density=1.5), "density"), (dict(layout="rings"), "layout"),
])
def test_bad_arguments_name_the_field(kwargs, field):
    args = dict(seed=0, shape=(9, 9), density=0.4) | kwargs
    layout = args.pop("layout", "uniform")
    with pytest.raises(ValueError, match=field):
        random_scene(**args, layout=layout)
