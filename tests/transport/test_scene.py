"""Tests for jaxplan.transport.scene: the geometry kernel against the shapely reference, validation, files,
built-in scenes and pytree behaviour under jit."""
from __future__ import annotations

import json
import math

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, MultiPolygon, Point, Polygon

from jaxplan.reference.geometry import reference_geometry
from jaxplan.transport import generators as scenes
from jaxplan.transport import geometry as G
from jaxplan.transport import scene as S

# --------------------------------------------------------------------------------------------------
# Kernel vs reference (property test)
# --------------------------------------------------------------------------------------------------

def _kernel(shape, cell_size, origin, target):
    mask, dist, tvec = G.target_geometry(jnp.asarray(G.target_segments(target)), tuple(shape),
                                         jnp.float32(cell_size), jnp.asarray(origin, jnp.float32))
    return np.asarray(mask), np.asarray(dist, np.float64), np.asarray(tvec, np.float64)


def _centres(shape, cell_size, origin):
    h, w = shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    return np.stack([origin[0] + xs * cell_size, origin[1] + ys * cell_size], axis=-1)


def _assert_matches_reference(shape, s, origin, target):
    k_mask, k_dist, k_tvec = _kernel(shape, s, origin, target)
    r_mask, r_dist, r_tvec = reference_geometry(shape, s, origin, target)
    centres = _centres(shape, s, origin)
    pts = shapely.points(centres[..., 0], centres[..., 1])
    bdist = shapely.distance(target.boundary, pts)

    # Mask: centres within 1e-5 s of the boundary are float32 coin flips; skip them.
    clear = bdist > 1e-5 * s
    np.testing.assert_array_equal(k_mask[clear], r_mask[clear])

    # Distance everywhere (near-boundary cells are within 1e-5 s of 0 either way).
    np.testing.assert_allclose(k_dist, r_dist, rtol=0, atol=1e-4 * s)

    outside = ~k_mask & ~r_mask
    np.testing.assert_array_equal(k_tvec[k_mask], 0.0)
    np.testing.assert_allclose(np.linalg.norm(k_tvec[outside], axis=-1), 1.0, atol=1e-5)

    # Direction: float32 rounding of the closest point (~1e-5 world units here) turns into an angle
    # error of ~1e-5 / dist, so only cells at least 1e-2 s from the target are held to 1e-3.
    far = outside & (r_dist >= 1e-2 * s)
    diff = np.abs(k_tvec - r_tvec).max(axis=-1)
    for r, c in np.argwhere(far & (diff > 1e-3)):
        # A different but equally close boundary point (a tie) is fine: the kernel's point must lie
        # on the boundary at the reference distance.
        q = centres[r, c] + k_dist[r, c] * k_tvec[r, c]
        on_boundary = target.boundary.distance(Point(q)) <= 1e-4 * s
        assert on_boundary and abs(k_dist[r, c] - r_dist[r, c]) <= 1e-4 * s, (
            f"tvec mismatch at ({r}, {c}): kernel {k_tvec[r, c]}, reference {r_tvec[r, c]}")


@st.composite
def _grids(draw):
    h = draw(st.integers(1, 30))
    w = draw(st.integers(1, 30))
    s = draw(st.sampled_from([0.5, 1.0, 2.0]))
    # Quarter units are exact in float32, so kernel and reference see the same centres.
    origin = (draw(st.integers(-80, 80)) / 4.0, draw(st.integers(-80, 80)) / 4.0)
    return (h, w), s, origin


def _coord(draw, lo, hi):
    return draw(st.floats(lo, hi, allow_nan=False, allow_infinity=False))


