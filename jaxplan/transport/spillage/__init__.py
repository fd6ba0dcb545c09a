"""Spill models: how much of a pushed load is lost along a route (Section 3.2).

``base`` holds what every model shares: ``SpillParams``, the route spline, the ``Evaluator``
signature and the registry of models by name (``register``, ``evaluator_for``). ``curvature`` is the
paper's model, ``capacity`` the capacity-aware one, ``fit`` fits the latter to observed deliveries,
and ``learned`` is a model whose loss rates a small network sets, fitted to the MuJoCo rover by
gradient (``LEARNED_FIT``; ``jaxplan.tune.fit_learned`` fits it to another rover). A new model is
one module plus one ``register`` call.
"""
from jaxplan.transport.spillage.base import (
    CENTRIPETAL,
    EVALUATORS,
    Evaluator,
    PathSamples,
    SpillParams,
    chord_lengths,
    evaluate_route,
    evaluator_for,
    pickups_per_sample,
    register,
    sample_route,
    sample_route_prefix,
    threshold_spill,
    validate_spill_params,
)
from jaxplan.transport.spillage.capacity import ROVER_FIT, CapacitySpillParams, capacity_spill, validate_capacity_params
from jaxplan.transport.spillage.curvature import curvature_spill
from jaxplan.transport.spillage.fit import (
    FIT_FIELDS,
    FIT_GRID,
    fit_capacity,
    fit_miss,
    predict_delivered,
    predict_missed,
)
from jaxplan.transport.spillage.learned import (
    FEATURES,
    LEARNED_FIT,
    LearnedSpillParams,
    learned_spill,
    load_learned,
    validate_learned_params,
)

# The spill models fitted to the MuJoCo rover, by name (``--spill-model`` of the CLI): the learned
# model (the default where physics checks a plan) and the capacity model's fit to the built-in scenes.
ROVER_MODELS = {"learned": LEARNED_FIT, "rover-fit": ROVER_FIT}

__all__ = ["CENTRIPETAL", "CapacitySpillParams", "EVALUATORS", "Evaluator", "FEATURES", "FIT_FIELDS", "FIT_GRID",
           "LEARNED_FIT", "LearnedSpillParams", "PathSamples", "ROVER_FIT", "ROVER_MODELS",
           "SpillParams", "capacity_spill", "curvature_spill", "evaluate_route", "evaluator_for", "fit_capacity",
           "fit_miss", "pickups_per_sample", "predict_delivered", "predict_missed", "register", "sample_route",
           "sample_route_prefix", "threshold_spill", "validate_capacity_params", "validate_learned_params",
           "validate_spill_params", "learned_spill", "load_learned", "chord_lengths"]
