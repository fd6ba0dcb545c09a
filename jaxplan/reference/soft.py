"""Serial reference of the soft fabric kernels (``jaxplan.transport.soft``): plain loops over cells, float64.

Follows docs/transport.md, "Soft kernels", one cell and one option at a time.
"""
from __future__ import annotations

import math

import numpy as np

from jaxplan.reference.visibility import CONE_EPS, GATE_EPS, MONOTONE_EPS, fallback_hop, in_grid, step_cells, step_unit

__all__ = ["reference_soft_fabric"]

DIRS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]
_TINY = 1e-30


def _log_sigmoid(x: float) -> float:
    return -math.log1p(math.exp(-x)) if x >= 0 else x - math.log1p(math.exp(x))


def _sigmoid(x: float) -> float:
    return math.exp(_log_sigmoid(x))


def _soft_max(options, t):
    """``(t * logsumexp(s / t), weights)`` over a list of finite scores; (0, []) for none."""
    if not options:
        return 0.0, []
    top = max(options)
    e = [math.exp((s - top) / t) for s in options]
    total = sum(e)
    return top + t * math.log(total), [x / total for x in e]


def _fallback_dir(tvec, r, c, shape):
    hop = fallback_hop(r, c, (float(tvec[r, c, 0]), float(tvec[r, c, 1])), shape)
    return -1 if hop is None else hop[0]


def _soft_mean(options, t):
    """The softmax-weighted mean of a list of finite scores; 0 for none."""
    if not options:
        return 0.0
    _, w = _soft_max(options, t)
    return sum(wi * s for wi, s in zip(w, options))


def _log_softmax(options, t):
    """log of the softmax weights of a list of finite scores at temperature t."""
    top = max(options)
    z = [(s - top) / t for s in options]
    lse = math.log(sum(math.exp(x) for x in z))
    return [x - lse for x in z]


CONE_SCALE, HIGHWAY_SCALE, LENGTH_EXPONENT, ORDER_EXPONENT = 0.05, 0.1, 1.5, 2.25