@st.composite
def _targets(draw, extent):
    (x0, y0, x1, y1) = extent
    size = max(x1 - x0, y1 - y0)
    mx, my = 0.25 * (x1 - x0) + 0.5, 0.25 * (y1 - y0) + 0.5
    kind = draw(st.sampled_from(["circle", "box", "triangle", "two_circles", "hole"]))

    def point():
        return _coord(draw, x0 - mx, x1 + mx), _coord(draw, y0 - my, y1 + my)

    def a_circle():
        radius = _coord(draw, 0.2, max(0.3, 0.6 * size))
        return S.circle(point(), radius, draw(st.sampled_from([3, 8, 16, 33, 64])))

    if kind == "circle":
        return a_circle()
    if kind == "box":
        (ax, ay), (bx, by) = point(), point()
        assume(abs(ax - bx) > 0.05 and abs(ay - by) > 0.05)
        return S.box(min(ax, bx), min(ay, by), max(ax, bx), max(ay, by))
    if kind == "triangle":
        tri = Polygon([point(), point(), point()])
        assume(tri.is_valid and tri.area > 0.05)
        return tri
    if kind == "two_circles":
        a, b = a_circle(), a_circle()
        assume(a.distance(b) > 0.05)
        return MultiPolygon([a, b])
    outer = a_circle()
    cx, cy = outer.centroid.x, outer.centroid.y
    inner_r = draw(st.floats(0.1, 0.7)) * outer.exterior.distance(outer.centroid)
    assume(inner_r > 0.05)
    hole = S.circle((cx, cy), inner_r, draw(st.sampled_from([4, 12, 32])))
    return Polygon(outer.exterior.coords, [hole.exterior.coords])


@st.composite
def _cases(draw):
    shape, s, origin = draw(_grids())
    h, w = shape
    extent = (origin[0], origin[1], origin[0] + w * s, origin[1] + h * s)
    target = draw(_targets(extent))
    assume(target.is_valid)
    return shape, s, origin, target


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_cases())
def test_geometry_kernel_matches_shapely_reference(case):
    _assert_matches_reference(*case)


@pytest.mark.parametrize("name", scenes.BUILTIN_SCENES)
def test_builtin_geometry_matches_reference(name):
    scene = scenes.builtin_scene(name)
    _assert_matches_reference(scene.shape, 1.0, (0.0, 0.0), scene.target)


def test_chunked_kernel_equals_single_block():
    outer = S.circle((6.3, 5.1), 5.0, 40)
    target = MultiPolygon([
        Polygon(outer.exterior.coords, [S.circle((6.0, 5.0), 2.0, 12).exterior.coords]),
        S.box(13.0, 1.0, 16.0, 9.5),
    ])
    segs = jnp.asarray(G.target_segments(target))
    args = (segs, (13, 17), jnp.float32(1.0), jnp.zeros(2, jnp.float32))
    whole = G.target_geometry(*args)
    chunked = G.target_geometry(*args, pair_budget=64, seg_chunk=7)  # many row blocks, padded chunks
    np.testing.assert_array_equal(whole[0], chunked[0])
    np.testing.assert_allclose(whole[1], chunked[1], rtol=0, atol=1e-6)
    np.testing.assert_allclose(whole[2], chunked[2], rtol=0, atol=1e-6)


def _star(center, r_out, r_in, points):
    ang = np.pi * np.arange(2 * points) / points
    rad = np.where(np.arange(2 * points) % 2 == 0, r_out, r_in)
    return Polygon(np.stack([center[0] + rad * np.cos(ang), center[1] + rad * np.sin(ang)], axis=1))


# Every scene has 80 segments on the same grid, so each kernel variant compiles once for all of them.
_TILED_GRID = ((70, 90), 0.75, (-3.25, 2.5))   # shape, cell size, origin: x in [-3.25, 64.25], y in [2.5, 55]
_TILED_SCENES = {
    "two_circles": MultiPolygon([S.circle((12.3, 20.1), 7.0, 48), S.circle((50.7, 40.2), 4.5, 32)]),
    "hole_box_circle": MultiPolygon([
        Polygon(S.circle((20.0, 30.0), 12.0, 40).exterior.coords, [S.circle((21.0, 29.0), 5.0, 24).exterior.coords]),
        S.box(44.0, 10.0, 58.0, 13.5),
        S.circle((55.0, 45.0), 3.0, 12),
    ]),
    # long concave edges reaching past the grid
    "star": _star((35.0, 30.0), 40.0, 9.0, 40),
}


@pytest.mark.parametrize("options", [
    {},                                    # default tiles
    {"tile": 4, "pair_budget": 256},       # many tiles, and many small blocks of every pass
    {"max_candidates": 2},                 # tiles on the boundary keep more: the brute-force fallback
], ids=["default", "many_tiles", "fallback"])
@pytest.mark.parametrize("name", list(_TILED_SCENES))
def test_tiled_kernel_equals_brute_force(name, options):
    shape, s, origin = _TILED_GRID
    segs = jnp.asarray(G.target_segments(_TILED_SCENES[name]))
    assert segs.shape[0] == 80
    args = (segs, shape, jnp.float32(s), jnp.asarray(origin, jnp.float32))
    brute = G.target_geometry(*args, method="brute")
    tiled = G.target_geometry(*args, method="tiled", **options)
    np.testing.assert_array_equal(tiled[0], brute[0])
    np.testing.assert_allclose(tiled[1], brute[1], rtol=0, atol=1e-6)
    np.testing.assert_allclose(tiled[2], brute[2], rtol=0, atol=1e-6)


