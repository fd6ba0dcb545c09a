"""PushAround execution (Section III-D): transition paths, P-controlled pushes with early stop in
physics, comparison with the plan, online replanning, the animation."""
from typing import NamedTuple

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, Point

from jaxplan.pusharound.animation import animate_execution, corridor_band, save_final_png
from jaxplan.pusharound.execution import ExecutionConfig, execute_schedule, transition_path
from jaxplan.pusharound.physics import build_push_world
from jaxplan.pusharound.push import PushTask, face_contacts, simulate_pushes, stack_tasks
from jaxplan.pusharound.scene import PushScene
from jaxplan.pusharound.wccg import build_wccg, connectivity

# 4 x 3 m; a wall hangs from the top down to y = 1.0; a 0.4 m box of 6 kg sits in the 1 m opening
# below it (0.3 m each side < W = 0.8): blocked until the box is pushed ~1.2 m along +x.
TINY = {"workspace": [0, 0, 4, 3], "vehicle_width": 0.8, "start": [1.0, 2.2], "goal": [3.0, 2.2],
        "fixed": [{"name": "wall", "pieces": [[[1.9, 1.0], [2.1, 1.0], [2.1, 3.0], [1.9, 3.0]]]}],
        "movables": [{"name": "box", "pieces": [[[-0.2, -0.2], [0.2, -0.2], [0.2, 0.2], [-0.2, 0.2]]],
                      "pose": [2.0, 0.5, 0.0], "mass": 6.0}],
        "robots": {"positions": [[0.5, 0.4], [0.5, 0.9]], "radius": 0.15}}


class Scheduled(NamedTuple):
    """The fields of search.ScheduledPush that execution reads (duck-typed on purpose)."""

    task: PushTask
    gap: object
    cost: float
    poses_before: np.ndarray
    poses_after: np.ndarray
    robots_before: np.ndarray
    robots_after: np.ndarray


class FakeResult(NamedTuple):
    success: bool
    schedule: list
    reason: str = ""


@pytest.fixture(scope="module")
def scene():
    return PushScene.from_dict(TINY)


@pytest.fixture(scope="module")
def world(scene):
    return build_push_world(scene)


def _push(world, speed, poses=None, robots=None, duration=2.0):
    """A two-robot +x push and its predicted outcome from the given state, as the search plans it."""
    c, d, a = face_contacts(world, 0, (1, 0), 2)
    task = PushTask(0, c, d, a, np.array([speed, 0.0, 0.0]), duration)
    poses = world.scene.poses if poses is None else poses
    robots = world.scene.robots if robots is None else robots
    out = simulate_pushes(world, stack_tasks([task]), backend="c", poses=poses, robots=robots)
    return task, out


@pytest.fixture(scope="module")
def planned(world, scene):
    task, out = _push(world, 0.6)
    assert out.valid[0]
    return Scheduled(task, None, 1.0, scene.poses, out.poses[0], scene.robots, out.robots[0])


@pytest.fixture(scope="module")
def executed(scene, world, planned):
    return execute_schedule(scene, [planned], world=world)


def _w_clear(scene, path):
    """Independent check: the path keeps W/2 from every obstacle and from the workspace boundary."""
    line = LineString(path)
    r = 0.5 * scene.width - 1e-6
    assert all(line.distance(o) >= r for o in scene.obstacle_polygons())
    assert scene.workspace_polygon.buffer(-r).covers(line)


def test_tiny_scene_is_blocked_and_the_planned_push_opens_it(scene, planned):
    assert not connectivity(build_wccg(scene), scene.start, scene.goal).connected
    opened = scene.with_poses(planned.poses_after)
    assert connectivity(build_wccg(opened), scene.start, scene.goal).connected


def test_transition_path_avoids_obstacles(scene, planned):
    """Around the wall's lower end, through the opening the push made; robot disks never touch an
    obstacle and stay in the workspace."""
    after = scene.with_poses(planned.poses_after)
    a, b = np.array([0.5, 2.5]), np.array([2.6, 2.5])
    path = transition_path(after, a, b)
    assert np.allclose(path[0], a) and np.allclose(path[-1], b)
    assert len(path) > 2                                    # not the straight line through the wall
    line = LineString(path)
    r = float(scene.robot_radius)
    assert min(line.distance(o) for o in after.obstacle_polygons()) >= r
    assert scene.workspace_polygon.buffer(-r).covers(line)
    assert np.all(np.isfinite(path))


