"""Blocked cells: the obstacle-aware geometry, the fabric, paths, pushes and episodes around them."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan import FabricParams, Scene, SpillParams, build_fabric, extract_paths
from jaxplan.core import lattice
from jaxplan.reference.execute import execute_route
from jaxplan.reference.obstacles import reference_detour_hops, reference_obstacle_geometry
from jaxplan.transport import EpisodeParams, obstacles, reset, run_episode, selective_rebuild
from jaxplan.transport import execute as ex
from jaxplan.transport.episode import STOP_REASONS, step_jit
from jaxplan.transport.geometry import box, target_geometry, target_segments
from jaxplan.transport.soft import build_soft_fabric
from tests._scenes import ANGLES, scenes
from tests.transport.test_fabric import assert_fabric_equals_reference
from tests.transport.test_rebuild import assert_same_fabric

SETTINGS = settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _straight_geometry(scene):
    """The scene's straight-line geometry (before blocked cells bend it)."""
    return target_geometry(jnp.asarray(target_segments(scene.target)), scene.shape, scene.cell_size, scene.origin)


@pytest.fixture(scope="module")
def walled():
    """A 16 x 16 site: a wall between the material and the target, a pile behind it."""
    h, w = 16, 16   # a shape of SHAPES: the fabric the property tests compiled
    blocked = np.zeros((h, w), bool)
    blocked[5:7, 3:12] = True
    obj = np.zeros((h, w), np.float32)
    obj[9:12, 5:9] = 1.0
    obj[12, 2] = 3.0
    obj[1, 4] = 2.0
    return Scene.from_arrays(obj, box(6, 0, 10, 3), blocked=blocked, name="walled")


# ---------------------------------------------------------------------------------- geometry

@SETTINGS
@given(scene=scenes(max_side=16, blocked=True))
def test_obstacle_geometry_equals_reference(scene):
    _, dist, tvec = _straight_geometry(scene)
    want_dist, want_tvec, want_detour = reference_obstacle_geometry(
        np.asarray(scene.blocked), np.asarray(scene.target_mask), np.asarray(dist), np.asarray(tvec),
        float(scene.cell_size))
    np.testing.assert_array_equal(np.asarray(scene.dist), want_dist)
    np.testing.assert_array_equal(np.asarray(scene.tvec), want_tvec)
    np.testing.assert_array_equal(np.asarray(scene.detour), want_detour)
    np.testing.assert_array_equal(np.asarray(obstacles.detour_hops(scene.detour)), reference_detour_hops(want_detour))


@SETTINGS
@given(scene=scenes(max_side=16, blocked=True))
def test_detours_are_open_steps_down_the_distance(scene):
    detour, dist = np.asarray(scene.detour), np.asarray(scene.dist)
    steps_open = np.asarray(obstacles.open_steps(scene.blocked))
    for r, c in np.argwhere(detour >= 0):
        d = detour[r, c]
        dr, dc = lattice.DIRS[d]
        assert steps_open[d, r, c], "a detour step enters a blocked cell or cuts its corner"
        assert dist[r + dr, c + dc] < dist[r, c]
    blocked = np.asarray(scene.blocked)
    assert np.all(np.isinf(dist[blocked])) and np.all(np.asarray(scene.tvec)[blocked] == 0)


def test_without_blocked_cells_the_geometry_is_the_straight_one(walled):
    free = Scene.from_arrays(walled.obj, walled.target)
    _, dist, tvec = _straight_geometry(walled)
    got = obstacles.obstacle_geometry(jnp.zeros(walled.shape, bool), free.target_mask, dist, tvec, free.cell_size)
    np.testing.assert_array_equal(np.asarray(got[0]), np.asarray(free.dist))
    np.testing.assert_array_equal(np.asarray(got[1]), np.asarray(free.tvec))
    assert np.all(np.asarray(got[2]) == obstacles.NO_DETOUR) and np.all(np.asarray(free.detour) == obstacles.NO_DETOUR)


def test_cells_behind_the_wall_detour_around_it(walled):
    detour = np.asarray(walled.detour)
    assert (detour[9:12, 5:9] >= 0).all(), "the pile behind the wall has no straight way to the target"
    assert detour[1, 4] == obstacles.NO_DETOUR
    assert float(walled.unreachable_mass) == 0.0


