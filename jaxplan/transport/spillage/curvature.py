"""The curvature spill model of the paper (Section 3.2): a fraction ``lam`` of the load spills per
radian of turning (``base`` module docstring)."""
from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan.transport.spillage.base import PathSamples, SpillParams, register, threshold_spill

__all__ = ["curvature_spill"]


def curvature_spill(samples: PathSamples, pickup, params: SpillParams):
    """The default ``Spill(P; Theta)``: ``(delivered f32[], spill f32[N])`` in objects.

    pickup: f32[N] objects picked up at each sample. A sequential scan because the load at a sample
    depends on everything spilled before it.
    """
    fraction = jnp.clip(params.lam * jnp.abs(samples.turn), 0.0, 1.0)

    def step(load, x):
        pick, frac = x
        load = load + pick
        spill = frac * load
        spill = threshold_spill(spill, params.threshold, params.temperature)
        return load - spill, spill

    delivered, spill = jax.lax.scan(step, jnp.float32(0.0), (pickup, fraction))
    return delivered, spill


register("curvature", curvature_spill)