def test_scheduled_push_ends_near_its_predicted_pose(scene, planned, executed):
    ex = executed
    assert len(ex.executed) == 1
    push = ex.executed[0]
    assert push.ok and push.valid
    assert push.stop in ("reached", "horizon", "stalled")
    dev = np.linalg.norm(push.poses_after[0, :2] - planned.poses_after[0, :2])
    assert dev < 0.06                                      # transit arrives a little differently
    assert push.poses_after[0, 0] > 3.0                    # the box really left the opening
    assert push.transit_s > 0 and push.push_s > 0
    assert ex.success and ex.connectivity and ex.reason == "connected" and ex.replans == 0
    _w_clear(ex.final_scene, ex.w_clear_path)
    assert ex.execution_time_s > push.transit_s + push.push_s              # + the final retreat
    # the robots backed off the box: the final scene is a valid scene again
    PushScene.from_dict(ex.final_scene.to_dict())


def test_frames_record_the_execution(scene, executed):
    fr = executed.frames
    k = len(fr.time)
    assert k > 10 and fr.poses.shape == (k, 1, 3) and fr.robots.shape == (k, 2, 2) and len(fr.phase) == k
    assert np.all(np.diff(fr.time) > 0) and fr.time[0] == 0.0
    assert np.all(np.isfinite(fr.poses)) and np.all(np.isfinite(fr.robots))
    assert set(fr.phase) == {"start", "transit", "push", "retreat"}
    assert np.allclose(fr.poses[0], scene.poses)
    np.testing.assert_allclose(fr.poses[-1], executed.final_scene.poses, atol=0.05)


def test_failed_push_triggers_an_online_replan(scene, world, planned):
    """The plan claims the outcome of 0.6 m/s for 2 s for a push of 0.2 m/s for 0.6 s: the box stalls
    far from its predicted pose, the push fails, ``replan`` gets the current state and its schedule
    finishes the job."""
    slow, _ = _push(world, 0.2, duration=0.6)
    wrong = planned._replace(task=slow)
    calls = []

    made = []

    def replan(now):
        calls.append(now)
        task, out = _push(world, 0.6, poses=now.poses, robots=now.robots)
        made.append(Scheduled(task, None, 1.0, now.poses, out.poses[0], now.robots, out.robots[0]))
        return FakeResult(True, made[-1:])

    ex = execute_schedule(scene, [wrong], world=world, replan=replan)
    assert len(calls) == 1 and ex.replans == 1
    first, second = ex.executed
    assert not first.ok and first.stop == "stalled" and first.deviation > 0.5
    assert first.plan == 0 and second.plan == 1 and second.ok
    # the replanner saw the state after the failed push, robots included
    assert calls[0].poses[0, 0] == pytest.approx(first.poses_after[0, 0])
    np.testing.assert_allclose(calls[0].robots, first.robots_after)
    assert ex.success
    _w_clear(ex.final_scene, ex.w_clear_path)

    # without a replanner the rest of the schedule runs open loop (the physics is deterministic: the
    # replanned push, appended to the schedule, starts from the same state and finishes the job)
    blind = execute_schedule(scene, [wrong, made[0]], world=world)
    assert [e.ok for e in blind.executed] == [False, True] and blind.success and blind.replans == 0
    # a replanner that finds nothing: the failure is recorded, the (empty) rest runs, execution ends
    gave_up = execute_schedule(scene, [wrong], world=world, replan=lambda now: FakeResult(False, [], "no plan"))
    assert not gave_up.success and gave_up.reason.startswith("push failed; replan 1 failed (no plan)")
    assert gave_up.replans == 1 and len(gave_up.executed) == 1


def test_push_cap_counts_from_the_schedule_length(scene, world, planned, monkeypatch):
    """``max_pushes=None`` allows the schedule's own pushes plus ``EXTRA_PUSHES`` for replanning, so
    a long plan is never cut short; an explicit cap counts every executed push."""
    from jaxplan.pusharound.execution import run as execution_run

    slow, _ = _push(world, 0.2, duration=0.6)
    wrong = planned._replace(task=slow)
    replan = lambda now: FakeResult(True, [planned._replace(poses_before=now.poses)])  # noqa: E731
    monkeypatch.setattr(execution_run, "EXTRA_PUSHES", 0)
    whole = execute_schedule(scene, [wrong, planned], world=world)   # two planned pushes, both run
    assert len(whole.executed) == 2 and whole.reason != "max_pushes (2) reached"
    capped = execute_schedule(scene, [wrong], world=world, replan=replan)   # no room for the replan's push
    assert capped.replans == 1 and len(capped.executed) == 1 and capped.reason == "max_pushes (1) reached"
    assert not capped.success
    explicit = execute_schedule(scene, [wrong, planned], world=world, config=ExecutionConfig(max_pushes=1))
    assert len(explicit.executed) == 1 and explicit.reason == "max_pushes (1) reached"


