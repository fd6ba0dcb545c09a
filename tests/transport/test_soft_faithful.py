"""The soft fabric's relaxation targets on small random grids, and its gradients against finite differences."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from jaxplan import FabricParams, Scene, box, build_fabric, circle
from jaxplan.core import lattice
from jaxplan.transport import visibility
from jaxplan.transport.soft import CONE_SCALE
from jaxplan.tune import gradient_probe

SIDE = 8   # one grid shape: one compile


@st.composite
def faithful_scenes(draw):
    """An 8 x 8 grid, density 0.2-0.6, integer or real counts, a circle or box target; and a cone angle."""
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    density = rng.uniform(0.2, 0.6)
    if rng.random() < 0.5:
        counts = rng.integers(1, 6, (SIDE, SIDE)).astype(np.float32)
    else:
        counts = np.round(rng.uniform(0.5, 5.0, (SIDE, SIDE)), 3).astype(np.float32)
    obj = np.where(rng.random((SIDE, SIDE)) < density, counts, 0.0).astype(np.float32)
    cx, cy = rng.uniform(1, SIDE - 1, 2)
    r = rng.uniform(0.8, 1.6)
    target = circle((cx, cy), r) if rng.random() < 0.5 else box(cx - r, cy - r, cx + r, cy + r * 0.7)
    return Scene.from_arrays(obj, target, cell_size=1.0), float(rng.uniform(30.0, 75.0))


def _near_cone_edge(scene, theta, margin):
    """Whether a step from an occupied cell into an occupied or target neighbour lies within
    ``margin`` (cosine) of the cone's edge."""
    target = np.asarray(scene.target_mask)
    occupied = ~target & (np.asarray(scene.obj) > 0)
    x = np.asarray(visibility.cone_alignment(scene.tvec) - visibility.cone_cos(theta))
    enterable = np.asarray(lattice.neighbours(jnp.asarray(occupied | target), False)) & lattice.in_grid(target.shape)
    return bool(np.any((np.abs(x) < margin) & enterable & occupied[None]))


def _error(soft, hard):
    soft, hard = np.asarray(soft, np.float64), np.asarray(hard, np.float64)
    return float(np.max(np.abs(soft - hard))) / max(float(np.max(np.abs(hard))), 1e-9)


def _errors(scene, params, t):
    hard = build_fabric(scene, params)
    soft = build_fabric(scene, params.replace(temperature=t))
    agree = float(np.mean((np.asarray(soft.highways) > 0.5) == np.asarray(hard.highways)))
    return dict(value=_error(soft.value, hard.value), raw=_error(soft.raw, hard.value),
                heat=_error(soft.heat, hard.heat)), agree


@settings(max_examples=6, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(case=faithful_scenes())
def test_soft_fabric_is_faithful_at_t_0_05(case):
    scene, theta = case
    t = 0.05
    # a step within a few t^2 CONE_SCALE of the cone's edge is half open in the soft fabric
    assume(not _near_cone_edge(scene, theta, 10 * t * t * CONE_SCALE))
    assume(np.asarray(scene.obj)[~np.asarray(scene.target_mask)].sum() > 0)
    params = FabricParams(theta_tol_deg=theta, tau_h=0.3)
    errors, agree = _errors(scene, params, t)
    assert max(errors.values()) < 0.05, errors
    assert agree >= 0.98
    warm, _ = _errors(scene, params, 0.2)
    assert max(errors.values()) <= max(warm.values()) + 1e-6, (errors, warm)


_value = jax.jit(gradient_probe)
_grad = jax.jit(jax.grad(gradient_probe, argnums=(1, 2, 3, 4)))


@pytest.fixture(scope="module")
def small():
    rng = np.random.default_rng(4)
    obj = np.round(rng.uniform(0.5, 4.0, (5, 6)), 2).astype(np.float32)   # every count > 0: occupancy fixed
    return Scene.from_arrays(obj, circle((4.6, 3.4), 1.1), cell_size=1.0)


@pytest.mark.parametrize("t", (0.05, 0.2))
@pytest.mark.parametrize("arg,eps", [(0, 0.05), (1, 2e-3), (2, 2e-2), (3, 2e-2)])
def test_gradients_agree_with_central_differences(small, t, arg, eps):
    x = [jnp.float32(52.0), jnp.float32(0.35), jnp.float32(0.6), jnp.asarray(small.obj)]
    analytic_all = _grad(small, *x, t)
    rng = np.random.default_rng(arg)
    direction = jnp.asarray(rng.normal(size=np.shape(x[arg])), jnp.float32)
    plus, minus = list(x), list(x)
    plus[arg], minus[arg] = x[arg] + eps * direction, x[arg] - eps * direction
    numeric = (float(_value(small, *plus, t)) - float(_value(small, *minus, t))) / (2 * eps)
    analytic = float(jnp.sum(analytic_all[arg] * direction))
    assert np.all([np.all(np.isfinite(np.asarray(g))) for g in analytic_all])
    assert analytic == pytest.approx(numeric, rel=0.02, abs=0.02 * (1.0 + abs(numeric)) if arg == 0 else 1e-2)
