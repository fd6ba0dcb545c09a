"""jaxplan.pusharound.ranking: candidate gaps, Eq. 8 on hand-built walls, the presearch of Eq. 9
against an exhaustive reference, and the traced weights under vmap and grad."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.pusharound import PushScene, RankingParams, build_wccg, connectivity, gap_costs, nominal_scene, rank_gaps
from jaxplan.pusharound.ranking import DEAD_END_PENALTY, candidate_gaps, one_hop_terms
from jaxplan.reference.pusharound import DEAD_END_PENALTY as REFERENCE_DEAD_END_PENALTY
from jaxplan.reference.pusharound import reference_gap_costs


def _frontier_gaps(scene, g=None):
    """The reference's WCCG input, from the kernels: ``removed -> (same_face, candidate gaps)``."""
    g = build_wccg(scene) if g is None else g

    def frontier_gaps(removed):
        conn = connectivity(g, scene.start, scene.goal, removed=removed)
        return conn.same_face, ([] if conn.same_face else candidate_gaps(g, conn.frontier, removed))

    return frontier_gaps


def _box(x0, y0, x1, y1):
    return [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]


def _wall(x: float, light: float, heavy: float) -> tuple[list, list]:
    """A wall at ``x`` across a 4 m tall workspace: three fixed bars leave two 1.05 m openings, each
    plugged by a 0.25 m tall movable box that leaves 0.4 m on either side (W = 1: every side is a
    bottleneck; the boxes stay 1.1 m from the floor and ceiling, so they make no gap with them).
    The lower box weighs ``light`` kg, the upper one ``heavy``."""
    fixed = [{"pieces": [_box(x - 0.1, 0, x + 0.1, 0.7)]}, {"pieces": [_box(x - 0.1, 1.75, x + 0.1, 2.25)]},
             {"pieces": [_box(x - 0.1, 3.3, x + 0.1, 4)]}]
    movables = [{"pieces": [_box(x - 0.15, 1.1, x + 0.15, 1.35)], "mass": light},
                {"pieces": [_box(x - 0.15, 2.65, x + 0.15, 2.9)], "mass": heavy}]
    return fixed, movables


def _scene(walls) -> PushScene:
    fixed, movables = [], []
    for x, light, heavy in walls:
        f, m = _wall(x, light, heavy)
        fixed += f
        movables += m
    return PushScene.from_dict({"workspace": [0, 0, 8, 4], "vehicle_width": 1.0, "start": [1, 2],
                                "goal": [7, 2], "fixed": fixed, "movables": movables,
                                "robots": {"positions": [[1.0, 2.0]], "radius": 0.15}})


def test_one_wall_gaps_and_eq8_by_hand():
    scene = _scene([(3.0, 5.0, 15.0)])
    params = RankingParams(lambda_t=1.0, lambda_p=2.0, eta=0.5, depth=2)
    r = rank_gaps(scene, params)
    assert not r.connected and r.frontier.encloses_start
    # Four gaps: each box against the bar below and above it; the fixed-fixed pairs are not gaps.
    assert len(r.gaps) == 4
    assert sorted(gap.movables for gap in r.gaps) == [(0,), (0,), (1,), (1,)]
    for gap, cost, seq in zip(r.gaps, r.cost, r.sequences):
        assert gap.width == pytest.approx(0.4)
        # o_g: W/2 from the bridge midpoint, on the start's (left) side.
        mid = gap.points.mean(axis=0)
        assert np.linalg.norm(gap.insertion - mid) == pytest.approx(0.5)
        assert gap.insertion[0] == pytest.approx(mid[0] - 0.5)  # the bridge is vertical
        # Crossing any one of them opens the wall: Eq. 9 reduces to Eq. 8 (no later gaps).
        assert seq == ()
        c_t = np.linalg.norm(gap.insertion - np.array([1.0, 2.0]))
        c_p = (1.0 - 0.4) * gap.mass / 10.0
        assert cost == pytest.approx(1.0 * c_t + 2.0 * c_p, rel=1e-5)
    # The light box's gaps come before the heavy box's gaps at the mirrored position.
    ranked = r.ranked()
    assert ranked[0].movables == (0,)
    light = sorted(c for g, c in zip(r.gaps, r.cost) if g.movables == (0,))
    heavy = sorted(c for g, c in zip(r.gaps, r.cost) if g.movables == (1,))
    assert all(a < b for a, b in zip(light, heavy))


