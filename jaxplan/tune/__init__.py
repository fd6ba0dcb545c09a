"""Gradient-based tuning of jaxplan's models with optax.

``jaxplan.tune.spill``: fit the spill model's ``SpillParams`` (lambda, threshold) to observed
(route, delivered, spilled) data, or the learned spill model's network to your rover's rollouts
(``fit_learned``: give rollouts, get ``LearnedSpillParams``).
``jaxplan.tune.fabric``: tune the fabric's ``theta_tol``, ``tau_h`` and anchor ``lambda`` through the
soft kernels (``FabricParams(temperature=...)``) and check the result with the hard episode loop.
``jaxplan.tune.ranking``: fit PushAround's gap-ranking weights (``RankingParams``: lambda_t, lambda_p,
eta of Eqs. 8-9) to the search's own records (``plan_pushes(..., record=True)``) by a listwise loss.
"""
from jaxplan.tune import fabric
from jaxplan.tune.fabric import gradient_probe
from jaxplan.tune.ranking import (
    RankingData,
    RankingFit,
    fit_ranking,
    ranking_data,
    ranking_logits,
    ranking_loss,
    synthetic_ranking_data,
)
from jaxplan.tune.spill import (
    LearnedFit,
    SpillData,
    SpillFit,
    fit_learned,
    fit_spill,
    learned_loss,
    predict_spill,
    spill_loss,
    synthetic_spill_data,
)

__all__ = ["fabric", "gradient_probe", "RankingData", "RankingFit", "SpillData", "SpillFit", "fit_ranking",
           "fit_learned", "fit_spill", "LearnedFit", "learned_loss", "predict_spill", "ranking_data", "ranking_logits",
           "ranking_loss", "spill_loss",
           "synthetic_ranking_data", "synthetic_spill_data"]
