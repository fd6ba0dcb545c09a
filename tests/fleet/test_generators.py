"""The built-in fleet sites: deterministic, the documented sizes, two to eight targets, material to move,
buildings on site1024 that hold no material and cut no free cell off."""
from __future__ import annotations

import numpy as np
import pytest

from jaxplan.fleet import SITES, site
from jaxplan.fleet.generators import MAX_COUNT, build_site

EXPECTED = {"site128": (128, 2), "site256": (256, 3), "site512": (512, 4), "site1024": (1024, 8)}


def _arrays(scene):
    return {k: np.asarray(getattr(scene, k)) for k in ("obj", "target_mask", "dist", "tvec")}


def test_sites_are_the_documented_four():
    assert SITES == tuple(EXPECTED)


def test_a_site_is_the_same_arrays_every_time_it_is_built():
    first, second = _arrays(build_site("site128")), _arrays(build_site("site128"))
    for key in first:
        np.testing.assert_array_equal(first[key], second[key], err_msg=key)
    cached = _arrays(site("site128"))
    for key in first:
        np.testing.assert_array_equal(first[key], cached[key], err_msg=key)
    assert site("site128") is site("site128")


@pytest.mark.parametrize("name", list(EXPECTED))
def test_site_shape_targets_and_mass(name):
    side, n_targets = EXPECTED[name]
    scene = site(name)
    assert scene.shape == (side, side)
    assert scene.name == name
    polygons = list(scene.target.geoms)
    assert 2 <= len(polygons) == n_targets <= 8
    mask = np.asarray(scene.target_mask)
    for i, poly in enumerate(polygons):
        # every target covers cells of its own, apart from the others
        x, y = poly.representative_point().coords[0]
        assert mask[int(y), int(x)], f"target {i} covers no cell at its own point"
        for other in polygons[i + 1:]:
            assert poly.distance(other) > 4.0
    obj = np.asarray(scene.obj)
    assert np.all(obj == np.rint(obj)) and obj.min() == 0 and obj.max() <= MAX_COUNT
    assert not obj[mask].any(), "material on a target cell"
    blocked = np.asarray(scene.blocked)
    assert blocked.any() == (name == "site1024")
    assert not obj[blocked].any() and not (blocked & mask).any()
    assert not np.asarray(scene.cut_off).any(), "a free cell cut off from every target"
    assert obj[~mask].sum() > 0
    # material spread over the site: every quarter of the grid holds some
    half = side // 2
    for rows in (slice(0, half), slice(half, side)):
        for cols in (slice(0, half), slice(half, side)):
            assert obj[rows, cols].sum() > 0


def test_an_unknown_site_is_a_named_error():
    with pytest.raises(ValueError, match="site128, site256, site512, site1024"):
        site("site64")
