"""Time-stepped simulation of one earthmoving site, as a ``jax.lax.scan`` over steps of ``dt``.

Each step (``t = s * dt``), in this order (the reference ``jaxplan.reference.teams`` does the same):

1. Conditions: the velocity on each route and each excavator's loading time at ``t`` (scheduled
   changes); the scheduled truck breaks down (its cargo is lost, it leaves its team).
2. Cooperators: every truck counts down its current phase and moves on when it reaches 0:
   to-site -> queue (arriving back after a load gives its round-trip time, Eq. 4's ``t_circ``),
   loading -> haul, haul -> dump, dump -> to-site (the cargo is delivered). A leg's duration is fixed
   when it starts: ``ceil(D / (v dt))`` steps, ``ceil(t_ld / dt)``, ``ceil(t_dp / dt)``.
3. Excavators: a free excavator with soil left loads the truck that has waited longest in its queue
   (ties: lower index), ``min(next pre-drawn load, soil left)`` kg.
4. Trucks driving to or waiting at an emptied site go back to the idle pool.
5. A site is cleared when it is empty and its excavator has finished loading (the paper's end of the
   task); the team is finished when, in addition, none of its trucks carries its soil.
6. Coordinators (strategy ``cfg.strategy``): update the model (Eqs. 1, 2, 4, error correction), test
   the deadline (Eq. 3), then release surplus trucks and recruit idle ones on the blackboard.
   Recruits drive ``join_dist`` to their new site.

``simulate_site(cfg, params)`` runs one site; ``run_sites`` is its jitted ``vmap`` over a batch.
"""
from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.teams import blackboard, model
from jaxplan.teams.params import SiteParams, TeamsConfig, validate_site

__all__ = ["IDLE_PHASE", "TO_SITE", "QUEUE", "LOADING", "HAUL", "DUMP", "BROKEN", "PHASES",
           "SiteState", "SiteResult", "Trace", "simulate_site", "run_sites", "step_ticks"]

# truck phases
IDLE_PHASE, TO_SITE, QUEUE, LOADING, HAUL, DUMP, BROKEN = range(7)
PHASES = ("idle", "to_site", "queue", "loading", "haul", "dump", "broken")

# A duration that is an exact multiple of dt, computed in float32, may land a hair above the
# integer; this slack (a thousandth of a step) keeps it from costing a whole extra step.
_TICK_SLACK = 1e-3


class SiteState(NamedTuple):
    """The scan carry. Trucks: ``[N]``; teams: ``[M]``."""

    team: Any          # i32[N] team index, blackboard.IDLE or blackboard.FAILED
    phase: Any         # i32[N] one of PHASES
    timer: Any         # i32[N] steps left in the phase
    cargo: Any         # f[N] soil on board [kg]
    queue_since: Any   # i32[N] step at which the truck joined its excavator's queue
    w_last: Any        # f[N] mass of its last load in the current team [kg]
    t_last: Any        # f[N] start time of that load [s]; -1: none since it joined
    cycled: Any        # bool[N] came back to the excavator after a load since it joined
    remaining: Any     # f[M] soil left at the loading site, X(t) [kg]
    delivered: Any     # f[M] soil dumped [kg]
    lost: Any          # f[M] soil lost on broken trucks [kg]
    loads_done: Any    # i32[M] loads started by excavator i
    w_hat: Any         # f[M] model: mean load [kg]
    tld_hat: Any       # f[M] model: loading time [s]
    v_hat: Any         # f[M] model: velocity [m/s]
    r_ref: Any         # f[M] real performance at the last error check [kg/s]; 0: none yet
    tld_meas: Any      # f[M] last measured loading duration [s]; nan: none
    tcirc_meas: Any    # f[M] last measured round-trip time [s]; nan: none
    clear_step: Any    # i32[M] step at which the site was cleared (empty, last loading over); -1
    finish_step: Any   # i32[M] step at which the team dumped its last soil; -1: not yet
    truck_steps: Any   # i32[] sum over steps of assigned trucks, until every team finished
    peak_trucks: Any   # i32[] most trucks assigned at once
    max_team: Any      # i32[M] largest size of each team


