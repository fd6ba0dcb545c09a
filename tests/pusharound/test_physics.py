"""PushAround physics: the MuJoCo world from a scene, batched push rollouts, quick-pass, Eq. 11 cost."""
import mujoco
import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import Point, box

from jaxplan.pusharound import shapes
from jaxplan.pusharound.generators import random_shape
from jaxplan.pusharound.physics import PushPhysicsConfig, build_push_world, initial_state, movable_poses
from jaxplan.pusharound.push import (
    PushTask,
    direction_tasks,
    face_contacts,
    make_push_simulator,
    push_cost,
    simulate_pushes,
    stack_tasks,
)
from jaxplan.pusharound.quickpass import free_components, quick_pass, swept_hulls
from jaxplan.pusharound.scene import Fixed, Movable, PushScene
from jaxplan.reference.pusharound import swept_polygon


def _movable(name, shape, pose, mass):
    return Movable(name, shape.pieces, pose, mass, shapes.polygon_inertia(shape.outline, mass), 0.5, None)


def _scene(walls_at=3.2, box_x=2.0):
    """5 x 3 m, a 0.6 x 0.4 m box of 8 kg at (box_x, 1.5), a wall x in [walls_at, walls_at + 0.2]."""
    mov = _movable("box", shapes.rectangle(0.6, 0.4), (box_x, 1.5, 0.0), 8.0)
    wall = Fixed("wall", (box(walls_at, 0.5, walls_at + 0.2, 2.5),))
    return PushScene(workspace=(0, 0, 5, 3), width=0.8, start=(0.5, 2.5), goal=(4.5, 0.5), fixed=(wall,),
                     movables=(mov,), robots=np.array([[0.5, 0.4], [0.5, 1.0]]), robot_radius=0.15)


def _task(world, direction, velocity, n_robots=2, duration=2.0, flip=False):
    c, d, a = face_contacts(world, 0, direction, n_robots)
    return PushTask(0, c, -d if flip else d, a, np.asarray(velocity, float), duration)


@pytest.fixture(scope="module")
def world():
    return build_push_world(_scene())


@pytest.fixture(scope="module")
def c_sim(world):
    return make_push_simulator(world, "c")


@pytest.fixture(scope="module")
def batch(world):
    return stack_tasks([
        _task(world, (1, 0), (0.3, 0, 0)),            # 0: clean push, 0.6 m along +x
        _task(world, (1, 0), (0.6, 0, 0)),            # 1: 1.2 m along +x: into the wall
        _task(world, (1, 0), (0.2, 0, 0.3)),          # 2: push and turn
        _task(world, (0, 1), (0, 0.2, 0), n_robots=1),  # 3: one robot pushes +y
    ])


@pytest.fixture(scope="module")
def c_out(world, c_sim, batch):
    return simulate_pushes(world, batch, sim=c_sim)