def reference_soft_fabric(obj, target_mask, dist, tvec, cell_size, origin, *, theta_tol_deg, tau_h,
                          anchor_lambda, temperature, monotone=True, rounds=None, highway_relative=True,
                          spill_lam=None, spill_threshold=1e-3, slack_tau=0.0):
    """A dict with the ``SoftFabric`` fields (no smoothing / non-max suppression) for one grid.

    obj: f[H, W] objects; target_mask: bool[H, W]; dist: f[H, W] and tvec: f[H, W, 2] the scene's
    geometry; cell_size, origin: world units. Keyword parameters as in ``FabricParams``; spill_lam
    (None: Eq. 5) and spill_threshold as in ``SpillParams`` select by predicted delivered mass (Eq. 6).
    """
    obj = np.asarray(obj, np.float64)
    target = np.asarray(target_mask, bool)
    dist = np.asarray(dist, np.float64)
    tvec = np.asarray(tvec, np.float64)
    h, w = obj.shape
    t = max(float(temperature), 1e-6)
    s = float(cell_size)
    rounds = 2 * (h + w) if rounds is None else int(rounds)
    occ = ~target & (obj > 0)
    n_occ = int(occ.sum())
    mass = max(float(obj[occ].sum()) / n_occ, 1e-6) if n_occ else 1.0
    temp = t * mass
    cos_t = math.cos(math.radians(float(theta_tol_deg))) - CONE_EPS
    eta = mass * t ** LENGTH_EXPONENT / s
    order = mass * t ** ORDER_EXPONENT

    # the cone gate's logit of every allowed step (the monotone rule stays hard)
    logit = {}
    for r in range(h):
        for c in range(w):
            if not occ[r, c]:
                continue
            for k, (dr, dc) in enumerate(DIRS):
                nr, nc = r + dr, c + dc
                if not in_grid(nr, nc, (h, w)) or not (occ[nr, nc] or target[nr, nc]):
                    continue
                if monotone and (dist[r, c] - dist[nr, nc]) / s - MONOTONE_EPS <= 0:
                    continue
                ux, uy = step_unit(k)
                logit[(r, c, k)] = (tvec[r, c, 0] * ux + tvec[r, c, 1] * uy - cos_t) / (t * t * CONE_SCALE)

    def options(value, r, c):
        """[(Q, cost, kind)]: kind = direction index or 8 for the fallback; cost = the length and
        gate terms subtracted from the neighbour's value."""
        out, log_fb = [], 0.0
        for k, (dr, dc) in enumerate(DIRS):
            if (r, c, k) not in logit:
                continue
            nr, nc = r + dr, c + dc
            nv = 0.0 if target[nr, nc] else value[nr, nc]
            cost = eta * step_cells(k) * s - mass / t * _log_sigmoid(logit[(r, c, k)])
            out.append((nv - cost, cost, k))
            log_fb += mass / t * _log_sigmoid(-logit[(r, c, k)])
        cost = eta * dist[r, c] - log_fb
        out.append((-cost, cost, 8))
        return out

    def weights(opts):
        _, wv = _soft_max([o[0] for o in opts], temp)
        _, pi = _soft_max([o[0] - (order * o[2] if o[2] < 8 else 0.0) for o in opts], temp)
        return wv, pi

    fb_cost = np.where(occ, eta * dist, 0.0)
    value, raw, length, cost = np.zeros((h, w)), np.where(occ, obj, 0.0), np.where(occ, dist, 0.0), np.zeros((h, w))
    for r in range(h):
        for c in range(w):
            if occ[r, c]:
                cost[r, c] = options(np.zeros((h, w)), r, c)[-1][1]
                value[r, c] = obj[r, c] - cost[r, c]
    del fb_cost
    for _ in range(rounds):
        nv, nr_, nl, nc_ = (np.zeros((h, w)) for _ in range(4))
        for r in range(h):
            for c in range(w):
                if not occ[r, c]:
                    continue
                opts = options(value, r, c)
                wv, pi = weights(opts)
                nv[r, c] = obj[r, c] + sum(q * o[0] for q, o in zip(wv, opts))
                nr_[r, c] = obj[r, c]
                for p, q, (_, cst, k) in zip(pi, wv, opts):
                    nc_[r, c] += q * cst
                    if k == 8:
                        nl[r, c] += p * dist[r, c]
                        continue
                    rr, cc = r + DIRS[k][0], c + DIRS[k][1]
                    cont = not target[rr, cc]
                    nr_[r, c] += p * (raw[rr, cc] if cont else 0.0)
                    nl[r, c] += p * (step_cells(k) * s + (length[rr, cc] if cont else 0.0))
                    nc_[r, c] += q * (cost[rr, cc] if cont else 0.0)
        value, raw, length, cost = nv, nr_, nl, nc_

    policy = np.zeros((h, w, 9))
    log_sharp = {}
    for r in range(h):
        for c in range(w):
            if occ[r, c]:
                opts = options(value, r, c)
                _, pi = weights(opts)
                tie = [o[0] - (order * o[2] if o[2] < 8 else 0.0) for o in opts]
                for p, ls, (_, _, k) in zip(pi, _log_softmax(tie, temp * t * t), opts):
                    policy[r, c, k] = p
                    log_sharp[(r, c, k)] = ls

    delivered = raw.copy()
    own = np.where(occ, raw, 0.0)
    if spill_lam is not None:
        policy, log_sharp, delivered, own = _select(obj, occ, target, tvec, raw, policy, logit, mass, t, rounds,
                                                     float(spill_lam), float(spill_threshold), float(slack_tau))

    # soft psi: 0, the own (selected) expected raw mass and every allowed predecessor P of U, lowered by
    # M log of P's sharpened step into U; a softmax-weighted mean at T
    psi = own.copy()
    for _ in range(rounds):
        new = np.zeros_like(psi)
        for r in range(h):
            for c in range(w):
                opts = [0.0] + ([own[r, c]] if occ[r, c] else [])
                for k, (dr, dc) in enumerate(DIRS):
                    pr, pc = r - dr, c - dc
                    if (pr, pc, k) in log_sharp:
                        opts.append(psi[pr, pc] + mass * log_sharp[(pr, pc, k)])
                new[r, c] = _soft_mean(opts, temp)
        psi = new

    # soft heat: the sharpened-policy-averaged Eq. 10 alignment of each source C = X - step
    heat = np.zeros((h, w))
    for r in range(h):
        for c in range(w):
            if target[r, c]:
                continue
            opts = []
            for j, (dr, dc) in enumerate(DIRS):
                pr, pc = r - dr, c - dc
                if not in_grid(pr, pc, (h, w)) or not occ[pr, pc]:
                    continue
                fb = _fallback_dir(tvec, pr, pc, (h, w))
                expected = 0.0
                for i in range(9):
                    hop = fb if i == 8 else i
                    if hop < 0 or (pr, pc, i) not in log_sharp:
                        continue
                    ux, uy = step_unit(hop)
                    jx, jy = step_unit(j)
                    a = ux * jx + uy * jy
                    if step_cells(j) <= step_cells(hop) + GATE_EPS and a * step_cells(j) > GATE_EPS:
                        expected += math.exp(log_sharp[(pr, pc, i)]) * a
                opts.append(expected * psi[pr, pc])
            heat[r, c] = _soft_mean(opts, temp)

    scale = max(heat.max(), 1e-6) if highway_relative else 1.0
    thr = float(tau_h) * scale if highway_relative else float(tau_h)
    width = t * HIGHWAY_SCALE * scale
    hw = np.zeros((h, w))
    for r in range(h):
        for c in range(w):
            if not target[r, c]:
                hw[r, c] = _sigmoid((heat[r, c] - thr) / width) * _sigmoid(heat[r, c] / width)
    cand = hw * occ

    ascale = max(heat.max(), 1e-6)
    anchors = np.zeros((h, w, h * w))
    centre = lambda r, c: (origin[0] + (c + 0.5) * s, origin[1] + (r + 0.5) * s)  # noqa: E731
    for r in range(h):
        for c in range(w):
            if not occ[r, c]:
                continue
            x0, y0 = centre(r, c)
            scores, idx = [], []
            for q in range(h * w):
                qr, qc = divmod(q, w)
                if cand[qr, qc] <= 0:
                    continue
                x1, y1 = centre(qr, qc)
                d = math.hypot(x1 - x0, y1 - y0)
                scores.append((heat[qr, qc] - float(anchor_lambda) * d) / ascale
                              + math.log(max(cand[qr, qc], _TINY)) / t)
                idx.append(q)
            _, wts = _soft_max(scores, t)
            for q, wt in zip(idx, wts):
                anchors[r, c, q] = wt
    return dict(value=value + cost, raw=raw, length=length, policy=policy, psi=psi, heat=heat, highways=hw,
                candidate=cand, anchor_weights=anchors, delivered=delivered)


