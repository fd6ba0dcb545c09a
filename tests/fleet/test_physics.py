"""Concurrent pushes in one MuJoCo world: disjoint routes never bring two rovers into contact, a
crossing pair does (the detector works), and every route's particle mass is accounted for. A 16 x 16
scene with hand-made straight and diagonal routes and a few dozen particles; the C engine."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxplan.fleet import physics as fp
from jaxplan.transport import execute, spillage
from jaxplan.transport.physics import model as rover_mod
from jaxplan.transport.scene import Scene, box

SLOTS = 24
SPILL = spillage.SpillParams()


def _scene():
    """16 x 16, the target is the top four rows; gravel on three columns and on the crossing's cells."""
    obj = np.zeros((16, 16))
    obj[4:8, 2] = 2
    obj[5:8, 7] = [1, 2, 1]
    obj[3:9, 12] = 1
    return Scene.from_arrays(obj, box(0.0, 12.0, 16.0, 16.0), name="fleet16")


def _route(scene, cells):
    pad = np.full((SLOTS, 2), -1, np.int32)
    pad[: len(cells)] = cells
    return execute.route_from_path(scene, jnp.asarray(pad), jnp.int32(len(cells)), jnp.bool_(False))


def _stack(routes):
    return jax.tree.map(lambda *a: np.stack([np.asarray(x) for x in a]), *routes)


def _columns(scene):
    """Three straight routes up columns 2, 7 and 12 into the target: footprints 4 cells apart;
    different lengths, so two rovers park while the third still pushes."""
    return _stack([_route(scene, [(r, 2) for r in range(4, 13)]), _route(scene, [(r, 7) for r in range(5, 13)]),
                   _route(scene, [(r, 12) for r in range(3, 13)])])


def _crossing(scene):
    """Two diagonals crossing at cell (9, 8), reached by both rovers at the same step."""
    a = [(5 + k, 4 + k) for k in range(8)]
    b = [(5 + k, 12 - k) for k in range(8)]
    return _stack([_route(scene, a), _route(scene, b)])


@pytest.fixture(scope="module")
def runs():
    scene = _scene()
    return scene, {"disjoint": fp.check_concurrent_pushes(scene, _columns(scene), spill=SPILL),
                   "crossing": fp.check_concurrent_pushes(scene, _crossing(scene), spill=SPILL)}


def test_disjoint_routes_have_no_rover_contact(runs):
    _, checks = runs
    chk = checks["disjoint"]
    assert chk.finite and chk.reached.all()
    assert chk.contacts == 0 and chk.contact_events.shape == (0, 3)
    assert chk.min_axle_distance > 4.0 * chk.world.cell_size


def test_a_crossing_pair_registers_contacts(runs):
    _, checks = runs
    chk = checks["crossing"]
    assert chk.contacts > 0
    assert set(map(tuple, chk.contact_events[:, 1:].tolist())) == {(0, 1)}
    assert np.all(chk.contact_events[:, 0] >= 1) and np.all(chk.contact_events[:, 0] <= chk.n_steps)
    assert chk.min_axle_distance < 2.0 * chk.world.cell_size


@pytest.mark.parametrize("case", ["disjoint", "crossing"])
def test_every_route_accounts_for_its_particles(runs, case):
    scene, checks = runs
    chk = checks[case]
    n = chk.collected.shape[0]
    parts = chk.delivered + chk.left_behind + chk.spilled + chk.lost
    for key in ("collected", "delivered", "left_behind", "spilled", "lost", "predicted_delivered",
                "predicted_collected"):
        value = getattr(chk, key)
        assert value.shape == (n,) and np.all(np.isfinite(value)) and np.all(value >= 0), key
    np.testing.assert_allclose(parts, chk.collected, atol=1e-9)
    # every particle belongs to one route and started on one of its cells, each cell once
    assert chk.particle_route.shape[0] == chk.particle_cells.shape[0] == int(round(chk.collected.sum()))
    np.testing.assert_array_equal(np.bincount(chk.particle_route, minlength=n), chk.collected)
    counts = np.zeros(scene.shape)
    np.add.at(counts, tuple(chk.particle_cells.T), 1.0)
    assert np.all(counts <= np.asarray(scene.obj))
    assert np.all(np.isfinite(chk.relative_error[chk.predicted_delivered > 0]))
    np.testing.assert_array_equal(chk.within, chk.relative_error <= fp.TOLERANCE)


def test_disjoint_pushes_deliver_what_the_2d_model_predicts(runs):
    _, checks = runs
    chk = checks["disjoint"]
    np.testing.assert_allclose(chk.collected, chk.predicted_collected)
    assert chk.fraction_within == 1.0 and np.all(chk.delivered > 0)


def test_a_route_that_ends_early_parks_its_rover(runs):
    _, checks = runs
    chk = checks["disjoint"]
    first = int(np.argmin(chk.finish_time))
    assert chk.finish_time[first] < chk.finish_time.max() - 0.5
    parked = int(round(chk.finish_time[first] / chk.tick_seconds)) + 10     # the rover coasted to rest
    drift = np.linalg.norm(chk.rover_xy[parked:, first] - chk.rover_xy[parked, first], axis=-1)
    assert drift.max() < 0.02 * chk.world.cell_size