def test_world_geometry_matches_scene_pieces():
    """Box pieces (rectangles, L bars) and mesh prisms (cylinder, diamond) sit where the scene says."""
    movs = (_movable("l", shapes.l_shape(0.8, 0.6, 0.2), (1.0, 1.0, 0.7), 6.0),
            _movable("cyl", shapes.cylinder(0.25), (2.5, 1.0, 0.0), 5.0),
            _movable("dia", shapes.diamond(0.5, 0.6), (3.8, 2.0, -0.4), 7.0))
    scene = PushScene(workspace=(0, 0, 5, 3), width=0.8, start=(0.5, 2.7), goal=(4.5, 0.3),
                      fixed=(Fixed("bar", (box(2.0, 2.0, 2.2, 3.0),)),), movables=movs,
                      robots=np.array([[0.3, 0.3]]), robot_radius=0.15)
    w = build_push_world(scene)
    m = w.model
    d = mujoco.MjData(m)
    d.qpos[:], _ = initial_state(w)
    mujoco.mj_forward(m, d)
    kinds = set()
    for gi in range(m.ngeom):
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, gi)
        if not name.startswith("mov"):
            continue
        mi, pi = map(int, name[3:].split("_"))
        rot = d.geom_xmat[gi].reshape(3, 3)
        if m.geom_type[gi] == mujoco.mjtGeom.mjGEOM_MESH:
            adr, n = m.mesh_vertadr[m.geom_dataid[gi]], m.mesh_vertnum[m.geom_dataid[gi]]
            verts = m.mesh_vert[adr:adr + n] @ rot.T + d.geom_xpos[gi]
            assert n <= 32
        else:
            s = m.geom_size[gi]
            verts = np.array([[a * s[0], b * s[1], c * s[2]]
                              for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)]) @ rot.T + d.geom_xpos[gi]
        kinds.add(int(m.geom_type[gi]))
        piece = scene.movables[mi].world_pieces()[pi]
        np.testing.assert_allclose(np.r_[verts[:, :2].min(0), verts[:, :2].max(0)], piece.bounds, atol=1e-6)
        np.testing.assert_allclose([verts[:, 2].min(), verts[:, 2].max()], [0.0, w.config.height], atol=1e-6)
    assert kinds == {int(mujoco.mjtGeom.mjGEOM_BOX), int(mujoco.mjtGeom.mjGEOM_MESH)}
    np.testing.assert_allclose(m.body_mass[1:4], [6.0, 5.0, 7.0])
    # At rest nothing moves (no initial penetration, no pops).
    mujoco.mj_step(m, d, nstep=120)
    poses, upright = movable_poses(w, d.qpos)
    dpos = np.abs(poses[:, :2] - scene.poses[:, :2]).max()
    dyaw = np.abs(np.angle(np.exp(1j * (poses[:, 2] - scene.poses[:, 2])))).max()
    assert dpos < 1e-4 and dyaw < 1e-4 and upright.min() > 0.999


def test_build_rejects_bad_input():
    scene = _scene()
    with pytest.raises(ValueError, match="scene.robots"):
        build_push_world(scene.replace(robots=np.zeros((0, 2))))
    with pytest.raises(ValueError, match="config.kv"):
        build_push_world(scene, PushPhysicsConfig(kv=0.0))


def test_push_moves_box_along_x_and_not_through_wall(world, c_out):
    start = world.scene.poses[0]
    clean, wall = c_out.poses[0, 0], c_out.poses[1, 0]
    assert c_out.valid[0] and not c_out.hit_fixed[0]
    assert 0.5 < clean[0] - start[0] < 0.65 and abs(clean[1] - start[1]) < 0.02 and abs(c_out.rotation[0]) < 0.03
    # The fast push stops at the wall (x = 3.2): the box's front face (x + 0.3) does not pass it.
    assert c_out.hit_fixed[1] and not c_out.valid[1]
    assert 3.2 - 0.3 - 0.02 < wall[0] <= 3.2 - 0.3 + 0.005
    # Push-and-turn turns counter-clockwise; the one-robot +y push moves +y.
    assert c_out.valid[2] and 0.4 < c_out.rotation[2] < 0.7
    assert c_out.valid[3] and c_out.poses[3, 0, 1] - start[1] > 0.3
    assert np.all(c_out.finite) and not np.any(c_out.left_workspace) and not np.any(c_out.tipped)
    assert np.all(c_out.effort > 0) and np.all(np.isfinite(c_out.effort))


def test_batch_equals_single_runs_on_c_engine(world, c_sim, batch, c_out):
    for i in (0, 2):
        one = simulate_pushes(world, PushTask(*(np.asarray(f)[i:i + 1] for f in batch)), sim=c_sim)
        np.testing.assert_allclose(one.poses[0], c_out.poses[i], atol=1e-6)
        np.testing.assert_allclose(one.robots[0], c_out.robots[i], atol=1e-6)
        assert one.valid[0] == c_out.valid[i]


