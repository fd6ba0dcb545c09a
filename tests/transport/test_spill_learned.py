"""The learned spill model (jaxplan.transport.spillage.learned) against its serial reference; mass,
gradients, parameter checks, the shipped fit, and its place in the pipeline."""
from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan.reference import execute as ref_ex
from jaxplan.reference import spill_learned as ref_sl
from jaxplan.transport import spillage as sp
from jaxplan.transport.spillage.learned import DISTANCE_CAP, sample_features
from tests.transport.test_spill_capacity import SLOTS, assert_equals_reference, routes

SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
REPO = Path(__file__).resolve().parents[2]
F = len(sp.FEATURES)


def _evaluate(points, n, pickup, params):
    delivered, spill, _ = sp.evaluate_route(jnp.asarray(points), n, jnp.asarray(pickup), params)
    return delivered, spill


_evaluate_jit = jax.jit(_evaluate)


def _params(seed: int, hidden: int = 4, scale: float = 1.0, threshold: float = 0.0) -> sp.LearnedSpillParams:
    rng = np.random.default_rng(seed)
    f32 = lambda *shape: (scale * rng.standard_normal(shape)).astype(np.float32)  # noqa: E731
    return sp.LearnedSpillParams(w1=f32(F, hidden), b1=f32(hidden), w2=f32(hidden, 3),
                                 b2=(f32(3) + np.array([-3.0, -2.0, -2.0], np.float32)), load_w=f32(2),
                                 threshold=np.float32(threshold))


def _reference(pts, n, pick, p):
    samples = ref_ex.catmull_rom_samples([tuple(map(float, q)) for q in pts[:n]], p.samples_per_step)
    return ref_sl.learned_spill_along(samples, [float(x) for x in pick], w1=p.w1, b1=p.b1, w2=p.w2, b2=p.b2,
                                      load_w=p.load_w, threshold=float(p.threshold),
                                      samples_per_step=p.samples_per_step)


@SETTINGS
@given(route=routes(), seed=st.integers(0, 10_000), scale=st.sampled_from([0.3, 1.0]),
       threshold=st.sampled_from([0.0, 0.2]))
def test_learned_spill_equals_serial_reference(route, seed, scale, threshold):
    pts, n, pick = route
    params = _params(seed, scale=scale, threshold=threshold)
    delivered, spill = _evaluate_jit(pts, n, pick, params)
    assert_equals_reference((delivered, spill), _reference(pts, n, pick, params), n, pick)
    assert float(delivered) >= -1e-3


def _zigzag():
    pts = np.array([[0.5 + i, 0.5 + (i % 2)] for i in range(SLOTS)], np.float32)
    return pts, SLOTS, np.array([4.0] * (SLOTS - 1) + [0.0], np.float32)


def test_jit_equals_no_jit_and_gradients_are_finite():
    pts, n, pick = _zigzag()
    params = _params(3)
    np.testing.assert_allclose(_evaluate_jit(pts, n, pick, params)[0], _evaluate(pts, n, pick, params)[0], rtol=1e-5)
    grads = jax.grad(lambda p: _evaluate(pts, n, pick, p)[0])(params)
    for name in ("w1", "b1", "w2", "b2", "load_w"):
        g = np.asarray(getattr(grads, name))
        assert np.all(np.isfinite(g)), name
    assert np.any(np.asarray(grads.w1) != 0)


def test_vmap_over_parameter_sets_equals_one_at_a_time():
    pts, n, pick = _zigzag()
    sets = [_params(s) for s in range(3)]
    stacked = jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *sets)
    batched = jax.vmap(lambda p: _evaluate(pts, n, pick, p)[0])(stacked)
    np.testing.assert_allclose(batched, [float(_evaluate_jit(pts, n, pick, p)[0]) for p in sets], rtol=1e-5)


def test_neutral_default_loses_a_little_everywhere():
    pts, n, pick = _zigzag()
    delivered, spill = _evaluate_jit(pts, n, pick, sp.LearnedSpillParams())
    assert 0.5 * pick.sum() < float(delivered) < pick.sum()
    assert np.all(np.asarray(spill) >= 0)


