"""Plain-Python reference of the team-organization simulation (``jaxplan.teams.sim``): loops over
steps, trucks and teams, Python floats (float64), no JAX, no numpy in the step logic.

It follows the step order documented in ``jaxplan.teams.sim`` and docs/teams.md, but is written
independently: the number of cooperators needed is found by trying ``n = 1, 2, ...`` instead of the
closed form, the queue and the blackboard are explicit lists. Tests hold the two equal.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["reference_site", "RefResult"]

IDLE_PHASE, TO_SITE, QUEUE, LOADING, HAUL, DUMP, BROKEN = range(7)
IDLE, FAILED = -1, -2
_TICK_SLACK = 1e-3


@dataclass
class RefResult:
    clear_time: list
    finish_time: list
    delivered: list
    lost: list
    remaining: list
    met: bool
    truck_seconds: float
    peak_trucks: int
    max_team: list
    # per-step records, lists of lists: [T][M] or [T][N]
    r_pred: list = field(default_factory=list)
    r_real: list = field(default_factory=list)
    n_trucks: list = field(default_factory=list)
    remaining_t: list = field(default_factory=list)
    delivered_t: list = field(default_factory=list)
    phase: list = field(default_factory=list)
    team: list = field(default_factory=list)


def _ticks(duration, dt):
    return max(int(math.ceil(duration / dt - _TICK_SLACK)), 1)


def _pred(n, w, d, v, tld, tdp):
    """Eq. 1 (queueing reading)."""
    tc = 2 * d / v + tld + tdp
    return w / tld if n * tld >= tc else n * w / tc


def _late(t, x, r, deadline):
    """Eq. 3."""
    if x <= 0:
        return False
    return r <= 0 or t + x / r > deadline


def _needed(x, t, deadline, w, d, v, tld, tdp):
    """Smallest n meeting the deadline by Eq. 1 and Eq. 3, found by trying n = 1, 2, ...; the
    saturation size when none does."""
    if x <= 0:
        return 0
    n_sat = int(math.ceil((2 * d / v + tld + tdp) / tld))
    for n in range(1, n_sat + 1):
        if deadline - t > 0 and t + x / _pred(n, w, d, v, tld, tdp) <= deadline:
            return n
    return n_sat


def _correct(est, meas, tol):
    if meas is None or not math.isfinite(meas) or meas <= 0:
        return est
    return meas if abs(meas - est) > tol * est else est


def reference_site(params, n_trucks: int, n_steps: int, strategy: str = "performance") -> RefResult:
    """Simulate one site (``SiteParams`` of scalars / 1-D arrays, no batch axis)."""
    g = lambda name: np.asarray(getattr(params, name), dtype=np.float64).tolist()  # noqa: E731
    mass, dist, v_true, v_after = g("mass"), g("dist"), g("v_true"), g("v_after")
    tld_true, tld_after, tdp_true = g("tld_true"), g("tld_after"), g("tdp_true")
    w_prior, tld_prior, v_prior, tdp_prior = g("w_prior"), g("tld_prior"), g("v_prior"), g("tdp_prior")
    loads = g("loads")
    v_change_t, tld_change_t, fail_t = g("v_change_t"), g("tld_change_t"), g("fail_t")
    deadline, join_dist, tol_perf, tol_param, dt = (g("deadline"), g("join_dist"), g("tol_perf"),
                                                    g("tol_param"), g("dt"))
    fail_truck = int(params.fail_truck)
    m, n = len(mass), n_trucks

    team = [IDLE] * n
    phase = [IDLE_PHASE] * n
    timer = [0] * n
    cargo = [0.0] * n
    queue_since = [0] * n
    w_last = [0.0] * n
    t_last = [-1.0] * n
    cycled = [False] * n
    remaining = list(mass)
    delivered = [0.0] * m
    lost = [0.0] * m
    loads_done = [0] * m
    w_hat, tld_hat, v_hat = list(w_prior), list(tld_prior), list(v_prior)
    r_ref = [0.0] * m
    tld_meas = [math.nan] * m
    tcirc_meas = [math.nan] * m
    clear_step = [-1] * m
    finish_step = [-1] * m
    truck_steps = 0
    peak = 0
    max_team = [0] * m
    out = RefResult([], [], [], [], [], False, 0.0, 0, [])

    def members(i):
        return [k for k in range(n) if team[k] == i]

    def leave(k):
        team[k], phase[k], timer[k] = IDLE, IDLE_PHASE, 0
        t_last[k], w_last[k], cycled[k] = -1.0, 0.0, False

    for s in range(n_steps):
        t = s * dt
        v_now = [v_after[i] if t >= v_change_t else v_true[i] for i in range(m)]
        tld_now = [tld_after[i] if t >= tld_change_t else tld_true[i] for i in range(m)]

        # 1. breakdown
        k = fail_truck
        if k >= 0 and t >= fail_t and phase[k] != BROKEN:
            if team[k] >= 0:
                lost[team[k]] += cargo[k]
            cargo[k], phase[k], team[k], timer[k] = 0.0, BROKEN, FAILED, 0

        # 2. cooperators
        for k in range(n):
            if phase[k] not in (TO_SITE, LOADING, HAUL, DUMP):
                continue
            timer[k] -= 1
            if timer[k] > 0:
                continue
            i = team[k]
            leg = _ticks(dist[i], v_now[i] * dt)
            if phase[k] == TO_SITE:
                phase[k], queue_since[k] = QUEUE, s
                if t_last[k] >= 0:
                    tcirc_meas[i] = t - t_last[k]  # higher k overwrites: the latest per team
                    cycled[k] = True
            elif phase[k] == LOADING:
                tld_meas[i] = t - t_last[k]
                phase[k], timer[k] = HAUL, leg
            elif phase[k] == HAUL:
                phase[k], timer[k] = DUMP, _ticks(tdp_true[i], dt)
            else:
                delivered[i] += cargo[k]
                cargo[k] = 0.0
                phase[k], timer[k] = TO_SITE, leg

        # 3. excavators
        for i in range(m):
            mem = members(i)
            if any(phase[k] == LOADING for k in mem) or remaining[i] <= 0:
                continue
            queue = sorted((queue_since[k], k) for k in mem if phase[k] == QUEUE)
            if not queue:
                continue
            k = queue[0][1]
            draw = loads[i][min(loads_done[i], len(loads[i]) - 1)]
            load = min(draw, remaining[i])
            remaining[i] -= load
            loads_done[i] += 1
            phase[k], timer[k] = LOADING, _ticks(tld_now[i], dt)
            cargo[k] = w_last[k] = load
            t_last[k] = t

        # 4. empty sites send their empty trucks home
        for k in range(n):
            if team[k] >= 0 and remaining[team[k]] <= 0 and phase[k] in (TO_SITE, QUEUE):
                leave(k)

        # 5. cleared / finished
        for i in range(m):
            mem = members(i)
            if remaining[i] <= 0:
                if clear_step[i] < 0 and not any(phase[k] == LOADING for k in mem):
                    clear_step[i] = s
                if finish_step[i] < 0 and not any(cargo[k] > 0 for k in mem):
                    finish_step[i] = s
        all_done_before = all(f >= 0 for f in finish_step)

        # 6. coordinators
        sizes = [len(members(i)) for i in range(m)]
        r_pred = [0.0] * m
        r_real = [math.nan] * m
        want = [0] * m
        surplus = [0] * m
        if strategy in ("performance", "oracle"):
            for i in range(m):
                mem = members(i)
                ok, rr = False, 0.0
                if strategy == "performance":
                    if mem and all(cycled[k] for k in mem):
                        span = t - min(t_last[k] for k in mem)
                        if span > 0:
                            ok, rr = True, sum(w_last[k] for k in mem) / span
                    rp_old = _pred(len(mem), w_hat[i], dist[i], v_hat[i], tld_hat[i], tdp_prior[i])
                    ref = r_ref[i] if r_ref[i] > 0 else rp_old
                    if ok and abs(rr - ref) > tol_perf * ref:
                        w_meas = sum(w_last[k] for k in mem) / len(mem)
                        w_hat[i] = _correct(w_hat[i], w_meas, tol_param)
                        tld_hat[i] = _correct(tld_hat[i], tld_meas[i], tol_param)
                        travel = tcirc_meas[i] - tld_hat[i] - tdp_prior[i]
                        v_meas = 2 * dist[i] / travel if travel > 0 else math.nan
                        v_hat[i] = _correct(v_hat[i], v_meas, tol_param)
                        r_ref[i] = rr
                    tdp = tdp_prior[i]
                else:
                    v_hat[i] = min(v_true[i], v_after[i]) if t < v_change_t else v_after[i]
                    tld_hat[i] = max(tld_true[i], tld_after[i]) if t < tld_change_t else tld_after[i]
                    w_hat[i] = sum(loads[i]) / len(loads[i])
                    tdp = tdp_true[i]
                rp = _pred(len(mem), w_hat[i], dist[i], v_hat[i], tld_hat[i], tdp)
                r_pred[i] = rp
                if ok:
                    r_real[i] = rr
                r_use = rr if ok else rp
                x = remaining[i]
                late = x > 0 and _late(t, x, r_use, deadline)
                need = _needed(x, t, deadline, w_hat[i], dist[i], v_hat[i], tld_hat[i], tdp)
                n_sat = int(math.ceil((2 * dist[i] / v_hat[i] + tld_hat[i] + tdp) / tld_hat[i]))
                nn = len(mem)
                if late and nn < n_sat:
                    want[i] = min(max(need, nn + 1), n_sat) - nn
                if x > 0 and not late and deadline - t > 0 and r_use > 0:
                    keep = max(need, int(math.ceil(nn * (x / (deadline - t)) / r_use)))
                    surplus[i] = max(nn - keep, 0)
        else:
            for i in range(m):
                r_pred[i] = _pred(sizes[i], w_prior[i], dist[i], v_prior[i], tld_prior[i],
                                  tdp_prior[i])
            usable = sum(1 for k in range(n) if team[k] != FAILED)
            active = [i for i in range(m) if remaining[i] > 0]
            target = [0] * m
            if strategy == "even":
                for rank, i in enumerate(active):
                    target[i] = usable // len(active) + (1 if rank < usable % len(active) else 0)
            elif active:
                target[max(active, key=lambda i: (mass[i], -i))] = usable
            want = [max(target[i] - sizes[i], 0) for i in range(m)]

        # blackboard: release surplus (team order, highest-index empty trucks first), then recruit
        shortfall = max(sum(want) - sum(1 for k in range(n) if team[k] == IDLE), 0)
        for i in range(m):
            eligible = [k for k in members(i) if phase[k] in (TO_SITE, QUEUE)]
            give = min(surplus[i], len(eligible), shortfall)
            for k in sorted(eligible, reverse=True)[:give]:
                leave(k)
            shortfall -= give
        for i in range(m):
            for _ in range(want[i]):
                idle = [k for k in range(n) if team[k] == IDLE]
                if not idle:
                    break
                k = idle[0]
                team[k], phase[k] = i, TO_SITE
                timer[k] = _ticks(join_dist, v_now[i] * dt)

        sizes = [len(members(i)) for i in range(m)]
        assigned = sum(sizes)
        if not all_done_before:
            truck_steps += assigned
        peak = max(peak, assigned)
        max_team = [max(a, b) for a, b in zip(max_team, sizes)]
        out.r_pred.append(r_pred)
        out.r_real.append(r_real)
        out.n_trucks.append(sizes)
        out.remaining_t.append(list(remaining))
        out.delivered_t.append(list(delivered))
        out.phase.append(list(phase))
        out.team.append(list(team))

    out.clear_time = [c * dt if c >= 0 else math.nan for c in clear_step]
    out.finish_time = [f * dt if f >= 0 else math.nan for f in finish_step]
    out.delivered, out.lost, out.remaining = delivered, lost, remaining
    out.met = all(c >= 0 for c in clear_step) and max(out.clear_time) <= deadline
    out.truck_seconds = truck_steps * dt
    out.peak_trucks, out.max_team = peak, max_team
    return out
