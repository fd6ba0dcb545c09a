"""PushAround hybrid search (Algorithm 1) and the ModeTable, on tiny scenes with the C engine."""
import json

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, box

from jaxplan.pusharound import shapes
from jaxplan.pusharound.modetable import ModeKey, ModeTable, shape_signature
from jaxplan.pusharound.physics import build_push_world
from jaxplan.pusharound.push import make_push_simulator
from jaxplan.pusharound.ranking import RankingParams
from jaxplan.pusharound.scene import Fixed, Movable, PushScene
from jaxplan.pusharound.search import SearchConfig, face_graph, plan_pushes
from jaxplan.pusharound.wccg import build_wccg, connectivity

# Small candidate sets keep every search to a few physics calls of at most 16 rollouts.
FAST = SearchConfig(backend="c", max_batch=16, n_directions=4, time_limit_s=60.0, max_expansions=12)


def _box(name, pose, w=0.6, h=0.4, mass=8.0):
    s = shapes.rectangle(w, h)
    return Movable(name, s.pieces, pose, mass, shapes.polygon_inertia(s.outline, mass), 0.5,
                   {"kind": "rectangle", "width": w, "height": h})


def _scene(movables, lo=1.0, hi=2.0):
    """5 x 3 m; a fixed wall at x in [2.4, 2.6] with an opening y in [lo, hi]; start left, goal right."""
    walls = (Fixed("low", (box(2.4, 0.0, 2.6, lo),)), Fixed("high", (box(2.4, hi, 2.6, 3.0),)))
    return PushScene(workspace=(0, 0, 5, 3), width=0.8, start=(0.8, 1.5), goal=(4.2, 1.5), fixed=walls,
                     movables=tuple(movables), robots=np.array([[0.5, 0.4], [0.5, 2.6]]), robot_radius=0.15)


ONE = _scene([_box("box", (2.5, 1.5, np.pi / 2))])


@pytest.fixture(scope="module")
def one_world():
    world = build_push_world(ONE)
    return world, make_push_simulator(world, "c")


def _check_corridor(result, scene):
    """Independent check: Eq. 7 on the final scene and the returned path W-clear (shapely)."""
    final = result.final_scene
    assert connectivity(build_wccg(final), final.start, final.goal).connected
    path = np.asarray(result.path)
    assert path.ndim == 2 and path.shape[1] == 2 and len(path) >= 2
    np.testing.assert_allclose(path[0], scene.start, atol=1e-9)
    np.testing.assert_allclose(path[-1], scene.goal, atol=1e-9)
    line = LineString(path)
    r = 0.5 * scene.width
    for poly in final.obstacle_polygons():
        assert line.distance(poly) >= r - 1e-9
    x0, y0, x1, y1 = scene.workspace
    assert shapely.box(x0 + r, y0 + r, x1 - r, y1 - r).buffer(1e-9).contains(line)


def _check_schedule(result, scene):
    poses = scene.poses
    for push in result.schedule:
        np.testing.assert_allclose(push.poses_before, poses)
        assert push.poses_after.shape == poses.shape and push.robots_after.shape == (len(scene.robots), 2)
        assert np.isfinite(push.cost) and push.cost > 0
        assert np.ndim(push.task.movable) == 0 and push.task.contacts.shape == (len(scene.robots), 2)
        poses = push.poses_after
    np.testing.assert_allclose(result.final_scene.poses, poses)


def test_opens_one_box_corridor(one_world):
    world, sim = one_world
    assert not connectivity(build_wccg(ONE), ONE.start, ONE.goal).connected
    events = []
    res = plan_pushes(ONE, FAST, world=world, sim=sim, progress=events.append)
    assert res.success and res.reason == ""
    assert 1 <= len(res.schedule) <= 4
    _check_corridor(res, ONE)
    _check_schedule(res, ONE)
    st = res.stats
    assert st.physics_calls >= 1 and st.simulated_pushes <= st.physics_calls * FAST.max_batch
    assert st.expansions >= 1 and st.planning_time_s > 0
    assert events and events[-1]["event"] == "done" and events[-1]["success"]


def test_opens_two_box_corridor():
    scene = _scene([_box("a", (2.5, 1.25, 0.0), 0.5, 0.3, 6.0), _box("b", (2.5, 1.8, 0.0), 0.5, 0.3, 9.0)],
                   lo=0.9, hi=2.2)
    assert not connectivity(build_wccg(scene), scene.start, scene.goal).connected
    res = plan_pushes(scene, FAST)
    assert res.success
    _check_corridor(res, scene)
    _check_schedule(res, scene)


