"""Tuning the fabric parameters by gradient (jaxplan.tune.fabric) on tiny scenes."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxplan.tune.fabric as tune
from jaxplan import FabricParams


@pytest.fixture(scope="module")
def scenes():
    return tune.random_scenes(3, (8, 8), seed=3)


def test_random_scenes_have_material_and_an_empty_target(scenes):
    for s in scenes:
        obj, target = np.asarray(s.obj), np.asarray(s.target_mask)
        assert target.any() and obj[~target].sum() > 0 and obj[target].sum() == 0


def test_objective_and_its_gradient_are_finite(scenes):
    def f(theta, tau, lam):
        return tune.soft_efficiency(scenes[0], FabricParams(theta_tol_deg=theta, tau_h=tau, anchor_lambda=lam))

    value, grads = jax.jit(jax.value_and_grad(f, argnums=(0, 1, 2)))(60.0, 0.5, 1.0)
    assert np.isfinite(float(value)) and float(value) > 0
    assert all(np.isfinite(float(g)) for g in grads)
    assert float(grads[0]) != 0.0


def test_expected_turning_is_zero_for_a_straight_row():
    from jaxplan import Scene, box
    scene = Scene.from_arrays(np.array([[1, 2, 3, 1, 0]], np.float32), box(4.0, 0.0, 5.0, 1.0))
    f = jax.jit(lambda s: tune.expected_turning(tune.build_fabric(s, FabricParams(temperature=1e-3)), s, 6))(scene)
    np.testing.assert_allclose(np.asarray(f), 0.0, atol=1e-4)


def test_unconstrained_round_trip():
    p = FabricParams(theta_tol_deg=47.0, tau_h=0.3, anchor_lambda=0.7)
    back = tune.from_unconstrained(tune.to_unconstrained(p), FabricParams())
    for k in tune.TUNED:
        assert float(getattr(back, k)) == pytest.approx(float(getattr(p, k)), rel=1e-4)


def test_fit_raises_the_soft_objective(scenes):
    fit = tune.fit_fabric(scenes, steps=6, learning_rate=0.1)
    objective = [h["objective"] for h in fit.history]
    assert len(objective) == 6 and all(np.isfinite(objective))
    assert objective[-1] > objective[0]
    assert isinstance(fit.params.theta_tol_deg, float) and fit.params.temperature is None


def test_fit_rejects_zero_steps(scenes):
    with pytest.raises(ValueError, match="steps"):
        tune.fit_fabric(scenes, steps=0)


def test_vmapped_objective_equals_single_calls(scenes):
    batch = tune.stack_scenes(scenes)
    p = FabricParams()
    stacked = jax.jit(jax.vmap(lambda s: tune.soft_efficiency(s, p)))(batch)
    single = jnp.array([tune.soft_efficiency_jit(s, p, tune.ObjectiveConfig()) for s in scenes])
    np.testing.assert_allclose(np.asarray(stacked), np.asarray(single), rtol=1e-4)


def test_evaluate_hard_runs_episodes(scenes):
    rows = tune.evaluate_hard(scenes[:1], FabricParams(), max_pushes=1)
    assert len(rows) == 1
    row = rows[0]
    assert row["pushes"] <= 1 and row["delivered"] >= 0 and row["driven"] > 0
    assert row["efficiency"] == pytest.approx(row["delivered"] / row["driven"])


def test_job_and_source_aggregates_agree_for_a_single_source():
    # one occupied cell and no rearranging: the harmonic and arithmetic means of one ratio agree
    from jaxplan import Scene, box
    scene = Scene.from_arrays(np.array([[0, 3, 0, 0, 0]], np.float32), box(4.0, 0.0, 5.0, 1.0))
    config = tune.ObjectiveConfig(rearrange_margin=1e9)
    job, source = (float(tune.soft_efficiency_jit(scene, FabricParams(), config._replace(aggregate=a)))
                   for a in ("job", "source"))
    assert job > 0 and np.isclose(job, source, rtol=1e-5)


def test_job_aggregate_charges_cheap_sources_less_than_the_mean_of_ratios(scenes):
    # harmonic <= arithmetic mean of the same per-object ratios (with the same approach charge)
    p = FabricParams()
    job, source = (float(tune.soft_efficiency_jit(scenes[0], p, tune.ObjectiveConfig(aggregate=a)))
                   for a in ("job", "source"))
    assert 0 < job <= source + 1e-6


def test_unknown_aggregate_is_rejected(scenes):
    with pytest.raises(ValueError, match="aggregate"):
        tune.soft_efficiency(scenes[0], FabricParams(), tune.ObjectiveConfig(aggregate="median"))


def test_fit_tunes_the_planner_spill_lambda_through_the_fabric(scenes):
    config = tune.ObjectiveConfig(spill_lam=0.2)

    def f(lam):
        return tune.soft_efficiency(scenes[0], FabricParams(slack_tau=1.0), config, lam)

    value, grad = jax.jit(jax.value_and_grad(f))(0.2)
    assert np.isfinite(float(value)) and np.isfinite(float(grad)) and float(grad) != 0.0
    fit = tune.fit_fabric(scenes, FabricParams(slack_tau=1.0), steps=2, learning_rate=0.1, config=config,
                          tune_spill=True)
    assert fit.spill_lam is not None and fit.spill_lam >= 0 and "spill_lam" in fit.history[0]


def test_evaluate_hard_plans_with_the_planner_spill_lambda(scenes):
    same = tune.evaluate_hard(scenes[:1], FabricParams(), max_pushes=3, spill_lam=0.05, plan_lam=0.05)
    default = tune.evaluate_hard(scenes[:1], FabricParams(), max_pushes=3, spill_lam=0.05)
    assert same == default
    other = tune.evaluate_hard(scenes[:1], FabricParams(slack_tau=2.0), max_pushes=3, spill_lam=0.05, plan_lam=1.0)
    assert other[0]["pushes"] >= 1 and np.isfinite(other[0]["efficiency"])
