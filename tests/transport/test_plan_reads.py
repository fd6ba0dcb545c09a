"""What a plan read (``plan_reads``) and whether a refresh changed it (``plans_unchanged``): a plan said
unchanged is the plan ``plan_for_source`` makes again on the refreshed fabric, route, mode and
predicted delivery, on random scenes with random count changes."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan import FabricParams, SpillParams, build_fabric, random_scene
from jaxplan.transport import (
    SPLINE_CHUNK,
    execute,
    fabric_changes,
    plan_for_source,
    plan_reads,
    plans_unchanged,
    source_anchors,
    waypoint_pickup,
    waypoints,
)
from jaxplan.transport.episode import EpisodeParams
from jaxplan.transport.spillage import curvature_spill, evaluate_route

SHAPE = (20, 20)
CAP = 200
SOURCES = 12
PARAMS, SPILL, EP = FabricParams(), SpillParams(), EpisodeParams()


@jax.jit
def _plans(scene, fabric, sources):
    def one(source):
        plan = plan_for_source(scene, PARAMS, EP, SPILL, fabric, source, CAP, curvature_spill)
        points, n_points = waypoints(scene, plan.route)
        pickup, _ = waypoint_pickup(scene, plan.route)
        predicted = evaluate_route(points, n_points, pickup, SPILL, curvature_spill, chunk=SPLINE_CHUNK)[0]
        return plan.route, plan.mode, plan.raw, predicted
    return jax.vmap(one)(sources)


@jax.jit
def _reads(scene, fabric, sources):
    anchors = source_anchors(scene, PARAMS, fabric, sources)
    return jax.vmap(lambda s, a: plan_reads(scene, PARAMS, fabric, s, a, CAP))(sources, anchors)


@jax.jit
def _unchanged(scene, reads, before, old, new):
    return plans_unchanged(scene, PARAMS, reads, old, new, fabric_changes(before, scene.obj, old, new))


def _changed_scene(scene, rng, cells: int):
    """The scene with ``cells`` random non-target cells given other counts (multiples of the quantum)."""
    obj = np.asarray(scene.obj).copy()
    free = np.argwhere(~np.asarray(scene.target_mask))
    for r, c in free[rng.choice(len(free), cells, replace=False)]:
        obj[r, c] = float(rng.integers(0, 7))
    return scene.with_obj(execute.quantize(jnp.asarray(obj)))


def _sources(scene, rng):
    occupied = np.argwhere((np.asarray(scene.obj) > 0) & ~np.asarray(scene.target_mask))
    return jnp.asarray(occupied[rng.choice(len(occupied), SOURCES, replace=len(occupied) < SOURCES)], jnp.int32)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2 ** 31 - 1), layout=st.sampled_from(["uniform", "piles"]), cells=st.integers(1, 4))
def test_a_plan_said_unchanged_is_the_plan_made_again(seed, layout, cells):
    rng = np.random.default_rng(seed)
    scene = random_scene(seed % 1000, SHAPE, 0.4, layout=layout)
    scene = scene.with_obj(execute.quantize(scene.obj))
    old = build_fabric(scene, PARAMS)
    sources = _sources(scene, rng)
    before, reads = _plans(scene, old, sources), _reads(scene, old, sources)
    changed = _changed_scene(scene, rng, cells)
    new = build_fabric(changed, PARAMS)
    same = np.asarray(_unchanged(changed, reads, scene.obj, old, new))
    after = _plans(changed, new, sources)
    for leaf_before, leaf_after in zip(jax.tree.leaves(before), jax.tree.leaves(after)):
        np.testing.assert_array_equal(np.asarray(leaf_before)[same], np.asarray(leaf_after)[same])


def test_a_change_far_from_a_plan_keeps_it_and_one_on_its_route_does_not():
    scene = random_scene(4, SHAPE, 0.4, layout="uniform")
    scene = scene.with_obj(execute.quantize(scene.obj))
    old = build_fabric(scene, PARAMS)
    sources = _sources(scene, np.random.default_rng(0))
    route = _plans(scene, old, sources)[0]
    reads = _reads(scene, old, sources)
    kept = dropped = 0
    for i in range(SOURCES):
        cells = np.asarray(route.cells[i])[1:int(route.n_cells[i])]
        cells = cells[~np.asarray(scene.target_mask)[cells[:, 0], cells[:, 1]]] if len(cells) else cells
        if len(cells):           # one count on the route changed: this plan is planned again
            obj = np.asarray(scene.obj).copy()
            obj[tuple(cells[0])] += 1.0
            on_route = scene.with_obj(jnp.asarray(obj))
            same = _unchanged(on_route, reads, scene.obj, old, build_fabric(on_route, PARAMS))
            assert not bool(same[i])
            dropped += 1
    # one count changed where a plan read nothing: some plans are kept
    for i in range(SOURCES):
        read = np.zeros(SHAPE, bool)
        walks = np.asarray(reads.walks[i]).reshape(-1)
        read.reshape(-1)[walks[walks >= 0]] = True
        r0, r1, c0, c1 = np.asarray(reads.window[i])
        read[r0:r1 + 1, c0:c1 + 1] = True
        far = np.argwhere(~read & ~np.asarray(scene.target_mask) & (np.asarray(scene.obj) > 0))
        if len(far):
            obj = np.asarray(scene.obj).copy()
            obj[tuple(far[-1])] += 1.0
            elsewhere = scene.with_obj(jnp.asarray(obj))
            kept += bool(_unchanged(elsewhere, reads, scene.obj, old, build_fabric(elsewhere, PARAMS))[i])
    assert kept > 0 and dropped > 0