def test_out_of_workspace_and_divergent_candidates_flagged():
    """No boundary walls; the box starts at x = 0.5 and is pushed -x at full speed: it leaves the
    workspace, and past the world box (workspace + 0.5 m) the rollout marks it not finite. A clean
    candidate in the same batch is unaffected."""
    w = build_push_world(_scene(box_x=0.5), PushPhysicsConfig(walls=False, world_margin=0.5))
    sim = make_push_simulator(w, "c")
    out_task = _task(w, (-1, 0), (-0.8, 0, 0), duration=2.0)
    slow_out = _task(w, (-1, 0), (-0.5, 0, 0), duration=1.2)
    fine = _task(w, (1, 0), (0.2, 0, 0))
    out = simulate_pushes(w, stack_tasks([out_task, slow_out, fine]), sim=sim)
    assert not out.finite[0] and out.first_bad[0] > 0 and not out.valid[0]
    assert out.finite[1] and out.left_workspace[1] and not out.valid[1]
    assert out.valid[2] and out.finite[2] and not out.left_workspace[2]
    solo = simulate_pushes(w, stack_tasks([fine]), sim=sim)
    np.testing.assert_allclose(solo.poses[0], out.poses[2], atol=1e-6)


def test_quick_pass(world, batch):
    qp = quick_pass(world, batch)
    np.testing.assert_array_equal(qp.ok, [True, False, True, True])
    assert "fixed obstacle" in qp.reason[1]
    inside = quick_pass(world, stack_tasks([_task(world, (1, 0), (0.3, 0, 0), flip=True)]))
    assert not inside.ok[0] and "overlaps" in inside.reason[0]


@settings(max_examples=40, deadline=None)
@given(shape_seed=st.integers(0, 10_000), pose=st.tuples(st.floats(-3, 3), st.floats(-3, 3), st.floats(-4, 4)),
       velocity=st.tuples(st.floats(-0.6, 0.6), st.floats(-0.6, 0.6), st.floats(-1, 1)),
       duration=st.floats(0.05, 2.0))
def test_swept_hulls_cover_the_reference_sweep(shape_seed, pose, velocity, duration):
    """The quick-pass's vectorised sweep (convex pieces) has the serial reference's union as its union."""
    shape = random_shape(np.random.default_rng(shape_seed))
    mov = Movable("m", shape.pieces, pose, 8.0, shapes.polygon_inertia(shape.outline, 8.0))
    hulls = swept_hulls(mov, np.asarray(pose), np.asarray(velocity), duration)
    assert len(hulls) == 7 * len(shape.pieces) and all(h.geom_type == "Polygon" for h in hulls)
    union = shapely.union_all(hulls)
    ref = swept_polygon(mov, pose, velocity, duration)
    assert union.symmetric_difference(ref).area <= 1e-9 * max(ref.area, 1.0)


def test_push_cost_eq11(world, batch, c_out):
    cost, dt, dj = push_cost(world, batch, c_out, alpha=0.01)
    assert np.isinf(cost[1])  # hit the wall: not validated
    ok = c_out.valid
    np.testing.assert_allclose(cost[ok], dt[ok] + 0.01 * dj[ok])
    # delta_T = farthest active robot's transit + duration: robot 0 of task 0 starts behind the box.
    assert np.all(dt >= batch.duration) and dt[0] > batch.duration[0] + 2.0


def test_bad_tasks_name_the_field(world, c_sim, batch):
    bad = batch._replace(duration=np.array([2.0, 2.0, 2.0, 99.0]))
    with pytest.raises(ValueError, match="tasks.duration"):
        simulate_pushes(world, bad, sim=c_sim)
    with pytest.raises(ValueError, match="tasks.contacts"):
        quick_pass(world, batch._replace(contacts=np.zeros((4, 3, 2))))
    with pytest.raises(ValueError, match="tasks.movable"):
        quick_pass(world, batch._replace(movable=np.array([0, 0, 0, 5])))