def test_targets_of_one_segment_bucket_share_a_program():
    """Targets whose segment counts round up to one bucket compile one program, and the padding changes
    nothing: each still matches the shapely reference."""
    assert [G.segment_bucket(m) for m in (1, 16, 17, 392, 1024, 1025)] == [16, 16, 32, 512, 1024, 2048]
    targets = [S.circle((6.2, 3.4), 2.5, n) for n in (17, 24, 31)]
    assert {G.segment_bucket(len(G.target_segments(t))) for t in targets} == {32}
    _assert_matches_reference((7, 12), 1.0, (0.0, 0.0), targets[0])
    compiled = G._target_geometry._cache_size()
    for target in targets[1:]:
        _assert_matches_reference((7, 12), 1.0, (0.0, 0.0), target)
    assert G._target_geometry._cache_size() == compiled


def test_segments_order_and_shape():
    hole = S.box(1, 1, 2, 2)
    poly = Polygon(S.box(0, 0, 4, 4).exterior.coords, [hole.exterior.coords])
    second = S.box(10, 10, 11, 12)
    segs = G.target_segments(MultiPolygon([poly, second]))
    assert segs.shape == (12, 2, 2) and segs.dtype == np.float32
    np.testing.assert_array_equal(segs[0, 0], np.asarray(poly.exterior.coords[0], np.float32))
    np.testing.assert_array_equal(segs[4, 0], np.asarray(hole.exterior.coords[0], np.float32))
    np.testing.assert_array_equal(segs[8, 0], np.asarray(second.exterior.coords[0], np.float32))
    np.testing.assert_array_equal(segs[:-1, 1][[0, 1, 2]], segs[1:4, 0])  # rings are chained


def test_simple_distances_and_directions():
    strip = Polygon([(1.0, -5.0), (1.0, 5.0), (2.0, 5.0), (2.0, -5.0)])  # x in [1, 2]
    mask, dist, tvec = _kernel((1, 3), 1.0, (0.0, 0.0), strip)  # centres x = 0.5, 1.5, 2.5
    assert mask.tolist() == [[False, True, False]]
    np.testing.assert_allclose(dist, [[0.5, 0.0, 0.5]], atol=1e-6)
    np.testing.assert_allclose(tvec[0], [[1.0, 0.0], [0.0, 0.0], [-1.0, 0.0]], atol=1e-6)


@pytest.mark.parametrize("hole, expected", [
    ([(0.0, 0.0), (0.0, 1.0), (3.0, 1.0), (3.0, 0.0)], [0.0, 1.0]),   # edge y = 1 listed first
    ([(3.0, 1.0), (3.0, 0.0), (0.0, 0.0), (0.0, 1.0)], [0.0, -1.0]),  # edge y = 0 listed first
])
def test_first_segment_wins_exact_ties(hole, expected):
    # The centre (1.5, 0.5) sits in a 3x1 hole, exactly 0.5 from its edges y = 1 and y = 0. Segments
    # are ordered exterior first, then the hole ring in its vertex order: the first closest edge wins.
    frame = Polygon([(-5, -5), (-5, 6), (8, 6), (8, -5)], [hole])
    mask, dist, tvec = _kernel((1, 1), 3.0, (0.0, -1.0), frame)
    assert not mask[0, 0]
    np.testing.assert_allclose(dist[0, 0], 0.5, atol=1e-6)
    np.testing.assert_allclose(tvec[0, 0], expected, atol=1e-6)


def test_boundary_centre_is_covered():
    # The box edge passes exactly through the centres of column 2 (x = 2.5).
    target = S.box(2.5, 0.0, 6.0, 4.0)
    scene = S.Scene.from_arrays(np.zeros((4, 6)), target)
    assert np.asarray(scene.target_mask)[:, 2].all()
    assert not np.asarray(scene.target_mask)[:, 1].any()


# --------------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------------

GOOD_TARGET = S.circle((5.0, 5.0), 2.0)
GOOD_OBJ = np.ones((10, 10))


