"""Soft (differentiable) fabric kernels: reference equality, the t -> 0 limit, gradients, no recompiles."""
from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from shapely.geometry import Polygon

from jaxplan import Fabric, FabricParams, Scene, box, build_fabric, circle
from jaxplan.core.lattice import cell_centers
from jaxplan.reference.soft import reference_soft_fabric
from jaxplan.transport import soft
from jaxplan.transport.connectors import choose_anchors
from tests._scenes import ANGLES, has_borderline_step, scenes

FIELDS = ("value", "raw", "length", "policy", "psi", "heat", "highways", "candidate", "anchor_weights")


def _unique_scene() -> Scene:
    """9 x 11 grid, real-valued counts (no exact ties in raw), a round target inside."""
    rng = np.random.default_rng(0)
    obj = np.round(rng.uniform(0.5, 5, (9, 11)), 3).astype(np.float32) * (rng.random((9, 11)) < 0.8)
    return Scene.from_arrays(obj, circle((5.5, 4.5), 1.6), cell_size=1.0)


@pytest.fixture(scope="module")
def scene():
    return _unique_scene()


def _reference(scene: Scene, params: FabricParams):
    return reference_soft_fabric(
        np.asarray(scene.obj, np.float64), np.asarray(scene.target_mask), np.asarray(scene.dist, np.float64),
        np.asarray(scene.tvec, np.float64), float(scene.cell_size), np.asarray(scene.origin, np.float64),
        theta_tol_deg=float(params.theta_tol_deg), tau_h=float(params.tau_h),
        anchor_lambda=float(params.anchor_lambda), temperature=float(params.temperature),
        monotone=params.monotone, rounds=params.soft_rounds)


# ---------------------------------------------------------------------------------------------- reference


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scene=scenes(max_side=6, integer_counts=False), theta=st.sampled_from(ANGLES),
       t=st.sampled_from((0.05, 0.3, 1.0)), tau=st.sampled_from((0.2, 0.6)),
       lam=st.sampled_from((0.0, 0.5, 2.0)))
def test_soft_kernels_equal_serial_reference(scene, theta, t, tau, lam):
    if has_borderline_step(scene, theta):
        return   # the hard part of the monotone rule is decided in float32 vs float64
    params = FabricParams(theta_tol_deg=theta, tau_h=tau, anchor_lambda=lam, temperature=t)
    got = build_fabric(scene, params)
    ref = _reference(scene, params)
    for name in FIELDS:
        want = ref[name]
        scale = 1.0 + float(np.max(np.abs(want), initial=0.0))
        np.testing.assert_allclose(np.asarray(getattr(got, name), np.float64), want, rtol=2e-4,
                                   atol=2e-4 * scale, err_msg=name)


# A 5 x 5 scene (found by a fresh hypothesis search) where the kernel's heat at (1, 0) is 21.40 and the
# float64 reference's 20.43 at t = 1, every other field and cell agreeing. The soft kernels are to be
# redesigned for faithfulness at working temperatures; until then the case is kept here, expected to fail.
_HEAT_MISMATCH_OBJ = [[4.051, 0.906, 1.093, 1.644, 1.474], [2.189, 0.0, 0.0, 0.0, 4.639],
                      [4.856, 1.194, 3.31, 0.0, 2.754], [4.978, 4.163, 3.97, 0.0, 1.324],
                      [0.0, 4.312, 4.468, 3.146, 0.0]]
_HEAT_MISMATCH_TARGET = [
    (2.3707965791868295, 0.6732122090721602),
    (2.238225693796282, 0.9932666385578293),
    (1.9932666385578293, 1.2382256937962821),
    (1.6732122090721602, 1.3707965791868297),
    (1.32678779092784, 1.3707965791868297),
    (1.006733361442171, 1.2382256937962823),
    (0.7617743062037177, 0.9932666385578293),
    (0.6292034208131703, 0.6732122090721604),
    (0.6292034208131703, 0.3267877909278398),
    (0.7617743062037177, 0.006733361442171),
    (1.0067333614421707, -0.2382256937962822),
    (1.3267877909278396, -0.3707965791868296),
    (1.6732122090721602, -0.3707965791868297),
    (1.993266638557829, -0.2382256937962823),
    (2.238225693796282, 0.0067333614421708),
    (2.3707965791868295, 0.3267877909278395),
]


def test_soft_heat_equals_reference_where_the_fallback_hop_is_a_tie():
    """A fallback cell whose t(C) lies halfway between two steps (an exact tie that float32 and
    float64 round apart): kernel and reference both take the lower direction index."""
    scene = Scene.from_arrays(np.asarray(_HEAT_MISMATCH_OBJ, np.float32), Polygon(_HEAT_MISMATCH_TARGET))
    params = FabricParams(theta_tol_deg=30.0, tau_h=0.2, anchor_lambda=0.0, temperature=1.0)
    got = np.asarray(build_fabric(scene, params).heat, np.float64)
    want = _reference(scene, params)["heat"]
    np.testing.assert_allclose(got, want, rtol=2e-4, atol=2e-4 * (1.0 + np.max(np.abs(want))))


