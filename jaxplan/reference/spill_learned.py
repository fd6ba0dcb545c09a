"""Serial reference of the learned spill model (``jaxplan.transport.spillage.learned.learned_spill``).

Plain Python and NumPy, float64, one sample at a time, written from the module docstring: the
features of every sample, the network on each, then the recurrence along the route.
"""
from __future__ import annotations

import math

import numpy as np

from jaxplan.reference.spill_capacity import turning_near_waypoints

LOAD_SCALE = 10.0
LENGTH_SCALE = 10.0
DISTANCE_CAP = 2.5


def _softplus(x: float) -> float:
    return x + math.log1p(math.exp(-x)) if x > 0 else math.log1p(math.exp(x))


def _sigmoid(x: float) -> float:
    return 1.0 / (1.0 + math.exp(-x)) if x >= 0 else math.exp(x) / (1.0 + math.exp(x))


def sample_features(samples, waypoint_pickup, samples_per_step: int):
    """``([[7 features] per sample], [chord per sample])`` in ``learned.FEATURES`` order."""
    m = samples_per_step
    n = len(samples)
    near = turning_near_waypoints(samples, len(waypoint_pickup), m)
    chords, prev = [], None
    for s in samples:
        chords.append(0.0 if prev is None else math.hypot(*(s["pos"] - prev)))
        prev = s["pos"]
    total = sum(chords)
    feats, done = [], 0.0
    for i, s in enumerate(samples):
        done += chords[i]
        window = range(max(0, i - m), min(n, i + m + 1))
        pick = waypoint_pickup[s["segment"]] if s["first"] else 0.0
        feats.append([abs(s["turn"]) * m, sum(abs(samples[j]["turn"]) for j in window),
                      abs(sum(samples[j]["turn"] for j in window)), pick / LOAD_SCALE, near[s["segment"]],
                      min((total - done) / LENGTH_SCALE, DISTANCE_CAP), min(done / LENGTH_SCALE, DISTANCE_CAP)])
    return feats, chords


def learned_spill_along(samples, waypoint_pickup, *, w1, b1, w2, b2, load_w, threshold: float = 0.0,
                        samples_per_step: int = 8):
    """``(delivered, [spill per sample])`` along ``samples`` (``reference.execute.catmull_rom_samples``)."""
    feats, chords = sample_features(samples, waypoint_pickup, samples_per_step)
    w1, b1, w2, b2 = (np.asarray(a, np.float64) for a in (w1, b1, w2, b2))
    load, spills = 0.0, []
    for s, f, dl in zip(samples, feats, chords):
        hidden = [math.tanh(sum(f[k] * w1[k, j] for k in range(len(f))) + b1[j]) for j in range(len(b1))]
        out = [sum(hidden[j] * w2[j, o] for j in range(len(b1))) + b2[o] for o in range(3)]
        pick = waypoint_pickup[s["segment"]] if s["first"] else 0.0
        missed = _sigmoid(out[2]) * pick if pick > 0 else 0.0
        load += pick - missed
        x = load / LOAD_SCALE
        rate = dl * _softplus(out[0] + float(load_w[0]) * x) + abs(s["turn"]) * _softplus(out[1] + float(load_w[1]) * x)
        spill = load * -math.expm1(-rate)
        if spill < threshold:
            spill = 0.0
        load -= spill
        spills.append(spill + missed)
    return load, spills
