"""Gradient-based tuning of jaxplan's models with optax.

``jaxplan.tune.spill``: fit the spill model's ``SpillParams`` (lambda, threshold) to observed
(route, delivered, spilled) data.
"""
from jaxplan.tune.spill import SpillData, SpillFit, fit_spill, predict_spill, spill_loss, synthetic_spill_data

__all__ = ["SpillData", "SpillFit", "fit_spill", "predict_spill", "spill_loss", "synthetic_spill_data"]
