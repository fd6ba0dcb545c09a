"""jaxplan.teams: the model equations on hand-computed cases, the blackboard, and the simulation
(mass bookkeeping, deadline logic, vmap/jit agreement) held equal to the plain reference."""
from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as hs

from jaxplan.reference.teams import reference_site
from jaxplan.teams import (
    STRATEGIES,
    SiteParams,
    TeamsConfig,
    blackboard,
    model,
    paper_config,
    paper_scenario,
    random_sites,
    run_sites,
    simulate_site,
)
from jaxplan.teams.sim import BROKEN, PHASES

N_STEPS = 1100  # past the 900 s deadline, enough for the paper site to finish


@functools.cache
def _jitted(cfg: TeamsConfig):
    return jax.jit(functools.partial(simulate_site, cfg))


# --------------------------------------------------------------------------------------------------
# Model: Table III numbers worked by hand (D 150 m, v 4 m/s, t_ld 35 s, t_dp 30 s, w 950 kg)
# --------------------------------------------------------------------------------------------------

def test_cycle_time_and_predicted_performance_by_hand():
    assert float(model.cycle_time(150.0, 4.0, 35.0, 30.0)) == pytest.approx(140.0)  # 75 + 35 + 30
    r = model.predicted_performance(jnp.array([0, 1, 2, 3, 4, 6]), 950.0, 150.0, 4.0, 35.0, 30.0)
    # n < 140/35 = 4: the excavator waits, n * 950 / 140; n >= 4: it is the bottleneck, 950 / 35
    expected = [0.0, 950 / 140, 1900 / 140, 2850 / 140, 950 / 35, 950 / 35]
    np.testing.assert_allclose(np.asarray(r), expected, rtol=1e-6)
    assert int(model.saturation_trucks(150.0, 4.0, 35.0, 30.0)) == 4
    assert int(model.saturation_trucks(150.0, 3.0, 35.0, 30.0)) == 5  # 165 / 35 = 4.71


def test_real_performance_by_hand():
    member = jnp.array([True, True, False])
    w_last = jnp.array([900.0, 1000.0, 5000.0])
    t_last = jnp.array([100.0, 150.0, 0.0])
    cycled = jnp.array([True, True, False])
    r, ok = model.real_performance(member, w_last, t_last, cycled, 200.0)
    assert bool(ok) and float(r) == pytest.approx(1900.0 / 100.0)  # the non-member is ignored
    r, ok = model.real_performance(member, w_last, t_last, jnp.array([True, False, True]), 200.0)
    assert not bool(ok) and float(r) == 0.0  # a member has not come back yet
    r, ok = model.real_performance(jnp.zeros(3, bool), w_last, t_last, cycled, 200.0)
    assert not bool(ok)


def test_deadline_test_eq3():
    # 100 + 8000 / 10 = 900: exactly on time is not late; slower is
    assert not bool(model.misses_deadline(100.0, 8000.0, 10.0, 900.0))
    assert bool(model.misses_deadline(100.0, 8000.0, 9.9, 900.0))
    assert bool(model.misses_deadline(100.0, 1.0, 0.0, 900.0))       # soil left, nothing moving
    assert not bool(model.misses_deadline(950.0, 0.0, 0.0, 900.0))   # nothing left: never late


def test_velocity_estimate_and_correction():
    # a round trip of 165 s with t_ld 35, t_dp 30 leaves 100 s for 2 x 150 m
    assert float(model.velocity_estimate(150.0, 165.0, 35.0, 30.0)) == pytest.approx(3.0)
    assert math.isnan(float(model.velocity_estimate(150.0, 60.0, 35.0, 30.0)))
    est = jnp.array([4.0, 4.0, 4.0, 4.0])
    meas = jnp.array([3.0, 3.9, jnp.nan, -1.0])
    np.testing.assert_allclose(np.asarray(model.correct_estimate(est, meas, 0.1)), [3.0, 4.0, 4.0, 4.0])