def test_mjx_agrees_with_c_engine(world, batch, c_out):
    """One tiny MJX batch (clean push, wall push): same verdicts; displacement within 0.02 m, final
    box pose within 0.03 m / 0.05 rad (MJX float32 vs C float64; contacts differ slightly)."""
    sub = PushTask(*(np.asarray(f)[:2] for f in batch))
    mj = simulate_pushes(world, sub, sim=make_push_simulator(world, "mjx"))
    np.testing.assert_array_equal(mj.valid, c_out.valid[:2])
    np.testing.assert_array_equal(mj.hit_fixed, c_out.hit_fixed[:2])
    np.testing.assert_allclose(mj.displacement, c_out.displacement[:2], atol=0.02)
    np.testing.assert_allclose(mj.poses[:, 0, :2], c_out.poses[:2, 0, :2], atol=0.03)
    np.testing.assert_allclose(mj.rotation, c_out.rotation[:2], atol=0.05)


def test_sleeping_bodies_do_not_change_verdicts(batch, c_out):
    """Island sleeping (C engine speed-up) off vs on: same verdicts, final poses within 0.01 m."""
    w = build_push_world(_scene(), PushPhysicsConfig(sleep=False))
    awake = simulate_pushes(w, batch, backend="c")
    np.testing.assert_array_equal(awake.valid, c_out.valid)
    np.testing.assert_array_equal(awake.hit_fixed, c_out.hit_fixed)
    np.testing.assert_allclose(awake.poses[..., :2], c_out.poses[..., :2], atol=0.01)


def test_direction_tasks_put_contacts_on_the_back_face(world):
    """Four world directions x team sizes 1 and 2 on the 0.6 x 0.4 m box: eight modes; each contact is
    on the boundary, the push direction points into the body, and two robots are a diameter apart."""
    tasks = direction_tasks(world, 0, np.arange(4) * np.pi / 2, speed=0.2, duration=1.0)
    assert len(tasks) == 8
    body = world.scene.movables[0].polygon      # yaw 0: body frame = world frame shifted
    x, y, _ = world.scene.movables[0].pose
    for t in tasks:
        act = np.nonzero(t.active)[0]
        for n in act:
            c = t.contacts[n] + (x, y)
            assert body.exterior.distance(Point(*c)) < 1e-9
            assert body.contains(Point(*(c + 0.02 * t.directions[n])))
            assert not body.contains(Point(*(c - 0.02 * t.directions[n])))
        np.testing.assert_allclose(t.velocity[:2] / 0.2, t.directions[act[0]], atol=1e-12)
        if len(act) == 2:
            assert np.linalg.norm(t.contacts[0] - t.contacts[1]) >= 2 * world.scene.robot_radius
    with pytest.raises(ValueError, match="speed"):
        direction_tasks(world, 0, [0.0], speed=0.0, duration=1.0)


def test_quick_pass_rejects_a_start_walled_off_from_every_robot():
    """A wall across the whole workspace between the robots and the box: every push start point is
    out of reach (check 4), which only the robots' positions reveal."""
    mov = _movable("box", shapes.rectangle(0.6, 0.4), (2.0, 1.5, 0.0), 8.0)
    wall = Fixed("wall", (box(1.0, 0.0, 1.2, 3.0),))
    scene = PushScene(workspace=(0, 0, 5, 3), width=0.8, start=(0.5, 2.5), goal=(4.5, 0.5), fixed=(wall,),
                      movables=(mov,), robots=np.array([[0.5, 0.4], [0.5, 1.0]]), robot_radius=0.15)
    w = build_push_world(scene)
    tasks = stack_tasks([_task(w, (1, 0), (0.3, 0, 0))])
    assert quick_pass(w, tasks).ok[0]                                     # no robots given: not checked
    cut_off = quick_pass(w, tasks, robots=scene.robots)
    assert not cut_off.ok[0] and "walled off" in cut_off.reason[0] and cut_off.walled_off[0]
    assert not quick_pass(w, tasks).walled_off[0]
    assert quick_pass(w, tasks, robots=np.array([[3.0, 0.5], [3.0, 1.0]])).ok[0]   # robots on the box's side
    assert len(free_components(scene, scene.poses, 0.18)) == 2