class Trace(NamedTuple):
    """Per-step record (``cfg.record``), leading axis T (then a batch axis in front, if any)."""

    r_pred: Any      # f[T, M] predicted performance, Eq. 1, after the step's model update [kg/s]
    r_real: Any      # f[T, M] real performance, Eq. 2 [kg/s]; nan while not available
    n_trucks: Any    # i32[T, M] team sizes after the step's transfers
    remaining: Any   # f[T, M] soil left at each loading site [kg]
    delivered: Any   # f[T, M] soil dumped so far [kg]
    phase: Any       # i32[T, N] each truck's phase at the end of the step
    team: Any        # i32[T, N] each truck's team at the end of the step


class SiteResult(NamedTuple):
    """Outcome of one site (a batch axis in front for ``run_sites``)."""

    clear_time: Any    # f[M] when site i was cleared (empty, last loading over) [s]; nan: never
    finish_time: Any   # f[M] when team i delivered its last soil [s]; nan: not within the horizon
    delivered: Any     # f[M] soil dumped [kg]
    lost: Any          # f[M] soil lost on broken trucks [kg]
    remaining: Any     # f[M] soil left at the loading site at the end [kg]
    met: Any           # bool[] every site cleared by the deadline (the paper's criterion, Eq. 3)
    finish_all: Any    # f[] when the last team dumped its last soil [s]; nan: not within the horizon
    truck_seconds: Any  # f[] integral of assigned trucks over time until all finished [truck s]
    peak_trucks: Any   # i32[] most trucks assigned at once
    max_team: Any      # i32[M] largest size each team reached


def step_ticks(duration, dt):
    """Steps a phase of ``duration`` seconds takes: ``ceil(duration / dt)``, at least 1 (int32)."""
    return jnp.maximum(jnp.ceil(duration / dt - _TICK_SLACK), 1).astype(jnp.int32)


def _initial_state(params: SiteParams, n_trucks: int) -> SiteState:
    fdt = jnp.result_type(params.mass, float)
    m = params.mass.shape[-1]
    zeros_m = jnp.zeros(m, fdt)
    nan_m = jnp.full(m, jnp.nan, fdt)
    return SiteState(
        team=jnp.full(n_trucks, blackboard.IDLE, jnp.int32),
        phase=jnp.full(n_trucks, IDLE_PHASE, jnp.int32),
        timer=jnp.zeros(n_trucks, jnp.int32),
        cargo=jnp.zeros(n_trucks, fdt),
        queue_since=jnp.zeros(n_trucks, jnp.int32),
        w_last=jnp.zeros(n_trucks, fdt),
        t_last=jnp.full(n_trucks, -1.0, fdt),
        cycled=jnp.zeros(n_trucks, bool),
        remaining=jnp.asarray(params.mass, fdt),
        delivered=zeros_m, lost=zeros_m,
        loads_done=jnp.zeros(m, jnp.int32),
        w_hat=jnp.asarray(params.w_prior, fdt), tld_hat=jnp.asarray(params.tld_prior, fdt),
        v_hat=jnp.asarray(params.v_prior, fdt), r_ref=zeros_m,
        tld_meas=nan_m, tcirc_meas=nan_m,
        clear_step=jnp.full(m, -1, jnp.int32), finish_step=jnp.full(m, -1, jnp.int32),
        truck_steps=jnp.zeros((), jnp.int32), peak_trucks=jnp.zeros((), jnp.int32),
        max_team=jnp.zeros(m, jnp.int32),
    )


def _latest_per_team(member, value, valid, old):
    """Per team, ``value`` of a member where ``valid`` (the highest-index one if several at once);
    ``old`` where no member has a valid value this step."""
    hit = member & valid[None, :]
    idx = jnp.argmax(jnp.where(hit, jnp.arange(hit.shape[1]), -1), axis=1)
    return jnp.where(jnp.any(hit, axis=1), value[idx], old)


def _leave_team(st: SiteState, leaving):
    """Trucks in ``leaving`` go to the idle pool and forget their per-team measurements."""
    return st._replace(
        team=jnp.where(leaving, blackboard.IDLE, st.team).astype(jnp.int32),
        phase=jnp.where(leaving, IDLE_PHASE, st.phase).astype(jnp.int32),
        timer=jnp.where(leaving, 0, st.timer).astype(jnp.int32),
        t_last=jnp.where(leaving, -1.0, st.t_last), w_last=jnp.where(leaving, 0.0, st.w_last),
        cycled=st.cycled & ~leaving)