def test_material_cut_off_from_every_target_is_counted_and_not_planned():
    blocked = np.zeros((13, 9), bool)   # a shape of SHAPES: a fabric the property tests compile too
    blocked[5:13, 5] = True
    blocked[5, 5:9] = True
    obj = np.zeros((13, 9), np.float32)
    obj[7, 7] = 4.0                      # inside the courtyard
    obj[2, 2] = 1.0
    scene = Scene.from_arrays(obj, box(0, 0, 2, 2), blocked=blocked)
    assert float(scene.unreachable_mass) == 4.0
    assert bool(scene.cut_off[7, 7]) and np.isinf(float(scene.dist[7, 7]))
    fab = build_fabric(scene, FabricParams())
    assert not bool(fab.occupied[7, 7]) and bool(fab.occupied[2, 2])


def test_jump_clear_follows_the_chebyshev_walk():
    blocked = np.zeros((8, 8), bool)
    blocked[3, 3] = True
    assert not bool(obstacles.jump_clear(blocked, jnp.array([0, 0]), jnp.array([6, 6])))
    assert bool(obstacles.jump_clear(blocked, jnp.array([0, 0]), jnp.array([0, 7])))
    assert bool(obstacles.jump_clear(blocked, jnp.array([2, 2]), jnp.array([2, 2])))
    corner = np.zeros((4, 4), bool)
    corner[0, 1] = True                 # (0, 0) -> (1, 1) passes between (0, 1) and (1, 0)
    assert not bool(obstacles.jump_clear(corner, jnp.array([0, 0]), jnp.array([1, 1])))


# ---------------------------------------------------------------------------------- scene inputs

def test_blocked_cells_may_not_hold_material_or_target():
    blocked = np.zeros((6, 6), bool)
    blocked[4, 4] = True
    obj = np.zeros((6, 6))
    obj[4, 4] = 1.0
    with pytest.raises(ValueError, match=r"Scene.blocked: 1 blocked cell\(s\) hold material \(first at row 4, col 4\)"):
        Scene.from_arrays(obj, box(0, 0, 2, 2), blocked=blocked)
    blocked[0, 0] = True
    with pytest.raises(ValueError, match="hold target area"):
        Scene.from_arrays(np.zeros((6, 6)), box(0, 0, 2, 2), blocked=blocked)
    blocked[0, 0] = False
    scene = Scene.from_arrays(np.zeros((6, 6)), box(0, 0, 2, 2), blocked=blocked)
    with pytest.raises(ValueError, match="hold material"):
        scene.with_obj(np.where(np.asarray(scene.blocked), 1.0, 0.0))


@pytest.mark.parametrize("bad, match", [
    (np.zeros((5, 6), bool), "shape"), (np.full((6, 6), 2), "bool mask"), (np.full((6, 6), 0.5), "bool mask"),
])
def test_bad_blocked_masks_name_the_field(bad, match):
    with pytest.raises(ValueError, match=f"Scene.blocked: .*{match}"):
        Scene.from_arrays(np.zeros((6, 6)), box(0, 0, 2, 2), blocked=bad)


# ---------------------------------------------------------------------------------- the fabric

@SETTINGS
@given(scene=scenes(max_side=16, blocked=True), theta=st.sampled_from(ANGLES))
def test_fabric_on_blocked_scenes_equals_reference(scene, theta):
    assert_fabric_equals_reference(scene, theta)


def _check_walk(scene, cells, fallback, prefix):
    """A walked path: the table's path, then its detour; open steps only, ending where it should."""
    blocked, detour, target = np.asarray(scene.blocked), np.asarray(scene.detour), np.asarray(scene.target_mask)
    steps_open = np.asarray(obstacles.open_steps(scene.blocked))
    assert not blocked[cells[:, 0], cells[:, 1]].any(), "a path enters a blocked cell"
    np.testing.assert_array_equal(cells[: len(prefix)], prefix)
    for a, b in zip(cells[:-1], cells[1:]):
        d = lattice.DIRS.index(tuple(int(v) for v in b - a))
        assert steps_open[d, a[0], a[1]], "a path cuts a blocked corner"
    for a, b in zip(cells[len(prefix) - 1:-1], cells[len(prefix):]):
        assert lattice.DIRS[detour[a[0], a[1]]] == tuple(int(v) for v in b - a), "a detour leaves its chain"
    end = cells[-1]
    assert detour[end[0], end[1]] == obstacles.NO_DETOUR
    assert fallback or target[end[0], end[1]]