@pytest.mark.parametrize("field, value, match", [
    ("w1", np.zeros((F + 1, 8), np.float32), "LearnedSpillParams.w1: expected shape"),
    ("w2", np.zeros((5, 3), np.float32), "LearnedSpillParams.w2: expected shape"),
    ("load_w", np.zeros(3, np.float32), "LearnedSpillParams.load_w"),
    ("b2", np.array([np.nan, 0, 0], np.float32), "LearnedSpillParams.b2: must be finite"),
])
def test_bad_parameters_are_refused_naming_the_field(field, value, match):
    with pytest.raises(ValueError, match=match):
        sp.validate_learned_params(sp.LearnedSpillParams().replace(**{field: value}))


def test_a_bad_fit_file_is_refused_naming_it(tmp_path):
    bad = tmp_path / "fit.json"
    bad.write_text(json.dumps({"w1": [[0.0]]}))
    with pytest.raises(ValueError, match="fit.json: not a learned spill model"):
        sp.load_learned(bad)
    bad.write_text(json.dumps({"w1": [[0.0]], "b1": [0.0], "w2": [[0.0, 0.0, 0.0]], "b2": [0, 0, 0], "load_w": [0, 0]}))
    with pytest.raises(ValueError, match="LearnedSpillParams.w1: expected shape"):
        sp.load_learned(bad)


def test_the_shipped_fit_is_the_one_its_results_file_reports():
    result = json.loads((REPO / "experiments/results/spill_models.json").read_text())
    shipped = json.loads((REPO / "jaxplan/transport/spillage/learned_fit.json").read_text())
    for name in ("w1", "b1", "w2", "b2", "load_w"):
        np.testing.assert_array_equal(result["learned"]["params"][name], shipped[name])
        np.testing.assert_allclose(np.asarray(getattr(sp.LEARNED_FIT, name)), shipped[name], rtol=1e-6)
    assert shipped["data_sha256"] == result["data_sha256"]
    assert sp.evaluator_for(sp.LEARNED_FIT) is sp.learned_spill


def test_execute_push_runs_with_the_learned_model():
    from jaxplan.transport import FabricParams, build_fabric, execute, extract_paths, random_scene, routes_from_paths

    scene = random_scene(2, (12, 12), 0.5, layout="piles")
    fabric = build_fabric(scene, FabricParams())
    source = np.unravel_index(np.argmax(np.where(np.asarray(fabric.occupied), np.asarray(fabric.value), -np.inf)),
                              scene.shape)
    paths = extract_paths(fabric, np.asarray([source], np.int32), np.zeros(1, np.int32), detour=scene.detour)
    route = jax.tree.map(lambda a: a[0], routes_from_paths(scene, paths))
    obj_after, push = execute.execute_jit(scene, route, sp.LEARNED_FIT, sp.evaluator_for(sp.LEARNED_FIT))
    before = float(np.asarray(scene.obj).sum())
    assert float(np.asarray(obj_after).sum()) == pytest.approx(before, rel=1e-5)   # nothing created or lost
    assert 0 < float(push.delivered) <= float(push.collected)


def test_distance_features_stop_at_the_cap_on_long_routes():
    # 40 cells: 39 world units, past the cap (25); the serial reference clips the same way
    n = 40
    pts = np.array([[0.5 + i, 0.5 + (i // 10) % 2] for i in range(n)], np.float32)
    pick = np.array([3.0] * (n - 1) + [0.0], np.float32)
    params = _params(7)
    samples = sp.sample_route(jnp.asarray(pts), n, params.samples_per_step)
    feats, _ = sample_features(samples, sp.pickups_per_sample(samples, jnp.asarray(pick)), params.samples_per_step)
    to_go, done = np.asarray(feats[:, 5]), np.asarray(feats[:, 6])
    assert to_go.max() == pytest.approx(DISTANCE_CAP) and done.max() == pytest.approx(DISTANCE_CAP)
    assert_equals_reference(_evaluate(pts, n, pick, params), _reference(pts, n, pick, params), n, pick)


def test_the_shipped_fit_keeps_a_long_straight_run_nearly_lossless():
    # site-scale fallback runs are far longer than the fit's 20 x 20 routes: the capped distance
    # features keep the fit from extrapolating a loss along them
    for n in (20, 80):
        pts = np.array([[0.5 + i, 0.5] for i in range(n)], np.float32)
        pick = np.zeros(n, np.float32)
        pick[:3] = 8.0
        delivered, _ = _evaluate_jit(pts, n, pick, sp.LEARNED_FIT)
        assert float(delivered) >= 0.95 * pick.sum()