def _conditions(p: SiteParams, t):
    """True velocity [m/s] and loading time [s] of each team at time t, f[M] each."""
    v_now = jnp.where(t >= p.v_change_t, p.v_after, p.v_true)
    tld_now = jnp.where(t >= p.tld_change_t, p.tld_after, p.tld_true)
    return v_now, tld_now


def _break_down(p: SiteParams, st: SiteState, t, n_teams: int):
    """The scheduled truck fails: its cargo is lost and it leaves the blackboard for good."""
    k = jnp.arange(st.team.shape[0])
    fails = (k == p.fail_truck) & (t >= p.fail_t) & (st.phase != BROKEN)
    member = blackboard.membership(st.team, n_teams)
    lost = st.lost + jnp.sum(jnp.where(member & fails[None, :], st.cargo[None, :], 0.0), axis=1)
    return st._replace(
        lost=lost, cargo=jnp.where(fails, 0.0, st.cargo),
        phase=jnp.where(fails, BROKEN, st.phase).astype(jnp.int32),
        team=jnp.where(fails, blackboard.FAILED, st.team).astype(jnp.int32),
        timer=jnp.where(fails, 0, st.timer).astype(jnp.int32))


def _cooperators(p: SiteParams, st: SiteState, s, t, v_now, n_teams: int):
    """Step 2: trucks advance their own phase from local information (timer, cargo, own team)."""
    moving = (st.phase == TO_SITE) | (st.phase == LOADING) | (st.phase == HAUL) | (st.phase == DUMP)
    timer = jnp.where(moving, st.timer - 1, st.timer)
    done = moving & (timer <= 0)
    ti = jnp.clip(st.team, 0, n_teams - 1)
    member = blackboard.membership(st.team, n_teams)
    arrive = done & (st.phase == TO_SITE)
    loaded = done & (st.phase == LOADING)
    hauled = done & (st.phase == HAUL)
    dumped = done & (st.phase == DUMP)

    # the coordinator times round trips (Eq. 4) and loading durations at its own site
    back = arrive & (st.t_last >= 0)
    tcirc_meas = _latest_per_team(member, t - st.t_last, back, st.tcirc_meas)
    tld_meas = _latest_per_team(member, t - st.t_last, loaded, st.tld_meas)
    delivered = st.delivered + jnp.sum(jnp.where(member & dumped[None, :], st.cargo[None, :], 0.0),
                                       axis=1)

    leg = step_ticks(p.dist[ti], v_now[ti] * p.dt)
    phase = jnp.select([arrive, loaded, hauled, dumped], [QUEUE, HAUL, DUMP, TO_SITE], st.phase)
    timer = jnp.select([loaded, hauled, dumped],
                       [leg, step_ticks(p.tdp_true[ti], p.dt), leg], timer)
    return st._replace(
        phase=phase.astype(jnp.int32), timer=timer.astype(jnp.int32),
        queue_since=jnp.where(arrive, s, st.queue_since).astype(jnp.int32),
        cycled=st.cycled | back, cargo=jnp.where(dumped, 0.0, st.cargo),
        delivered=delivered, tcirc_meas=tcirc_meas, tld_meas=tld_meas)


def _excavators(p: SiteParams, st: SiteState, s, t, tld_now, n_teams: int):
    """Step 3: each free excavator with soil left loads the longest-waiting truck of its queue."""
    n = st.team.shape[0]
    member = blackboard.membership(st.team, n_teams)
    busy = jnp.any(member & (st.phase == LOADING)[None, :], axis=1)
    waiting = member & (st.phase == QUEUE)[None, :]
    key = st.queue_since[None, :] * n + jnp.arange(n)[None, :]
    pick = jnp.argmin(jnp.where(waiting, key, jnp.iinfo(jnp.int32).max), axis=1)  # [M]
    start = ~busy & jnp.any(waiting, axis=1) & (st.remaining > 0)
    col = jnp.clip(st.loads_done, 0, p.loads.shape[-1] - 1)
    draw = jnp.take_along_axis(p.loads, col[:, None], axis=1)[:, 0]
    load = jnp.where(start, jnp.minimum(draw, st.remaining), 0.0)
    chosen = (jnp.arange(n)[None, :] == pick[:, None]) & start[:, None]  # [M, N]
    starts = jnp.any(chosen, axis=0)
    truck_load = jnp.sum(jnp.where(chosen, load[:, None], 0.0), axis=0)
    ti = jnp.clip(st.team, 0, n_teams - 1)
    return st._replace(
        remaining=st.remaining - load, loads_done=st.loads_done + start.astype(jnp.int32),
        phase=jnp.where(starts, LOADING, st.phase).astype(jnp.int32),
        timer=jnp.where(starts, step_ticks(tld_now[ti], p.dt), st.timer).astype(jnp.int32),
        cargo=jnp.where(starts, truck_load, st.cargo),
        w_last=jnp.where(starts, truck_load, st.w_last),
        t_last=jnp.where(starts, t, st.t_last))


