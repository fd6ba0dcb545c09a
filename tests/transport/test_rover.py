"""Physics: both rollout engines agree, divergence is flagged per element, contact caps hold the pile,
projection back to the grid conserves mass and feeds the selective rebuild, a vmapped batch equals
single rollouts. Tiny scenes and short horizons; each engine compiles/builds once per module."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxplan import FabricParams, build_fabric, builtin_scene
from jaxplan.physics.rollout import Simulator, warp_available
from jaxplan.transport import execute
from jaxplan.transport.physics import bridge
from jaxplan.transport.physics import model as rover
from jaxplan.transport.rebuild import selective_rebuild
from jaxplan.transport.scene import Scene, box

TICKS = 240      # 12 s: the tiny routes finish in 10.2 and 9.3 s (blade pushed 1 cell past the end)
# MJX's rollouts here are bound by running, not compiling (hundreds of contact-rich ticks): with LLVM's
# optimisations, which tests/conftest.py turns off suite-wide, they compile ~15% slower and run ~5x
# faster. Optimised programs of different horizons or batch sizes round differently, so a check to 1e-5
# compares runs of one program.
MJX_OPTIONS = {"xla_backend_optimization_level": 2}


def _tiny_scene():
    obj = np.zeros((5, 8))
    obj[2, 1:4] = [2, 1, 2]
    obj[1, 2] = 1
    return Scene.from_arrays(obj, box(6.0, 0.0, 8.0, 5.0), name="tiny")


@pytest.fixture(scope="module")
def tiny():
    scene = _tiny_scene()
    _, routes, _ = bridge.plan_routes(scene, n_routes=2)
    world = bridge.world_for_routes(scene, routes)
    sims = {be: Simulator(world.model, bridge.pursuit_policy, substeps=world.config.substeps,
                          bounds=world.bounds, backend=be, compiler_options=MJX_OPTIONS) for be in ("c", "mjx")}
    checks = {be: bridge.check_routes(scene, routes, n_ticks=TICKS, world=world, simulator=sim)
              for be, sim in sims.items()}
    return scene, routes, world, sims, checks


def test_backends_agree_on_verdicts(tiny):
    _, _, world, _, checks = tiny
    c, m = checks["c"].outcome, checks["mjx"].outcome
    assert c.finite.all() and m.finite.all() and c.reached.all() and m.reached.all()
    # tolerances of docs/physics.md: delivered mass within 10% of the collected mass (+ 1 particle),
    # mean lateral error within 0.02 cell, stopping time within 0.5 s, final rover pose within 0.05 cell
    assert np.all(np.abs(c.delivered - m.delivered) <= 0.1 * c.collected + 1.0)
    assert np.allclose(c.mean_lateral, m.mean_lateral, atol=0.02)
    assert np.allclose(c.time, m.time, atol=0.5)
    pose_c = checks["c"].trajectory.qpos[:, -1, :2]
    pose_m = checks["mjx"].trajectory.qpos[:, -1, :2]
    assert np.max(np.abs(pose_c - pose_m)) / world.cell_size < 0.05
    # and the rover did drive the route: the tiny routes deliver their whole load
    assert np.all(c.delivered == c.collected) and np.all(c.collected > 0)


FREE_TICKS = 17   # ticks before the blade meets the tiny scene's gravel (a particle moves at tick 17)
# 2 s: the rover is under way and its blade has pushed the first particles for 23 ticks. The checks
# that are not about a whole route (Warp's path, divergence, vmap) run this many ticks, not TICKS:
# MJX-Warp steps the tiny world at ~180 ms of CPU per tick, and a NaN element in a batch makes MJX's
# steps several times slower (its solver never converges).
SHORT_TICKS = 40


@pytest.mark.skipif(not warp_available(), reason="warp-lang not installed (pip install 'jaxplan[warp]')")
def test_warp_drives_the_routes_like_the_c_engine(tiny):
    """MJX-Warp on the rover world: finite, and the rover's path within 1 cm of the C engine's at
    every tick of the first 2 s (the C run is the fixture's, whose first ticks are these)."""
    scene, routes, world, _, checks = tiny
    sim = Simulator(world.model, bridge.pursuit_policy, substeps=world.config.substeps, bounds=world.bounds,
                    backend="warp")
    warp = bridge.check_routes(scene, routes, n_ticks=SHORT_TICKS, world=world, simulator=sim)
    assert warp.trajectory.backend == "warp" and warp.trajectory.finite.all()
    path_c = checks["c"].trajectory.qpos[:, :SHORT_TICKS + 1, :2]
    path_w = warp.trajectory.qpos[:, :, :2]
    assert np.max(np.abs(path_w - path_c)) / world.cell_size < 0.01
    assert np.max(np.abs(path_c[:, -1] - path_c[:, 0])) > 1.0     # it did drive


DEMO_TICKS = 90    # 4.5 s: the blade is in the pile (the test asserts at least 10 particles moved)
DEMO_CELLS = 4     # the route's first cells: the ones the blade reaches in DEMO_TICKS, and one more


def test_backends_agree_on_the_demo_route_while_it_pushes_gravel():
    """The first cells of the demo scene's first route (22 of its 64 particles) on both engines, cut
    short: MJX on a CPU compiles and steps every particle pair. Tolerances of docs/physics.md
    ("Engine agreement")."""
    scene = builtin_scene("default")
    _, routes, _ = bridge.plan_routes(scene, n_routes=1)
    routes = routes._replace(n_cells=np.minimum(np.asarray(routes.n_cells), DEMO_CELLS))
    world = bridge.world_for_routes(scene, routes)
    sims = {be: Simulator(world.model, bridge.pursuit_policy, substeps=world.config.substeps, bounds=world.bounds,
                          backend=be, compiler_options=MJX_OPTIONS) for be in ("c", "mjx")}
    runs = {be: bridge.check_routes(scene, routes, n_ticks=DEMO_TICKS, world=world, simulator=sim)
            for be, sim in sims.items()}
    n = len(runs["c"].particle_cells[0])

    def displacement(check):
        q = check.trajectory.qpos[0]
        return np.linalg.norm(world.particle_xyz(q[-1])[:n, :2] - world.particle_xyz(q[0])[:n, :2], axis=1)

    c, m = runs["c"], runs["mjx"]
    assert c.outcome.finite[0] and m.outcome.finite[0]
    moved_c, moved_m = displacement(c), displacement(m)
    assert (moved_c > 0.1 * world.cell_size).sum() >= 10          # the blade is in the pile
    assert abs(int((moved_c > 0.1).sum()) - int((moved_m > 0.1).sum())) <= 4
    assert abs(float(moved_c.mean()) - float(moved_m.mean())) <= 0.05 * world.cell_size
    assert abs(float(c.outcome.mean_lateral[0]) - float(m.outcome.mean_lateral[0])) <= 0.005
    pose = np.abs(c.trajectory.qpos[0, -1, :2] - m.trajectory.qpos[0, -1, :2])
    assert np.max(pose) / world.cell_size < 0.02


@pytest.mark.parametrize("backend, broken", [("c", 0), ("c", 1), ("mjx", 0)])
def test_divergence_is_flagged_not_fatal(tiny, backend, broken):
    """One element starts broken (element 0: a NaN velocity; element 1: a particle outside the world):
    it is flagged at its first tick and its healthy neighbour is untouched: the same trajectory as in the
    unbroken batch (for MJX, run by the same program). Batch 2. Both engines check a state with one
    function (``rollout._state_ok``), so MJX, slow to run on a CPU, runs the NaN case only, and for
    SHORT_TICKS (past the blade's first contacts with the gravel, where the solver works hardest); the C
    engine runs the fixture's whole horizon."""
    _, _, world, sims, checks = tiny
    ref = checks[backend]
    params, pstate = _stack(ref.params, [0, 1]), _stack(_pstate0(2), [0, 1])
    q0 = ref.trajectory.qpos[:, 0].copy()
    v0 = ref.trajectory.qvel[:, 0].copy()
    if broken == 0:
        v0[0, 0] = np.nan
    else:
        q0[1, 9: 12] = world.bounds[1] + 1.0
    n_ticks = TICKS if backend == "c" else SHORT_TICKS
    out = sims[backend].run(q0, v0, params, pstate, n_ticks)
    healthy = 1 - broken
    assert not bool(out.finite[broken]) and bool(out.finite[healthy])
    assert out.first_bad[broken] == 1 and out.first_bad[healthy] == -1
    if backend == "c":
        unbroken = ref.trajectory.qpos[:, :n_ticks + 1]
    else:
        unbroken = sims[backend].run(ref.trajectory.qpos[:, 0], ref.trajectory.qvel[:, 0], params, pstate,
                                     n_ticks).qpos
    np.testing.assert_allclose(out.qpos[healthy], unbroken[healthy], atol=1e-5)


def _pstate0(b):
    import jax.numpy as jnp

    return (jnp.zeros(b, jnp.float32), jnp.zeros(b, bool))


def _stack(tree, rows):
    import jax

    return jax.tree_util.tree_map(lambda a: a[np.asarray(rows)], tree)


def test_vmapped_batch_equals_single_rollouts(tiny):
    """B=1 rollouts of SHORT_TICKS against the fixture's B=2 rollout over the same ticks."""
    _, _, _, sims, checks = tiny
    ref = checks["mjx"]
    n = SHORT_TICKS
    for i in range(2):
        one = sims["mjx"].run(ref.trajectory.qpos[i:i + 1, 0], ref.trajectory.qvel[i:i + 1, 0],
                              _stack(ref.params, [i]), _stack(_pstate0(2), [i]), n)
        # a B=1 program is compiled differently (float32 rounding differs, more so optimised), and
        # contacts amplify rounding: states agree within 5e-4 world units before the blade meets the
        # gravel, and the verdict after
        np.testing.assert_allclose(one.qpos[0, :FREE_TICKS], ref.trajectory.qpos[i, :FREE_TICKS], atol=5e-4)
        assert np.max(np.abs(one.qpos[0, -1, :2] - ref.trajectory.qpos[i, n, :2])) < 0.05
        first_bad = int(ref.trajectory.first_bad[i])
        assert bool(one.finite[0]) == (first_bad == -1 or first_bad > n)
        # the B=1 program is compiled by the first call and reused by the second (and by compile)
        assert (sims["mjx"].compile_seconds > 0) == (i == 0)
        args = (ref.trajectory.qpos[i:i + 1, 0], ref.trajectory.qvel[i:i + 1, 0], _stack(ref.params, [i]),
                _stack(_pstate0(2), [i]), n)
        assert sims["mjx"].compile(*args) == 0.0 and sims["c"].compile(*args) == 0.0
    assert sims["mjx"].memory_bytes > 0 and sims["c"].memory_bytes is None


def test_contact_caps_hold_the_pile_on_the_demo_scene():
    scene = builtin_scene("default")
    _, routes, _ = bridge.plan_routes(scene, n_routes=1)
    check = bridge.check_routes(scene, routes, backend="c", horizon_factor=1.2)
    world = check.world
    assert bridge.world_for_routes(scene, routes).n_particles == world.n_particles   # the world check_routes built
    assert check.outcome.finite.all() and check.outcome.collected[0] > 30
    usage = rover.contact_usage(world, check.trajectory.qpos[0, ::5])
    caps = world.caps
    # MJX keeps the max_geom_pairs closest pairs per type group and the max_contact_points deepest
    # contacts: nothing is dropped while the penetrating contacts fit under both
    assert usage["sphere-sphere"] <= caps["max_geom_pairs"]
    assert world.n_particles * rover.HULL_BOXES <= caps["max_geom_pairs"]   # hull pairs never culled
    assert usage["total"] <= caps["max_contact_points"]
    assert usage["sphere-sphere"] > 0 and usage["sphere-box"] > 0          # the blade did push gravel


def test_projection_conserves_mass_and_feeds_the_selective_rebuild(tiny):
    scene, _, _, _, checks = tiny
    check = checks["c"]
    params = FabricParams()
    fabric = build_fabric(scene, params)
    for i in range(2):
        obj, lost = bridge.projected_obj(scene, check, i)
        assert abs(obj.sum() + lost - float(np.asarray(scene.obj).sum())) < 1e-9
        assert np.all(obj >= 0)
        moved = obj != np.asarray(scene.obj)
        assert moved.any()
        after = scene.with_obj(obj.astype(np.float32))
        rebuilt, _ = selective_rebuild(after, params, fabric, moved)
        np.testing.assert_array_equal(np.asarray(rebuilt.value), np.asarray(build_fabric(after, params).value))


def test_rasterise_counts_particles_per_cell():
    scene = _tiny_scene()
    xy = np.array([[0.5, 0.5], [0.6, 0.4], [7.9, 4.9], [-1.0, 2.0]])
    obj, off = bridge.rasterise(scene, xy, np.array([1.0, 0.5, 2.0, 3.0]))
    assert obj[0, 0] == 1.5 and obj[4, 7] == 2.0 and off == 3.0 and obj.sum() == 3.5


def test_particle_layout_matches_counts():
    scene = _tiny_scene()
    mask = np.asarray(scene.obj) > 0
    xyz, cells, represented = rover.particle_layout(scene, mask, rover.RoverConfig(particles_per_object=2))
    assert len(xyz) == 2 * int(np.asarray(scene.obj).sum())
    np.testing.assert_array_equal(represented, np.asarray(scene.obj))
    row, col, inside = bridge.cells_of(scene, xyz[:, :2])
    assert inside.all() and np.array_equal(np.stack([row, col], -1), cells)
    d = np.linalg.norm(xyz[:, None] - xyz[None], axis=-1) + np.eye(len(xyz)) * 9
    assert d.min() >= 2 * rover.RoverConfig().particle_radius     # no two particles overlap


def test_simulator_rejects_bad_input(tiny):
    _, _, world, sims, _ = tiny
    with pytest.raises(ValueError, match="qpos0"):
        sims["c"].run(np.zeros((1, 3)), np.zeros((1, world.model.nv)), None, None, 5)
    with pytest.raises(ValueError, match="backend"):
        Simulator(world.model, bridge.pursuit_policy, backend="gpu")


def _distance_to_polyline(points, line):
    a, b = line[:-1][None], line[1:][None]
    ab = b - a
    t = np.clip(np.sum((points[:, None] - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-12), 0, 1)
    return np.min(np.linalg.norm(points[:, None] - (a + t[..., None] * ab), axis=-1), axis=1)


def test_tracked_path_does_not_loop_before_a_long_fallback_segment():
    # sparse65's fourth route: three one-cell steps, then a fallback segment of ~30 cells. The
    # uniform spline through those waypoints looped on the last short step (the rover drove the
    # loop); with long segments split, the path stays near the waypoint polyline and no longer.
    scene = builtin_scene("sparse65")
    _, routes, _ = bridge.plan_routes(scene, n_routes=4)
    route = bridge._index(routes, 3)
    pts, n = execute.waypoints(scene, route)
    pts = np.asarray(pts, np.float64)[: int(n)]
    assert np.linalg.norm(pts[-1] - pts[-2]) > 10 * scene.cell_size     # the case this test is about
    geom = rover.build_world(scene, 4).geometry
    path, arc, total, *_ = bridge.route_path(scene, route, geom, push_in=0.0)
    on_route = _distance_to_polyline(path, np.concatenate([path[:1], pts], 0))
    assert on_route.max() < 0.3 * scene.cell_size
    polyline = np.sum(np.linalg.norm(np.diff(np.concatenate([path[:1], pts], 0), axis=0), axis=1))
    assert total <= 1.05 * polyline and np.all(np.diff(arc) >= 0)


@pytest.mark.parametrize("field, value", [("wing_length", 0.0), ("particle_radius", -0.1),
                                          ("timestep", float("nan")), ("substeps", 0), ("solver", "PGS")])
def test_rover_config_rejects_bad_values(field, value):
    with pytest.raises(ValueError, match=f"RoverConfig.{field}"):
        rover.RoverConfig().replace(**{field: value})


def test_world_runs_the_configured_solver():
    scene = builtin_scene("default")
    for name, code in (("CG", mujoco.mjtSolver.mjSOL_CG), ("Newton", mujoco.mjtSolver.mjSOL_NEWTON)):
        world = rover.build_world(scene, 2, rover.RoverConfig(solver=name))
        assert world.model.opt.solver == code


_SLIDER = """<mujoco><option timestep="0.005"/><worldbody><geom type="plane" size="5 5 .1"/>
<body><freejoint/><geom type="box" size=".1 .1 .1" mass="1"/></body></worldbody></mujoco>"""


def _no_control(params, pstate, qpos, qvel, time):
    return jnp.zeros(0), pstate


@pytest.fixture(scope="module")
def slides():
    """A box launched at 2 m/s along x on the floor, once per sliding friction, on both engines."""
    import mujoco

    model = mujoco.MjModel.from_xml_string(_SLIDER)
    mus = np.array([0.2, 0.5])
    table = np.stack([np.tile([mu, 0.005, 0.0001], (model.ngeom, 1)) for mu in mus])
    q0 = np.tile([0, 0, 0.1, 1, 0, 0, 0], (2, 1)).astype(float)
    v0 = np.tile([2.0, 0, 0, 0, 0, 0], (2, 1))
    out = {}
    for backend in ("c", "mjx"):
        sim = Simulator(model, _no_control, substeps=10, backend=backend)
        out[backend] = sim.run(q0, v0, jnp.zeros(2), jnp.zeros(2), 40, model_fields={"geom_friction": table})
    return model, mus, out


def test_model_fields_vary_per_element_on_both_engines(slides):
    model, mus, out = slides
    # Coulomb sliding: the box stops after v^2 / (2 mu g)
    expected = 2.0 ** 2 / (2 * mus * 9.81)
    for backend, traj in out.items():
        assert traj.finite.all()
        np.testing.assert_allclose(traj.qpos[:, -1, 0], expected, rtol=0.05, err_msg=backend)
    np.testing.assert_allclose(out["c"].qpos[:, -1, 0], out["mjx"].qpos[:, -1, 0], atol=1e-3)
    assert np.all(model.geom_friction[:, 0] == 1.0)        # the caller's model is untouched


def test_model_fields_are_validated(slides):
    model, _, _ = slides
    sim = Simulator(model, _no_control, backend="c")
    q0, v0 = np.zeros((2, model.nq)), np.zeros((2, model.nv))
    with pytest.raises(ValueError, match="geom_friction.*expected shape"):
        sim.run(q0, v0, jnp.zeros(2), jnp.zeros(2), 2, model_fields={"geom_friction": np.ones((3, 3))})
    with pytest.raises(ValueError, match="not a numeric MjModel array field"):
        sim.run(q0, v0, jnp.zeros(2), jnp.zeros(2), 2, model_fields={"no_such_field": np.ones(2)})


def test_check_routes_takes_a_friction_per_route(tiny):
    scene, routes, world, sims, checks = tiny
    chk = bridge.check_routes(scene, routes, n_ticks=TICKS, world=world, simulator=sims["c"],
                              friction=np.array([0.3, 1.2]))
    assert chk.outcome.finite.all() and chk.outcome.reached.all()
    # same routes, layouts, world and engine as the fixture's run at the default friction (0.6): the
    # C engine is deterministic, so a different trajectory means the frictions reached the physics
    assert not np.allclose(chk.trajectory.qpos, checks["c"].trajectory.qpos)
    fields = bridge.friction_fields(world, [0.3, 1.2], 2)["geom_friction"]
    wheel = world.model.geom("wheel_left").id
    assert (fields[0, 0, 0] == 0.3 and fields[1, 0, 0] == 1.2
            and fields[1, wheel, 0] == world.model.geom_friction[wheel, 0])
    with pytest.raises(ValueError, match="friction"):
        bridge.check_routes(scene, routes, n_ticks=2, world=world, simulator=sims["c"], friction=-1.0)


# -- blocked cells: static boxes in the world (issue 45) ---------------------------------------------

def _blocked_scene():
    """6 x 8 cells of 0.5 m at origin (1, -2): an L of blocked cells (rows 1-2 x cols 3-4, and (3, 3))
    and a single blocked cell at (0, 7); gravel at (4, 1), the target on cells (4-5, 6-7)."""
    obj = np.zeros((6, 8))
    obj[4, 1] = 2
    blocked = np.zeros((6, 8), bool)
    blocked[1:3, 3:5] = True
    blocked[3, 3] = True
    blocked[0, 7] = True
    return Scene.from_arrays(obj, box(4.0, 0.0, 5.0, 1.0), cell_size=0.5, origin=(1.0, -2.0), name="walls",
                             blocked=blocked)


def _obstacle_geoms(model):
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or "" for g in range(model.ngeom)]
    return [g for g, name in enumerate(names) if name.startswith(rover.OBSTACLE_PREFIX)]


def test_blocked_cells_become_static_boxes_at_their_cells():
    scene = _blocked_scene()
    world = rover.build_world(scene, 3)
    m, s = world.model, 0.5
    rects = rover.blocked_rectangles(scene.blocked)
    np.testing.assert_array_equal(rects, [[0, 7, 1, 1], [1, 3, 2, 2], [3, 3, 1, 1]])   # (row, col, rows, cols)
    geoms = _obstacle_geoms(m)
    assert world.n_obstacles == len(geoms) == 3
    height = rover.obstacle_height(s, world.config)
    assert height >= 4 * 2 * world.config.particle_radius * s and height > 0.25 * s   # taller than the hull
    # world (x, y) centre and half sizes: cell (r, c) has centre origin + ((c + 0.5) s, (r + 0.5) s)
    expected = {"blocked0": ([4.75, -1.75], [0.25, 0.25]), "blocked1": ([3.0, -1.0], [0.5, 0.5]),
                "blocked2": ([2.75, -0.25], [0.25, 0.25])}
    for g in geoms:
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g)
        centre, half = expected[name]
        assert m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX and m.geom_bodyid[g] == 0      # static, world body
        np.testing.assert_allclose(m.geom_pos[g], centre + [height / 2], atol=1e-9)     # standing on the floor
        np.testing.assert_allclose(m.geom_size[g], half + [height / 2], atol=1e-9)
        assert (m.geom_contype[g], m.geom_conaffinity[g]) == (1, 4)
    # the boxes cover exactly the blocked cells: every cell centre is inside a box iff it is blocked
    rows, cols = np.mgrid[0:6, 0:8]
    xy = np.stack([1.0 + (cols + 0.5) * s, -2.0 + (rows + 0.5) * s], -1)
    inside = np.zeros((6, 8), int)
    for g in geoms:
        inside += np.all(np.abs(xy - m.geom_pos[g][:2]) < m.geom_size[g][:2], -1)
    np.testing.assert_array_equal(inside, np.asarray(scene.blocked).astype(int))
    # MJX must keep every particle-box pair (walls have large bounding spheres) and their contacts
    assert world.caps == rover.caps_for(3, world.config, 1, 3)
    assert world.caps["max_geom_pairs"] >= 3 * (rover.HULL_BOXES + 3) + 4 * 3