def test_cooperators_needed_by_hand():
    args = (950.0, 150.0, 4.0, 35.0, 30.0)
    # 12,000 kg in 900 s: 13.3 kg/s; n * 950 / 140 >= 13.3 first at n = 2
    assert int(model.cooperators_needed(12000.0, 0.0, 900.0, *args)) == 2
    assert int(model.cooperators_needed(12000.0, 300.0, 900.0, *args)) == 3  # 20 kg/s: 2.95 -> 3
    assert int(model.cooperators_needed(12000.0, 400.0, 900.0, *args)) == 4  # 24 kg/s -> 3.54 -> 4
    assert int(model.cooperators_needed(30000.0, 0.0, 900.0, *args)) == 4   # infeasible: saturation
    assert int(model.cooperators_needed(100.0, 950.0, 900.0, *args)) == 4   # past the deadline
    assert int(model.cooperators_needed(0.0, 0.0, 900.0, *args)) == 0


@settings(max_examples=60, deadline=None)
@given(x=hs.floats(1.0, 40000.0), t=hs.floats(0.0, 899.0), d=hs.floats(20.0, 400.0),
       v=hs.floats(0.5, 6.0), tld=hs.floats(10.0, 60.0))
def test_cooperators_needed_is_the_smallest_team_that_meets_eq3(x, t, d, v, tld):
    with jax.enable_x64(True):
        n = int(model.cooperators_needed(x, t, 900.0, 950.0, d, v, tld, 30.0))
        n_sat = int(model.saturation_trucks(d, v, tld, 30.0))
        meets = lambda k: not bool(model.misses_deadline(  # noqa: E731
            t, x, model.predicted_performance(k, 950.0, d, v, tld, 30.0), 900.0))
        if meets(n_sat):
            assert 1 <= n <= n_sat and meets(n) and (n == 1 or not meets(n - 1))
        else:
            assert n == n_sat


# --------------------------------------------------------------------------------------------------
# Blackboard
# --------------------------------------------------------------------------------------------------

def test_recruit_team_order_lowest_index_first():
    I, F = blackboard.IDLE, blackboard.FAILED  # noqa: E741
    team = jnp.array([F, I, I, 0, I, I, I], jnp.int32)
    new, joined = blackboard.recruit(team, jnp.array([2, 1], jnp.int32))
    assert np.asarray(new).tolist() == [F, 0, 0, 0, 1, I, I]
    assert np.asarray(joined).tolist() == [False, True, True, False, True, False, False]
    new, _ = blackboard.recruit(team, jnp.array([3, 5], jnp.int32))  # more wanted than idle
    assert np.asarray(new).tolist() == [F, 0, 0, 0, 0, 1, 1]


def test_release_only_what_others_need():
    team = jnp.array([0, 0, 0, 1, -1], jnp.int32)
    eligible = jnp.array([True, True, False, True, True])
    # team 1 wants 3, the pool has 1: team 0 may give 2 of its surplus 5, its highest eligible first
    new, released = blackboard.release(team, eligible, jnp.array([5, 0]), jnp.array([0, 3]))
    assert np.asarray(released).tolist() == [True, True, False, False, False]
    assert np.asarray(new).tolist() == [-1, -1, 0, 1, -1]
    _, released = blackboard.release(team, eligible, jnp.array([5, 0]), jnp.array([0, 1]))
    assert not np.asarray(released).any()  # the idle truck covers it


# --------------------------------------------------------------------------------------------------
# The paper scenario
# --------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def paper_runs():
    p = paper_scenario()
    return p, {s: _jitted(paper_config(s, n_steps=N_STEPS))(p) for s in STRATEGIES}


def test_paper_scenario_mass_conservation(paper_runs):
    p, runs = paper_runs
    mass = np.asarray(p.mass)
    for strategy, (res, trace) in runs.items():
        delivered = np.asarray(trace.delivered)
        remaining = np.asarray(trace.remaining)
        assert np.all(delivered <= mass * (1 + 1e-6)), strategy
        assert np.all(np.diff(delivered, axis=0) >= 0) and np.all(np.diff(remaining, axis=0) <= 0)
        # every step: at the site + delivered + on trucks = initial mass (no failure here)
        np.testing.assert_allclose(np.asarray(res.delivered) + np.asarray(res.remaining)
                                   + np.asarray(res.lost), mass, rtol=1e-5)
        assert np.all(np.isfinite(np.asarray(res.finish_time))), strategy
        assert np.all(np.asarray(trace.n_trucks).sum(axis=1) <= 10)
        for leaf in (res.delivered, res.truck_seconds, trace.r_pred, trace.remaining):
            assert np.all(np.isfinite(np.asarray(leaf)))