def _release_from_empty_sites(st: SiteState, n_teams: int):
    """Step 4: an empty site needs no more trucks; the empty ones return to the waiting area."""
    ti = jnp.clip(st.team, 0, n_teams - 1)
    empty_site = (st.team >= 0) & (st.remaining[ti] <= 0)
    unloaded = (st.phase == TO_SITE) | (st.phase == QUEUE)
    return _leave_team(st, empty_site & unloaded)


def _finish(st: SiteState, s, n_teams: int):
    """Step 5: record when each site was cleared (empty, its excavator done: the paper's end of the
    task and Eq. 3's ``X = 0``) and when the team's last soil was dumped."""
    member = blackboard.membership(st.team, n_teams)
    empty = st.remaining <= 0
    loading = jnp.any(member & (st.phase == LOADING)[None, :], axis=1)
    carrying = jnp.any(member & (st.cargo > 0)[None, :], axis=1)
    cleared = empty & ~loading & (st.clear_step < 0)
    finished = empty & ~carrying & (st.finish_step < 0)
    return st._replace(clear_step=jnp.where(cleared, s, st.clear_step).astype(jnp.int32),
                       finish_step=jnp.where(finished, s, st.finish_step).astype(jnp.int32))


def _performance_model(p: SiteParams, st: SiteState, t, n_teams: int):
    """Eqs. 1, 2, 4 and the error correction. Returns the updated state, r_pred, r_real, available."""
    member = blackboard.membership(st.team, n_teams)
    n = jnp.sum(member, axis=1)
    r_real, ok = model.real_performance(member, st.w_last[None, :], st.t_last[None, :],
                                        st.cycled[None, :], t)
    r_pred_old = model.predicted_performance(n, st.w_hat, p.dist, st.v_hat, st.tld_hat, p.tdp_prior)
    ref = jnp.where(st.r_ref > 0, st.r_ref, r_pred_old)
    # error correction: real performance moved more than tol_perf from its previous value
    trigger = ok & (jnp.abs(r_real - ref) > p.tol_perf * ref)
    w_meas = (jnp.sum(jnp.where(member, st.w_last[None, :], 0.0), axis=1)
              / jnp.maximum(n, 1))
    w_hat = jnp.where(trigger, model.correct_estimate(st.w_hat, w_meas, p.tol_param), st.w_hat)
    tld_hat = jnp.where(trigger, model.correct_estimate(st.tld_hat, st.tld_meas, p.tol_param),
                        st.tld_hat)
    v_meas = model.velocity_estimate(p.dist, st.tcirc_meas, tld_hat, p.tdp_prior)
    v_hat = jnp.where(trigger, model.correct_estimate(st.v_hat, v_meas, p.tol_param), st.v_hat)
    st = st._replace(w_hat=w_hat, tld_hat=tld_hat, v_hat=v_hat,
                     r_ref=jnp.where(trigger, r_real, st.r_ref))
    r_pred = model.predicted_performance(n, w_hat, p.dist, v_hat, tld_hat, p.tdp_prior)
    return st, r_pred, r_real, ok