def test_a_scene_without_blocked_cells_gets_no_boxes_and_the_same_world():
    scene = _tiny_scene()
    world = rover.build_world(scene, 4)
    assert world.n_obstacles == 0 and not _obstacle_geoms(world.model) and "blocked" not in world.xml
    assert world.caps == rover.caps_for(4, world.config, 1)
    assert rover.blocked_rectangles(np.zeros((5, 8), bool)).shape == (0, 4)
    clear = Scene.from_arrays(np.asarray(scene.obj), scene.target, name="tiny", blocked=np.zeros((5, 8), bool))
    assert rover.build_world(clear, 4).xml == world.xml
    fleet = rover.build_world(scene, 4, n_rovers=2)
    assert fleet.n_obstacles == 0 and not _obstacle_geoms(fleet.model)


def test_blocked_rectangles_tile_any_mask_with_row_maximal_runs():
    rng = np.random.default_rng(0)
    for _ in range(20):
        mask = rng.random((rng.integers(1, 9), rng.integers(1, 9))) < 0.5
        rects = rover.blocked_rectangles(mask)
        cover = np.zeros(mask.shape, int)
        for r, c, nr, nc in rects:
            cover[r:r + nr, c:c + nc] += 1
            for row in range(r, r + nr):     # a maximal run in each of its rows
                assert c == 0 or not mask[row, c - 1]
                assert c + nc == mask.shape[1] or not mask[row, c + nc]
        np.testing.assert_array_equal(cover, mask.astype(int))     # disjoint, exact
        runs = sum(int(np.sum(np.diff(np.concatenate([[0], row.astype(int), [0]])) == 1)) for row in mask)
        assert len(rects) <= runs


