"""Selective rebuild: after any sequence of pushes it equals a from-scratch build of the same grid."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan import FabricParams, build_fabric, builtin_scene, extract_paths
from jaxplan.reference import rebuild as ref_rb
from jaxplan.transport import execute as ex
from jaxplan.transport import heatmap, visibility
from jaxplan.transport import rebuild as rb
from jaxplan.transport import spillage as sp
from jaxplan.transport.fabric import first_hops, hop_lengths
from tests._scenes import ANGLES, scenes

SETTINGS = settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# lengths are sums of s and s*sqrt(2) in a different order in each solver: equal up to rounding
_FLOAT_FIELDS = {"length"}


def assert_same_fabric(got, want):
    for name in got._fields:
        if name in ("rounds", "converged"):
            continue
        a, b = getattr(got, name), getattr(want, name)
        if name == "table":
            np.testing.assert_array_equal(np.asarray(a.raw), np.asarray(b.raw), err_msg="table.raw")
            np.testing.assert_allclose(np.asarray(a.length), np.asarray(b.length), rtol=1e-6, err_msg="table.length")
            np.testing.assert_array_equal(np.asarray(a.next_dir), np.asarray(b.next_dir), err_msg="table.next_dir")
            np.testing.assert_array_equal(np.asarray(a.next_rank), np.asarray(b.next_rank), err_msg="table.next_rank")
        elif name in _FLOAT_FIELDS:
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6, err_msg=name)
        else:
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=name)


def _push(scene, fabric, source, rank, spill):
    h, w = scene.shape
    paths = extract_paths(fabric, jnp.array([source]), jnp.array([rank]), max_steps=h * w + 1)
    route = jax.tree.map(lambda a: a[0], ex.routes_from_paths(scene, paths))
    return ex.execute_jit(scene, route, spill)


@SETTINGS
@given(scene=scenes(max_side=13, integer_counts=False), theta=st.sampled_from(ANGLES),
       lam=st.sampled_from((0.0, 0.05, 0.5)), pushes=st.lists(st.tuples(st.integers(0, 2**16), st.integers(0, 3)),
                                                              min_size=1, max_size=4), local=st.booleans(),
       dense=st.booleans())
def test_selective_rebuild_equals_full_build_after_random_pushes(scene, theta, lam, pushes, local, dense):
    # dense: the dirty cells listed by whole-grid dilation (small grids' default) or by the queue
    scene = scene.with_obj(ex.quantize(scene.obj))   # exact sums: see execute.QUANTUM
    params = FabricParams(theta_tol_deg=theta)
    spill = sp.SpillParams(lam=lam, threshold=0.01)
    fabric = build_fabric(scene, params)
    for seed, rank in pushes:
        sources = np.argwhere(np.asarray(fabric.occupied))
        if len(sources) == 0:
            break
        source = tuple(sources[seed % len(sources)])
        rank = rank if np.isfinite(float(fabric.table.raw[source + (rank,)])) else 0
        new_obj, push = _push(scene, fabric, source, rank, spill)
        old_feasible = fabric.feasible
        scene = scene.with_obj(new_obj)
        fabric, affected = rb.selective_rebuild(scene, params, fabric, push.changed, local_flow=local,
                                                dense_listing=dense)
        assert_same_fabric(fabric, build_fabric(scene, params))
        want_dirty = ref_rb.upstream_closure(np.asarray(push.changed), np.asarray(old_feasible),
                                             np.asarray(fabric.feasible))
        np.testing.assert_array_equal(np.asarray(affected.dirty), want_dirty)
        assert int(affected.n_dirty) == int(want_dirty.sum())


@pytest.fixture(scope="module")
def pushed():
    """The default scene, its fabric, and the scene after pushing its best route."""
    scene = builtin_scene()
    scene = scene.with_obj(ex.quantize(scene.obj))
    params = FabricParams()
    fabric = build_fabric(scene, params)
    source = tuple(int(v) for v in np.unravel_index(int(jnp.argmax(fabric.value)), fabric.value.shape))
    new_obj, push = _push(scene, fabric, source, 0, sp.SpillParams(lam=0.1))
    return scene.with_obj(new_obj), params, fabric, push


def test_overflowing_capacity_falls_back_to_a_full_build(pushed):
    scene, params, fabric, push = pushed
    small, affected = rb.selective_rebuild(scene, params, fabric, push.changed, capacity=1)
    assert bool(affected.full) and int(affected.n_dirty) > 1
    assert_same_fabric(small, build_fabric(scene, params))
    roomy, affected = rb.selective_rebuild(scene, params, fabric, push.changed)
    assert not bool(affected.full)
    assert_same_fabric(roomy, small)


def test_rebuilding_a_reselected_fabric_gives_the_entry_0_fabric(pushed):
    # an Eq. 6 fabric's first hops and psi follow other entries: the rebuild must not patch them
    from jaxplan import reselect

    scene, params, fabric, push = pushed
    before = builtin_scene().with_obj(ex.quantize(builtin_scene().obj))
    spill = sp.SpillParams(lam=0.5, threshold=0.0)
    chosen = reselect(before, params.replace(slack_tau=5.0), fabric, spill, max_steps=before.obj.size + 1)
    assert bool(jnp.any(chosen.selected != 0))
    for local in (False, True):
        rebuilt, _ = rb.selective_rebuild(scene, params, chosen, push.changed, local_flow=local)
        assert_same_fabric(rebuilt, build_fabric(scene, params))


def test_local_refresh_of_psi_flags_a_walk_that_overflows(pushed):
    scene, params, fabric, push = pushed
    full = build_fabric(scene, params)
    dirty = ref_rb.upstream_closure(np.asarray(push.changed), np.asarray(fabric.feasible), np.asarray(full.feasible))
    cells = jnp.asarray(np.flatnonzero(dirty), jnp.int32)
    args = (fabric.psi, full.value, rb._path_pointer(fabric.table), rb._path_pointer(full.table), jnp.asarray(dirty),
            cells)
    psi, touched, count = heatmap.repropagated_mass(*args, 4 * cells.size, 10_000)
    assert cells.size < int(count) <= touched.shape[0]     # the walk left the dirty set and fitted
    np.testing.assert_array_equal(np.asarray(psi), np.asarray(full.psi))
    _, touched, count = heatmap.repropagated_mass(*args, 0, 10_000)
    assert int(count) > touched.shape[0]


@jax.jit
def _cell_and_grid_kernels(scene, fabric, theta):
    """The selective rebuild's per-cell kernels on every cell (then 3 padding cells) beside the
    whole-grid ones they stand in for; one program per grid shape."""
    h, w = scene.shape
    cells = jnp.arange(h * w + 3, dtype=jnp.int32).at[-3:].set(h * w)
    target = scene.target_mask
    args = (scene.obj, ~target & (scene.obj > 0), target, scene.dist, scene.tvec, theta, scene.cell_size, True)
    _, _, hop_len = first_hops(fabric.table, scene.tvec, scene.cell_size)
    return dict(grid=visibility.successor_graph(*args), lanes=visibility.successor_lanes(cells, *args),
                fallback_at=visibility.fallback_direction_at(scene.tvec, cells),
                fallback=visibility.fallback_direction(scene.tvec),
                heat_at=heatmap.heat_at(cells, fabric.psi, fabric.occupied, fabric.heading, hop_len, target,
                                        scene.cell_size),
                hop_len=hop_len, hop_lengths=hop_lengths(fabric.first_hop, scene.cell_size))


@SETTINGS
@given(scene=scenes(max_side=16), theta=st.sampled_from(ANGLES))
def test_cell_lists_give_the_grid_kernels_values(scene, theta):
    # the selective rebuild's per-cell kernels against the whole-grid ones they stand in for
    fabric = build_fabric(scene, FabricParams(theta_tol_deg=theta))
    h, w = scene.shape
    got = jax.tree.map(np.asarray, _cell_and_grid_kernels(scene, fabric, jnp.float32(theta)))
    lanes, grid = got["lanes"], got["grid"]
    for name in ("obj", "feasible", "enters_goal", "fallback", "fallback_len"):
        want = getattr(grid, name)
        np.testing.assert_array_equal(getattr(lanes, name)[..., : h * w], want.reshape(want.shape[:-2] + (-1,)),
                                      err_msg=name)
    assert not lanes.feasible[:, h * w:].any()
    np.testing.assert_array_equal(got["fallback_at"][: h * w], got["fallback"].reshape(-1))
    np.testing.assert_array_equal(got["heat_at"][: h * w], np.asarray(fabric.heat).reshape(-1))
    np.testing.assert_array_equal(got["hop_lengths"], got["hop_len"])


def test_without_the_monotone_rule_the_rebuild_is_a_full_build(pushed):
    scene, params, fabric, push = pushed
    params = params.replace(monotone=False)
    rebuilt, affected = rb.selective_rebuild(scene, params, build_fabric(scene, params), push.changed)
    assert bool(affected.full)
    assert_same_fabric(rebuilt, build_fabric(scene, params))


def test_no_change_keeps_the_fabric(pushed):
    scene, params, _, _ = pushed
    fabric = build_fabric(scene, params)
    rebuilt, affected = rb.selective_rebuild(scene, params, fabric, jnp.zeros(scene.shape, bool))
    assert int(affected.n_dirty) == 0
    assert_same_fabric(rebuilt, fabric)


def test_paper_sets_equal_reference(pushed):
    scene, params, _, push = pushed
    vis, everything = rb.paper_sets(scene, push.changed, params.theta_tol_deg)
    want = ref_rb.a_vis(np.asarray(push.changed), np.asarray(scene.occupied), np.asarray(scene.tvec, np.float64),
                        float(scene.cell_size), (0.0, 0.0), float(params.theta_tol_deg))
    np.testing.assert_array_equal(np.asarray(vis), want)
    np.testing.assert_array_equal(np.asarray(everything), want | np.asarray(push.changed))


def test_rebuild_compiles_once_per_grid(pushed):
    scene, params, fabric, push = pushed
    rb.selective_rebuild(scene, params, fabric, push.changed)
    before = (rb._listing_jit._cache_size(), rb._finish_jit._cache_size())
    for theta in (50.0, 70.0):   # traced parameters change; shapes, hence the buffer size here, do not
        rebuilt, affected = rb.selective_rebuild(scene, params.replace(theta_tol_deg=theta), fabric, push.changed)
        assert bool(jnp.all(jnp.isfinite(rebuilt.heat)))
    assert (rb._listing_jit._cache_size(), rb._finish_jit._cache_size()) == before


def test_inside_jit_the_switch_program_gives_the_same_fabric(pushed):
    scene, params, fabric, push = pushed
    host, host_affected = rb.selective_rebuild(scene, params, fabric, push.changed)
    traced, traced_affected = jax.jit(lambda s, f, c: rb.selective_rebuild(s, params, f, c))(scene, fabric,
                                                                                            push.changed)
    assert_same_fabric(traced, host)
    assert int(traced_affected.n_dirty) == int(host_affected.n_dirty)
    assert bool(traced_affected.full) == bool(host_affected.full)


def test_refreshed_connectors_equal_planning_from_scratch(pushed):
    from jaxplan import plan_connectors

    _, params, _, _ = pushed
    before = builtin_scene().with_obj(ex.quantize(builtin_scene().obj))
    fabric = build_fabric(before, params)
    # a small push (the source whose route collects least), so that most anchors survive it
    value = np.where(np.asarray(fabric.occupied), np.asarray(fabric.value), np.inf)
    source = tuple(int(v) for v in np.unravel_index(int(np.argmin(value)), value.shape))
    new_obj, push = _push(before, fabric, source, 0, sp.SpillParams(lam=0.0))
    scene = before.with_obj(new_obj)
    rebuilt, _ = rb.selective_rebuild(scene, params, fabric, push.changed)
    old = plan_connectors(before, params, fabric, max_anchors=16)
    refreshed, reused = rb.refresh_connectors(scene, params, rebuilt, fabric, old, push.changed)
    want = plan_connectors(scene, params, rebuilt, max_anchors=16)
    for name in want._fields:
        for a, b in zip(jax.tree.leaves(getattr(refreshed, name)), jax.tree.leaves(getattr(want, name))):
            a, b = np.asarray(a), np.asarray(b)
            if np.issubdtype(a.dtype, np.floating):
                np.testing.assert_allclose(a, b, rtol=1e-6, err_msg=name)
            else:
                np.testing.assert_array_equal(a, b, err_msg=name)
    assert bool(jnp.any(reused))   # some anchors survived the push and were updated, not replanned
