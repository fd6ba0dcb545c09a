"""jaxplan.pusharound geometry: scene validation and JSON, shapes, the batched distance kernel, the
WCCG's Eq. 7 against the exact free-space cross-check, and W-clear paths."""
from __future__ import annotations

import copy
import functools
import math
import re

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import shapely  # noqa: E402
from hypothesis import HealthCheck, assume, example, given, settings  # noqa: E402
from hypothesis import strategies as hs  # noqa: E402

from jaxplan.pusharound import (  # noqa: E402
    PushScene,
    build_wccg,
    connectivity,
    nominal_scene,
    plot_wccg,
    shapes,  # noqa: E402
    w_clear_path,
)
from jaxplan.pusharound.kernels import pack_polygons, pair_distances  # noqa: E402
from jaxplan.pusharound.wccg import frontier_bridges  # noqa: E402
from jaxplan.reference.pusharound import path_clearance, reference_connected, reference_pair_distances  # noqa: E402


def _box(x0, y0, x1, y1):
    return [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]


def _bar_scene(gap: float, width: float = 1.0) -> dict:
    """A 6 x 4 workspace split by a wall at x = 3: a fixed lower bar and a movable upper bar with an
    opening of ``gap`` between them at y = 2."""
    return {"workspace": [0, 0, 6, 4], "vehicle_width": width, "start": [1, 2], "goal": [5, 2],
            "fixed": [{"name": "low", "pieces": [_box(2.8, 0, 3.2, 2 - gap / 2)]}],
            "movables": [{"name": "high", "pieces": [_box(2.8, 2 + gap / 2, 3.2, 4)], "mass": 8.0}],
            "robots": {"positions": [[0.5, 0.5], [1.0, 0.5]], "radius": 0.15}}


# --------------------------------------------------------------------------------------------------
# Scene validation and JSON
# --------------------------------------------------------------------------------------------------

def _broken(mutate):
    d = _bar_scene(0.8)
    mutate(d)
    return d


@pytest.mark.parametrize("mutate, field, words", [
    (lambda d: d["movables"][0].update(pieces=[[[0, 0], [1, 1], [1, 0], [0, 1]]]),
     "movables[0].pieces[0]", "self-intersecting"),
    (lambda d: d["movables"][0].update(mass=0.0), "movables[0].mass", "> 0"),
    (lambda d: d["movables"][0].update(mass=-3), "movables[0].mass", "> 0"),
    (lambda d: d.update(vehicle_width=0.0), "vehicle_width", "> 0"),
    (lambda d: d.update(start=[7, 2]), "start", "outside the workspace"),
    (lambda d: d.update(goal=[3.0, 0.5]), "goal", "inside fixed[0]"),
    (lambda d: d["movables"][0].update(pieces=[_box(2.9, 1.0, 3.1, 4)]), "movables[0] and fixed[0]",
     "overlap"),
    (lambda d: d["movables"][0].update(pieces=[[[0, 0], [2, 0], [2, 2], [1, 0.5], [0, 2]]]),
     "movables[0].pieces[0]", "not convex"),
    (lambda d: d["fixed"][0].update(pieces=[_box(5.5, 0, 6.5, 1)]), "fixed[0]", "outside the workspace"),
    (lambda d: d["robots"].update(radius=-1), "robots.radius", "> 0"),
    (lambda d: d["movables"][0].update(pieces=[_box(0.1, 0.1, 0.3, 0.3), _box(1, 1, 1.2, 1.2)]),
     "movables[0].pieces", "connected"),
])
def test_validation_errors_name_the_field(mutate, field, words):
    with pytest.raises(ValueError) as err:
        PushScene.from_dict(_broken(mutate))
    assert str(err.value).startswith(field) and words in str(err.value)


def test_non_convex_outline_is_decomposed_and_inertia_computed():
    d = _bar_scene(0.8)
    d["movables"].append({"polygon": [[4, 0.5], [5, 0.5], [5, 0.7], [4.2, 0.7], [4.2, 1.5], [4, 1.5]],
                          "mass": 6.0})
    scene = PushScene.from_dict(d)
    m = scene.movables[1]
    assert all(shapes.is_convex(p) for p in m.pieces) and len(m.pieces) >= 2
    assert shapely.union_all(m.pieces).area == pytest.approx(0.2 * 1.0 + 0.8 * 0.2)
    assert m.polygon.centroid.distance(shapely.Point(m.pose[:2])) < 1e-9
    assert m.inertia == pytest.approx(shapes.polygon_inertia(m.polygon, 6.0))


