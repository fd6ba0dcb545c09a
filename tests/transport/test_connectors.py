"""Anchors (Eq. 12) and connectors (Algorithm 4) against the serial reference."""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan import FabricParams, Scene, build_fabric, builtin_scene, circle, plan_connectors
from jaxplan.core import lattice
from jaxplan.transport.connector_closure import CLOSURE_CAPACITY
from jaxplan.transport.connectors import anchor_for, anchors_for, connector_table, connector_walks
from jaxplan.transport.fabric import walk_table
from tests._scenes import has_borderline_step, random_blocked, reference_of, scenes


def _anchor_near_tie(ref, cell_size, anchor_lambda, rel=1e-5) -> bool:
    """Whether some root's two best anchor scores (Eq. 12, from the reference's float64 heat) are
    within float32 rounding: equal heats summed in another order may then pick either anchor."""
    cand = np.argwhere(ref.highways & ref.occupied)
    roots = np.argwhere(ref.occupied & ~ref.highways)
    if len(cand) < 2 or len(roots) == 0:
        return False
    dist = np.linalg.norm(roots[:, None, :] - cand[None, :, :], axis=-1) * cell_size
    score = ref.heat[cand[:, 0], cand[:, 1]][None, :] - anchor_lambda * dist
    top2 = -np.sort(-score, axis=1)[:, :2]
    return bool(np.any(top2[:, 0] - top2[:, 1] <= rel * (1.0 + np.abs(top2[:, 0]))))


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scene=scenes(max_side=16, integer_counts=False), theta=st.sampled_from((45.0, 60.0, 90.0)),
       lam=st.sampled_from((0.0, 0.5, 2.0)), tau_h=st.sampled_from((0.3, 0.6)))
def test_anchors_and_connectors_equal_reference(scene, theta, lam, tau_h):
    _check_against_reference(scene, theta, lam, tau_h)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scene=scenes(max_side=16, integer_counts=False, blocked=True), theta=st.sampled_from((45.0, 60.0, 90.0)),
       lam=st.sampled_from((0.0, 0.5, 2.0)), tau_h=st.sampled_from((0.3, 0.6)))
def test_anchors_and_connectors_around_blocked_cells_equal_reference(scene, theta, lam, tau_h):
    _check_against_reference(scene, theta, lam, tau_h)