def test_jitted_and_unjitted_soft_fabric_agree():
    tiny = EDGE_SCENES["target_on_edge"]()
    params = FabricParams(tau_h=0.4, temperature=0.2, soft_rounds=4)
    jitted = build_fabric(tiny, params)
    with jax.disable_jit():
        eager = soft._soft_build(tiny, params)
    for name in FIELDS:
        np.testing.assert_allclose(np.asarray(getattr(eager, name)), np.asarray(getattr(jitted, name)),
                                   rtol=1e-5, atol=1e-5, err_msg=name)


# ---------------------------------------------------------------------------------------------- hard limit


def test_temperature_none_or_zero_is_the_exact_hard_fabric(scene):
    hard = build_fabric(scene, FabricParams())
    zero = build_fabric(scene, FabricParams(temperature=0.0))
    assert isinstance(zero, Fabric)
    for a, b in zip(jax.tree_util.tree_leaves(hard), jax.tree_util.tree_leaves(zero)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.fixture(scope="module")
def limits(scene):
    params = FabricParams(tau_h=0.3, anchor_lambda=0.5)
    hard = build_fabric(scene, params)
    temps = (0.1, 1e-2, 1e-3, 1e-4)
    return params, hard, {t: build_fabric(scene, params.replace(temperature=t)) for t in temps}


def test_soft_dp_converges_to_the_hard_value_and_length(limits):
    _, hard, by_t = limits
    errors = [float(jnp.max(jnp.abs(s.raw - hard.value))) for s in by_t.values()]
    assert errors[-1] < 1e-3 and errors[-1] <= errors[0]
    low = by_t[1e-4]
    # the policy's length tie-break weighs t^(-1/4) per cell in its softmax: lengths converge slowly
    np.testing.assert_allclose(np.asarray(low.length), np.asarray(hard.length), atol=0.1 * float(jnp.max(hard.length)))
    # value (the soft Bellman value with its expected costs added back) tends to J
    np.testing.assert_allclose(np.asarray(low.value), np.asarray(hard.value), atol=1e-2)
    hop = np.asarray(hard.table.next_dir[..., 0])
    pick = np.argmax(np.asarray(low.policy), -1)
    occ = np.asarray(hard.occupied)
    np.testing.assert_array_equal(pick[occ], hop[occ])


def test_soft_psi_heat_and_highways_converge_to_the_hard_ones(limits):
    _, hard, by_t = limits
    low = by_t[1e-4]
    np.testing.assert_allclose(np.asarray(low.psi), np.asarray(hard.psi), atol=2e-2)
    np.testing.assert_allclose(np.asarray(low.heat), np.asarray(hard.heat), atol=2e-2)
    np.testing.assert_array_equal(np.asarray(low.highways) > 0.5, np.asarray(hard.highways))
    heat_err = [float(jnp.max(jnp.abs(s.heat - hard.heat))) for s in by_t.values()]
    assert heat_err[-1] <= heat_err[0]


def test_soft_anchor_weights_converge_to_the_hard_anchor(limits, scene):
    params, hard, by_t = limits
    centers = cell_centers(scene.shape, scene.cell_size, scene.origin)
    anchor = np.asarray(choose_anchors(hard.heat, hard.highways, hard.occupied, centers, params.anchor_lambda))
    roots = anchor >= 0
    assert roots.any()
    # roots whose best Eq. 12 score is unique (the hard kernel breaks exact ties by index, the soft
    # one splits them evenly)
    cand = np.asarray(hard.highways & hard.occupied).reshape(-1)
    flat = np.asarray(centers, np.float64).reshape(-1, 2)
    d = np.linalg.norm(flat[:, None] - flat[None], axis=-1)
    score = np.where(cand[None], np.asarray(hard.heat, np.float64).reshape(-1)[None] - params.anchor_lambda * d,
                     -np.inf)
    top2 = np.sort(score, axis=1)[:, -2:]
    unique = (top2[:, 1] - top2[:, 0] > 1e-3).reshape(anchor.shape) & roots
    assert unique.any()
    weights = np.asarray(by_t[1e-4].anchor_weights)
    np.testing.assert_array_equal(np.argmax(weights, -1)[unique], anchor[unique])
    assert np.all(np.max(weights, -1)[unique] > 0.99)


# ---------------------------------------------------------------------------------------------- gradients


def _scalar(scene, theta, tau, lam, obj, t):
    """A scalar touching every output of the soft fabric."""
    f = build_fabric(scene.with_obj(obj), FabricParams(theta_tol_deg=theta, tau_h=tau, anchor_lambda=lam,
                                                       temperature=t))
    pos = jnp.arange(f.anchor_weights.shape[-1], dtype=jnp.float32)
    return (jnp.sum(f.value) + jnp.sum(f.raw / (1.0 + f.length)) + jnp.sum(f.psi) + jnp.sum(f.heat)
            + jnp.sum(f.highways * f.heat) + jnp.sum(f.anchor_weights * pos) * 0.1)


# one jitted gradient for every grid of a shape (compiled once per shape)
_grad = jax.jit(jax.grad(_scalar, argnums=(1, 2, 3, 4, 5)))

# edge cases on one 3 x 4 shape (one compile) and the single-cell grid
EDGE_SCENES = {
    "empty_cells": lambda: Scene.from_arrays(np.array([[0, 2, 0, 1], [3, 0, 0, 0], [0, 1, 0, 0]], np.float32),
                                             box(2.6, 0.6, 4.0, 3.0)),
    "target_on_edge": lambda: Scene.from_arrays(np.arange(1, 13, dtype=np.float32).reshape(3, 4) % 4,
                                                box(0.0, 0.0, 1.4, 3.0)),
    "one_source": lambda: Scene.from_arrays(np.array([[0, 0, 0, 2.5], [0, 0, 0, 0], [0, 0, 0, 0]], np.float32),
                                            box(0.0, 0.0, 1.0, 1.0)),
    "no_source": lambda: Scene.from_arrays(np.zeros((3, 4), np.float32), box(0.0, 0.0, 1.0, 1.0)),
    "single_cell": lambda: Scene.from_arrays(np.ones((1, 1), np.float32), box(0.0, 0.0, 1.0, 1.0)),
}


@pytest.mark.parametrize("name", sorted(EDGE_SCENES))
@pytest.mark.parametrize("t", (0.3, 1e-3))
def test_gradients_are_finite_on_edge_case_grids(name, t):
    scene = EDGE_SCENES[name]()
    grads = _grad(scene, 60.0, 0.4, 0.5, scene.obj, t)
    for g in grads:
        assert np.all(np.isfinite(np.asarray(g)))


_value = jax.jit(_scalar)


def test_gradients_agree_with_finite_differences():
    # all counts positive: occupancy (obj > 0) is a hard switch, so a difference across 0 would jump.
    # Central differences along random directions of (theta, tau_h, lambda, obj, t), as
    # jax.test_util.check_grads does, reusing the module's compiled gradient.
    small = Scene.from_arrays(np.array([[1.5, 2.0, 0.7, 1.1], [3.0, 0.8, 2.2, 1.3], [0.6, 1.7, 2.9, 1.2]],
                                       np.float32), box(2.6, 0.6, 4.0, 3.0))
    x = (jnp.float32(55.0), jnp.float32(0.4), jnp.float32(0.5), jnp.asarray(small.obj), jnp.float32(0.5))
    grads = _grad(small, *x)
    rng = np.random.default_rng(0)
    for eps in (3e-3,):
        for _ in range(3):
            v = tuple(jnp.asarray(rng.normal(size=np.shape(a)), jnp.float32) for a in x)
            plus = _value(small, *(a + eps * d for a, d in zip(x, v)))
            minus = _value(small, *(a - eps * d for a, d in zip(x, v)))
            numeric = (float(plus) - float(minus)) / (2 * eps)
            analytic = sum(float(jnp.sum(g * d)) for g, d in zip(grads, v))
            assert analytic == pytest.approx(numeric, rel=3e-2, abs=3e-2)


def test_gradient_of_a_scalar_reaches_every_float_parameter():
    scene = EDGE_SCENES["target_on_edge"]()
    # the cone gate's logit is x / (t^2 CONE_SCALE): theta's gradient comes from steps within a few
    # t^2 CONE_SCALE of the cone's edge, so this uses a high temperature
    grads = _grad(scene, 60.0, 0.3, 0.5, scene.obj, 1.0)
    for name, g in zip(("theta_tol_deg", "tau_h", "anchor_lambda", "obj", "temperature"), grads):
        assert np.all(np.isfinite(np.asarray(g))) and np.any(np.asarray(g) != 0.0), name


# ---------------------------------------------------------------------------------------------- tracing


def test_no_recompile_for_a_new_temperature(scene):
    traced = jax.jit(chex.assert_max_traces(soft._soft_build, n=1))
    for t in (0.5, 0.1, 0.02):
        traced(scene, FabricParams(temperature=t))
    before = soft._soft_build_jit._cache_size()
    for t in (0.7, 0.05):
        build_fabric(scene, FabricParams(temperature=t))
    assert soft._soft_build_jit._cache_size() <= before + 1


def test_vmap_over_temperatures_equals_single_calls(scene):
    temps = jnp.array([0.05, 0.2, 0.8])
    batch = FabricParams(theta_tol_deg=jnp.full(3, 60.0), tau_h=jnp.full(3, 0.5), anchor_lambda=jnp.ones(3),
                         slack_tau=jnp.zeros(3), temperature=temps)
    stacked = jax.vmap(build_fabric, in_axes=(None, 0))(scene, batch)
    for i, t in enumerate(np.asarray(temps)):
        single = build_fabric(scene, FabricParams(temperature=float(t)))
        np.testing.assert_allclose(np.asarray(stacked.heat[i]), np.asarray(single.heat), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("field,value", [("temperature", -0.1), ("temperature", float("nan")), ("soft_rounds", 0)])
def test_bad_soft_parameters_raise(scene, field, value):
    with pytest.raises(ValueError, match=f"FabricParams.{field}"):
        build_fabric(scene, FabricParams(temperature=0.1).replace(**{field: value}))