def test_json_round_trip(tmp_path):
    scene = nominal_scene(3)
    loaded = PushScene.load(scene.save(tmp_path / "scene.json"))
    assert loaded.to_dict() == scene.to_dict()
    a, b = build_wccg(scene), build_wccg(loaded)
    np.testing.assert_allclose(a.bridge_width, b.bridge_width, atol=1e-9)


def test_load_rejects_bad_json(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        PushScene.load(path)


# --------------------------------------------------------------------------------------------------
# Shapes
# --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("shape", [shapes.rectangle(0.8, 0.4), shapes.cylinder(0.3), shapes.ellipse(0.5, 0.3),
                                   shapes.ring(0.45, 0.27), shapes.l_shape(0.9, 0.7, 0.2),
                                   shapes.t_shape(0.9, 0.8, 0.2), shapes.x_shape(0.8, 0.8, 0.2),
                                   shapes.diamond(0.8, 0.6), shapes.arrow(1.0, 0.2, 0.3, 0.45)])
def test_shapes_are_tiled_by_convex_pieces(shape):
    assert all(shapes.is_convex(p) for p in shape.pieces)
    assert sum(p.area for p in shape.pieces) == pytest.approx(shape.outline.area, rel=1e-9)  # no overlap
    assert shapely.union_all(shape.pieces).symmetric_difference(shape.outline).area < 1e-9
    assert abs(shape.outline.centroid.x) < 1e-9 and abs(shape.outline.centroid.y) < 1e-9


def test_inertia_of_a_rectangle_and_an_annulus():
    assert shapes.polygon_inertia(shapes.rectangle(0.6, 0.2).outline, 3.0) == pytest.approx(3.0 * (0.36 + 0.04) / 12)
    ring = shapes.ring(0.5, 0.3, n=256).outline  # close to the true annulus: m (R^2 + r^2) / 2
    assert shapes.polygon_inertia(ring, 2.0) == pytest.approx(2.0 * (0.25 + 0.09) / 2, rel=1e-3)


def test_shape_arguments_are_checked():
    with pytest.raises(ValueError, match="r_in"):
        shapes.ring(0.3, 0.4)
    with pytest.raises(ValueError, match="thickness"):
        shapes.l_shape(0.5, 0.5, 0.6)


# --------------------------------------------------------------------------------------------------
# Batched distances vs shapely
# --------------------------------------------------------------------------------------------------

def _random_convex(rng, n_max=7, spread=2.0):
    c = rng.uniform(0, spread, 2)
    k = rng.integers(3, n_max + 1)
    ang = rng.uniform(0, 2 * np.pi, k)
    rad = rng.uniform(0.1, 0.6, k)
    return shapely.Polygon(np.c_[c[0] + rad * np.cos(ang), c[1] + rad * np.sin(ang)]).convex_hull


def test_pair_distances_match_shapely_including_overlaps():
    rng = np.random.default_rng(7)
    polys = [p for p in (_random_convex(rng) for _ in range(30)) if p.area > 1e-4]
    verts, _ = pack_polygons(polys)
    iu, iv = np.triu_indices(len(polys), k=1)
    import jax  # noqa: PLC0415
    with jax.enable_x64(True):
        d, pa, pb = (np.asarray(x) for x in pair_distances(verts[iu], verts[iv]))
    ref = reference_pair_distances(polys)[iu, iv]
    np.testing.assert_allclose(d, ref, atol=1e-9)
    assert np.sum(ref == 0) > 5  # the draw has overlapping pairs
    for k in range(len(iu)):
        a, b = polys[iu[k]], polys[iv[k]]
        assert a.distance(shapely.Point(pa[k])) < 1e-9 and b.distance(shapely.Point(pb[k])) < 1e-9
        assert np.linalg.norm(pa[k] - pb[k]) == pytest.approx(d[k], abs=1e-9)


# --------------------------------------------------------------------------------------------------
# WCCG on hand-built cases
# --------------------------------------------------------------------------------------------------

