"""A coordinated planning that tries a short walk length first (``FleetConfig.short_cap``) plans the
tasks of planning with the whole walk cap: the chunks whose walks fit are padded to the cap's slots,
the others planned again with the cap. A fleet run with a short walk first is tests/fleet/test_fleet.py's
(test_a_fleet_with_a_short_walk_first_runs_as_with_the_whole_cap), which compiles its whole-cap run anyway."""
from __future__ import annotations

import functools

import chex
import jax
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan import FabricParams, SpillParams, build_fabric
from jaxplan.fleet import FleetConfig, assign
from jaxplan.fleet.state import SHORT_CAP
from jaxplan.transport import connector_walk, execute, plan_reads, source_anchors, spillage
from jaxplan.transport.episode import EpisodeParams
from tests.fleet._sites import LAYOUTS, site

SHAPE = (16, 16)
CAP, M = 64, 12
SHORT = 8                 # on these 16 x 16 sites some walks fit in 8 steps and some do not
PARAMS = FabricParams()
SPILL = SpillParams(lam=0.1)
EP = EpisodeParams()


@functools.cache
def _planner(short_cap):
    def plan(scene, fabric, owner):
        return assign.plan_candidates(scene, PARAMS, EP, SPILL, fabric, owner, candidates=M, cap=CAP,
                                      evaluator=spillage.curvature_spill, clearance=0, short_cap=short_cap)

    # one trace per walk length, whatever the site (chex counts the traces of this code)
    return jax.jit(chex.assert_max_traces(plan, n=2))


@functools.cache
def _reads(walk: int):
    """The reads and connector completion of planning every candidate alone with walk length ``walk``."""
    def reads(scene, fabric, sources, anchors):
        conns = connector_walk(scene, PARAMS, fabric, sources, anchors, walk)
        got = jax.vmap(lambda s, a: plan_reads(scene, PARAMS, fabric, s, a, walk))(sources, anchors)
        return assign.walks_fit(got, conns.complete)

    return jax.jit(reads)


def _inputs(seed, layout):
    scene = site(seed, SHAPE, layout)
    scene = scene.with_obj(execute.quantize(scene.obj))
    return scene, build_fabric(scene, PARAMS), np.full(SHAPE, -1, np.int32)


def _assert_same_candidates(got, want):
    chex.assert_trees_all_equal(got.exists, want.exists)
    exists = np.asarray(want.exists)
    rows = lambda tree: jax.tree.map(lambda a: np.asarray(a)[exists], tree)  # noqa: E731
    for name in ("source", "route", "mode", "code", "steps", "footprint"):
        chex.assert_trees_all_equal(rows(getattr(got.tasks, name)), rows(getattr(want.tasks, name)))
    # the predicted mass is summed over arrays of another length: equal within float rounding
    np.testing.assert_allclose(rows(got.tasks.predicted), rows(want.tasks.predicted), rtol=1e-6)
    chex.assert_trees_all_equal(rows(got.reads), rows(want.reads))
    for name in ("usable", "clear", "overlap"):
        chex.assert_trees_all_equal(getattr(got, name), getattr(want, name))


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10 ** 6), layout=st.sampled_from(LAYOUTS))
def test_a_short_walk_first_plans_the_tasks_of_the_whole_cap(seed, layout):
    scene, fabric, owner = _inputs(seed, layout)
    want = _planner(None)(scene, fabric, owner)
    got = _planner(SHORT)(scene, fabric, owner)
    assert got.tasks.route.cells.shape == want.tasks.route.cells.shape == (M, 2 * (CAP + 1), 2)
    _assert_same_candidates(got, want)
    for tree in (got.tasks.predicted, got.tasks.route.end):
        assert np.all(np.isfinite(np.asarray(tree)))


def test_both_ways_are_taken_on_one_site():
    """On this site some candidates' walks fit the short length and some do not: more fit than there
    are chunks, so a chunk is padded, and not all, so one is planned again. The planning still equals
    planning with the whole cap."""
    scene, fabric, owner = _inputs(3, "two_targets")
    want = _planner(None)(scene, fabric, owner)
    exists = np.asarray(want.exists)
    sources = want.tasks.source
    anchors = source_anchors(scene, PARAMS, fabric, sources)
    fits = np.asarray(_reads(SHORT)(scene, fabric, sources, anchors))[exists]
    assert fits.sum() > M // assign.PLAN_CHUNK and not fits.all(), fits
    assert np.asarray(_reads(CAP)(scene, fabric, sources, anchors))[exists].all()
    _assert_same_candidates(_planner(SHORT)(scene, fabric, owner), want)


def test_walks_fit_only_when_no_walk_fills_its_last_slot():
    """``walks_fit`` (un-jitted here): a plan fits when every read walk ends before its last slot and
    the connector walked to its end."""
    from jaxplan.transport import PlanReads

    walks = np.full((3, 2, 5), -1, np.int32)
    walks[0, :, :3] = 7          # short walks
    walks[1, 1, :] = 7           # one walk fills its last slot: it may have been cut
    walks[2, 0, :4] = 7
    reads = PlanReads(np.zeros((3, 2), np.int32), np.zeros(3, np.int32), walks, np.zeros((3, 4), np.int32))
    np.testing.assert_array_equal(np.asarray(assign.walks_fit(reads, np.array([True, True, True]))),
                                  [True, False, True])
    np.testing.assert_array_equal(np.asarray(assign.walks_fit(reads, np.array([True, True, False]))),
                                  [True, False, False])


def test_widen_pads_routes_and_walks_to_the_caps_slots():
    scene, fabric, owner = _inputs(0, "uniform")
    planned = _planner(None)(scene, fabric, owner)
    tasks, reads = assign.widen(planned.tasks, planned.reads, 2 * CAP)
    assert tasks.route.cells.shape == (M, 2 * (2 * CAP + 1), 2) and reads.walks.shape[-1] == 2 * CAP + 1
    assert np.all(np.asarray(tasks.route.cells)[:, 2 * (CAP + 1):] == -1)
    assert np.all(np.asarray(reads.walks)[..., CAP + 1:] == -1)
    np.testing.assert_array_equal(np.asarray(tasks.route.cells)[:, :2 * (CAP + 1)],
                                  np.asarray(planned.tasks.route.cells))


def test_the_config_resolves_the_short_cap():
    assert FleetConfig(4).resolved((16, 16)).short_cap == FleetConfig(4).resolved((16, 16)).walk_cap == 128
    assert FleetConfig(4).resolved((512, 512)).short_cap == SHORT_CAP
    assert FleetConfig(4, short_cap=50_000).resolved((512, 512)).short_cap == 4096
    assert FleetConfig(4, walk_cap=100, short_cap=30).resolved((512, 512)).short_cap == 30
    for bad in (0, -3, 2.5, "64"):
        with pytest.raises(ValueError, match="FleetConfig.short_cap"):
            FleetConfig(4, short_cap=bad).validate()
