"""Gradient-based tuning of jaxplan's models with optax.

``jaxplan.tune.spill``: fit the spill model's ``SpillParams`` (lambda, threshold) to observed
(route, delivered, spilled) data.
``jaxplan.tune.fabric``: tune the fabric's ``theta_tol``, ``tau_h`` and anchor ``lambda`` through the
soft kernels (``FabricParams(temperature=...)``) and check the result with the hard episode loop.
"""
from jaxplan.tune import fabric
from jaxplan.tune.spill import SpillData, SpillFit, fit_spill, predict_spill, spill_loss, synthetic_spill_data

__all__ = ["fabric", "SpillData", "SpillFit", "fit_spill", "predict_spill", "spill_loss", "synthetic_spill_data"]