def _oracle_model(p: SiteParams, st: SiteState, t, n_teams: int):
    """Eq. 1 with the truth: mean pre-drawn load, the worst loading time and velocity still to come."""
    n = blackboard.team_sizes(st.team, n_teams)
    before_v = t < p.v_change_t
    v = jnp.where(before_v, jnp.minimum(p.v_true, p.v_after), p.v_after)
    tld = jnp.where(t < p.tld_change_t, jnp.maximum(p.tld_true, p.tld_after), p.tld_after)
    w = jnp.mean(p.loads, axis=-1)
    st = st._replace(w_hat=w, tld_hat=tld, v_hat=v)
    r_pred = model.predicted_performance(n, w, p.dist, v, tld, p.tdp_true)
    return st, r_pred, jnp.zeros_like(r_pred), jnp.zeros(r_pred.shape, bool)


def _deadline_demand(p: SiteParams, st: SiteState, t, r_pred, r_real, ok, tdp, n_teams: int):
    """Eq. 3 and the cooperators needed: ``(want, surplus)``, i32[M] each.

    A late team (Eq. 3, real performance when available) asks for the model's number of trucks, at
    least one more, at most the saturation size. A team on time offers the trucks beyond both the
    model's need and ``n * r_need / r`` (its current performance scaled to the rate it needs).
    """
    n = blackboard.team_sizes(st.team, n_teams)
    active = st.remaining > 0
    r_use = jnp.where(ok, r_real, r_pred)
    late = active & model.misses_deadline(t, st.remaining, r_use, p.deadline)
    n_need = model.cooperators_needed(st.remaining, t, p.deadline, st.w_hat, p.dist, st.v_hat,
                                      st.tld_hat, tdp)
    n_sat = model.saturation_trucks(p.dist, st.v_hat, st.tld_hat, tdp)
    target = jnp.where(late & (n < n_sat), jnp.minimum(jnp.maximum(n_need, n + 1), n_sat), n)
    time_left = p.deadline - t
    r_need = st.remaining / jnp.where(time_left > 0, time_left, 1.0)
    scaled = jnp.ceil(n * r_need / jnp.where(r_use > 0, r_use, 1.0)).astype(jnp.int32)
    keep = jnp.maximum(n_need, scaled)
    can_give = active & ~late & (time_left > 0) & (r_use > 0)
    surplus = jnp.where(can_give, jnp.maximum(n - keep, 0), 0)
    return (target - n).astype(jnp.int32), surplus.astype(jnp.int32)


def _fixed_demand(p: SiteParams, st: SiteState, strategy: str, n_teams: int):
    """Fixed shares of the working trucks among the unfinished sites: ``(want, surplus=0)``."""
    n = blackboard.team_sizes(st.team, n_teams)
    usable = jnp.sum(st.team != blackboard.FAILED)
    active = st.remaining > 0
    if strategy == "even":
        count = jnp.maximum(jnp.sum(active), 1)
        rank = jnp.cumsum(active) - 1
        share = usable // count + (rank < usable % count)
        target = jnp.where(active, share, 0)
    else:  # "largest": every truck to the unfinished site with the most soil at t = 0
        first = jnp.argmax(jnp.where(active, p.mass, -jnp.inf))
        target = jnp.where(active & (jnp.arange(n_teams) == first), usable, 0)
    return jnp.maximum(target - n, 0).astype(jnp.int32), jnp.zeros(n_teams, jnp.int32)


def _coordinators(cfg: TeamsConfig, p: SiteParams, st: SiteState, t, v_now, n_teams: int):
    """Step 6: model update, deadline test, then release and recruit on the blackboard."""
    if cfg.strategy == "performance":
        st, r_pred, r_real, ok = _performance_model(p, st, t, n_teams)
        want, surplus = _deadline_demand(p, st, t, r_pred, r_real, ok, p.tdp_prior, n_teams)
    elif cfg.strategy == "oracle":
        st, r_pred, r_real, ok = _oracle_model(p, st, t, n_teams)
        want, surplus = _deadline_demand(p, st, t, r_pred, r_real, ok, p.tdp_true, n_teams)
    else:
        n = blackboard.team_sizes(st.team, n_teams)
        r_pred = model.predicted_performance(n, p.w_prior, p.dist, p.v_prior, p.tld_prior,
                                             p.tdp_prior)
        r_real, ok = jnp.zeros_like(r_pred), jnp.zeros(r_pred.shape, bool)
        want, surplus = _fixed_demand(p, st, cfg.strategy, n_teams)

    empty = (st.phase == TO_SITE) | (st.phase == QUEUE)
    team, released = blackboard.release(st.team, empty, surplus, want)
    st = _leave_team(st._replace(team=team), released)
    team, joined = blackboard.recruit(st.team, want)
    ti = jnp.clip(team, 0, n_teams - 1)
    st = st._replace(
        team=team, phase=jnp.where(joined, TO_SITE, st.phase).astype(jnp.int32),
        timer=jnp.where(joined, step_ticks(p.join_dist, v_now[ti] * p.dt), st.timer).astype(jnp.int32))
    return st, r_pred, jnp.where(ok, r_real, jnp.nan)


