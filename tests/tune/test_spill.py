"""The soft spill threshold and fitting SpillParams to observed routes (jaxplan.tune.spill)."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxplan.reference.execute import spill_along
from jaxplan.transport import spillage
from jaxplan.transport.spillage import SpillParams
from jaxplan.tune import SpillData, fit_spill, predict_spill, spill_loss, synthetic_spill_data
from jaxplan.tune.spill import synthetic_routes

TRUE = SpillParams(lam=0.08, threshold=0.03, temperature=0.005)
_loss_grad = jax.jit(jax.grad(spill_loss))   # temperature and threshold are traced: one compile
_evaluate = jax.jit(spillage.evaluate_route)


@pytest.fixture(scope="module")
def clean_data():
    return synthetic_spill_data(TRUE, seed=0, n_routes=32)


def test_hard_threshold_is_the_default_and_exact():
    spill = jnp.array([0.0, 0.01, 0.0299, 0.03, 0.2])
    out = spillage.threshold_spill(spill, 0.03, SpillParams().temperature)
    np.testing.assert_array_equal(np.asarray(out), np.asarray(spill) * np.array([0, 0, 0, 1, 1], np.float32))


@pytest.mark.parametrize("jit", [False, True])
def test_soft_threshold_tends_to_the_hard_one(jit):
    fn = jax.jit(spillage.threshold_spill) if jit else spillage.threshold_spill
    spill = jnp.array([0.0, 0.01, 0.02, 0.04, 0.2])   # no value at the threshold itself
    hard = np.asarray(fn(spill, 0.03, 0.0))
    errors = [np.max(np.abs(np.asarray(fn(spill, 0.03, t)) - hard)) for t in (1e-2, 1e-3, 1e-4)]
    assert errors[0] > errors[1] > errors[2] and errors[2] < 1e-6


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**16), lam=st.sampled_from((0.0, 0.05, 0.3)),
       threshold=st.sampled_from((0.0, 0.01, 0.1)), temperature=st.sampled_from((0.0, 0.003, 0.05)))
def test_soft_spill_equals_reference(seed, lam, threshold, temperature):
    way, counts, pickup = synthetic_routes(seed, 1, n_points=8)
    params = SpillParams(lam=lam, threshold=threshold, temperature=temperature)
    delivered, spill, samples = _evaluate(way[0], counts[0], pickup[0], params)
    turn = np.asarray(samples.turn, np.float64)
    ref_samples = [dict(turn=float(t), first=bool(f) and bool(v), segment=int(s)) for t, f, v, s in
                   zip(turn, np.asarray(samples.first), np.asarray(samples.valid), np.asarray(samples.segment))]
    ref_delivered, ref_spill = spill_along(ref_samples, pickup[0].astype(np.float64), lam, threshold, temperature)
    np.testing.assert_allclose(float(delivered), ref_delivered, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(np.asarray(spill), ref_spill, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("temperature", [0.0, 0.005])
def test_loss_gradients_are_finite(clean_data, temperature):
    empty = clean_data._replace(pickup=jnp.zeros_like(clean_data.pickup), delivered=jnp.zeros(32),
                                spilled=jnp.zeros(32))
    for data in (clean_data, empty):
        for threshold in (0.0, 0.03):
            grads = _loss_grad(TRUE.replace(threshold=threshold, temperature=temperature), data)
            leaves = jax.tree_util.tree_leaves(grads)
            assert all(np.all(np.isfinite(np.asarray(g))) for g in leaves)
    g = jax.grad(spill_loss)(TRUE.replace(lam=0.1, threshold=0.05, temperature=0.005), clean_data)   # un-jitted
    assert float(g.lam) != 0.0 and float(g.threshold) != 0.0   # the soft threshold gives both a gradient


def test_fit_recovers_known_parameters_on_clean_data(clean_data):
    fit = fit_spill(clean_data, SpillParams(lam=0.2, threshold=0.1, temperature=TRUE.temperature))
    assert abs(float(fit.params.lam) / TRUE.lam - 1) < 0.02
    assert abs(float(fit.params.threshold) / TRUE.threshold - 1) < 0.02
    losses = np.asarray(fit.losses)
    assert np.all(np.isfinite(losses)) and losses[-1] < 1e-3 * losses[0]
    delivered, _ = predict_spill(fit.params, clean_data)
    np.testing.assert_allclose(np.asarray(delivered), np.asarray(clean_data.delivered), rtol=1e-3, atol=1e-3)


def test_fit_rejects_bad_input(clean_data):
    with pytest.raises(ValueError, match="init.threshold"):
        fit_spill(clean_data, SpillParams(lam=0.1, threshold=0.0, temperature=0.01))
    with pytest.raises(ValueError, match="steps"):
        fit_spill(clean_data, steps=0)
    with pytest.raises(ValueError, match="SpillParams.temperature"):
        fit_spill(clean_data, SpillParams(temperature=-1.0))
    with pytest.raises(ValueError, match="data"):
        fit_spill(SpillData(clean_data.waypoints, clean_data.n_points, clean_data.pickup,
                            clean_data.delivered[:3], clean_data.spilled))


def test_loss_gradients_agree_with_finite_differences(clean_data):
    """d loss / d lam and d loss / d threshold of the soft spill model against central differences."""
    loss = jax.jit(spill_loss)
    at = TRUE.replace(lam=0.1, threshold=0.05, temperature=0.02)
    grads = _loss_grad(at, clean_data)
    for field, eps in (("lam", 1e-3), ("threshold", 1e-3)):
        x = float(getattr(at, field))
        up = float(loss(at.replace(**{field: x + eps}), clean_data))
        down = float(loss(at.replace(**{field: x - eps}), clean_data))
        numeric = (up - down) / (2 * eps)
        np.testing.assert_allclose(float(getattr(grads, field)), numeric, rtol=0.05, atol=1e-3 * abs(numeric) + 1e-6)


def test_sample_lengths_have_finite_gradients_on_padded_routes():
    """A route shorter than its waypoint slots repeats its last point; ds there is 0 and so is its gradient."""
    way = jnp.array([[0.0, 0.0], [1.0, 0.0], [2.0, 1.0], [2.0, 1.0], [2.0, 1.0]])
    # jitted: one compile (eagerly, each of the spline's many small operations compiled apart took 5x longer)
    grad = jax.jit(jax.grad(lambda w: spillage.sample_route(w, 3, 4).ds.sum()))(way)
    assert np.all(np.isfinite(np.asarray(grad)))
    assert float(jnp.abs(grad[:3]).sum()) > 0.0


def _learned_truth(seed=5, hidden=4):
    rng = np.random.default_rng(seed)
    f = len(spillage.FEATURES)
    return spillage.LearnedSpillParams(w1=(0.5 * rng.standard_normal((f, hidden))).astype(np.float32),
                                       b1=np.zeros(hidden, np.float32),
                                       w2=(0.5 * rng.standard_normal((hidden, 3))).astype(np.float32),
                                       b2=np.array([-2.5, -1.5, -2.0], np.float32),
                                       load_w=np.array([0.5, -0.3], np.float32))


def test_fit_learned_brings_the_loss_down_on_data_of_a_learned_model():
    from jaxplan.tune import fit_learned, learned_loss

    data = synthetic_spill_data(_learned_truth(), seed=1, n_routes=48)
    fit = fit_learned(data, hidden=4, steps=200, learning_rate=0.02, seed=0, chunk=100)
    assert fit.losses.shape == (200,) and np.all(np.isfinite(fit.losses))
    final = float(learned_loss(fit.params, data))
    assert final < 0.2 * float(fit.losses[0])
    delivered, _ = predict_spill(fit.params, data)
    rel = np.abs(np.asarray(delivered) - np.asarray(data.delivered)) / np.maximum(np.asarray(data.delivered), 1.0)
    assert np.median(rel) < 0.05
    # a second fit with the same schedule runs the compiled steps again: the same weights from the same start
    from jaxplan.tune import spill as tune_spill

    compiled = tune_spill._learned_steps._cache_size()
    again = fit_learned(data, hidden=4, steps=200, learning_rate=0.02, seed=0, chunk=100)
    assert tune_spill._learned_steps._cache_size() == compiled
    np.testing.assert_array_equal(again.losses, fit.losses)


@pytest.mark.parametrize("kwargs, match", [({"hidden": 0}, "hidden: must be an int >= 1"),
                                           ({"steps": 0}, "steps: must be an int >= 1"),
                                           ({"chunk": 2.5}, "chunk: must be an int >= 1")])
def test_fit_learned_rejects_bad_settings(clean_data, kwargs, match):
    from jaxplan.tune import fit_learned

    with pytest.raises(ValueError, match=match):
        fit_learned(clean_data, **kwargs)