def test_endpoint_disk_is_cleared():
    """Remark 5: start and goal share a face but a box intrudes into the goal's disk."""
    scene = _scene([_box("b", (4.2, 1.85, 0.0))], lo=0.8, hi=2.2)
    conn = connectivity(build_wccg(scene), scene.start, scene.goal)
    assert conn.same_face and not conn.goal_clear
    res = plan_pushes(scene, FAST)
    assert res.success and res.schedule and res.schedule[0].gap == (0,)
    _check_corridor(res, scene)


def test_already_clear_scene_gives_empty_schedule():
    scene = _scene([_box("box", (1.5, 0.4, 0.0))], lo=0.8, hi=2.2)
    res = plan_pushes(scene, FAST)
    assert res.success and res.schedule == [] and res.reason == ""
    assert res.stats.physics_calls == 0
    _check_corridor(res, scene)


@pytest.mark.parametrize("switch", ["presearch", "mode_table", "quick_pass", "reinsertion", "beam"])
def test_ablations_still_solve(one_world, switch):
    world, sim = one_world
    change = {"presearch_mode": "beam"} if switch == "beam" else {switch: False}
    res = plan_pushes(ONE, FAST.replace(**change), world=world, sim=sim)
    assert res.success, res.reason
    _check_corridor(res, ONE)
    if switch == "quick_pass":
        assert res.stats.quick_pass_rejected == 0
    if switch == "mode_table":
        assert res.stats.mode_table_hits == 0


def test_face_graph_on_the_tiny_scene():
    """Both gaps of the box (to the lower and the upper wall) separate the start's face from the
    goal's: crossing either reaches the goal (continuation 0); a second box far from the wall opening
    adds no gap on the way."""
    g = build_wccg(ONE)
    fg = face_graph(g, ONE.goal, RankingParams())
    assert set(fg.tail) == {(0, 1), (0, 2)}
    assert all(fg.final.values()) and all(t == 0.0 for t in fg.tail.values())
    assert all(len(f) == 2 for f in fg.faces.values())
    blocked = _scene([_box("box", (2.5, 1.5, np.pi / 2)), _box("b2", (3.65, 1.5, np.pi / 2), 2.2, 0.2)])
    fg2 = face_graph(build_wccg(blocked), blocked.goal, RankingParams())
    # The opening's gaps now lead to a face from which the tall box's gaps to the walls remain.
    assert not fg2.final[(0, 2)] and 0 < fg2.tail[(0, 2)] < 1e3


def test_stale_stuck_penalties_are_taken_in_on_pop():
    """The stuck penalty of a gap grows during the search; an evaluated node takes the growth into its
    targets' one-hop costs (so a node evaluated early does not keep a cheaper estimate than its
    later siblings), once per growth."""
    from jaxplan.pusharound.search import SEARCH_RANKING  # noqa: PLC0415
    from jaxplan.pusharound.search.context import SearchRun, new_context  # noqa: PLC0415
    from jaxplan.pusharound.search.evaluation import evaluate_node, refresh_stuck  # noqa: PLC0415
    ctx = new_context(ONE, FAST, SEARCH_RANKING)
    run = SearchRun(np.random.default_rng(FAST.seed))
    root = run.new_node(ONE.poses, np.asarray(ONE.robots, np.float64), (), 0.0, 0.0)
    assert evaluate_node(ctx, run, root) is None
    best = root.targets[0]
    assert not refresh_stuck(ctx, run, root)
    run.stuck[best.bodies] = 2.0
    assert refresh_stuck(ctx, run, root)
    refreshed = {tg.bodies: tg.cost for tg in root.targets}
    assert refreshed[best.bodies] == pytest.approx(best.cost + 2.0)
    assert root.h == pytest.approx(min(refreshed.values()))
    assert not refresh_stuck(ctx, run, root)


def test_deterministic_for_a_seed(one_world):
    world, sim = one_world
    a = plan_pushes(ONE, FAST.replace(seed=3), world=world, sim=sim)
    b = plan_pushes(ONE, FAST.replace(seed=3), world=world, sim=sim)
    assert a.success and b.success and len(a.schedule) == len(b.schedule)
    for pa, pb in zip(a.schedule, b.schedule):
        for f in pa.task._fields:
            np.testing.assert_array_equal(getattr(pa.task, f), getattr(pb.task, f))
        np.testing.assert_array_equal(pa.poses_after, pb.poses_after)
    assert a.stats.simulated_pushes == b.stats.simulated_pushes