def test_two_walls_presearch_adds_the_second_gap():
    scene = _scene([(2.5, 5.0, 15.0), (5.5, 15.0, 5.0)])
    params = RankingParams(lambda_t=1.0, lambda_p=1.0, eta=0.5, beam=16, depth=2)
    r = rank_gaps(scene, params)
    assert len(r.gaps) == 4
    for gap, cost, seq in zip(r.gaps, r.cost, r.sequences):
        assert len(seq) == 1 and seq[0].movables[0] in (2, 3)  # then one gap of the second wall
        nxt = seq[0]
        c_t0, c_p0 = one_hop_terms(gap, scene.robots, 1.0, 10.0)
        c_t1, c_p1 = one_hop_terms(nxt, gap.insertion[None], 1.0, 10.0)  # the robots moved to o_g
        h1 = np.linalg.norm(nxt.insertion - np.array(scene.goal))
        assert cost == pytest.approx(c_t0 + c_p0 + c_t1 + c_p1 + 0.5 * h1, rel=1e-5)
    ref = reference_gap_costs(scene, params, _frontier_gaps(scene))
    for gap, cost in zip(r.gaps, r.cost):
        assert cost == pytest.approx(ref[gap.bodies], rel=1e-5)


def test_beam_search_equals_exhaustive_reference_on_a_nominal_scene():
    scene = nominal_scene(1)
    g = build_wccg(scene)
    params = RankingParams(lambda_t=0.7, lambda_p=1.3, eta=0.4, beam=64, depth=1)
    r = rank_gaps(scene, params, g)
    ref = reference_gap_costs(scene, params, _frontier_gaps(scene, g))
    assert len(r.gaps) >= 2 and set(ref) == {gap.bodies for gap in r.gaps}
    for gap, cost in zip(r.gaps, r.cost):
        assert cost == pytest.approx(ref[gap.bodies], rel=1e-5)
    assert list(np.argsort([ref[gap.bodies] for gap in r.gaps], kind="stable")) == list(r.order)


def test_reference_restates_the_dead_end_penalty():
    assert REFERENCE_DEAD_END_PENALTY == DEAD_END_PENALTY


@pytest.fixture(scope="module")
def two_wall_ranking():
    return rank_gaps(_scene([(2.5, 5.0, 15.0), (5.5, 15.0, 5.0)]), RankingParams(beam=16, depth=2))


def test_traced_weights_vmap_and_grad(two_wall_ranking):
    feats = two_wall_ranking.features
    batch = RankingParams(lambda_t=jnp.array([0.5, 1.0, 2.0]), lambda_p=jnp.array([1.0, 1.0, 3.0]),
                          eta=jnp.array([0.1, 0.5, 1.0]))
    costs = jax.jit(jax.vmap(gap_costs, in_axes=(0, None)))(batch, feats)
    assert costs.shape == (3, len(two_wall_ranking.gaps))
    for i in range(3):
        one = RankingParams(lambda_t=float(batch.lambda_t[i]), lambda_p=float(batch.lambda_p[i]),
                            eta=float(batch.eta[i]))
        np.testing.assert_allclose(costs[i], gap_costs(one, feats), rtol=1e-6)

    # The cost is linear in the weights given the selected leaf: its gradient is that leaf's features.
    params = RankingParams(lambda_t=1.0, lambda_p=1.0, eta=0.5)
    grads = jax.grad(lambda p: jnp.sum(gap_costs(p, feats)))(params)
    for name in ("lambda_t", "lambda_p", "eta"):
        assert np.isfinite(float(getattr(grads, name)))
    tail = np.asarray(feats.tail)
    score = tail @ np.array([1.0, 1.0, 0.5])
    best = np.argmin(np.where(np.asarray(feats.mask), score, np.inf), axis=1)
    chosen = tail[np.arange(len(best)), best]
    first = np.asarray(feats.first)
    assert float(grads.lambda_t) == pytest.approx(first[:, 0].sum() + chosen[:, 0].sum(), rel=1e-5)
    assert float(grads.lambda_p) == pytest.approx(first[:, 1].sum() + chosen[:, 1].sum(), rel=1e-5)
    assert float(grads.eta) == pytest.approx(chosen[:, 2].sum(), rel=1e-5)


def test_connected_scene_has_no_gaps_and_bad_params_are_named():
    scene = PushScene.from_dict({"workspace": [0, 0, 6, 4], "vehicle_width": 1.0, "start": [1, 2],
                                 "goal": [5, 2], "movables": [{"pieces": [_box(2.5, 0, 3.5, 1)], "mass": 5}]})
    r = rank_gaps(scene)
    assert r.connected and r.gaps == () and r.order.shape == (0,)
    with pytest.raises(ValueError, match=r"^RankingParams.beam"):
        rank_gaps(scene, RankingParams(beam=0))
    with pytest.raises(ValueError, match=r"^RankingParams.lambda_t"):
        rank_gaps(scene, RankingParams(lambda_t=-1.0))
