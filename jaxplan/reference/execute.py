"""Serial reference of the spill model and of pushing a route (``jaxplan.transport.spillage``,
``jaxplan.transport.execute``).

Plain Python, float64, one sample at a time, written straight from docs/transport.md.
"""
from __future__ import annotations

import math

import numpy as np

QUANTUM = 2.0 ** -10   # as jaxplan.transport.execute.QUANTUM: spills land on the grid in these units
STRAIGHT_TURN = 1e-4   # as jaxplan.transport.execute.STRAIGHT_TURN: a sample turning less spills on its own cell


def _tangents(p0, p1, p2, p3, alpha: float):
    """End tangents of the segment p1 -> p2 of the Catmull-Rom spline with knot gaps |.|^alpha,
    per unit of the segment's parameter (alpha 0: the uniform spline's (p2 - p0) / 2, (p3 - p1) / 2)."""
    def gap(a, b):
        return float(np.linalg.norm(b - a)) ** alpha if np.any(a != b) else 0.0

    def ratio(v, d):
        return v / d if d > 0 else np.zeros(2)

    d0, d1, d2 = gap(p0, p1), gap(p1, p2), gap(p2, p3)
    m1 = (p2 - p1) + d1 * (ratio(p1 - p0, d0) - ratio(p2 - p0, d0 + d1))
    m2 = (p2 - p1) + d1 * (ratio(p3 - p2, d2) - ratio(p3 - p1, d1 + d2))
    return m1, m2


def catmull_rom_samples(points, samples_per_step: int, alpha: float = 0.5):
    """Samples of the Catmull-Rom spline through ``points`` (list of (x, y)), knot exponent ``alpha``
    (0.5 centripetal, as ``SpillParams.spline_alpha``; 0 uniform).

    Returns a list of dicts with ``pos``, ``tangent``, ``turn`` (signed radians), ``ds`` and
    ``segment``, ``first`` (first sample of its segment), in travel order.
    """
    n = len(points)
    p = [np.asarray(q, np.float64) for q in points]
    out = []
    for j in range(n - 1):
        p1, p2 = p[j], p[j + 1]
        p0 = p[j - 1] if j > 0 else 2 * p1 - p2
        p3 = p[j + 2] if j + 2 <= n - 1 else 2 * p2 - p1
        m1, m2 = _tangents(p0, p1, p2, p3, alpha)
        # the cubic Hermite segment p1 -> p2 with tangents m1, m2
        for q in range(samples_per_step):
            t = (q + 0.5) / samples_per_step
            h00, h10, h01, h11 = 2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t, -2 * t**3 + 3 * t**2, t**3 - t**2
            pos = h00 * p1 + h10 * m1 + h01 * p2 + h11 * m2
            vel = ((6 * t**2 - 6 * t) * p1 + (3 * t**2 - 4 * t + 1) * m1 + (6 * t - 6 * t**2) * p2
                   + (3 * t**2 - 2 * t) * m2)
            acc = (12 * t - 6) * p1 + (6 * t - 4) * m1 + (6 - 12 * t) * p2 + (6 * t - 2) * m2
            speed = math.hypot(vel[0], vel[1])
            cross = vel[0] * acc[1] - vel[1] * acc[0]
            turn = cross / speed ** 3 * speed / samples_per_step if speed > 0 else 0.0
            tangent = vel / speed if speed > 0 else np.zeros(2)
            out.append(dict(pos=pos, tangent=tangent, turn=turn, ds=speed / samples_per_step,
                            segment=j, first=q == 0))
    return out


def spill_along(samples, waypoint_pickup, lam: float, threshold: float, temperature: float = 0.0):
    """``(delivered, [spill per sample])``: the load recurrence of ``spillage.curvature_spill``
    (``temperature > 0``: the soft threshold ``spill * sigmoid((spill - threshold) / temperature)``)."""
    load = 0.0
    spills = []
    for s in samples:
        if s["first"]:
            load += waypoint_pickup[s["segment"]]
        spill = min(1.0, lam * abs(s["turn"])) * load
        if temperature > 0:
            z = (spill - threshold) / temperature
            spill *= 1.0 / (1.0 + math.exp(-z)) if z > -700 else 0.0
        elif spill < threshold:
            spill = 0.0
        load -= spill
        spills.append(spill)
    return load, spills


def first_visits(cells):
    """``[bool]``: for each cell of the list ``cells`` ((row, col) tuples), whether it is its first
    occurrence (a pushed route collects each cell once; ``execute._first_visit``)."""
    seen = set()
    out = []
    for rc in cells:
        out.append(rc not in seen)
        seen.add(rc)
    return out


def execute_route(obj, target_mask, dist, tvec, cell_size, origin, cells, fallback, *,
                  lam: float, threshold: float, samples_per_step: int, spline_alpha: float = 0.5, blocked=None):
    """Push the route ``cells`` (list of (row, col)) on a copy of ``obj``.

    Returns ``(new_obj, info)`` with info keys ``collected``, ``spilled``, ``delivered`` (collected - spilled),
    ``residual_load`` (the evaluator's delivered mass, before spills are rounded to ``QUANTUM``), ``length``,
    ``samples``, ``spills``, ``drop_cells``. blocked: optional bool[H, W]; a spill that would land on a
    blocked cell drops on the route cell its sample's segment leaves instead.
    """
    obj = np.array(obj, np.float64)
    h, w = obj.shape
    ox, oy = origin

    def centre(rc):
        return np.array([ox + (rc[1] + 0.5) * cell_size, oy + (rc[0] + 0.5) * cell_size])

    points = [centre(rc) for rc in cells]
    last = cells[-1]
    end = centre(last) + np.asarray(tvec[last]) * dist[last] if fallback else centre(last)
    if fallback:
        points.append(end)
    pickup = [obj[rc] if first and not target_mask[rc] else 0.0 for rc, first in zip(cells, first_visits(cells))]
    pickup.append(0.0)
    samples = catmull_rom_samples(points, samples_per_step, spline_alpha)
    delivered, spills = spill_along(samples, pickup, lam, threshold)
    spills = [round(v / QUANTUM) * QUANTUM for v in spills]   # what lands on the grid
    collected = sum(pickup)
    for rc, amount in zip(cells, pickup):
        if amount > 0:
            obj[rc] = 0.0
    drops = []
    for s, amount in zip(samples, spills):
        drop = cells[s["segment"]]
        if abs(s["turn"]) > STRAIGHT_TURN:
            left = np.array([-s["tangent"][1], s["tangent"][0]])
            x, y = s["pos"] - math.copysign(1.0, s["turn"]) * left * cell_size
            r, c = math.floor((y - oy) / cell_size), math.floor((x - ox) / cell_size)
            if 0 <= r < h and 0 <= c < w and not target_mask[r, c] and not (blocked is not None and blocked[r, c]):
                drop = (r, c)
        drops.append(drop)
        obj[drop] += amount
    if fallback:
        targets = [(r, c) for r in range(h) for c in range(w) if target_mask[r, c]]
        deposit = min(targets, key=lambda rc: (float(np.sum((centre(rc) - end) ** 2)), rc))
    else:
        deposit = last
    spilled = sum(spills)
    obj[deposit] += collected - spilled
    return obj, dict(collected=collected, spilled=spilled, delivered=collected - spilled, residual_load=delivered,
                     length=sum(s["ds"] for s in samples), samples=samples, spills=spills, drop_cells=drops)