@pytest.mark.parametrize("obj, words", [
    (np.ones(10), "2-D"),
    (np.ones((2, 3, 4)), "2-D"),
    (np.ones((0, 5)), "empty"),
    (np.ones((5, 0)), "empty"),
    (np.array([["a", "b"], ["c", "d"]]), "numbers"),
    (np.where(np.eye(10, dtype=bool), np.inf, 1.0), "infinite"),
    (-GOOD_OBJ, "negative"),
])
def test_bad_obj(obj, words):
    with pytest.raises(ValueError, match="Scene.obj") as err:
        S.Scene.from_arrays(obj, GOOD_TARGET)
    assert words in str(err.value)


def test_nan_message_names_count_and_first_position():
    obj = GOOD_OBJ.copy()
    obj[2, 5] = obj[3, 1] = obj[7, 7] = np.nan
    with pytest.raises(ValueError) as err:
        S.Scene.from_arrays(obj, GOOD_TARGET)
    assert str(err.value) == ("Scene.obj: counts must be finite and >= 0; found 3 NaN value(s) "
                              "(first at row 2, col 5). Replace them with 0 or a measured count.")


@pytest.mark.parametrize("target, words", [
    (Point(5, 5), "Polygon or MultiPolygon"),
    (LineString([(0, 0), (5, 5)]), "Polygon or MultiPolygon"),
    ("POLYGON ((0 0, 1 0, 1 1, 0 0))", "Polygon or MultiPolygon"),
    (Polygon(), "empty"),
    (MultiPolygon(), "empty"),
    (Polygon([(0, 0), (6, 6), (6, 0), (0, 6)]), "Self-intersection"),
    (MultiPolygon([S.box(0, 0, 4, 4), S.box(2, 2, 6, 6)]), "invalid"),
    (Polygon([(5.6, 5.6), (5.9, 5.6), (5.9, 5.9)]), "covers no cell centre"),
    (S.circle((50.0, 50.0), 3.0), "wholly outside"),
])
def test_bad_target(target, words):
    with pytest.raises(ValueError, match="Scene.target") as err:
        S.Scene.from_arrays(GOOD_OBJ, target)
    assert words in str(err.value)


@pytest.mark.parametrize("cell_size", [0, -1.0, float("nan"), float("inf"), "abc", None, 1e-60])
def test_bad_cell_size(cell_size):
    with pytest.raises(ValueError, match="Scene.cell_size"):
        S.Scene.from_arrays(GOOD_OBJ, GOOD_TARGET, cell_size=cell_size)


@pytest.mark.parametrize("origin", [(1.0,), (1.0, 2.0, 3.0), (float("nan"), 0.0), (0.0, float("inf")),
                                    "ab", None, [[0.0, 0.0]]])
def test_bad_origin(origin):
    with pytest.raises(ValueError, match="Scene.origin"):
        S.Scene.from_arrays(GOOD_OBJ, GOOD_TARGET, origin=origin)


def test_bad_name():
    with pytest.raises(ValueError, match="Scene.name"):
        S.Scene.from_arrays(GOOD_OBJ, GOOD_TARGET, name=3)


def test_with_obj_validates_concrete_counts():
    scene = S.Scene.from_arrays(GOOD_OBJ, GOOD_TARGET)
    with pytest.raises(ValueError, match="Scene.obj.*shape"):
        scene.with_obj(np.ones((3, 3)))
    with pytest.raises(ValueError, match="Scene.obj.*NaN"):
        scene.with_obj(np.full((10, 10), np.nan))
    with pytest.raises(ValueError, match="Scene.obj.*negative"):
        scene.with_obj(jnp.full((10, 10), -1.0))


def test_bad_suffix_and_builtin_name(tmp_path):
    scene = scenes.builtin_scene()
    with pytest.raises(ValueError, match="suffix"):
        scene.save(tmp_path / "scene.txt")
    with pytest.raises(ValueError, match="suffix"):
        S.Scene.load(tmp_path / "scene.pkl")
    with pytest.raises(ValueError, match="default") as err:
        scenes.builtin_scene("nope")
    assert all(name in str(err.value) for name in scenes.BUILTIN_SCENES)


