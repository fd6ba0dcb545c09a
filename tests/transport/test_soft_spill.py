"""Spill through the soft fabric: Eq. 6 as a softmax over predicted delivered mass (soft.soft_select)."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan import FabricParams, Scene, build_fabric, circle
from jaxplan.reference.soft import reference_soft_fabric
from jaxplan.transport.spillage import SpillParams
from tests._scenes import ANGLES, has_borderline_step, scenes


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(4)
    obj = np.round(rng.uniform(0.5, 4.0, (8, 8)), 2).astype(np.float32)   # every count > 0
    return Scene.from_arrays(obj, circle((6.6, 5.4), 1.1), cell_size=1.0)


PARAMS = FabricParams(theta_tol_deg=60.0, tau_h=0.3, slack_tau=2.0)


def _scalar(scene, lam, threshold, t):
    f = build_fabric(scene, PARAMS.replace(temperature=t), SpillParams(lam=lam, threshold=threshold))
    return jnp.sum(f.heat) + jnp.sum(f.highways * f.heat) + jnp.sum(f.delivered) + jnp.sum(f.psi)


_value = jax.jit(_scalar)
_grad = jax.jit(jax.grad(_scalar, argnums=(1, 2)))


def test_heat_highways_and_delivered_depend_on_the_spill_lambda(scene):
    params = PARAMS.replace(temperature=0.2)
    low = build_fabric(scene, params, SpillParams(lam=0.0))
    high = build_fabric(scene, params, SpillParams(lam=0.3))
    assert float(jnp.max(jnp.abs(low.heat - high.heat))) > 1e-2 * float(jnp.max(low.heat))
    np.testing.assert_allclose(np.asarray(low.delivered), np.asarray(low.raw), rtol=0.05, atol=0.5)
    assert float(jnp.sum(high.delivered)) < float(jnp.sum(low.delivered))
    # value, raw and length stay Eq. 5's
    np.testing.assert_array_equal(np.asarray(low.raw), np.asarray(high.raw))


def test_without_spill_delivered_is_raw_and_disabled_spill_is_eq_5(scene):
    params = PARAMS.replace(temperature=0.2)
    plain = build_fabric(scene, params)
    off = build_fabric(scene, params, SpillParams(lam=0.3, enabled=False))
    np.testing.assert_array_equal(np.asarray(plain.delivered), np.asarray(plain.raw))
    np.testing.assert_allclose(np.asarray(off.heat), np.asarray(plain.heat), rtol=1e-6, atol=1e-6)


_JUMPY = pytest.mark.xfail(strict=True, reason="at t = 0.2 on this scene the sharpened Eq. 6 policy (temperature "
                            "t^3 M) has transitions finer than every difference step tried")


@pytest.mark.parametrize("t", (0.05, pytest.param(0.2, marks=_JUMPY), 0.5))
@pytest.mark.parametrize("lam,threshold", [(0.1, 0.5), (0.3, 2.0)])
def test_spill_gradients_agree_with_central_differences(scene, t, lam, threshold):
    grads = _grad(scene, lam, threshold, t)
    # the sharpened policy (temperature t^2) has narrow transitions: a difference step may cross one,
    # so each derivative must match the central difference at one of three step sizes
    for i, steps in ((0, (1e-3, 3e-4, 1e-4)), (1, (1e-2, 3e-3, 1e-3))):
        assert np.isfinite(float(grads[i]))
        numeric = []
        for eps in steps:
            x = [lam, threshold]
            plus, minus = list(x), list(x)
            plus[i] += eps
            minus[i] -= eps
            numeric.append((float(_value(scene, *plus, t)) - float(_value(scene, *minus, t))) / (2 * eps))
        assert any(float(grads[i]) == pytest.approx(n, rel=0.02, abs=0.05) for n in numeric), (float(grads[i]), numeric)


def test_the_hard_fabric_rejects_spill_params(scene):
    with pytest.raises(ValueError, match="spill"):
        build_fabric(scene, PARAMS, SpillParams())


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scene=scenes(max_side=6, integer_counts=False), theta=st.sampled_from(ANGLES),
       t=st.sampled_from((0.05, 0.3, 1.0)), lam=st.sampled_from((0.0, 0.1, 0.4)),
       threshold=st.sampled_from((1e-3, 0.5)), slack=st.sampled_from((0.0, 2.0)))
def test_soft_select_equals_serial_reference(scene, theta, t, lam, threshold, slack):
    if has_borderline_step(scene, theta):
        return   # the hard part of the monotone rule is decided in float32 vs float64
    params = FabricParams(theta_tol_deg=theta, tau_h=0.3, slack_tau=slack, temperature=t)
    got = build_fabric(scene, params, SpillParams(lam=lam, threshold=threshold))
    ref = reference_soft_fabric(
        np.asarray(scene.obj, np.float64), np.asarray(scene.target_mask), np.asarray(scene.dist, np.float64),
        np.asarray(scene.tvec, np.float64), float(scene.cell_size), np.asarray(scene.origin, np.float64),
        theta_tol_deg=theta, tau_h=0.3, anchor_lambda=float(params.anchor_lambda), temperature=t,
        spill_lam=lam, spill_threshold=threshold, slack_tau=slack)
    for name in ("policy", "delivered", "psi", "heat", "highways"):
        want = ref[name]
        scale = 1.0 + float(np.max(np.abs(want), initial=0.0))
        np.testing.assert_allclose(np.asarray(getattr(got, name), np.float64), want, rtol=2e-4,
                                   atol=2e-4 * scale, err_msg=name)