def test_paper_scenario_teams_grow_after_the_velocity_drop(paper_runs):
    p, runs = paper_runs
    res, trace = runs["performance"]
    n = np.asarray(trace.n_trucks)
    assert bool(res.met)  # both sites cleared by 900 s
    assert int(res.peak_trucks) < 10  # only the trucks it needs
    # the coordinators correct their model (actual velocity below spec): r_pred changes over time
    assert len(np.unique(np.asarray(trace.r_pred)[1:400, 0])) > 1
    # after the drop at 400 s some team recruits beyond its size before it
    assert np.any(n[400:800].max(axis=0) > n[300:400].max(axis=0))
    # real performance is unknown until every truck has made a round trip
    assert np.isnan(np.asarray(trace.r_real)[:100]).all()


def test_fixed_allocations_use_all_trucks(paper_runs):
    _, runs = paper_runs
    assert np.asarray(runs["even"][1].n_trucks)[5].tolist() == [5, 5]
    assert np.asarray(runs["largest"][1].n_trucks)[5].tolist() == [10, 0]


def test_paper_scenario_matches_reference_float32(paper_runs):
    p, runs = paper_runs
    for strategy, (res, trace) in runs.items():
        ref = reference_site(p, 10, N_STEPS, strategy)
        np.testing.assert_array_equal(np.asarray(trace.phase), np.array(ref.phase), strategy)
        np.testing.assert_array_equal(np.asarray(trace.team), np.array(ref.team))
        np.testing.assert_allclose(np.asarray(res.finish_time), ref.finish_time)
        np.testing.assert_allclose(np.asarray(res.delivered), ref.delivered, rtol=1e-5)


def test_generous_deadline_needs_one_truck_per_team():
    p = paper_scenario(deadline=1e6, v_actual=4.0, v_after=4.0)
    res, trace = _jitted(paper_config(n_steps=400))(p)
    assert np.asarray(trace.n_trucks).max(axis=0).tolist() == [1, 1]


def test_impossible_deadline_is_missed_with_saturated_teams():
    p = paper_scenario(deadline=120.0)
    res, trace = _jitted(paper_config(n_steps=400))(p)
    assert not bool(res.met)
    assert int(res.peak_trucks) == 10  # every idle truck recruited


def test_failed_loaded_truck_loses_its_cargo():
    p = paper_scenario()
    cfg = paper_config(strategy="even", n_steps=N_STEPS)
    _, trace = _jitted(cfg)(p)
    hauling = np.argwhere(np.asarray(trace.phase)[:, 0] == PHASES.index("haul"))[0, 0]
    res, trace = _jitted(cfg)(p.replace(fail_truck=np.int32(0), fail_t=np.float32(hauling)))
    lost = np.asarray(res.lost)
    assert lost.sum() > 0
    np.testing.assert_allclose(np.asarray(res.delivered) + lost, np.asarray(p.mass), rtol=1e-5)
    assert np.asarray(trace.phase)[-1, 0] == BROKEN


# --------------------------------------------------------------------------------------------------
# Batches: vmap equals single runs, jit equals no jit
# --------------------------------------------------------------------------------------------------

def test_vmapped_batch_equals_single_runs():
    batch = random_sites(3, 4)
    cfg = TeamsConfig(n_trucks=10, n_steps=N_STEPS, strategy="performance", record=False)
    res, _ = run_sites(cfg, batch)
    for b in range(4):
        site = jax.tree_util.tree_map(lambda a: a[b], batch)
        one, _ = _jitted(cfg)(site)
        for name in ("clear_time", "finish_time", "delivered", "truck_seconds", "met"):
            np.testing.assert_allclose(np.asarray(getattr(res, name))[b],
                                       np.asarray(getattr(one, name)), rtol=1e-6, err_msg=name)
    # un-jitted (scan still compiles its body, but the outer function runs eagerly)
    eager, _ = simulate_site(cfg, jax.tree_util.tree_map(lambda a: a[0], batch))
    np.testing.assert_allclose(np.asarray(eager.delivered), np.asarray(res.delivered)[0], rtol=1e-6)
    assert bool(eager.met) == bool(np.asarray(res.met)[0])
    mass = np.asarray(batch.mass)
    total = np.asarray(res.delivered) + np.asarray(res.lost) + np.asarray(res.remaining)
    assert np.all(total <= mass * (1 + 1e-5) + 1e-3)
    assert np.all(np.isfinite(np.asarray(res.truck_seconds)))


