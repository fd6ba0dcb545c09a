"""A node's candidate pushes ``tau = (g, v, xi)`` (Algorithm 1, step 2) in the order they are tried,
and the :class:`PushTask` of each (its contact mode from :func:`push.face_contacts`)."""
from __future__ import annotations

import itertools
import math

import numpy as np

from jaxplan.pusharound.push import PushTask, face_contacts
from jaxplan.pusharound.search.context import SearchContext, SearchRun
from jaxplan.pusharound.search.nodes import Candidate, SearchNode, Target

__all__ = ["candidate_task", "candidates", "softmax_order"]


def softmax_order(costs, temperature: float, rng: np.random.Generator) -> np.ndarray:
    """A seeded sample without replacement from softmax(-normalised cost / T) (Gumbel top-k) of
    ``costs`` f[K]: i64[K] indices, first drawn first."""
    c = np.asarray(costs, np.float64)
    if len(c) <= 1:
        return np.arange(len(c))
    span = float(c.max() - c.min())
    z = (c - c.min()) / span if span > 0 else np.zeros_like(c)
    return np.argsort(z / temperature - rng.gumbel(size=len(c)), kind="stable")


def candidates(ctx: SearchContext, run: SearchRun, node: SearchNode) -> list:
    """Every candidate of ``node``, in the order they are tried: the first pass (no yaw rate, the
    ``gaps_per_node`` first gaps of the sampled order) then the second (the other gaps, yaw rates);
    within a pass, round-robin over (gap, movable) so that a batch covers every gap's movables with
    their best modes; modes the ModeTable saw fail last."""
    with run.timed("time_candidates_s"):
        cfg, targets = ctx.cfg, node.targets
        order = softmax_order([tg.cost for tg in targets], cfg.temperature, run.rng)
        rel = _relative_angles(cfg.n_directions)
        first, second, last = [], [], []
        for rank_pos, ti in enumerate(order):
            tg = targets[int(ti)]
            for m in sorted(tg.movables, key=lambda m: ctx.scene.movables[m].mass):
                g1, g2, bad = _movable_candidates(ctx, node, int(ti), tg, m, rank_pos < cfg.gaps_per_node, rel)
                last += bad
                for grp, bucket in ((g1, first), (g2, second)):
                    if grp:
                        grp.sort(key=lambda x: x[0])
                        bucket.append([c for _, c in grp])
        last.sort(key=lambda x: x[0])
        return _interleave(first) + _interleave(second) + [c for _, c in last]


def _relative_angles(n: int) -> list:
    """Push directions relative to "away from the gap" [rad]: 0, +d, -d, +2d, ... with d = 2 pi / n."""
    step = 2 * math.pi / n
    return [((k + 1) // 2) * step * (1 if k % 2 else -1) for k in range(n)]


def _speeds(ctx: SearchContext, tg: Target) -> list:
    """The candidate body speeds [m/s] for ``tg``: the configured ones, 0 replaced by the speed that
    opens it (plus 0.3 m) in the push duration, within [0.1, 0.6]."""
    w = float(ctx.scene.width)
    need = (w - tg.width + 0.3) if tg.kind == "gap" else (0.5 * w - tg.width + 0.3)
    return [round(min(max(need / ctx.duration, 0.1), 0.6), 3) if s == 0 else float(s) for s in ctx.cfg.speeds]


def _movable_candidates(ctx: SearchContext, node: SearchNode, ti: int, tg: Target, m: int, top: bool,
                        rel: list) -> tuple:
    """The candidates on movable ``m`` of target ``ti`` as (score, Candidate) lists: (first pass,
    second pass, modes the ModeTable saw fail at least twice). ``top``: the target is among the
    ``gaps_per_node`` first of the sampled order."""
    cfg, table = ctx.cfg, ctx.table
    psi = float(node.poses[m, 2])
    base = math.atan2(tg.away[m][1], tg.away[m][0])
    omegas = (0.0,) + tuple(om for om in cfg.omegas if om != 0)
    teams = [n for n in cfg.team_sizes if n <= ctx.n_robots]
    first, second, failed = [], [], []
    for omega, (j, da), n, (si, s) in itertools.product(omegas, enumerate(rel), teams, enumerate(_speeds(ctx, tg))):
        ang = base + da
        key = table.key(ang - psi, n, s, omega)
        rec = table.prior(ctx.scene.movables[m], key) if ctx.use_table else None
        hit = rec is not None and rec.success > 0
        # Reuse exactly a stored mode: the validated bin's centre.
        ang_c = table.bin_angle(key.bin) + psi if hit else ang
        entry = ((0 if hit else 1, -(rec.rate if rec else 0.5), j, si),
                 Candidate(ti, m, (ang_c, n, s, omega), key, bool(hit)))
        if rec is not None and rec.trials >= 2 and rec.success == 0:
            failed.append(entry)
        elif top and (hit or (omega == 0 and si == 0 and j < cfg.first_directions)):
            first.append(entry)
        else:
            second.append(entry)
    return first, second, failed


def _interleave(groups: list) -> list:
    """Round-robin over the lists in ``groups``: every list's first, then every list's second, ..."""
    out, k = [], 0
    while any(k < len(gr) for gr in groups):
        out += [gr[k] for gr in groups if k < len(gr)]
        k += 1
    return out


def candidate_task(ctx: SearchContext, node: SearchNode, cand: Candidate) -> PushTask | None:
    """The unbatched :class:`PushTask` of ``cand`` at the node's poses (None when the face has no room
    for the team)."""
    ang, n, s, omega = cand.spec
    psi = float(node.poses[cand.movable, 2])
    d_world = np.array([math.cos(ang), math.sin(ang)])
    d_body = np.array([math.cos(ang - psi), math.sin(ang - psi)])
    try:
        c, d, act = face_contacts(ctx.world, cand.movable, d_body, n)
    except ValueError:
        return None
    return PushTask(np.int64(cand.movable), c, d, act, np.r_[s * d_world, omega], np.float64(ctx.duration))
