"""Route evaluation over the route's own length: the chunked spline (``spillage.sample_route_prefix``)
and the first visits of a route's cells (``execute._first_visit``) against the serial reference."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan.reference import execute as ref_ex
from jaxplan.transport import execute as ex
from jaxplan.transport import spillage as sp

SETTINGS = settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
# Every example's buffer has one length, so each jitted program compiles once for all examples.
SPLINE_ROWS, EVAL_ROWS = 22, 17
_prefix_jit = jax.jit(sp.sample_route_prefix, static_argnums=(2, 3), static_argnames="chunk")
_full_jit = jax.jit(sp.sample_route, static_argnums=(2, 3))
_evaluate_jit = jax.jit(sp.evaluate_route, static_argnames="chunk")


@SETTINGS
@given(seed=st.integers(0, 2**16), n=st.integers(1, 9), chunk=st.sampled_from((1, 2, 3, 32)),
       alpha=st.sampled_from((0.0, 0.5, 1.0)))
def test_prefix_spline_equals_reference_and_full_spline(seed, n, chunk, alpha):
    rng = np.random.default_rng(seed)
    points = rng.integers(-4, 5, size=(n, 2)).astype(np.float64)   # grid-like, with repeats
    # a long buffer, as a walk cap leaves it: rows past n are arbitrary and must not be read
    buffer = np.concatenate([points, rng.integers(-9, 9, size=(SPLINE_ROWS - n, 2))]).astype(np.float32)
    got = _prefix_jit(jnp.asarray(buffer), n, 4, alpha, chunk=chunk)
    full = _full_jit(jnp.asarray(buffer), n, 4, alpha)
    for field in ("segment", "first", "valid"):
        np.testing.assert_array_equal(np.asarray(getattr(got, field)), np.asarray(getattr(full, field)))
    valid = np.asarray(got.valid)
    for field in ("pos", "tangent", "turn", "ds"):
        np.testing.assert_allclose(np.asarray(getattr(got, field))[valid], np.asarray(getattr(full, field))[valid],
                                   rtol=1e-5, atol=1e-5)
        assert not np.any(np.asarray(getattr(got, field))[~valid]), f"padding samples' {field} must be 0"
    want = ref_ex.catmull_rom_samples([tuple(q) for q in points], 4, alpha)
    k = len(want)
    assert int(valid.sum()) == k
    np.testing.assert_allclose(np.asarray(got.pos)[:k], np.reshape([w["pos"] for w in want], (k, 2)), atol=1e-4)
    np.testing.assert_allclose(np.asarray(got.ds)[:k], [w["ds"] for w in want], atol=1e-4)
    moving = np.array([w["ds"] for w in want]) > 1e-3     # the turn of a near-stationary sample is ill-conditioned
    np.testing.assert_allclose(np.asarray(got.turn)[:k][moving], np.array([w["turn"] for w in want])[moving],
                               atol=1e-3)


@SETTINGS
@given(seed=st.integers(0, 2**16), n=st.integers(1, 8), chunk=st.sampled_from((1, 3, 32)),
       lam=st.sampled_from((0.05, 0.5)))
def test_prefix_evaluation_delivers_as_the_full_one(seed, n, chunk, lam):
    rng = np.random.default_rng(seed)
    points = np.concatenate([rng.integers(-4, 5, size=(n, 2)), np.full((EVAL_ROWS - n, 2), -1)]).astype(np.float32)
    pickup = np.concatenate([rng.integers(0, 5, n), np.zeros(EVAL_ROWS - n)]).astype(np.float32)
    params = sp.SpillParams(lam=lam)
    full = _evaluate_jit(jnp.asarray(points), n, jnp.asarray(pickup), params)
    prefix = _evaluate_jit(jnp.asarray(points), n, jnp.asarray(pickup), params, chunk=chunk)
    np.testing.assert_allclose(float(prefix[0]), float(full[0]), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(prefix[1]), np.asarray(full[1]), rtol=1e-5, atol=1e-5)
    samples = ref_ex.catmull_rom_samples([tuple(q) for q in points[:n]], params.samples_per_step)
    delivered, _ = ref_ex.spill_along(samples, pickup[:n].tolist() + [0.0], lam, float(params.threshold))
    np.testing.assert_allclose(float(prefix[0]), delivered, rtol=1e-4, atol=1e-3)


@SETTINGS
@given(seed=st.integers(0, 2**16), n=st.integers(0, 20), pad=st.integers(0, 10), side=st.integers(1, 4))
def test_first_visits_equal_reference(seed, n, pad, side):
    rng = np.random.default_rng(seed)
    cells = rng.integers(0, side, size=(n, 2))          # a small grid: many repeats
    padded = np.concatenate([cells, np.full((pad + 1, 2), -1)]).astype(np.int32)
    got = np.asarray(ex._first_visit(jnp.asarray(padded), n, (side, side)))
    want = ref_ex.first_visits([tuple(int(v) for v in rc) for rc in cells])
    np.testing.assert_array_equal(got[:n], want)
    assert not got[n:].any()