def test_load_revalidates(tmp_path):
    path = tmp_path / "bad.json"
    doc = {"format_version": 1, "name": None, "cell_size": 1.0, "origin": [0, 0],
           "obj": [[1.0, -2.0], [0.0, 0.0]], "target": "POLYGON ((0 0, 2 0, 2 2, 0 2, 0 0))"}
    path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="^Scene file .*bad.json: obj: .*negative"):
        S.Scene.load(path)
    path.write_text(json.dumps({**doc, "obj": [[1.0, 2.0]], "format_version": 99}))
    with pytest.raises(ValueError, match="format_version"):
        S.Scene.load(path)
    path.write_text(json.dumps({k: v for k, v in doc.items() if k != "target"}))
    with pytest.raises(ValueError, match="target"):
        S.Scene.load(path)


# --------------------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------------------

def _awkward_scene(name):
    rng = np.random.default_rng(7)
    outer = S.circle((1.37, 2.91), 3.3, 29)
    target = MultiPolygon([
        Polygon(outer.exterior.coords, [S.circle((1.37, 2.91), 1.1, 9).exterior.coords]),
        S.box(6.1, -1.9, 7.3, 0.4),
    ])
    obj = rng.random((11, 9)) * 5.0
    return S.Scene.from_arrays(obj, target, cell_size=0.85, origin=(-3.3, -1.7), name=name)


@pytest.mark.parametrize("suffix", [".npz", ".json"])
@pytest.mark.parametrize("name", ["awkward", None])
def test_save_load_round_trip(tmp_path, suffix, name):
    scene = _awkward_scene(name)
    path = scene.save(tmp_path / f"scene{suffix}")
    back = S.Scene.load(path)
    assert back.name == name
    assert back.target.equals(scene.target)
    assert back.target.equals_exact(scene.target, 0.0)
    for key in ("obj", "target_mask", "dist", "tvec", "cell_size", "origin"):
        np.testing.assert_array_equal(np.asarray(getattr(back, key)), np.asarray(getattr(scene, key)))
        assert getattr(back, key).dtype == getattr(scene, key).dtype


def test_json_layout(tmp_path):
    scene = scenes.builtin_scene("default")
    doc = json.loads(scene.save(tmp_path / "s.json").read_text())
    assert doc["format_version"] == 2 and doc["name"] == "default"
    assert doc["blocked"] == ["." * 25] * 25
    assert doc["cell_size"] == 1.0 and doc["origin"] == [0.0, 0.0]
    assert np.asarray(doc["obj"]).shape == (25, 25)
    assert shapely.from_wkt(doc["target"]).equals(scene.target)


# --------------------------------------------------------------------------------------------------
# Built-in scenes and the Scene API
# --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name, shape", [
    ("default", (25, 25)), ("corridor", (45, 45)), ("two_targets", (30, 30)), ("sparse65", (65, 65)),
    ("yard", (40, 40)),
])
def test_builtin_scenes(name, shape):
    assert set(scenes.BUILTIN_SCENES) == {"default", "corridor", "two_targets", "sparse65", "yard"}
    assert scenes.DEFAULT_SCENE in scenes.BUILTIN_SCENES
    scene = scenes.builtin_scene(name)
    assert scene.name == name and scene.shape == shape
    obj, mask = np.asarray(scene.obj), np.asarray(scene.target_mask)
    assert obj.dtype == np.float32 and mask.dtype == bool
    assert 0 < mask.sum() < mask.size
    np.testing.assert_array_equal(obj, np.rint(obj))
    assert obj.min() >= 0 and obj.max() <= 6
    assert (obj[mask] == 0).all() and np.asarray(scene.occupied).any()
    assert scenes.builtin_scene(name) is scene  # cached; safe because immutable


def test_builtin_two_targets_is_multipolygon():
    assert isinstance(scenes.builtin_scene("two_targets").target, MultiPolygon)
    occupancy = np.asarray(scenes.builtin_scene("sparse65").occupied).mean()
    assert 0.10 < occupancy < 0.20


def test_scene_accessors():
    scene = _awkward_scene("x")
    h, w = scene.shape
    centres = np.asarray(scene.cell_centers())
    assert centres.shape == (h, w, 2) and centres.dtype == np.float32
    np.testing.assert_allclose(centres, _centres((h, w), 0.85, (-3.3, -1.7)), atol=1e-5)
    obj, mask = np.asarray(scene.obj), np.asarray(scene.target_mask)
    np.testing.assert_array_equal(np.asarray(scene.occupied), ~mask & (obj > 0))
    np.testing.assert_allclose(float(scene.total_mass), obj.sum(), rtol=1e-6)
    assert scene.dist.dtype == jnp.float32 and scene.tvec.shape == (h, w, 2)
    assert scene.cell_size.shape == () and scene.origin.shape == (2,)


