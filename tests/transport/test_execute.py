"""The spill model and route execution against the serial reference; mass conservation."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan import FabricParams, Scene, box, build_fabric, extract_paths
from jaxplan.reference import execute as ref_ex
from jaxplan.transport import execute as ex
from jaxplan.transport import spillage as sp
from tests._scenes import scenes

SETTINGS = settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _route(scene, fabric, source, rank=0):
    h, w = scene.shape   # one walk length per grid shape: one compile per shape
    paths = extract_paths(fabric, jnp.array([source]), jnp.array([rank]), max_steps=h * w + 1)
    return jax.tree.map(lambda a: a[0], ex.routes_from_paths(scene, paths))


def _reference_push(scene, route, spill):
    n = int(route.n_cells)
    cells = [tuple(int(v) for v in rc) for rc in np.asarray(route.cells)[:n]]
    return ref_ex.execute_route(
        np.asarray(scene.obj), np.asarray(scene.target_mask), np.asarray(scene.dist, np.float64),
        np.asarray(scene.tvec, np.float64), float(scene.cell_size), tuple(np.asarray(scene.origin, float)),
        cells, bool(route.fallback), lam=float(spill.lam), threshold=float(spill.threshold),
        samples_per_step=spill.samples_per_step)


def _near_cell_edge(info, scene, tol=1e-3):
    """A spill point within ``tol`` cells of a grid line: float32 and float64 may pick different cells."""
    s = float(scene.cell_size)
    for smp in info["samples"]:
        if smp["turn"] == 0:
            continue
        left = np.array([-smp["tangent"][1], smp["tangent"][0]])
        p = (smp["pos"] - np.sign(smp["turn"]) * left * s) / s
        if np.any(np.abs(p - np.round(p)) < tol):
            return True
    return False


@pytest.fixture(scope="module")
def corner_scene():
    """An L of material: the best route turns a corner, so it spills."""
    obj = np.zeros((13, 9), np.float32)   # a shape of SHAPES: programs the property tests compile too
    obj[1, 1:7] = 3.0
    obj[1:7, 6] = 3.0
    return Scene.from_arrays(obj, box(5.0, 7.0, 8.0, 9.0), cell_size=1.0)


# ------------------------------------------------------------------------------------ the spline

def test_straight_route_has_no_turn_and_no_spill():
    points = jnp.array([[0.5, 0.5], [1.5, 0.5], [2.5, 0.5], [3.5, 0.5], [0.0, 0.0]])
    delivered, spill, samples = sp.evaluate_route(points, 4, jnp.array([2.0, 1.0, 1.0, 0.0, 0.0]),
                                                  sp.SpillParams(lam=1.0))
    assert np.allclose(np.asarray(samples.turn), 0.0, atol=1e-6)
    assert float(delivered) == pytest.approx(4.0)
    assert float(jnp.sum(spill)) == 0.0
    assert float(jnp.sum(samples.ds)) == pytest.approx(3.0, rel=1e-5)


def test_right_angle_turns_about_ninety_degrees():
    points = jnp.array([[0.5, 0.5], [1.5, 0.5], [2.5, 0.5], [2.5, 1.5], [2.5, 2.5], [2.5, 3.5]])
    samples = sp.sample_route(points, 6, 32)
    total = float(jnp.sum(samples.turn))
    assert total == pytest.approx(np.pi / 2, rel=0.02)   # counter-clockwise: + sign


def test_centripetal_spline_does_not_loop_before_a_long_fallback_segment():
    # a one-cell step, a diagonal, then a 30-cell fallback segment: the uniform spline (alpha 0)
    # takes half of the long segment as the short one's tangent and loops (more than 2 pi of turning)
    points = jnp.array([[0.0, 0.0], [1.0, 0.0], [2.0, 1.0], [32.0, 6.0]])
    uniform = sp.sample_route(points, 4, 16, alpha=0.0)
    centripetal = sp.sample_route(points, 4, 16)
    assert float(jnp.sum(jnp.abs(uniform.turn))) > 2 * np.pi
    # the polyline turns 0.79 rad (45 deg) and then 0.62 rad back; a smooth curve without a loop turns
    # little more than that
    assert float(jnp.sum(jnp.abs(centripetal.turn))) < 2.5
    assert float(jnp.sum(centripetal.ds)) == pytest.approx(
        float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1))), rel=0.02)


@SETTINGS
@given(seed=st.integers(0, 2**16), n=st.integers(2, 7), alpha=st.sampled_from((0.0, 0.5, 1.0)))
def test_spline_equals_reference(seed, n, alpha):
    rng = np.random.default_rng(seed)
    points = rng.integers(-4, 5, size=(n, 2)).astype(np.float64)   # grid-like, with repeats
    # padded to 7 rows, which the spline ignores past n: one shape for every n, compiled once per alpha
    padded = np.zeros((7, 2), np.float32)
    padded[:n] = points
    got = sp.sample_route(jnp.asarray(padded), n, 4, alpha)
    want = ref_ex.catmull_rom_samples([tuple(q) for q in points], 4, alpha)
    k = len(want)
    np.testing.assert_allclose(np.asarray(got.pos)[:k], [w["pos"] for w in want], atol=1e-4)
    np.testing.assert_allclose(np.asarray(got.ds)[:k], [w["ds"] for w in want], atol=1e-4)
    moving = np.array([w["ds"] for w in want]) > 1e-3     # the turn of a near-stationary sample is ill-conditioned
    np.testing.assert_allclose(np.asarray(got.turn)[:k][moving], np.array([w["turn"] for w in want])[moving],
                               atol=1e-3)


def test_spill_grows_with_lambda_and_threshold_drops_small_losses(corner_scene):
    fab = build_fabric(corner_scene)
    route = _route(corner_scene, fab, (1, 1))
    out = [ex.execute_jit(corner_scene, route, sp.SpillParams(lam=lam))[1].spilled for lam in (0.0, 0.05, 0.2)]
    assert float(out[0]) == 0.0 and 0.0 < float(out[1]) < float(out[2])
    big = ex.execute_jit(corner_scene, route, sp.SpillParams(lam=0.05, threshold=100.0))[1]
    assert float(big.spilled) == 0.0


# --------------------------------------------------------------------------------- vs reference

@SETTINGS
@given(scene=scenes(max_side=16), lam=st.sampled_from((0.0, 0.05, 0.3, 2.0)),
       threshold=st.sampled_from((0.0, 0.01, 0.5)), seed=st.integers(0, 2**16), rank=st.integers(0, 3))
def test_push_equals_reference(scene, lam, threshold, seed, rank):
    fab = build_fabric(scene, FabricParams())
    occupied = np.argwhere(np.asarray(fab.occupied))
    if len(occupied) == 0:
        return
    source = tuple(occupied[seed % len(occupied)])
    if not np.isfinite(float(fab.table.raw[source + (rank,)])):
        rank = 0
    route = _route(scene, fab, source, rank)
    spill = sp.SpillParams(lam=lam, threshold=threshold)
    new_obj, push = ex.execute_jit(scene, route, spill)
    ref_obj, info = _reference_push(scene, route, spill)
    np.testing.assert_allclose(float(push.collected), info["collected"], rtol=1e-6)
    np.testing.assert_allclose(float(push.spilled), info["spilled"], rtol=1e-4, atol=4 * ex.QUANTUM)
    np.testing.assert_allclose(float(push.delivered), info["delivered"], rtol=1e-4, atol=4 * ex.QUANTUM)
    np.testing.assert_allclose(info["delivered"], info["residual_load"], rtol=1e-3,
                               atol=ex.QUANTUM * len(info["spills"]))
    np.testing.assert_allclose(float(push.length), info["length"], rtol=1e-4)
    np.testing.assert_allclose(np.asarray(push.spill),
                               np.pad(info["spills"], (0, push.spill.shape[0] - len(info["spills"]))),
                               rtol=1e-3, atol=ex.QUANTUM + threshold)
    if not _near_cell_edge(info, scene) and not any(0 < abs(v - threshold) < 1e-4 for v in info["spills"]):
        np.testing.assert_allclose(np.asarray(new_obj), ref_obj, rtol=1e-4, atol=8 * ex.QUANTUM)


# ------------------------------------------------------------------------------ conservation

@SETTINGS
@given(scene=scenes(max_side=16, integer_counts=False), lam=st.sampled_from((0.05, 0.5)),
       seeds=st.lists(st.integers(0, 2**16), min_size=1, max_size=5))
def test_mass_is_conserved_over_random_pushes(scene, lam, seeds):
    spill = sp.SpillParams(lam=lam, threshold=0.01)
    total = float(jnp.sum(scene.obj))
    in_target0 = float(jnp.sum(jnp.where(scene.target_mask, scene.obj, 0.0)))
    delivered = spilled = 0.0
    for seed in seeds:
        fab = build_fabric(scene, FabricParams())
        occupied = np.argwhere(np.asarray(fab.occupied))
        if len(occupied) == 0:
            break
        route = _route(scene, fab, tuple(occupied[seed % len(occupied)]))
        new_obj, push = ex.execute_jit(scene, route, spill)
        assert float(push.delivered) + float(push.spilled) == pytest.approx(float(push.collected), rel=1e-5, abs=1e-5)
        assert float(push.spilled) >= 0 and float(push.delivered) >= -1e-5
        delivered += float(push.delivered)
        spilled += float(push.spilled)
        scene = scene.with_obj(new_obj)
        assert float(jnp.sum(scene.obj)) == pytest.approx(total, rel=1e-5, abs=1e-4)
    in_target = float(jnp.sum(jnp.where(scene.target_mask, scene.obj, 0.0)))
    assert in_target - in_target0 == pytest.approx(delivered, rel=1e-5, abs=1e-3)


# --------------------------------------------------------------- pluggable, jit, gradients

def test_evaluator_is_pluggable(corner_scene):
    fab = build_fabric(corner_scene)
    route = _route(corner_scene, fab, (1, 1))

    def spill_everything_at_first_sample(samples, pickup, params):
        spill = jnp.where(jnp.arange(pickup.shape[0]) == 0, pickup, 0.0)
        return jnp.sum(pickup) - jnp.sum(spill), spill

    new_obj, push = ex.execute_push(corner_scene, route, sp.SpillParams(), spill_everything_at_first_sample)
    assert float(push.spilled) == pytest.approx(3.0)
    assert float(jnp.sum(new_obj)) == pytest.approx(float(jnp.sum(corner_scene.obj)))


def test_jit_matches_eager_and_gradients_are_finite(corner_scene):
    fab = build_fabric(corner_scene)
    route = _route(corner_scene, fab, (1, 1))
    spill = sp.SpillParams(lam=0.1, threshold=0.0)
    eager = ex.execute_push(corner_scene, route, spill)[1]
    jitted = ex.execute_jit(corner_scene, route, spill)[1]
    np.testing.assert_allclose(float(eager.delivered), float(jitted.delivered), rtol=1e-6)
    points, n = ex.waypoints(corner_scene, route)
    pickup, _ = ex.waypoint_pickup(corner_scene, route)

    def delivered(lam, points):
        return sp.evaluate_route(points, n, pickup, spill.replace(lam=lam))[0]

    g_lam, g_points = jax.grad(delivered, argnums=(0, 1))(0.1, points)
    assert np.isfinite(float(g_lam)) and float(g_lam) < 0      # more spill per radian delivers less
    assert np.all(np.isfinite(np.asarray(g_points)))


def test_bad_spill_params_name_the_field():
    with pytest.raises(ValueError, match="SpillParams.lam"):
        sp.validate_spill_params(sp.SpillParams(lam=-1.0))
    with pytest.raises(ValueError, match="samples_per_step"):
        sp.validate_spill_params(sp.SpillParams(samples_per_step=0))
    with pytest.raises(ValueError, match="SpillParams.spline_alpha"):
        sp.validate_spill_params(sp.SpillParams(spline_alpha=2.0))