@SETTINGS
@given(scene=scenes(max_side=16, blocked=True))
def test_walked_paths_drive_the_detour_and_keep_the_table_length(scene):
    fab = build_fabric(scene, FabricParams())
    sources = np.argwhere(np.asarray(fab.occupied))
    if len(sources) == 0:
        return
    plain = jax.tree.map(np.asarray, extract_paths(fab, sources))      # indexed on the host, per path
    walked = jax.tree.map(np.asarray, extract_paths(fab, sources, detour=scene.detour))
    dist = np.asarray(scene.dist, np.float64)
    for i in range(len(sources)):
        cells = np.asarray(walked.cells[i, : int(walked.n_cells[i])])
        prefix = np.asarray(plain.cells[i, : int(plain.n_cells[i])])
        assert bool(walked.complete[i])
        _check_walk(scene, cells, bool(walked.fallback[i]), prefix)
        steps = np.hypot(*np.diff(cells, axis=0).T).sum() if len(cells) > 1 else 0.0
        if bool(walked.fallback[i]):
            steps += dist[cells[-1][0], cells[-1][1]]
        assert steps == pytest.approx(float(walked.length[i]), rel=1e-5, abs=1e-4)


@SETTINGS
@given(scene=scenes(max_side=13, blocked=True, integer_counts=False), lam=st.sampled_from((0.05, 0.5)))
def test_pushes_leave_blocked_cells_empty_keep_the_mass_and_equal_reference(scene, lam):
    scene = scene.with_obj(ex.quantize(scene.obj))
    fab = build_fabric(scene, FabricParams())
    sources = np.argwhere(np.asarray(fab.occupied))
    if len(sources) == 0:
        return
    paths = extract_paths(fab, sources, detour=scene.detour)
    routes = ex.routes_from_paths(scene, paths)
    spill = SpillParams(lam=lam, threshold=0.01)
    blocked = np.asarray(scene.blocked)
    for i in range(min(len(sources), 6)):
        route = jax.tree.map(lambda a, i=i: a[i], routes)
        new, push = ex.execute_jit(scene, route, spill)
        new = np.asarray(new, np.float64)
        assert not new[blocked].any(), "material on a blocked cell"
        assert new.sum() == pytest.approx(float(np.sum(np.asarray(scene.obj, np.float64))), rel=1e-6)
        cells = [tuple(int(v) for v in rc) for rc in np.asarray(route.cells[: int(route.n_cells)])]
        want, _ = execute_route(np.asarray(scene.obj), np.asarray(scene.target_mask), np.asarray(scene.dist),
                                np.asarray(scene.tvec), float(scene.cell_size), tuple(np.asarray(scene.origin, float)),
                                cells, bool(route.fallback), lam=lam, threshold=0.01, samples_per_step=8,
                                blocked=blocked)
        np.testing.assert_allclose(new, want, atol=2e-3)


@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scene=scenes(max_side=13, blocked=True, integer_counts=False))
def test_selective_rebuild_equals_full_build_on_blocked_scenes(scene):
    scene = scene.with_obj(ex.quantize(scene.obj))
    params = FabricParams()
    fabric = build_fabric(scene, params)
    spill = SpillParams(lam=0.3, threshold=0.01)
    for _ in range(3):
        sources = np.argwhere(np.asarray(fabric.occupied))
        if len(sources) == 0:
            break
        h, w = scene.shape
        paths = extract_paths(fabric, sources[:1], max_steps=h * w + 1, detour=scene.detour)
        route = jax.tree.map(lambda a: a[0], ex.routes_from_paths(scene, paths))
        new_obj, push = ex.execute_jit(scene, route, spill)
        scene = scene.with_obj(new_obj)
        fabric, _ = selective_rebuild(scene, params, fabric, push.changed)
        assert_same_fabric(fabric, build_fabric(scene, params))


def test_soft_fabric_is_finite_around_blocked_cells(walled):
    params = FabricParams(temperature=0.1)
    soft = build_soft_fabric(walled, params)
    assert all(bool(jnp.all(jnp.isfinite(a))) for a in jax.tree.leaves(soft))
    grad = jax.grad(lambda t: jnp.sum(build_soft_fabric(walled, params.replace(temperature=t)).value))(0.1)
    assert np.isfinite(float(grad))


# ---------------------------------------------------------------------------------- episodes

def test_episode_clears_the_site_behind_the_wall(walled):
    params, spill, ep = FabricParams(), SpillParams(lam=0.05), EpisodeParams(max_pushes=40)
    state = reset(walled, params, spill, ep)
    blocked = np.asarray(walled.blocked)
    total = float(np.sum(np.asarray(state.scene.obj, np.float64)))
    for _ in range(40):
        state, record = step_jit(state, params, spill, ep)
        obj = np.asarray(state.scene.obj, np.float64)
        assert not obj[blocked].any(), "material on a blocked cell during the episode"
        assert obj.sum() == pytest.approx(total, rel=1e-6)
        if bool(state.done):
            break
    assert STOP_REASONS[int(state.stop)] == "done"
    result = run_episode(walled, params, spill, ep)
    assert result.stop_reason == "done" and result.totals()["unreachable_mass"] == 0.0
    np.testing.assert_array_equal(result.final_obj, np.asarray(state.scene.obj))