def test_particles_and_the_rover_collide_with_the_boxes_on_both_engines():
    """One forward pass, no rollout: the blade, the wings and a particle pressed into blocked1 (x 2.5..3.5,
    y -1.5..-0.5) touch it on the C engine and on MJX; a particle thrown at the wall stays out of it."""
    from mujoco import mjx

    scene = _blocked_scene()
    world = rover.build_world(scene, 2)
    m = world.model
    r = world.config.particle_radius * 0.5
    q = rover.initial_qpos(world, [2.5 - world.geometry.blade_front + 0.01, -1.0], 0.0,
                           [[3.5 + r - 0.01, -0.75, r], [4.25, -0.25, r]])
    wall = m.geom("blocked1").id
    particle = m.body_geomadr[m.body("p0").id]
    touching = {m.geom("blade").id, m.geom("wing_left").id, m.geom("wing_right").id, particle}
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_forward(m, d)
    pairs = {tuple(sorted(map(int, g))) for g, dist in zip(d.contact.geom[:d.ncon], d.contact.dist[:d.ncon])
             if dist < 0}
    assert {tuple(sorted((wall, g))) for g in touching} <= pairs
    mx = jax.jit(mjx.forward)(mjx.put_model(m), mjx.put_data(m, d))
    contact = mx._impl.contact
    hit = {tuple(sorted(map(int, g))) for g, dist in zip(np.asarray(contact.geom), np.asarray(contact.dist))
           if dist < 0}
    assert {tuple(sorted((wall, g))) for g in touching} <= hit
    # particle p1, just right of blocked2 (x 2.5..3.0, y -0.5..0), thrown at it at 2 m/s for 0.15 s
    d = mujoco.MjData(m)
    d.qpos[:] = rover.initial_qpos(world, [1.5, 0.5], 0.0, [[3.5 + r + 0.1, -0.75, r], [3.0 + r + 0.02, -0.25, r]])
    p1 = m.jnt_dofadr[m.body("p1").jntadr[0]]
    d.qvel[p1] = -2.0
    for _ in range(30):
        mujoco.mj_step(m, d)
    assert world.particle_xyz(d.qpos)[1, 0] > 3.0 + 0.5 * r     # stopped by the wall, not through it
