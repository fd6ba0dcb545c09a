"""Serial reference of the capacity-aware spill model (``jaxplan.transport.spillage.capacity.capacity_spill``).

Plain Python, float64, one sample at a time, written from the module docstring's recurrence.
"""
from __future__ import annotations

import math


def _softplus(x: float) -> float:
    # log(1 + e^x) without overflow for large x
    return x + math.log1p(math.exp(-x)) if x > 0 else math.log1p(math.exp(x))


def turning_near_waypoints(samples, n_waypoints: int, samples_per_step: int):
    """``[|turning| within half a step of waypoint k]``: the first half of segment k's samples and the
    second half of segment k - 1's (radians)."""
    near = [0.0] * n_waypoints
    index_in_segment = 0
    for s in samples:
        index_in_segment = 0 if s["first"] else index_in_segment + 1
        k = s["segment"] if index_in_segment < samples_per_step // 2 else s["segment"] + 1
        if k < n_waypoints:
            near[k] += abs(s["turn"])
    return near


def capacity_spill_along(samples, waypoint_pickup, *, capacity: float, lam: float, mu: float,
                         temperature: float, threshold: float, samples_per_step: int = 8, miss: float = 0.0,
                         turn_saturation: float = math.inf):
    """``(delivered, [spill per sample])`` along ``samples`` (``reference.execute.catmull_rom_samples``
    with ``samples_per_step`` samples per segment).

    waypoint_pickup: objects picked up at each waypoint (at the first sample of its segment).
    """
    near = turning_near_waypoints(samples, len(waypoint_pickup), samples_per_step)
    load = 0.0
    spills = []
    prev = None
    for s in samples:
        dl = 0.0 if prev is None else math.hypot(*(s["pos"] - prev))
        prev = s["pos"]
        pick = waypoint_pickup[s["segment"]] if s["first"] else 0.0
        missed = min(1.0, miss * near[s["segment"]]) * pick
        collected = pick - missed
        load += collected
        over = 0.0
        if collected > 0:   # the blade's limit acts where it takes something in
            over = min(max(temperature * _softplus((load - capacity) / temperature), 0.0), load)
        turn_frac = min(1.0, lam * abs(s["turn"]) / (1.0 + load / turn_saturation))   # S = inf: lam |turn|
        frac = 1.0 - (1.0 - turn_frac) * (1.0 - min(1.0, mu * dl))
        spill = over + frac * (load - over)
        if spill < threshold:
            spill = 0.0
        load -= spill
        spills.append(spill + missed)
    return load, spills