def _turn(i, j):
    ux, uy = step_unit(i)
    vx, vy = step_unit(j)
    return math.acos(max(-1.0, min(1.0, ux * vx + uy * vy)))


def _select(obj, occ, target, tvec, raw, policy, logit, mass, t, rounds, lam, threshold, slack):
    """Eq. 6 softened, one cell at a time: ``(policy, log_sharp, delivered, own)`` (``soft.soft_select``)."""
    h, w = obj.shape
    temp = t * mass

    def local(r, c, i):
        """Expected turning right after stepping from (r, c) in direction i into N."""
        nr, nc = r + DIRS[i][0], c + DIRS[i][1]
        ux, uy = step_unit(i)
        fb = math.acos(max(-1.0, min(1.0, tvec[nr, nc, 0] * ux + tvec[nr, nc, 1] * uy)))
        return sum(policy[nr, nc, j] * _turn(i, j) for j in range(8)) + policy[nr, nc, 8] * fb

    def option_theta(theta, r, c, i):
        nr, nc = r + DIRS[i][0], c + DIRS[i][1]
        return 0.0 if target[nr, nc] else local(r, c, i) + theta[nr, nc]

    theta = np.zeros((h, w))
    for _ in range(rounds):
        new = np.zeros((h, w))
        for (r, c, i) in logit:
            new[r, c] += policy[r, c, i] * option_theta(theta, r, c, i)
        theta = new

    new_policy, log_sharp = np.zeros_like(policy), {}
    delivered, own = np.zeros((h, w)), np.zeros((h, w))
    for r in range(h):
        for c in range(w):
            if not occ[r, c]:
                continue
            opts, log_fb = [], 0.0
            for i in range(8):
                if (r, c, i) not in logit:
                    continue
                nr, nc = r + DIRS[i][0], c + DIRS[i][1]
                r_i = obj[r, c] + (0.0 if target[nr, nc] else raw[nr, nc])
                opts.append((i, r_i, option_theta(theta, r, c, i), mass / t * _log_sigmoid(logit[(r, c, i)])))
                log_fb += mass / t * _log_sigmoid(-logit[(r, c, i)])
            opts.append((8, obj[r, c], 0.0, log_fb))
            best = max(o[1] for o in opts)
            scores, d_opts = [], []
            for _, r_i, th, gate in opts:
                spilled = r_i * -math.expm1(-lam * th)
                d_i = r_i - spilled * _sigmoid((spilled - threshold) / temp)
                d_opts.append(d_i)
                scores.append((d_i + gate) / temp + _log_sigmoid((r_i - best + slack) / temp) / t)
            _, pi = _soft_max(scores, 1.0)
            for (k, r_i, _, _), p, ls, d_i in zip(opts, pi, _log_softmax(scores, t * t), d_opts):
                new_policy[r, c, k] = p
                log_sharp[(r, c, k)] = ls
                delivered[r, c] += p * d_i
                own[r, c] += p * r_i
    return new_policy, log_sharp, delivered, own