def test_narrow_opening_disconnects_and_widening_connects():
    narrow = PushScene.from_dict(_bar_scene(0.8))
    g = build_wccg(narrow)
    conn = connectivity(g, narrow.start, narrow.goal)
    assert not conn.connected and not conn.same_face and conn.frontier is not None
    assert conn.frontier.encloses_start  # the start's face is the left room
    on_loop = frontier_bridges(g, conn.frontier)
    widths = g.bridge_width[on_loop][~g.internal[on_loop]]
    assert np.any(np.isclose(widths, 0.8))  # the opening is a bottleneck on the loop
    assert w_clear_path(g, narrow.start, narrow.goal) is None
    assert not reference_connected(narrow)

    wide = PushScene.from_dict(_bar_scene(1.2))
    g = build_wccg(wide)
    assert connectivity(g, wide.start, wide.goal).connected and reference_connected(wide)
    path = w_clear_path(g, wide.start, wide.goal)
    assert path_clearance(wide, path) >= 0.5 - 1e-9
    # Removing the bottleneck (a virtually widened gap) reconnects the narrow scene.
    g = build_wccg(narrow)
    assert connectivity(g, narrow.start, narrow.goal, removed=[(0, 1)]).same_face


def _strip_union_holes(g, sk, c):
    """The faces of cluster c the plain way: the pieces unioned with a thin polygon per bridge."""
    from jaxplan.pusharound.faces import BRIDGE_EPS  # noqa: PLC0415
    comps = np.nonzero(sk.labels == c)[0]
    bridges = np.nonzero(sk.active & np.isin(g.bridge_uv[:, 0], comps))[0]
    eps = BRIDGE_EPS * g.width
    strips = [shapely.buffer(shapely.LineString(g.bridge_pts[e]) if g.bridge_width[e] > 0
                             else shapely.Point(g.bridge_pts[e, 0]), eps, quad_segs=1) for e in bridges]
    region = shapely.union_all([g.pieces[i] for i in comps] + strips)
    return region, shapely.union_all([shapely.Polygon(h) for h in region.interiors])


@pytest.mark.parametrize("seed", [0, 3])
def test_face_rings_equal_the_strip_union(seed):
    """The polygonized faces (less the islands in them) cover what the strip union's holes cover,
    and the exterior is the same, up to the strips' width."""
    from jaxplan.pusharound.faces import build_skeleton, cluster_region  # noqa: PLC0415
    g = build_wccg(nominal_scene(seed))
    sk = build_skeleton(g)
    for c in np.unique(sk.labels):
        rings = cluster_region(g, sk, int(c))
        region, holes = _strip_union_holes(g, sk, int(c))
        # faces and islands nest alternately (an island may enclose faces of its own): free space is
        # what an odd number of them enclose
        free = functools.reduce(shapely.symmetric_difference,
                                [shapely.Polygon(r) for r in rings.interiors + rings.islands], shapely.Polygon())
        assert free.symmetric_difference(holes).area < 1e-4
        assert shapely.Polygon(rings.exterior).symmetric_difference(shapely.Polygon(region.exterior)).area < 1e-4


def test_an_island_in_a_face_is_a_ring_of_its_own():
    """A movable hanging off the bar by one bridge, inside the left room: its outline is a ring that
    encloses obstacle, not a face, and the frontier loop of the room includes it."""
    d = _bar_scene(0.4, width=0.5)
    d["movables"].append({"name": "island", "pieces": [_box(2.0, 2.6, 2.6, 3.2)], "mass": 5.0})
    scene = PushScene.from_dict(d)
    g = build_wccg(scene)
    from jaxplan.pusharound.faces import build_skeleton, cluster_region, cluster_rings  # noqa: PLC0415
    sk = build_skeleton(g)
    rings = [r for c in np.unique(sk.labels) for r in cluster_rings(cluster_region(g, sk, int(c)), int(c))]
    island = [r for r in rings if not r.is_hole and r.region.contains(shapely.Point(2.3, 2.9))]
    assert len(island) == 2    # its cluster's exterior and the island ring
    assert min(r.region.area for r in island) == pytest.approx(0.36, abs=1e-5)
    conn = connectivity(g, (1.0, 2.9), scene.goal)
    assert not conn.connected and conn.frontier.encloses_start and len(conn.frontier.islands) == 1
    # the loop walks around the island as around any part of the room's boundary: the island's gap
    # (to the upper bar) is on it with the opening, and the island is not part of the room's face
    on_loop = {tuple(b) for b in g.bridge_bodies[frontier_bridges(g, conn.frontier)]}
    assert (0, 1) in on_loop and (0, 2) in on_loop
    assert not conn.frontier.region().contains(shapely.Point(2.3, 2.9))


