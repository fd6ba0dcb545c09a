"""The search's gap recorder and fitting the ranking weights (jaxplan.tune.ranking)."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import box

from jaxplan.pusharound import shapes
from jaxplan.pusharound.ranking import DEAD_END_PENALTY, RankingParams, gap_costs
from jaxplan.pusharound.scene import Fixed, Movable, PushScene
from jaxplan.pusharound.search import SEARCH_RANKING, SearchConfig, plan_pushes
from jaxplan.reference.ranking import reference_ranking_loss
from jaxplan.tune import RankingData, fit_ranking, ranking_data, ranking_loss, synthetic_ranking_data
from jaxplan.tune.ranking import WEIGHTS

TRUE = RankingParams(lambda_t=1.0, lambda_p=2.5, eta=0.2)
FAST = SearchConfig(backend="c", max_batch=16, n_directions=4, time_limit_s=60.0, max_expansions=12)
_loss_grad = jax.jit(jax.grad(ranking_loss, argnums=(0, 2)))
_loss = jax.jit(ranking_loss)
_costs = jax.jit(jax.vmap(gap_costs, in_axes=(None, 0)))


def _box(name, pose, w, h, mass):
    s = shapes.rectangle(w, h)
    return Movable(name, s.pieces, pose, mass, shapes.polygon_inertia(s.outline, mass), 0.5,
                   {"kind": "rectangle", "width": w, "height": h})


# Two boxes in a wall's opening (5 x 3 m): two or three gaps, a few expansions with the C engine.
TWO = PushScene(workspace=(0, 0, 5, 3), width=0.8, start=(0.8, 1.5), goal=(4.2, 1.5),
                fixed=(Fixed("low", (box(2.4, 0.0, 2.6, 0.9),)), Fixed("high", (box(2.4, 2.2, 2.6, 3.0),))),
                movables=(_box("a", (2.5, 1.25, 0.0), 0.5, 0.3, 6.0), _box("b", (2.5, 1.8, 0.0), 0.5, 0.3, 9.0)),
                robots=np.array([[0.5, 0.4], [0.5, 2.6]]), robot_radius=0.15)


@pytest.fixture(scope="module")
def synthetic():
    return synthetic_ranking_data(TRUE, 0.5, seed=0, n_expansions=1024)


def _ratios(params):
    lt = float(params.lambda_t)
    return np.array([float(params.lambda_p) / lt, float(params.eta) / lt])


@pytest.mark.parametrize("fit", [("lambda_p", "eta"), WEIGHTS])
def test_fit_recovers_known_weights(synthetic, fit):
    """Labels drawn from softmax(-Cost / 0.5) under known weights: the fit finds their ratios (and, with
    lambda_t held, the weights and the temperature) within 12%, and ranks like them."""
    res = fit_ranking(synthetic, fit=fit, steps=300, learning_rate=0.1)
    np.testing.assert_allclose(_ratios(res.params), _ratios(TRUE), rtol=0.12)
    if "lambda_t" not in fit:
        assert res.params.lambda_t == RankingParams().lambda_t
        np.testing.assert_allclose(res.temperature, 0.5, rtol=0.15)
    assert np.all(np.isfinite(np.asarray(res.losses))) and res.losses[-1] < 0.5 * res.losses[0]
    assert res.trajectory.shape == (300, 4)
    valid = np.asarray(synthetic.valid)
    fitted = np.where(valid, np.asarray(_costs(res.params, synthetic.features)), np.inf)
    true = np.where(valid, np.asarray(_costs(TRUE, synthetic.features)), np.inf)
    assert np.mean(np.argmin(fitted, 1) == np.argmin(true, 1)) > 0.95


def test_gradients_are_finite(synthetic):
    """Finite at the paper's weights, at extreme weights and temperatures, with dead-end penalties and
    padded gap slots in the data; and not all zero."""
    data = synthetic._replace(features=synthetic.features._replace(
        penalty=synthetic.features.penalty.at[::7, 0].set(DEAD_END_PENALTY)))
    for params, t in ((RankingParams(), 1.0), (RankingParams(lambda_t=1e-3, lambda_p=1e3, eta=1e-3), 1e-3),
                      (RankingParams(lambda_t=50.0, lambda_p=1e-4, eta=20.0), 100.0)):
        g_params, g_t = _loss_grad(params, data, jnp.float32(t))
        grads = np.array([float(g_params.lambda_t), float(g_params.lambda_p), float(g_params.eta), float(g_t)])
        assert np.all(np.isfinite(grads)), (params, t, grads)
    g_params, _ = _loss_grad(RankingParams(), data, jnp.float32(1.0))
    assert abs(float(g_params.lambda_p)) > 0 and abs(float(g_params.eta)) > 0


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**16), lp=st.floats(0.1, 5.0), eta=st.floats(0.05, 2.0), t=st.sampled_from((0.1, 1.0, 5.0)))
def test_loss_equals_reference(seed, lp, eta, t):
    data = synthetic_ranking_data(TRUE, 1.0, seed=seed, n_expansions=8, n_gaps=5, n_leaves=3)
    rng = np.random.default_rng(seed)
    data = data._replace(weight=jnp.asarray(rng.uniform(0.0, 2.0, 8), jnp.float32))
    params = RankingParams(lambda_t=1.0, lambda_p=lp, eta=eta)
    np.testing.assert_allclose(float(_loss(params, data, jnp.float32(t))), reference_ranking_loss(params, data, t),
                               rtol=2e-4, atol=1e-4)


@pytest.fixture(scope="module", params=["graph", "beam"])
def recorded(request):
    cfg = FAST.replace(presearch_mode=request.param)
    return plan_pushes(TWO, cfg), plan_pushes(TWO, cfg, record=True)


def test_recorder_does_not_change_the_plan(recorded):
    off, on = recorded
    assert off.records is None and on.records is not None
    assert off.success and on.success and off.reason == on.reason
    assert len(off.schedule) == len(on.schedule)
    for a, b in zip(off.schedule, on.schedule):
        assert a.gap == b.gap and a.cost == b.cost
        np.testing.assert_array_equal(a.poses_after, b.poses_after)
        np.testing.assert_array_equal(np.asarray(a.task.velocity), np.asarray(b.task.velocity))
    skip = {"planning_time_s"} | {f for f in off.stats._fields if f.startswith("time_")}
    assert {f: v for f, v in off.stats._asdict().items() if f not in skip} == \
           {f: v for f, v in on.stats._asdict().items() if f not in skip}


def test_records_hold_the_costs_and_the_solution(recorded):
    _, res = recorded
    recs = res.records
    assert len(recs) == res.stats.expansions >= 1
    for rec in recs:
        k = len(rec.cost)
        assert rec.features.first.shape == (k, 2) and rec.features.tail.shape[::2] == (k, 3)
        # gap_costs on the recorded terms is the cost the search used (the weights it ran with).
        np.testing.assert_allclose(np.asarray(gap_costs(SEARCH_RANKING, rec.features)),
                                   rec.cost, rtol=1e-5, atol=1e-4)
        assert rec.tried.sum() >= 1 and np.all(rec.children <= rec.tried) and np.all(rec.opened <= rec.children)
        assert len(rec.child_node) == rec.children.sum()
        assert rec.solution.sum() in (0, 1)
    on_path = [r for r in recs if r.solution.any()]
    # one labelled node per push of the solution, from the root down
    assert sorted({int(r.depth) for r in on_path}) == list(range(len(res.schedule)))
    for r in on_path:
        assert int(r.to_go_pushes) == len(res.schedule) - int(r.depth)
        np.testing.assert_allclose(float(r.to_go_cost), sum(p.cost for p in res.schedule[int(r.depth):]), rtol=1e-9)
    for nid in {int(r.node) for r in on_path}:   # some batch of the node made the solution's child
        assert sum(r.children[np.argmax(r.solution)] for r in on_path if int(r.node) == nid) >= 1
    off_path = [r for r in recs if not r.solution.any()]
    assert all(np.isnan(r.to_go_cost) and int(r.to_go_pushes) == -1 for r in off_path)


def test_fit_on_recorded_searches(recorded):
    data = ranking_data(recorded[1].records)
    assert isinstance(data, RankingData) and data.valid.shape == data.target.shape
    np.testing.assert_allclose(np.asarray(data.target).sum(1), 1.0)
    res = fit_ranking(data, steps=20)
    assert all(np.isfinite(float(getattr(res.params, w))) and float(getattr(res.params, w)) > 0 for w in WEIGHTS)
    assert np.all(np.isfinite(np.asarray(res.losses)))


@pytest.mark.parametrize("field, change, match", [
    ("first", lambda d: d._replace(features=d.features._replace(first=d.features.first[..., :1])),
     "data.features.first"),
    ("tail", lambda d: d._replace(features=d.features._replace(tail=d.features.tail[:, :, :, :2])),
     "data.features.tail"),
    ("mask", lambda d: d._replace(features=d.features._replace(mask=jnp.zeros_like(d.features.mask))),
     "data.features.mask"),
    ("penalty", lambda d: d._replace(features=d.features._replace(penalty=d.features.penalty.at[0, 0].set(jnp.nan))),
     "data.features.penalty"),
    ("valid", lambda d: d._replace(valid=d.valid[:, :2]), "data.valid"),
    ("target", lambda d: d._replace(target=d.target * 2.0), "data.target"),
    ("weight", lambda d: d._replace(weight=-d.weight), "data.weight"),
    ("type", lambda d: tuple(d), "data: expected a RankingData"),
])
def test_bad_data_raises_naming_the_field(field, change, match):
    data = synthetic_ranking_data(TRUE, 1.0, seed=1, n_expansions=4)
    with pytest.raises(ValueError, match=match):
        fit_ranking(change(data), steps=1)


def test_bad_arguments_raise():
    data = synthetic_ranking_data(TRUE, 1.0, seed=1, n_expansions=4)
    for kwargs, match in (({"fit": ("lambda_q",)}, "fit"), ({"steps": 0}, "steps"),
                          ({"temperature": 0.0}, "temperature"), ({"learning_rate": -1.0}, "learning_rate"),
                          ({"init": RankingParams(eta=0.0)}, "RankingParams.eta")):
        with pytest.raises(ValueError, match=match):
            fit_ranking(data, **kwargs)
    with pytest.raises(ValueError, match="records"):
        ranking_data([])
    with pytest.raises(ValueError, match="record"):
        plan_pushes(TWO, FAST, record="yes")
    with pytest.raises(ValueError, match="temperature"):
        synthetic_ranking_data(TRUE, 0.0)