def test_scene_is_immutable():
    scene = scenes.builtin_scene()
    with pytest.raises(AttributeError):
        scene.obj = jnp.zeros((25, 25))
    with pytest.raises(AttributeError):
        scene.extra = 1


def test_with_obj_keeps_geometry():
    scene = scenes.builtin_scene()
    new = scene.with_obj(np.full(scene.shape, 2.0))
    assert new.target is scene.target and new.name == scene.name
    assert new.dist is scene.dist and new.tvec is scene.tvec
    np.testing.assert_array_equal(np.asarray(new.obj), 2.0)


def test_pytree_structure():
    scene = scenes.builtin_scene()
    leaves, treedef = jax.tree_util.tree_flatten(scene)
    assert len(leaves) == 8
    assert leaves[0] is scene.obj and leaves[3] is scene.tvec and leaves[5] is scene.origin
    assert leaves[6] is scene.blocked and leaves[7] is scene.detour
    other = S.Scene.from_arrays(np.ones((25, 25)), S.box(0, 0, 3, 3), name="other")
    assert jax.tree_util.tree_structure(other) == treedef  # aux data is None: same structure
    rebuilt = jax.tree_util.tree_unflatten(treedef, leaves)
    assert rebuilt.target is None and rebuilt.name is None
    paths = [jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_flatten_with_path(scene)[0]]
    assert paths == [".obj", ".target_mask", ".dist", ".tvec", ".cell_size", ".origin", ".blocked", ".detour"]


def test_with_obj_under_jit():
    scene = scenes.builtin_scene()

    @jax.jit
    def doubled_mass(sc, obj):
        new = sc.with_obj(2.0 * obj)
        assert new.target is None  # only leaves travel through jit
        return new.obj.sum(), new.occupied.sum()

    mass, n_occ = doubled_mass(scene, scene.obj)
    np.testing.assert_allclose(float(mass), 2.0 * float(scene.total_mass))
    assert int(n_occ) == int(scene.occupied.sum())
    assert float(jax.jit(lambda sc: sc.obj.sum())(scene)) == float(scene.total_mass)
    out = jax.jit(lambda sc: sc.with_obj(sc.obj + 1.0))(scene)
    assert isinstance(out, S.Scene) and out.target is None
    np.testing.assert_array_equal(np.asarray(out.obj), np.asarray(scene.obj) + 1.0)
    with pytest.raises(ValueError, match="Scene.obj.*shape"):
        jax.jit(lambda sc: sc.with_obj(jnp.zeros((3, 3))).obj.sum())(scene)


def test_no_recompilation_for_new_obj_or_target():
    traces = []

    @jax.jit
    @chex.assert_max_traces(n=1)
    def mass(sc):
        traces.append(1)
        return (sc.obj * sc.dist).sum() + sc.tvec.sum() + sc.cell_centers().sum()

    scene = scenes.builtin_scene()
    mass(scene)
    mass(scene.with_obj(np.ones(scene.shape)))
    mass(scene.with_obj(jnp.zeros(scene.shape)))
    # Another target with the same number of segments, cell size and origin: same trace.
    moved = S.Scene.from_arrays(np.ones((25, 25)), S.circle((4.5, 4.5), 2.0), cell_size=0.5,
                                origin=(1.0, -2.0), name="moved")
    mass(moved)
    assert len(traces) == 1


def test_vmap_over_stacked_scenes():
    scene = scenes.builtin_scene()
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), scene,
                                     scene.with_obj(np.ones(scene.shape)))
    masses = jax.vmap(lambda sc: sc.total_mass)(stacked)
    np.testing.assert_allclose(np.asarray(masses), [float(scene.total_mass), 625.0])


def test_circle_helper():
    c = S.circle((1.0, 2.0), 3.0, resolution=16)
    assert isinstance(c, Polygon) and c.is_valid and len(c.exterior.coords) == 17
    np.testing.assert_allclose(np.hypot(*(np.asarray(c.exterior.coords) - [1.0, 2.0]).T), 3.0)
    assert c.area == pytest.approx(0.5 * 16 * 9 * math.sin(2 * math.pi / 16))
    for bad in [dict(radius=0.0), dict(radius=float("nan")), dict(resolution=2)]:
        kwargs = dict(center=(0.0, 0.0), radius=1.0, resolution=8) | bad
        with pytest.raises(ValueError, match="circle"):
            S.circle(**kwargs)