def test_path_through_an_opening_a_hair_wider_than_w():
    """An opening 2e-4 W wider than W: Eq. 7 holds and a path exists, though the 32-segment buffers of
    the inflated walk close the opening (the finer fallback finds it)."""
    scene = PushScene.from_dict(_bar_scene(1.0002))
    g = build_wccg(scene)
    assert connectivity(g, scene.start, scene.goal).connected and reference_connected(scene)
    path = w_clear_path(g, scene.start, scene.goal)
    assert path is not None and path_clearance(scene, path) >= 0.5 - 1e-9
    assert np.allclose(path[0], scene.start) and np.allclose(path[-1], scene.goal)


def test_endpoint_disk_condition_of_eq7():
    d = _bar_scene(1.2)
    d["start"] = [0.3, 2.0]  # closer than W/2 to the left wall: same face, but the disk is not free
    scene = PushScene.from_dict(d)
    conn = connectivity(build_wccg(scene), scene.start, scene.goal)
    assert conn.same_face and not conn.start_clear and not conn.connected
    assert not reference_connected(scene)


def test_path_goes_around_an_island():
    d = _bar_scene(1.2)
    d["fixed"] = [{"name": "island", "pieces": [_box(2.5, 1.2, 3.5, 2.8)]}]  # 1.2 m free above and below
    d["movables"] = []
    scene = PushScene.from_dict(d)
    g = build_wccg(scene)
    path = w_clear_path(g, scene.start, scene.goal)
    assert path is not None and len(path) > 2  # not the straight segment
    assert path_clearance(scene, path) >= 0.5 - 1e-9
    assert np.allclose(path[0], scene.start) and np.allclose(path[-1], scene.goal)
    # Shortening only cuts the frontier walk's detours: no longer, fewer points, same clearance.
    walk = w_clear_path(g, scene.start, scene.goal, shorten=False)
    length = lambda p: float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())  # noqa: E731
    assert length(path) <= length(walk) + 1e-9 and len(path) < len(walk)
    assert path_clearance(scene, walk) >= 0.5 - 1e-9


# --------------------------------------------------------------------------------------------------
# Property test: WCCG (Eq. 7) vs the exact free-space components; paths are W-clear
# --------------------------------------------------------------------------------------------------

def _random_scene(seed: int, n: int) -> PushScene:
    rng = np.random.default_rng(seed)
    polys = []
    for _ in range(300):
        if len(polys) == n:
            break
        p = _random_convex(rng, spread=1.0)
        p = shapely.affinity.translate(p, *rng.uniform([0, 0], [5.0, 3.0]))
        if shapely.box(0, 0, 6, 4).contains(p) and not any(p.intersects(q) for q in polys):
            polys.append(p)
    while True:
        s, gl = rng.uniform([0.1, 0.1], [5.9, 3.9], (2, 2))
        if not any(q.covers(shapely.Point(x)) for q in polys for x in (s, gl)):
            break
    half = len(polys) // 2
    verts = lambda p: np.asarray(p.exterior.coords)[:-1].tolist()  # noqa: E731
    return PushScene.from_dict({"workspace": [0, 0, 6, 4], "vehicle_width": 0.8, "start": list(s),
                                "goal": list(gl), "fixed": [{"pieces": [verts(p)]} for p in polys[:half]],
                                "movables": [{"pieces": [verts(p)], "mass": 5} for p in polys[half:]]})


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=hs.integers(0, 2**31 - 1), n=hs.integers(3, 10))
@example(seed=459, n=9)   # goal 0.0035 m from W/2: the path's retry margin once swallowed it
def test_wccg_agrees_with_exact_free_space(seed, n):
    scene = _random_scene(seed, n)
    g = build_wccg(scene, bridge_range=1.01)
    # Near-ties (a gap within 1e-3 m of W, or an endpoint within 1e-3 of W/2) are ambiguous to the
    # polygonal buffers of the cross-check: skip them.
    assume(not np.any(np.abs(g.bridge_width - g.width) < 1e-3))
    from jaxplan.pusharound.wccg import clearance  # noqa: PLC0415
    assume(np.all(np.abs(clearance(g, [scene.start, scene.goal]) - 0.4) > 1e-3))
    g = build_wccg(scene)
    conn = connectivity(g, scene.start, scene.goal)
    assert conn.connected == reference_connected(scene)
    if conn.connected:
        path = w_clear_path(g, scene.start, scene.goal)
        assert path is not None
        assert path_clearance(scene, path) >= 0.4 - 1e-9