def test_bad_execution_input_is_named(scene, planned):
    with pytest.raises(ValueError, match="record_every"):
        execute_schedule(scene, [planned], record_every=0)
    with pytest.raises(ValueError, match="max_replans"):
        execute_schedule(scene, [planned], config=ExecutionConfig(max_replans=-1))
    with pytest.raises(ValueError, match="max_pushes"):
        execute_schedule(scene, [planned], config=ExecutionConfig(max_pushes=0))
    with pytest.raises(ValueError, match="scene"):
        execute_schedule({"not": "a scene"}, [planned])
    other = build_push_world(PushScene.from_dict({**TINY, "robots": {"positions": [[0.5, 0.4]], "radius": 0.15}}))
    with pytest.raises(ValueError, match="world"):
        execute_schedule(scene, [planned], world=other)


def test_animation_and_final_png(tmp_path, scene, executed):
    import matplotlib

    matplotlib.use("Agg")
    gif, png = tmp_path / "a.gif", tmp_path / "a.png"
    seen = []
    animate_execution(scene, executed, gif, max_frames=4, hold_s=0.2, dpi=40, progress=lambda i, n: seen.append(i))
    save_final_png(executed.final_scene, executed.final_scene.poses, executed.final_scene.robots,
                   executed.w_clear_path, png, dpi=40)
    from PIL import Image

    assert Image.open(gif).n_frames >= 2 and Image.open(png).size[0] > 0
    assert max(seen) == len(set(seen)) >= 2          # every frame reported (frame 0 twice: the init draw)
    band = corridor_band(executed.w_clear_path, scene.width)
    # the band is the vehicle's swept disk: it covers both endpoint disks and no obstacle
    assert band.covers(Point(scene.start).buffer(0.5 * scene.width - 1e-3, 16))
    assert all(band.intersection(o).area < 1e-6 for o in executed.final_scene.obstacle_polygons())
    assert corridor_band(None, scene.width) is None
    assert shapely.is_valid(band)


def test_transit_policy_tracks_its_path_jitted_and_not():
    """On the reference the control is the feed-forward: speed along the current segment; a robot with
    a one-point path holds still; the padded tail of a path is finite (no 0/0 in the interpolation)."""
    import functools

    import jax
    import jax.numpy as jnp

    from jaxplan.pusharound.execution import transit_policy
    from jaxplan.pusharound.execution.control import pack_paths

    path, lens = pack_paths([np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]), np.array([[2.0, 2.0]])])
    pol = functools.partial(transit_policy, (0, 1, 2, 3), 4.0, 0.8)
    params = {"path": jnp.asarray(path), "arclen": jnp.asarray(lens), "speed": jnp.asarray(0.5), "t0": jnp.asarray(1.0)}
    for t, on_ref, ff in ((0.0, [0.5, 0.0], [0.5, 0.0]), (2.0, [1.0, 0.5], [0.0, 0.5]), (9.0, [1.0, 1.0], [0.0, 0.0])):
        qpos = jnp.asarray(on_ref + [2.0, 2.0])
        for f in (pol, jax.jit(pol)):
            u, _ = f(params, None, qpos, jnp.zeros(4), jnp.asarray(t))
            np.testing.assert_allclose(np.asarray(u), ff + [0.0, 0.0], atol=1e-6)
    # off the reference the P term pulls back, clipped to vmax
    u, _ = jax.jit(pol)(params, None, jnp.asarray([0.5, 3.0, 2.0, 2.0]), jnp.zeros(4), jnp.asarray(0.0))
    assert np.all(np.isfinite(np.asarray(u))) and np.linalg.norm(np.asarray(u)[:2]) == pytest.approx(0.8, rel=1e-5)
    assert np.asarray(u)[1] < 0


