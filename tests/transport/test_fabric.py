"""The fabric kernels against the serial reference, and their jit / vmap / edge-case behaviour."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan import FabricParams, Scene, build_fabric, circle, extract_paths
from jaxplan.transport import fabric as fabric_module
from tests._scenes import ANGLES, has_borderline_step, reference_of, scenes

SETTINGS = settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _tables_equal(fab, ref):
    raw = np.asarray(fab.table.raw, np.float64)
    length = np.asarray(fab.table.length, np.float64)
    assert np.array_equal(raw, ref.table_raw), "continuation-table raw counts differ"
    finite = np.isfinite(ref.table_len)
    assert np.array_equal(np.isfinite(length), finite)
    np.testing.assert_allclose(length[finite], ref.table_len[finite], rtol=1e-5, atol=1e-4)


# ---------------------------------------------------------------------------------- vs reference

@SETTINGS
@given(scene=scenes(), theta=st.sampled_from(ANGLES))
def test_value_length_and_table_equal_reference(scene, theta):
    assert_fabric_equals_reference(scene, theta)


def assert_fabric_equals_reference(scene, theta):
    """The fabric's per-cell fields and table equal the serial reference's (unless a step of the
    scene lies at its threshold, which float32 and float64 may decide apart)."""
    if has_borderline_step(scene, theta):
        return
    params = FabricParams(theta_tol_deg=theta)
    fab = build_fabric(scene, params)
    ref = reference_of(scene, params, with_connectors=False)
    assert bool(fab.converged)
    np.testing.assert_array_equal(np.asarray(fab.occupied), ref.occupied)
    np.testing.assert_array_equal(np.asarray(fab.feasible), ref.feasible)
    np.testing.assert_array_equal(np.asarray(fab.fallback), ref.fallback)
    np.testing.assert_array_equal(np.asarray(fab.value, np.float64), ref.value)
    np.testing.assert_allclose(np.asarray(fab.length), ref.length, rtol=1e-5, atol=1e-4)
    _tables_equal(fab, ref)
    unique = ref.unique_first_hop
    np.testing.assert_array_equal(np.asarray(fab.first_hop)[unique], ref.first_hop[unique])


@SETTINGS
@given(scene=scenes(integer_counts=False), theta=st.sampled_from(ANGLES))
def test_psi_heat_highways_equal_reference_where_unique(scene, theta):
    if has_borderline_step(scene, theta):
        return
    params = FabricParams(theta_tol_deg=theta)
    fab = build_fabric(scene, params)
    ref = reference_of(scene, params, with_connectors=False)
    occupied = ref.occupied
    if not np.all(ref.unique_first_hop[occupied]):
        return  # a tie somewhere: psi and heat may legitimately differ; first hops are tested above
    np.testing.assert_array_equal(np.asarray(fab.first_hop), ref.first_hop)
    np.testing.assert_allclose(np.asarray(fab.psi), ref.psi, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(np.asarray(fab.heat), ref.heat, rtol=1e-5, atol=1e-4)
    heat = np.asarray(fab.heat, np.float64)
    near_threshold = np.abs(heat - params.tau_h * heat.max()) < 1e-4
    np.testing.assert_array_equal(np.asarray(fab.highways)[~near_threshold], ref.highways[~near_threshold])


@settings(max_examples=12, deadline=None)
@given(scene=scenes(max_side=5), theta=st.sampled_from((60.0, 90.0, 120.0, 150.0)))
def test_without_monotone_rule_matches_reference_or_bounds_it(scene, theta):
    if has_borderline_step(scene, theta):
        return
    params = FabricParams(theta_tol_deg=theta, monotone=False, max_hops=8)
    fab = build_fabric(scene, params)
    ref = reference_of(scene, params, with_connectors=False)
    value = np.asarray(fab.value, np.float64)
    has_path = np.isfinite(ref.value)
    if bool(fab.converged):
        np.testing.assert_array_equal(value, ref.value)
        np.testing.assert_allclose(np.asarray(fab.length)[has_path], ref.length[has_path], atol=1e-4)
    else:  # walks can only do better than simple paths, wherever the kernel's rounds reach
        steps = np.array([[len(ref.paths.get((r, c), [])) - 1 for c in range(value.shape[1])]
                          for r in range(value.shape[0])])
        reachable = has_path & (steps < params.max_hops)
        assert np.all(value[reachable] >= ref.value[reachable])


@settings(max_examples=10, deadline=None)
@given(scene=scenes(), theta=st.sampled_from(ANGLES), k=st.sampled_from((1, 2, 4)))
def test_policy_solver_equals_wavefront_solver(scene, theta, k):
    fast = build_fabric(scene, FabricParams(theta_tol_deg=theta, k=k, solver="policy"))
    plain = build_fabric(scene, FabricParams(theta_tol_deg=theta, k=k, solver="wavefront"))
    assert bool(fast.converged) and bool(plain.converged)
    np.testing.assert_array_equal(np.asarray(fast.table.raw), np.asarray(plain.table.raw))
    np.testing.assert_allclose(np.asarray(fast.table.length), np.asarray(plain.table.length), rtol=1e-5, atol=1e-4)
    np.testing.assert_array_equal(np.asarray(fast.first_hop), np.asarray(plain.first_hop))


# ---------------------------------------------------------------------------------- paths

@settings(max_examples=10, deadline=None)
@given(scene=scenes(max_side=20))
def test_extracted_paths_reproduce_table_scores(scene):
    fab = build_fabric(scene, FabricParams())
    sources = np.argwhere(np.asarray(fab.occupied))
    if len(sources) == 0:
        return
    k = fab.table.raw.shape[-1]
    ranks = np.arange(len(sources) * k) % k
    sources = np.repeat(sources, k, axis=0)
    paths = jax.tree.map(np.asarray, extract_paths(fab, sources, ranks))   # indexed on the host, per path
    obj, target = np.asarray(scene.obj), np.asarray(scene.target_mask)
    dist = np.asarray(scene.dist)
    for i in range(len(sources)):
        if not np.isfinite(float(paths.raw[i])):
            continue
        cells = np.asarray(paths.cells[i, : int(paths.n_cells[i])])
        assert bool(paths.complete[i])
        raw = sum(obj[r, c] for r, c in cells if not target[r, c])
        steps = np.hypot(*np.diff(cells, axis=0).T).sum() if len(cells) > 1 else 0.0
        end = cells[-1]
        if bool(paths.fallback[i]):
            steps += dist[end[0], end[1]]
        else:
            assert target[end[0], end[1]], "a path must end in a target cell or with a fallback"
        assert raw == pytest.approx(float(paths.raw[i]))
        assert steps == pytest.approx(float(paths.length[i]), abs=1e-4)


# ---------------------------------------------------------------------------------- jit, vmap

@pytest.fixture(scope="module")
def small_scene():
    # a shape of SHAPES: its default build is the one the property tests above compiled
    rng = np.random.default_rng(3)
    obj = np.where(rng.random((7, 12)) < 0.5, rng.integers(1, 5, (7, 12)), 0).astype(np.float32)
    return Scene.from_arrays(obj, circle((9.0, 3.5), 2.2), cell_size=1.0)


def test_jitted_equals_unjitted(small_scene):
    params = FabricParams(theta_tol_deg=50.0)
    jitted = build_fabric(small_scene, params)
    with jax.disable_jit():
        plain = fabric_module.fabric_of(small_scene, params)
    for a, b in zip(jax.tree_util.tree_leaves(jitted), jax.tree_util.tree_leaves(plain)):
        a, b = np.asarray(a), np.asarray(b)
        if np.issubdtype(a.dtype, np.floating):   # XLA may fuse float ops differently under jit
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)
        else:
            np.testing.assert_array_equal(a, b)


def test_no_recompilation_for_new_counts_or_angle(small_scene):
    build_fabric(small_scene, FabricParams(theta_tol_deg=40.0))
    before = fabric_module._build_jit._cache_size()
    rng = np.random.default_rng(0)
    for theta in (35.0, 55.0, 80.0):
        obj = rng.integers(0, 4, small_scene.shape).astype(np.float32)
        build_fabric(small_scene.with_obj(obj), FabricParams(theta_tol_deg=theta))
    assert fabric_module._build_jit._cache_size() == before


def test_auto_solver_shares_the_program_of_the_solver_it_runs(small_scene):
    """"policy" (what "auto" runs with the monotone rule) is spelled "auto" before the jit, so both
    compile one program and build the same fabric."""
    auto = build_fabric(small_scene, FabricParams())
    before = fabric_module._build_jit._cache_size()
    policy = build_fabric(small_scene, FabricParams(solver="policy"))
    assert fabric_module._build_jit._cache_size() == before
    for a, b in zip(jax.tree_util.tree_leaves(auto), jax.tree_util.tree_leaves(policy)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert FabricParams(monotone=False).resolved_solver() == "wavefront"
    assert FabricParams(monotone=False, solver="wavefront").with_canonical_solver().solver == "auto"
    assert FabricParams(solver="wavefront").with_canonical_solver().solver == "wavefront"   # another solver


def test_vmap_over_angles_equals_single_calls(small_scene):
    angles = jnp.array([30.0, 45.0, 60.0, 90.0])
    batch = FabricParams(theta_tol_deg=angles, tau_h=jnp.full(4, 0.5), anchor_lambda=jnp.ones(4),
                         slack_tau=jnp.zeros(4))
    stacked = jax.vmap(build_fabric, in_axes=(None, 0))(small_scene, batch)
    for i, theta in enumerate(np.asarray(angles)):
        single = build_fabric(small_scene, FabricParams(theta_tol_deg=float(theta)))
        np.testing.assert_array_equal(np.asarray(stacked.value[i]), np.asarray(single.value))
        np.testing.assert_array_equal(np.asarray(stacked.heat[i]), np.asarray(single.heat))


def test_vmap_over_stacked_grids(small_scene):
    rng = np.random.default_rng(1)
    objs = rng.integers(0, 4, (3,) + small_scene.shape).astype(np.float32)
    stacked = jax.vmap(lambda o: build_fabric(small_scene.with_obj(o), FabricParams()))(jnp.asarray(objs))
    for i in range(3):
        single = build_fabric(small_scene.with_obj(objs[i]), FabricParams())
        np.testing.assert_array_equal(np.asarray(stacked.value[i]), np.asarray(single.value))


def test_outputs_finite(small_scene):
    fab = build_fabric(small_scene, FabricParams())
    for name in ("value", "length", "heading", "psi", "heat"):
        assert np.all(np.isfinite(np.asarray(getattr(fab, name)))), name


# ---------------------------------------------------------------------------------- edge cases
# on shapes of SHAPES, whose builds the property tests above compiled

def test_no_occupied_cell_gives_an_empty_fabric():
    scene = Scene.from_arrays(np.zeros((5, 5), np.float32), circle((2.5, 2.5), 1.5))
    fab = build_fabric(scene)
    assert not np.any(np.asarray(fab.occupied))
    assert np.all(np.asarray(fab.value) == 0) and np.all(np.asarray(fab.first_hop) == -1)
    assert np.all(np.asarray(fab.heat) == 0) and not np.any(np.asarray(fab.highways))


def test_everything_target_gives_an_empty_fabric():
    scene = Scene.from_arrays(np.ones((2, 3), np.float32), circle((1.5, 1.0), 5.0))
    fab = build_fabric(scene)
    assert np.all(np.asarray(scene.target_mask))
    assert np.all(np.asarray(fab.value) == 0) and np.all(np.asarray(fab.psi) == 0)


def test_single_cell_next_to_target():
    scene = Scene.from_arrays(np.array([[3.0, 0.0, 0.0, 0.0, 0.0, 0.0]], np.float32), circle((1.5, 0.5), 0.4))
    fab = build_fabric(scene)
    assert float(fab.value[0, 0]) == 3.0 and float(fab.length[0, 0]) == pytest.approx(1.0)
    assert tuple(np.asarray(fab.first_hop[0, 0])) == (0, 1)
    assert float(fab.psi[0, 1]) == 3.0  # the target cell the path ends in carries its mass


def test_fallback_cell_goes_straight_to_the_boundary():
    # the target is two cells away across an empty cell: no successor, so the boundary fallback
    scene = Scene.from_arrays(np.array([[2.0, 0.0, 0.0, 0.0, 0.0, 0.0]], np.float32), circle((2.5, 0.5), 0.4))
    fab = build_fabric(scene)
    assert bool(fab.fallback[0, 0])
    assert float(fab.value[0, 0]) == 2.0
    assert float(fab.length[0, 0]) == pytest.approx(float(scene.dist[0, 0]), rel=1e-6)
    assert tuple(np.asarray(fab.first_hop[0, 0])) == (0, 1)   # the heatmap's fallback hop


def test_target_outside_the_grid_is_rejected():
    with pytest.raises(ValueError, match="target"):
        Scene.from_arrays(np.ones((4, 4), np.float32), circle((40.0, 40.0), 1.0))


@pytest.mark.parametrize("field, value", [
    ("theta_tol_deg", 0.0), ("theta_tol_deg", 180.0), ("theta_tol_deg", -10.0),
    ("theta_tol_deg", float("nan")), ("tau_h", -1.0), ("anchor_lambda", -0.5), ("k", 0),
    ("k", 25), ("k", 1000), ("k", True), ("k", 4.0), ("max_hops", 0),
])
def test_bad_params_name_the_field(small_scene, field, value):
    with pytest.raises(ValueError, match=field):
        build_fabric(small_scene, FabricParams(**{field: value}))


# ---------------------------------------------------------------------------------- what a build costs

def test_k_range_names_the_bound_and_the_reason():
    from jaxplan.transport.params import K_MAX, validate_params

    validate_params(FabricParams(k=1))
    validate_params(FabricParams(k=K_MAX))
    with pytest.raises(ValueError, match=r"FabricParams\.k: 1000 is out of range; K must be an int in \[1, 24\]"):
        validate_params(FabricParams(k=1000))


@pytest.mark.parametrize("k, measured_gib", [(8, 0.30), (10, 0.71), (12, 1.63), (16, 6.61)])
def test_build_estimate_follows_the_measured_cost(k, measured_gib):
    """Peak RSS over an idle process of a first `jaxplan fabric` (estimate_build_bytes' comment)."""
    est = fabric_module.estimate_build_bytes((25, 25), FabricParams(k=k)) / 2**30
    assert est == pytest.approx(measured_gib, rel=0.1)


def test_build_estimate_grows_with_k_and_grid():
    est = fabric_module.estimate_build_bytes
    by_k = [est((25, 25), FabricParams(k=k)) for k in range(1, 25)]
    assert all(a < b for a, b in zip(by_k, by_k[1:]))
    assert est((25, 25)) < est((100, 100)) < est((1000, 1000))
    assert est((25, 25)) == est((25, 25), FabricParams(k=4))


def test_check_build_memory_refuses_what_does_not_fit():
    shape = (25, 25)
    need = fabric_module.estimate_build_bytes(shape, FabricParams(k=16))
    assert fabric_module.check_build_memory(shape, FabricParams(k=16), available=need) == need
    with pytest.raises(ValueError, match=r"FabricParams\.k: K = 16 needs about 7\.0 GB .* use k <= 14"):
        fabric_module.check_build_memory(shape, FabricParams(k=16), available=5 * 10**9)
    with pytest.raises(ValueError, match="free memory or use a smaller grid"):
        fabric_module.check_build_memory(shape, FabricParams(k=2), available=1)