# --------------------------------------------------------------------------------------------------
# Property: the JAX simulation equals the plain reference on random sites (float64, same draws)
# --------------------------------------------------------------------------------------------------

REF_STEPS = 700
REF_TRUCKS = 6


@hs.composite
def _sites(draw):
    rng = np.random.default_rng(draw(hs.integers(0, 2**31 - 1)))
    q = lambda lo, hi, step: draw(hs.integers(lo, hi)) * step  # noqa: E731  grid values: no ties
    m = 2
    mass = np.array([q(2, 12, 500.0), q(1, 12, 500.0)])
    w = 950.0
    loads = np.clip(w * (1 + 0.15 * rng.standard_normal((m, 60))), 0.5 * w, 1.5 * w)
    v = np.array([q(4, 16, 0.25), q(4, 16, 0.25)])
    fail = draw(hs.integers(-1, REF_TRUCKS - 1))
    p = SiteParams(
        mass=mass, dist=np.array([q(4, 40, 5.0), q(4, 40, 5.0)]), v_true=v,
        v_after=v * draw(hs.sampled_from([1.0, 0.75, 0.5])), v_change_t=np.float64(q(0, 60, 10.0)),
        tld_true=np.array([q(20, 50, 1.0)] * m), tld_after=np.array([q(20, 70, 1.0)] * m),
        tld_change_t=np.float64(draw(hs.sampled_from([np.inf, 250.0]))),
        tdp_true=np.array([q(20, 40, 1.0)] * m), loads=loads, fail_truck=np.int32(fail),
        fail_t=np.float64(q(0, 60, 10.0) + 0.5), deadline=np.float64(q(30, 90, 10.0)),
        w_prior=np.full(m, w), tld_prior=np.full(m, 35.0), v_prior=np.full(m, 4.0),
        tdp_prior=np.full(m, 30.0), join_dist=np.float64(q(0, 20, 10.0)),
        tol_perf=np.float64(0.1), tol_param=np.float64(0.1), dt=np.float64(draw(hs.sampled_from([1.0, 2.0]))))
    return p, draw(hs.sampled_from(STRATEGIES))


@settings(max_examples=24, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=_sites())
def test_simulation_equals_reference(case):
    p, strategy = case
    cfg = TeamsConfig(n_trucks=REF_TRUCKS, n_steps=REF_STEPS, strategy=strategy, record=True)
    with jax.enable_x64(True):
        res, trace = _jitted(cfg)(p)
        res, trace = jax.device_get((res, trace))
    ref = reference_site(p, REF_TRUCKS, REF_STEPS, strategy)
    np.testing.assert_array_equal(trace.phase, np.array(ref.phase))  # the event timeline
    np.testing.assert_array_equal(trace.team, np.array(ref.team))
    np.testing.assert_array_equal(trace.n_trucks, np.array(ref.n_trucks))
    np.testing.assert_allclose(trace.delivered, np.array(ref.delivered_t), rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(trace.r_pred, np.array(ref.r_pred), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(trace.r_real, np.array(ref.r_real), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(res.clear_time, ref.clear_time)
    np.testing.assert_allclose(res.finish_time, ref.finish_time)
    np.testing.assert_allclose(res.lost, ref.lost, rtol=1e-9, atol=1e-6)
    assert bool(res.met) == ref.met
    assert float(res.truck_seconds) == ref.truck_seconds and int(res.peak_trucks) == ref.peak_trucks


# --------------------------------------------------------------------------------------------------
# Bad input
# --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("change, field", [
    ({"dist": np.array([150.0, -1.0], np.float32)}, "SiteParams.dist"),
    ({"mass": np.array([1.0, 2.0, 3.0], np.float32)}, "SiteParams.dist"),
    ({"fail_truck": np.int32(12)}, "SiteParams.fail_truck"),
    ({"loads": np.zeros((2, 3), np.float32)}, "SiteParams.loads"),
    ({"dt": np.float32(0.0)}, "SiteParams.dt"),
])
def test_bad_params_name_the_field(change, field):
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        simulate_site(paper_config(), paper_scenario().replace(**change))


def test_bad_config_names_the_field():
    with pytest.raises(ValueError, match=r"TeamsConfig\.strategy"):
        simulate_site(paper_config(strategy="greedy"), paper_scenario())
    with pytest.raises(ValueError, match=r"TeamsConfig\.n_steps"):
        simulate_site(TeamsConfig(n_steps=0), paper_scenario())
