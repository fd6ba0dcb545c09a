"""The MJX model's declared contact pairs and contact cap hold the contacts pushes really make (C engine)."""
import mujoco
import numpy as np
import pytest

from jaxplan.pusharound.generators import nominal_scene
from jaxplan.pusharound.physics import PushPhysicsConfig, build_push_world, contact_usage
from jaxplan.pusharound.push import direction_tasks, make_push_simulator, simulate_pushes, stack_tasks
from jaxplan.pusharound.quickpass import quick_pass


def _candidates(world, n, speed=0.3, duration=2.0):
    """``n`` quick-pass candidates spread over the movables (8 directions, teams of 1 and 2)."""
    per = [direction_tasks(world, m, np.arange(8) * np.pi / 4, speed, duration)
           for m in range(len(world.scene.movables))]
    order = [t for k in range(16) for ts in per for t in ts[k:k + 1]]
    batch = stack_tasks(order[:64])
    keep = np.nonzero(quick_pass(world, batch).ok)[0][:n]
    return type(batch)(*(np.asarray(f)[keep] for f in batch))


@pytest.fixture(scope="module")
def world():
    return build_push_world(nominal_scene(0))


def test_mjx_model_declares_pairs_only(world):
    """Every geom of the MJX model has contype = conaffinity = 0; the pairs are the declared ones;
    same bodies, joints and actuators as the C model; congruent pieces share one mesh."""
    mm, m = world.mjx_model, world.model
    assert not mm.geom_contype.any() and not mm.geom_conaffinity.any()
    assert mm.npair == len(world.pairs) > 0
    assert (mm.nq, mm.nv, mm.nu, mm.ngeom) == (m.nq, m.nv, m.nu, m.ngeom)
    np.testing.assert_allclose(mm.geom_pos, m.geom_pos)
    # pair friction and condim follow MuJoCo's mixing of the two geoms (max), as the C model's contacts
    g1, g2 = mm.pair_geom1, mm.pair_geom2
    mixed = np.maximum(m.geom_friction[g1], m.geom_friction[g2])[:, [0, 0, 1, 2, 2]]
    np.testing.assert_allclose(mm.pair_friction, mixed)
    np.testing.assert_array_equal(mm.pair_dim, np.maximum(m.geom_condim[g1], m.geom_condim[g2]))
    n_mesh_geoms = int(np.sum(m.geom_type == mujoco.mjtGeom.mjGEOM_MESH))
    assert 0 < m.nmesh < n_mesh_geoms
    # a longer reach declares a superset of pairs
    far = build_push_world(world.scene, PushPhysicsConfig(push_reach=3.0))
    assert set(world.pairs) < set(far.pairs)


def test_c_engine_contacts_are_declared_and_capped(world):
    """16 quick-pass pushes on the nominal scene, every control tick: each geom pair the C engine
    (collision bits) finds in contact is declared, and no state has more contacts than MJX's cap."""
    tasks = _candidates(world, 16)
    out, traj = simulate_pushes(world, tasks, sim=make_push_simulator(world, "c"), trajectory=True)
    use = contact_usage(world, traj.qpos)
    assert use["undeclared"] == []
    assert 0 < use["max_contacts"] <= use["cap"]
    assert any("robot" in a or "robot" in b for a, b in use["pairs"])   # the robots did push


def test_mjx_rejects_pushes_beyond_reach(world):
    tasks = _candidates(world, 1, speed=0.8, duration=2.0)
    sim = make_push_simulator(world, "mjx")
    with pytest.raises(ValueError, match="reach"):
        simulate_pushes(world, tasks, sim=sim)


def test_declared_pairs_model_steps_like_the_full_model():
    """The C engine on the declared-pairs model and on the full model (sleeping off in both): the same
    final poses for 4 pushes on the nominal scene (the pair rule loses no contact they make)."""
    w = build_push_world(nominal_scene(0), PushPhysicsConfig(sleep=False))
    tasks = _candidates(w, 4)
    full = simulate_pushes(w, tasks, sim=make_push_simulator(w, "c"))
    lean_world = w._replace(model=w.mjx_model)
    lean = simulate_pushes(lean_world, tasks, sim=make_push_simulator(lean_world, "c"))
    np.testing.assert_array_equal(lean.valid, full.valid)
    np.testing.assert_allclose(lean.poses, full.poses, atol=1e-6)