def _step(cfg: TeamsConfig, p: SiteParams, st: SiteState, s):
    n_teams = st.remaining.shape[0]
    t = s * p.dt
    v_now, tld_now = _conditions(p, t)
    st = _break_down(p, st, t, n_teams)
    st = _cooperators(p, st, s, t, v_now, n_teams)
    st = _excavators(p, st, s, t, tld_now, n_teams)
    st = _release_from_empty_sites(st, n_teams)
    st = _finish(st, s, n_teams)
    all_done_before = jnp.all(st.finish_step >= 0)
    st, r_pred, r_real = _coordinators(cfg, p, st, t, v_now, n_teams)
    sizes = blackboard.team_sizes(st.team, n_teams)
    assigned = jnp.sum(sizes).astype(jnp.int32)
    st = st._replace(
        truck_steps=st.truck_steps + jnp.where(all_done_before, 0, assigned).astype(jnp.int32),
        peak_trucks=jnp.maximum(st.peak_trucks, assigned),
        max_team=jnp.maximum(st.max_team, sizes))
    record = None
    if cfg.record:
        record = Trace(r_pred=r_pred, r_real=r_real, n_trucks=sizes, remaining=st.remaining,
                       delivered=st.delivered, phase=st.phase, team=st.team)
    return st, record


def _result(p: SiteParams, st: SiteState) -> SiteResult:
    done = st.finish_step >= 0
    finish_time = jnp.where(done, st.finish_step * p.dt, jnp.nan)
    cleared = st.clear_step >= 0
    clear_time = jnp.where(cleared, st.clear_step * p.dt, jnp.nan)
    all_done = jnp.all(done)
    finish_all = jnp.where(all_done, jnp.max(jnp.where(done, finish_time, 0.0)), jnp.nan)
    met = jnp.all(cleared) & (jnp.max(jnp.where(cleared, clear_time, 0.0)) <= p.deadline)
    return SiteResult(
        clear_time=clear_time, finish_time=finish_time, delivered=st.delivered, lost=st.lost,
        remaining=st.remaining, met=met, finish_all=finish_all,
        truck_seconds=st.truck_steps * p.dt, peak_trucks=st.peak_trucks, max_team=st.max_team)


def simulate_site(cfg: TeamsConfig, params: SiteParams):
    """Simulate one site for ``cfg.n_steps`` steps. Pure; ``jit``/``vmap`` over ``params``.

    Returns ``(SiteResult, Trace or None)``; the trace (``cfg.record``) has a leading axis T.
    """
    validate_site(params, cfg)
    params = jax.tree_util.tree_map(jnp.asarray, params)
    state = _initial_state(params, cfg.n_trucks)
    steps = jnp.arange(cfg.n_steps, dtype=jnp.int32)
    state, trace = jax.lax.scan(functools.partial(_step, cfg, params), state, steps)
    return _result(params, state), trace


@functools.partial(jax.jit, static_argnums=0)
def run_sites_jit(cfg: TeamsConfig, params: SiteParams):
    """``run_sites`` without the input checks, jitted: for ahead-of-time compiles
    (``run_sites_jit.lower(cfg, params).compile()``) on inputs already checked by ``validate_site``."""
    return jax.vmap(functools.partial(simulate_site, cfg))(params)


def run_sites(cfg: TeamsConfig, params: SiteParams):
    """Simulate a batch of sites at once: every array of ``params`` has a leading batch axis B.

    Returns ``(SiteResult, Trace or None)`` with a leading axis B (Trace: ``[B, T, ...]``).
    """
    validate_site(params, cfg)
    return run_sites_jit(cfg, params)