def test_explicit_starts_at_the_default_pose_change_nothing(runs):
    scene, checks = runs
    routes = _crossing(scene)
    again = fp.check_concurrent_pushes(scene, routes, checks["crossing"].rover_xy[0], spill=SPILL, n_ticks=40)
    np.testing.assert_array_equal(again.rover_xy, checks["crossing"].rover_xy[:41])


def test_the_world_holds_n_colliding_rovers_and_one_rover_is_unchanged():
    scene = _scene()
    one = rover_mod.build_world(scene, 3)
    three = rover_mod.build_world(scene, 3, n_rovers=3)
    assert one.n_rovers == 1 and one.model.geom("chassis").contype == 4 and one.model.geom("chassis").conaffinity == 0
    assert three.model.nu == 6 and list(rover_mod.rover_qpos_adr(three)) == [0, 9, 18]
    for i in range(3):
        chassis = three.model.geom(f"r{i}_chassis")
        assert chassis.contype & 8 and chassis.conaffinity & 8
    q = rover_mod.initial_qpos(three, [[1.0, 1.0], [4.0, 1.0], [8.0, 1.0]], [0.0, 0.5, 1.0],
                               [[5.0, 5.0, 0.06]])
    np.testing.assert_allclose(three.particle_xyz(q)[0], [5.0, 5.0, 0.06])
    assert q[9] == 4.0 and q[18] == 8.0
    d = mujoco.MjData(three.model)
    d.qpos[:] = q
    mujoco.mj_forward(three.model, d)
    assert np.all(np.isfinite(d.qacc))


def test_footprints_pick_disjoint_routes():
    scene = _scene()
    routes = _stack([_route(scene, [(r, 2) for r in range(4, 13)]), _route(scene, [(r, 3) for r in range(4, 13)]),
                     _route(scene, [(r, 5) for r in range(4, 13)]), _route(scene, [(r, 7) for r in range(5, 13)])])
    foot = fp.route_footprint(scene, jax.tree.map(lambda a: a[0], routes))
    assert foot[4:13, 1:4].all() and foot.sum() == 11 * 3
    # dilated columns: route 0 -> 1..3, route 1 -> 2..4 (overlaps 0), route 2 -> 4..6, route 3 -> 6..8 (overlaps 2)
    np.testing.assert_array_equal(fp.disjoint_routes(scene, routes, 4), [0, 2])
    np.testing.assert_array_equal(fp.disjoint_routes(scene, routes, 1), [0])


@pytest.mark.parametrize("kwargs, field", [({"speed": -1.0}, "speed"), ({"starts_xy": np.zeros((3, 2))}, "starts_xy"),
                                           ({"settle_ticks": -1}, "settle_ticks")])
def test_bad_inputs_name_the_field(kwargs, field):
    scene = _scene()
    with pytest.raises(ValueError, match=field):
        fp.check_concurrent_pushes(scene, _crossing(scene), spill=SPILL, **kwargs)


def test_the_first_round_is_the_first_step_with_the_most_tasks_running():
    class Run:
        pushes = [dict(rover=0, first_step=1, last_step=5), dict(rover=1, first_step=3, last_step=9),
                  dict(rover=0, first_step=6, last_step=8), dict(rover=2, first_step=7, last_step=12),
                  dict(rover=1, first_step=10, last_step=11)]

    picked = fp.first_round(Run())
    assert [(p["rover"], p["first_step"]) for p in picked] == [(0, 6), (1, 3), (2, 7)]   # all running at step 7
    Run.pushes = []
    assert fp.first_round(Run()) == []


def test_blocked_cells_are_walls_in_the_fleet_world_and_no_rover_contact():
    """A wall of blocked cells (columns 4-5, rows 2-10) between the first two columns: one box in the
    fleet's world; rover 0, started with its wing in the wall, touches it, and that is not counted as a
    contact between rovers. Two control ticks."""
    base = _scene()
    blocked = np.zeros((16, 16), bool)
    blocked[2:11, 4:6] = True
    scene = Scene.from_arrays(np.asarray(base.obj), base.target, name="walled", blocked=blocked)
    routes = _columns(scene)
    starts = fp.check_concurrent_pushes(scene, routes, spill=SPILL, n_ticks=1).rover_xy[0].copy()
    starts[0, 0] = 3.55                  # the wing's outer face at x = 4.05, 0.05 inside the wall
    chk = fp.check_concurrent_pushes(scene, routes, starts, spill=SPILL, n_ticks=2)
    m = chk.world.model
    wall = m.geom("blocked0").id
    assert chk.world.n_obstacles == 1 and chk.world.n_rovers == 3
    np.testing.assert_allclose(m.geom_pos[wall][:2], [5.0, 6.5])
    np.testing.assert_allclose(m.geom_size[wall][:2], [1.0, 4.5])
    assert chk.finite and chk.contacts == 0 and chk.contact_events.shape == (0, 3)
    d = mujoco.MjData(m)
    d.qpos[:] = rover_mod.initial_qpos(chk.world, starts, np.full(3, np.pi / 2), [])
    mujoco.mj_forward(m, d)
    rover0 = m.body("r0_rover").id
    touched = {int(g2 if g1 == wall else g1) for g1, g2 in d.contact.geom[: d.ncon] if wall in (g1, g2)}
    assert touched and all(m.body_rootid[m.geom_bodyid[g]] == rover0 for g in touched)