def test_mode_table_round_trip_and_hit_on_similar_obstacle(one_world, tmp_path):
    world, sim = one_world
    table = ModeTable()
    res = plan_pushes(ONE, FAST, world=world, sim=sim, mode_table=table)
    assert res.success and len(table) >= 1
    path = table.save(tmp_path / "modes.json")
    loaded = ModeTable.load(path)
    assert loaded.to_dict() == table.to_dict() and len(loaded) == len(table)
    # A similar box (2 cm larger: same signature at 0.1 m), elsewhere and turned: the stored modes come first.
    other = _scene([_box("other", (2.5, 1.45, np.pi / 2 + 0.1), 0.62, 0.41, 11.0)])
    assert shape_signature(other.movables[0]) == shape_signature(ONE.movables[0])
    res2 = plan_pushes(other, FAST, mode_table=loaded)
    assert res2.success and res2.stats.mode_table_hits > 0
    fresh = plan_pushes(other, FAST.replace(mode_table=False), mode_table=ModeTable())
    assert fresh.stats.mode_table_hits == 0


def test_mode_table_unit():
    t = ModeTable(resolution=0.1, angle_bins=16)
    m = _box("box", (0, 0, 0))
    k = t.key(0.05, 2, 0.31, 0.0)
    assert k == ModeKey(0, 2, 0.3, 0.0)
    t.record(m, k, True, np.array([[-0.3, 0.1], [-0.3, -0.1]]))
    t.record(m, k, False)
    t.record(m, t.key(np.pi, 1, 0.3, 0.0), False)
    assert len(t) == 1
    recs = t.lookup(_box("twin", (3, 1, 1.0), 0.64, 0.38))          # same signature
    assert [r.key for r in recs] == [k] and recs[0].success == 1 and recs[0].trials == 2
    assert t.lookup(m, body_angle=np.pi / 2) == [] and t.lookup(m, body_angle=0.3, window=1)
    assert t.lookup(_box("big", (0, 0, 0), 1.0, 0.4)) == []
    data = json.loads(json.dumps(t.to_dict()))
    assert ModeTable.from_dict(data).to_dict() == t.to_dict()
    with pytest.raises(ValueError, match="format"):
        ModeTable.from_dict({"format": "other"})
    with pytest.raises(ValueError, match="entries"):
        ModeTable.from_dict({"format": "jaxplan.pusharound.modetable", "version": 1, "entries": {"x": [{"bin": 1}]}})
    with pytest.raises(ValueError, match="key"):
        t.record(m, (0, 2, 0.3, 0.0), True)


@pytest.mark.parametrize("field, value", [("max_batch", 0), ("max_batch", 65), ("backend", "gpu"),
                                          ("time_limit_s", 0.0), ("presearch", "yes"), ("seed", 1.5),
                                          ("speeds", ()), ("team_sizes", (0,)), ("heuristic_weight", -1.0),
                                          ("presearch_mode", "dfs"), ("batch_size", 0),
                                          ("refresh_stuck", 1)])
def test_bad_config_raises(field, value):
    with pytest.raises(ValueError, match=field):
        SearchConfig(**{field: value})


def test_bad_inputs_raise(one_world):
    world, _ = one_world
    with pytest.raises(TypeError, match="scene"):
        plan_pushes("scene.json")
    with pytest.raises(TypeError, match="config"):
        plan_pushes(ONE, {"presearch": False})
    with pytest.raises(ValueError, match="mode_table"):
        plan_pushes(ONE, FAST, mode_table={})
    with pytest.raises(ValueError, match="world"):
        plan_pushes(_scene([_box("a", (1.5, 0.4, 0.0)), _box("b", (3.5, 0.4, 0.0))]), FAST, world=world)
    with pytest.raises(ValueError, match="robots"):
        plan_pushes(ONE.replace(robots=np.zeros((0, 2))), FAST)


def test_no_movables():
    clear = plan_pushes(_scene([]), FAST)                      # a 1 m opening: nothing to push
    assert clear.success and clear.schedule == []
    with pytest.raises(ValueError, match="^fixed: "):           # 0.6 m: nothing can open it, so no search
        plan_pushes(_scene([], lo=1.2, hi=1.8), FAST)


def test_infeasible_geometry_is_refused_before_the_search(monkeypatch):
    from jaxplan.pusharound.search import loop

    def no_search(*args, **kwargs):
        raise AssertionError("searched")

    monkeypatch.setattr(loop, "new_context", no_search)
    with pytest.raises(ValueError, match="^vehicle_width: 10 m is not narrower"):
        plan_pushes(ONE.replace(width=10.0), FAST)
    with pytest.raises(ValueError, match="^goal: "):
        plan_pushes(ONE.replace(goal=(4.9, 1.5)), FAST)
    with pytest.raises(ValueError, match="SearchConfig.seed: must be an int >= 0"):
        FAST.replace(seed=-1)