def _check_against_reference(scene, theta, lam, tau_h):
    if has_borderline_step(scene, theta):
        return  # float32 vs float64 may decide a step at its threshold differently
    params = FabricParams(theta_tol_deg=theta, anchor_lambda=lam, tau_h=tau_h)
    fab = build_fabric(scene, params)
    ref = reference_of(scene, params)
    if not np.all(ref.unique_first_hop[ref.occupied]):
        return  # ties change the heatmap, and with it the anchors; first hops are tested elsewhere
    if _anchor_near_tie(ref, float(scene.cell_size), lam):
        return  # two anchors score equal up to rounding; float32 and float64 may pick either
    conn = plan_connectors(scene, params, fab, max_anchors=64)
    assert not bool(conn.truncated)
    np.testing.assert_array_equal(np.asarray(fab.highways), ref.highways)
    np.testing.assert_array_equal(np.asarray(conn.anchor), ref.anchor)
    has = np.asarray(conn.has_connector)
    np.testing.assert_array_equal(has, ref.anchor[..., 0] >= 0)
    np.testing.assert_allclose(np.asarray(conn.raw)[has], ref.conn_raw[has], rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(np.asarray(conn.length)[has], ref.conn_len[has], rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(np.asarray(conn.via_raw)[has], ref.via_raw[has], rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(np.asarray(conn.via_len)[has], ref.via_len[has], rtol=1e-5, atol=1e-4)


def test_truncated_when_anchors_do_not_fit():
    scene = builtin_scene("default")
    params = FabricParams(anchor_lambda=5.0)   # a strong distance weight spreads roots over anchors
    fab = build_fabric(scene, params)
    full = plan_connectors(scene, params, fab, max_anchors=64)
    distinct = int(np.sum(np.asarray(full.anchors) >= 0))
    assert distinct >= 2 and not bool(full.truncated)
    cut = plan_connectors(scene, params, fab, max_anchors=1)
    assert bool(cut.truncated)
    assert int(np.sum(np.asarray(cut.has_connector))) < int(np.sum(np.asarray(full.has_connector)))


def test_roots_are_occupied_non_highway_cells():
    scene = builtin_scene("default")
    fab = build_fabric(scene)
    conn = plan_connectors(scene, None, fab)
    has = np.asarray(conn.has_connector)
    assert np.all(np.asarray(fab.occupied)[has]) and not np.any(np.asarray(fab.highways)[has])
    anchors = np.asarray(conn.anchor)[has]
    assert np.all(np.asarray(fab.highways)[anchors[:, 0], anchors[:, 1]])


def test_candidate_buffer_gives_the_same_anchors_as_scoring_every_cell():
    from jaxplan.core import lattice
    from jaxplan.transport import connectors as conn

    scene = builtin_scene("sparse65")
    fabric = build_fabric(scene, FabricParams())
    centers = lattice.cell_centers(scene.shape, scene.cell_size, scene.origin)
    args = (fabric.heat, fabric.highways, fabric.occupied, centers, 1.0)
    size = conn.candidate_buffer(fabric)
    assert conn.candidate_count(fabric) <= size < scene.shape[0] * scene.shape[1]
    np.testing.assert_array_equal(np.asarray(conn.choose_anchors(*args, max_candidates=size)),
                                  np.asarray(conn.choose_anchors(*args)))


WINDOW_SHAPE = (22, 26)
LEVELS = (8, 16)
PARAMS = FabricParams()


def _window_scene(seed: int, blocked: bool):
    rng = np.random.default_rng(seed)
    obj = np.where(rng.random(WINDOW_SHAPE) < 0.6, np.round(rng.uniform(0.5, 5.0, WINDOW_SHAPE), 3), 0.0)
    target = circle((3.5, 3.5), 2.0)
    mask = random_blocked(WINDOW_SHAPE, rng) if blocked else np.zeros(WINDOW_SHAPE, bool)
    mask &= ~np.asarray(Scene.from_arrays(obj.astype(np.float32), target).target_mask)
    return Scene.from_arrays(np.where(mask, 0.0, obj).astype(np.float32), target, blocked=mask), rng


@functools.cache
def _walks(closure: int):
    cap = 2 * (WINDOW_SHAPE[0] + WINDOW_SHAPE[1])
    windowed = jax.jit(lambda scene, fabric, sources, anchors: connector_walks(
        scene, fabric, PARAMS, sources, anchors, cap, levels=LEVELS, closure=closure))
    whole = jax.jit(jax.vmap(lambda scene, fabric, source, anchor: walk_table(
        connector_table(scene, fabric, PARAMS, anchor), source, jnp.int32(0), cap), in_axes=(None, None, 0, 0)))
    return windowed, whole


@pytest.mark.parametrize("blocked", [False, True])
@pytest.mark.parametrize("closure", [0, 12])
def test_connectors_on_their_anchors_windows_are_the_whole_grids(blocked, closure):
    """Eight sources at a time, some sharing an anchor: near it (their DP on an 8 x 8 or 16 x 16
    window around it), far from it (the whole grid), or without one: the same walks, cell by cell,
    with the same collected mass and length. An anchor need not be a highway cell: any cell may end
    a connector. With a closure buffer the DP runs on the cells the connectors can visit when they fit
    (``closure`` 12: some fit, some overflow to the windows; 0: never; every closure fitting is the
    next test's case)."""
    windowed, whole = _walks(closure)
    for seed in range(4):
        scene, rng = _window_scene(seed, blocked)
        fabric = build_fabric(scene, PARAMS)
        occupied = np.argwhere(np.asarray(fabric.occupied))
        free = np.argwhere(~np.asarray(scene.blocked))
        sources = occupied[rng.choice(len(occupied), 8, replace=False)]
        anchors = []
        for k, source in enumerate(sources):
            if k in (1, 4):    # share the previous source's anchor
                anchors.append(anchors[-1])
                continue
            reach = (2, 2, 6, 40)[k % 4]     # 8 x 8, 8 x 8, 16 x 16, the whole grid
            cells = free[np.max(np.abs(free - source), 1) <= reach]
            anchor = cells[rng.integers(len(cells))]
            anchors.append(int(anchor[0] * WINDOW_SHAPE[1] + anchor[1]))
        anchors[7] = -1
        anchors = jnp.asarray(anchors, jnp.int32)
        got = windowed(scene, fabric, jnp.asarray(sources, jnp.int32), anchors)
        want = whole(scene, fabric, jnp.asarray(sources, jnp.int32), jnp.maximum(anchors, 0))
        has = np.asarray(anchors) >= 0
        for name in got._fields:
            np.testing.assert_array_equal(np.asarray(getattr(got, name))[has], np.asarray(getattr(want, name))[has],
                                          err_msg=f"seed {seed}: {name}")
        assert int(got.n_cells[7]) == 1 and not np.isfinite(float(got.raw[7]))   # no anchor: no connector
        np.testing.assert_array_equal(np.asarray(got.cells[7, 0]), sources[7])


def test_anchors_of_many_roots_equal_one_at_a_time():
    """``anchors_for`` scoring a list of the candidates (the shorter of two that holds them), or (both
    too short) the grid root by root: the anchors ``anchor_for`` gives each root."""
    scene, rng = _window_scene(5, False)
    fabric = build_fabric(scene, PARAMS)
    centers = lattice.cell_centers(scene.shape, scene.cell_size, scene.origin)
    roots = jnp.asarray(np.argwhere(np.ones(WINDOW_SHAPE, bool))[rng.choice(WINDOW_SHAPE[0] * WINDOW_SHAPE[1], 40)],
                        jnp.int32)
    one = jax.vmap(lambda r: anchor_for(fabric.heat, fabric.highways, fabric.occupied, centers, 0.5, r))(roots)
    assert int(jnp.sum(fabric.highways & fabric.occupied)) > 4 and bool(jnp.any(one >= 0))
    for short, size in ((2, 4), (4, 64), (64, 128), (8, WINDOW_SHAPE[0] * WINDOW_SHAPE[1])):
        many = anchors_for(fabric.heat, fabric.highways, fabric.occupied, centers, 0.5, roots, max_candidates=size,
                           short_candidates=short)
        np.testing.assert_array_equal(np.asarray(many), np.asarray(one), err_msg=f"lists of {short} and {size}")


@functools.cache
def _closure_walks(cap: int):
    """Jitted connector walks on closures only (no window levels) and on the whole grid."""
    on_closure = jax.jit(lambda scene, fabric, sources, anchors: connector_walks(
        scene, fabric, PARAMS, sources, anchors, cap, levels=(), closure=CLOSURE_CAPACITY))
    whole = jax.jit(jax.vmap(lambda scene, fabric, source, anchor: walk_table(
        connector_table(scene, fabric, PARAMS, anchor), source, jnp.int32(0), cap), in_axes=(None, None, 0, 0)))
    return on_closure, whole


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scene=scenes(max_side=16, integer_counts=False, blocked=True), cell_size=st.sampled_from((0.37, 1.0, 2.5)),
       origin=st.tuples(st.sampled_from((-3.1, 0.0, 12.7)), st.sampled_from((-0.4, 0.0, 5.3))),
       seed=st.integers(0, 2**31 - 1))
def test_connectors_on_their_closures_are_the_whole_grids(scene, cell_size, origin, seed):
    """The connector DP solved on the cells its sources can visit gives the whole grid's walks, cell
    by cell, with the same mass, length, fallback and completion: random scenes with blocked cells,
    cell sizes and origins (the distances to the anchor computed per cell round as the grid's do),
    sources on and off the material, two of them sharing an anchor, one its own anchor."""
    h, w = scene.shape
    obj, mask = np.asarray(scene.obj), np.array(scene.blocked)
    target = circle((origin[0] + cell_size * w / 2, origin[1] + cell_size * h / 2), cell_size * max(min(h, w) / 4, 1.0))
    grid = Scene.from_arrays(obj, target, cell_size=cell_size, origin=origin)
    mask &= ~np.asarray(grid.target_mask)
    scene = Scene.from_arrays(np.where(mask, 0.0, obj), target, cell_size=cell_size, origin=origin, blocked=mask)
    fabric = build_fabric(scene, PARAMS)
    rng = np.random.default_rng(seed)
    free = np.flatnonzero(~mask.reshape(-1))
    sources = rng.choice(free, 6)
    anchors = rng.choice(free, 6)
    anchors[1] = anchors[0]
    anchors[5] = sources[5]
    sources = np.stack([sources // w, sources % w], -1).astype(np.int32)
    cap = 2 * (h + w)
    on_closure, whole = _closure_walks(cap)
    got = on_closure(scene, fabric, jnp.asarray(sources), jnp.asarray(anchors, jnp.int32))
    want = whole(scene, fabric, jnp.asarray(sources), jnp.asarray(anchors, jnp.int32))
    for name in got._fields:
        np.testing.assert_array_equal(np.asarray(getattr(got, name)), np.asarray(getattr(want, name)), err_msg=name)