def test_transition_path_brushes_a_movable_only_when_no_clear_route_exists(scene):
    """The box leaves 0.3 m each side in the opening below the wall, too little for a robot with its
    margin: with brushing the path squeezes past the box (never touching the wall); without it, the
    straight segment through the wall. Where a clear route exists both find it."""
    from jaxplan.pusharound.execution.roadmap import Roadmap

    r = float(scene.robot_radius)
    a, b = np.array([0.5, 2.0]), np.array([3.5, 2.0])
    strict = Roadmap(scene, scene.poses, r + 0.03, 0.05)
    assert len(strict.path(a, b)) == 2
    brush = Roadmap(scene, scene.poses, r + 0.03, 0.05, (), r + 0.01, 10.0)
    path = brush.path(a, b)
    assert len(path) > 2 and np.allclose(path[0], a) and np.allclose(path[-1], b)
    line = LineString(path)
    assert line.distance(scene.fixed[0].polygon) >= r
    assert line.distance(scene.movables[0].polygon) < r + 0.03
    assert scene.workspace_polygon.buffer(-r).covers(line)
    opened = scene.with_poses([[3.5, 2.6, 0.0]])
    clear = Roadmap(opened, opened.poses, r + 0.03, 0.05, (), r + 0.01, 10.0).path(a, b)
    assert LineString(clear).distance(opened.movables[0].polygon) >= r + 0.03 - 1e-6
    with pytest.raises(ValueError, match="brush_weight"):
        execute_schedule(scene, [], config=ExecutionConfig(brush_weight=-1.0))


def test_contacts_are_swapped_when_a_late_robot_would_cross_an_early_ones_contact(scene):
    """Two robots come from the left to two start points side by side on a line: the far robot must
    take the nearer point, or it would drive over the near robot's point after that robot arrived
    (a deadlock in physics). Both assignments have the same total length: only the timing decides."""
    from jaxplan.pusharound.execution.roadmap import Roadmap
    from jaxplan.pusharound.execution.transit import plan_transit

    open_scene = scene.with_poses([[3.5, 2.6, 0.0]])                    # box out of the way
    robots = np.array([[0.3, 0.5], [1.2, 0.5]])                          # far, near
    starts = np.array([[2.66, 0.5], [2.34, 0.5]])                        # right, left
    roadmap = Roadmap(open_scene, open_scene.poses, 0.18, 0.05)
    perm, paths = plan_transit(roadmap, robots, starts, np.array([True, True]), 0.5, 0.15)
    assert perm.tolist() == [1, 0]                                       # far -> left point, near -> right
    np.testing.assert_allclose(paths[0][-1], starts[1])
    np.testing.assert_allclose(paths[1][-1], starts[0])
    # one active robot: nothing to swap; the idle one keeps its place
    perm, paths = plan_transit(roadmap, robots, starts, np.array([True, False]), 0.5, 0.15)
    assert perm.tolist() == [0, 1] and len(paths[1]) == 1


def test_robots_driving_head_on_meet_and_parallel_ones_do_not():
    from jaxplan.pusharound.execution.transit import paths_meet

    a, b = np.array([[0.0, 0.0], [2.0, 0.0]]), np.array([[2.0, 0.0], [0.0, 0.0]])
    assert paths_meet(a, b, 0.5, 0.15)                                         # swap places on one line
    assert not paths_meet(a, a + [0.0, 0.5], 0.5, 0.15)                        # side by side, 0.5 m apart
    touching = np.array([[0.0, 0.3], [0.0, 1.0]])                         # start in contact, move apart
    assert not paths_meet(np.array([[0.0, 0.0], [0.0, -1.0]]), touching, 0.5, 0.15)
    assert not paths_meet(a[:1], np.array([[1.0, 0.0]]), 0.5, 0.15)            # two robots standing still


def test_a_corridor_that_closes_during_the_retreat_does_not_end_the_execution():
    """Nominal seed 14: the plan's first push opens the corridor just W wide and the body, still
    sliding after the early stop, closes it again while the robots back off. Execution must judge the
    corridor after the retreat and carry on (here with the schedule's second push), not end
    "connected" on a state that fails Eq. 7 (as it did before)."""
    from jaxplan.pusharound.generators import nominal_scene
    from jaxplan.pusharound.search import SearchConfig, plan_pushes

    scene = nominal_scene(14)
    res = plan_pushes(scene, SearchConfig(seed=14))
    out = execute_schedule(scene, res)
    assert "corridor closed during the retreat" in out.reason
    assert out.success and out.connectivity and out.reason.startswith("connected")
    assert len(out.executed) == len(res.schedule) == 2
