"""Serial reference of the capacity-aware spill model (``jaxplan.spill_capacity.capacity_spill``).

Plain Python, float64, one sample at a time, written from the module docstring's recurrence.
"""
from __future__ import annotations

import math


def _softplus(x: float) -> float:
    # log(1 + e^x) without overflow for large x
    return x + math.log1p(math.exp(-x)) if x > 0 else math.log1p(math.exp(x))


def capacity_spill_along(samples, waypoint_pickup, *, capacity: float, lam: float, mu: float,
                         temperature: float, threshold: float):
    """``(delivered, [spill per sample])`` along ``samples`` (``reference.execute.catmull_rom_samples``).

    waypoint_pickup: objects picked up at each waypoint (at the first sample of its segment).
    """
    load = 0.0
    spills = []
    prev = None
    for s in samples:
        dl = 0.0 if prev is None else math.hypot(*(s["pos"] - prev))
        prev = s["pos"]
        pick = waypoint_pickup[s["segment"]] if s["first"] else 0.0
        load += pick
        over = 0.0
        if pick > 0:
            over = min(max(temperature * _softplus((load - capacity) / temperature), 0.0), load)
        frac = 1.0 - (1.0 - min(1.0, lam * abs(s["turn"]))) * (1.0 - min(1.0, mu * dl))
        spill = over + frac * (load - over)
        if spill < threshold:
            spill = 0.0
        load -= spill
        spills.append(spill)
    return load, spills