# --------------------------------------------------------------------------------------------------
# Nominal scenario and plot
# --------------------------------------------------------------------------------------------------

def test_nominal_scene_is_seeded_and_blocked():
    a, b = nominal_scene(5), nominal_scene(5)
    assert a.to_dict() == b.to_dict()
    assert 10 <= len(a.movables) <= 15
    assert all(5.0 <= m.mass <= 15.0 for m in a.movables)
    assert a.workspace == (0.0, 0.0, 8.0, 5.0) and len(a.fixed) == 2 and len(a.robots) == 2
    assert not connectivity(build_wccg(a), a.start, a.goal).connected
    assert not reference_connected(a)
    # Minimum separation between movables.
    polys = [m.polygon for m in a.movables]
    assert min(p.distance(q) for i, p in enumerate(polys) for q in polys[i + 1:]) >= 0.15 - 1e-9
    assert nominal_scene(6).to_dict() != a.to_dict()


def test_plot_writes_png(tmp_path):
    import matplotlib.pyplot as plt  # noqa: PLC0415

    scene = PushScene.from_dict(_bar_scene(1.2))
    g = build_wccg(scene)
    ax = plot_wccg(scene, g, path=w_clear_path(g, scene.start, scene.goal))
    out = tmp_path / "wccg.png"
    ax.figure.savefig(out)
    plt.close(ax.figure)
    assert out.stat().st_size > 1000


def test_deepcopy_free_geometry_is_immutable():
    scene = PushScene.from_dict(_bar_scene(0.8))
    moved = scene.with_poses(scene.poses + np.array([[0.0, 0.3, 0.0]]))
    assert scene.movables[0].pose != moved.movables[0].pose
    assert copy.deepcopy(scene).to_dict() == scene.to_dict()
    assert math.isclose(moved.movables[0].pose[1] - scene.movables[0].pose[1], 0.3)


# --------------------------------------------------------------------------------------------------
# Feasibility: geometry no push can change
# --------------------------------------------------------------------------------------------------

def _walled_off() -> PushScene:
    """The bar scene with a fixed wall across the whole room instead of the bars: no push can help."""
    d = _bar_scene(0.8)
    d["fixed"][0]["pieces"] = [_box(2.8, 0, 3.2, 4)]
    del d["movables"][0]
    return PushScene.from_dict(d)


@pytest.mark.parametrize("change, field, words", [
    ({"width": 10.0}, "vehicle_width", "10 m is not narrower than the workspace's narrow side (4 m"),
    ({"width": 4.0}, "vehicle_width", "use a width below 4 m"),
    ({"start": (0.3, 2.0)}, "start", "0.3 m from a workspace wall, closer than W/2 = 0.5 m"),
    ({"goal": (5.0, 3.8)}, "goal", "closer than W/2 = 0.5 m"),
    ({"goal": (2.6, 0.5)}, "goal", "from fixed[0] (low), closer than W/2"),
    ({"robot_radius": 2.5}, "robots.radius", "does not fit across"),
    (None, "fixed", "the fixed obstacles and walls alone leave no W-clear corridor"),
])
def test_check_feasible_names_the_field_and_the_fix(change, field, words):
    from jaxplan.pusharound import check_feasible

    base = PushScene.from_dict(_bar_scene(0.8))
    check_feasible(base)               # blocked by the movable bar only: pushing can open it
    scene = _walled_off() if change is None else base.replace(**change)
    with pytest.raises(ValueError, match=rf"^{re.escape(field)}: ") as info:
        check_feasible(scene)
    assert words in str(info.value)


def test_nominal_scenes_are_feasible():
    from jaxplan.pusharound import check_feasible

    for seed in (0, 1):
        check_feasible(nominal_scene(seed))
    with pytest.raises(ValueError, match="vehicle_width"):
        check_feasible(nominal_scene(0).replace(width=10.0))
    with pytest.raises(ValueError, match="^fixed: "):    # the bars' openings are 1.7 m wide
        check_feasible(nominal_scene(0).replace(width=1.8))
    with pytest.raises(ValueError, match=r"seed: must be an int >= 0; got -1"):
        nominal_scene(-1)
