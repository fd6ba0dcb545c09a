"""Fit the gap-ranking weights of Eqs. 8-9 (``lambda_t``, ``lambda_p``, ``eta``) to what the search learnt.

Data: the search's gap recorder (``plan_pushes(..., record=True)``) keeps, per expansion, the node's
targets with the Eq. 8-9 terms of their costs and, after the search, the target that led to the
solution. :func:`ranking_data` stacks the labelled expansions into a padded :class:`RankingData`.

Model and loss (listwise): at expansion e the search should try first the gap that leads to the
solution. With ``Cost_e = gap_costs(params, features_e)`` (Eq. 9 through the differentiable
``gap_costs``), the model's choice is ``softmax(-Cost_e / T)`` over the expansion's gaps and the loss
is the cross-entropy to the label distribution (``target``), averaged over expansions with their
``weight``::

    loss = sum_e w_e * sum_k -target_ek * log_softmax_k(-Cost_ek / T) / sum_e w_e

A ranking sees the weights only up to a common factor (Eq. 9 is linear in them; only the stuck and
dead-end penalties are not), so the fit keeps one weight, by default ``lambda_t``, at its initial
value: it sets the unit of ``Cost`` and with it the balance of Eq. 10 between the realised cost
``chi`` and the estimate. The others and the temperature ``T`` (how deterministic the labels are,
in cost units) are fitted in log space (all positive) with optax's Adam, one ``lax.scan`` under
``jit``.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxplan.pusharound import PresearchFeatures, RankingParams, gap_costs, validate_ranking_params

__all__ = ["WEIGHTS", "RankingData", "RankingFit", "fit_ranking", "ranking_data", "ranking_logits", "ranking_loss",
           "synthetic_ranking_data", "validate_ranking_data"]

# The traced weights of RankingParams a fit may move.
WEIGHTS = ("lambda_t", "lambda_p", "eta")
# The logit of a padded gap slot: far below any real one, finite so that 0 * logit stays 0.
_PAD_LOGIT = -1e9


class RankingData(NamedTuple):
    """E expansions with at most K gaps and P presearch leaves per gap (padded).

    features: :class:`PresearchFeatures` stacked over expansions: first f32[E, K, 2], tail
    f32[E, K, P, 3], mask bool[E, K, P], penalty f32[E, K] (``gap_costs`` of row e is Eq. 9 at
    expansion e). valid: bool[E, K] the real gaps (padded slots False). target: f32[E, K] >= 0 the
    label distribution over the valid gaps (the gaps that led to the solution; each row sums to 1).
    weight: f32[E] >= 0 the expansions' weights in the loss.
    """

    features: PresearchFeatures
    valid: Any
    target: Any
    weight: Any


class RankingFit(NamedTuple):
    """Result of :func:`fit_ranking`. params: the fitted ``RankingParams`` (weights as floats; beam,
    depth and mass_ref of ``init``); temperature: the fitted ``T`` [cost units]; losses: f32[steps]
    the loss before each step; trajectory: f32[steps, 4] (lambda_t, lambda_p, eta, T) before each
    step."""

    params: RankingParams
    temperature: float
    losses: Any
    trajectory: Any


# ---------------------------------------------------------------------------------------------------
# Data
# ---------------------------------------------------------------------------------------------------

def ranking_data(records: Sequence, *, weights: Sequence | None = None) -> RankingData:
    """Stack the labelled expansions of ``records`` (``ExpansionRecord``s of one or many searches:
    those with a solution target; the others carry no label and are skipped) into a
    :class:`RankingData`. weights: one per record (default 1), e.g. to weigh searches or scenes.
    Raises ValueError when no record is labelled."""
    records = list(records)
    w_all = np.ones(len(records)) if weights is None else np.asarray(weights, np.float64)
    if w_all.shape != (len(records),):
        raise ValueError(f"weights: need one per record ({len(records)}); got shape {w_all.shape}.")
    keep = [(r, w) for r, w in zip(records, w_all) if np.any(np.asarray(r.solution)) and len(r.cost) > 0]
    if not keep:
        raise ValueError("records: no expansion is labelled with a solution target (record searches that "
                         "succeeded: plan_pushes(..., record=True)).")
    e = len(keep)
    k = max(len(r.cost) for r, _ in keep)
    p = max(r.features.tail.shape[1] for r, _ in keep)
    first = np.zeros((e, k, 2), np.float32)
    tail = np.zeros((e, k, p, 3), np.float32)
    mask = np.zeros((e, k, p), bool)
    mask[:, :, 0] = True       # padded gaps: one zero leaf, a finite cost (finite gradients)
    penalty = np.zeros((e, k), np.float32)
    valid = np.zeros((e, k), bool)
    target = np.zeros((e, k), np.float32)
    for i, (r, _) in enumerate(keep):
        f = r.features
        n, q = f.tail.shape[:2]
        first[i, :n], penalty[i, :n], valid[i, :n] = f.first, f.penalty, True
        tail[i, :n, :q], mask[i, :n] = f.tail, False
        mask[i, :n, :q] = f.mask
        sol = np.asarray(r.solution, np.float32)
        target[i, :n] = sol / sol.sum()
    feats = PresearchFeatures(jnp.asarray(first), jnp.asarray(tail), jnp.asarray(mask), jnp.asarray(penalty))
    return RankingData(feats, jnp.asarray(valid), jnp.asarray(target),
                       jnp.asarray(np.array([w for _, w in keep], np.float32)))


def synthetic_ranking_data(params: RankingParams, temperature: float, *, seed: int = 0, n_expansions: int = 512,
                           n_gaps: int = 6, n_leaves: int = 3) -> RankingData:
    """Expansions with random Eq. 8-9 terms and a label drawn from the model itself.

    Per expansion: 2..``n_gaps`` gaps, each with C_t ~ U(0, 5) m, C_p ~ U(0, 1.5) and 1..``n_leaves``
    presearch leaves of (sum C_t ~ U(0, 8) m, sum C_p ~ U(0, 3), sum h / eta ~ U(0, 15) m); the label
    is one gap drawn from ``softmax(-gap_costs(params, .) / temperature)`` (Gumbel-max), so the fit
    of :func:`fit_ranking` is a maximum-likelihood fit of a well-specified model.
    """
    validate_ranking_params(params)
    if not float(temperature) > 0:
        raise ValueError(f"temperature: must be > 0; got {temperature!r}.")
    for name, v, lo in (("n_expansions", n_expansions, 1), ("n_gaps", n_gaps, 2), ("n_leaves", n_leaves, 1)):
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < lo:
            raise ValueError(f"{name}: must be an int >= {lo}; got {v!r}.")
    rng = np.random.default_rng(seed)
    e, k, p = n_expansions, n_gaps, n_leaves
    valid = np.arange(k)[None, :] < rng.integers(2, k + 1, e)[:, None]
    first = np.stack([rng.uniform(0, 5, (e, k)), rng.uniform(0, 1.5, (e, k))], -1)
    tail = np.stack([rng.uniform(0, 8, (e, k, p)), rng.uniform(0, 3, (e, k, p)), rng.uniform(0, 15, (e, k, p))], -1)
    mask = np.arange(p)[None, None, :] < rng.integers(1, p + 1, (e, k))[..., None]
    first, tail = np.where(valid[..., None], first, 0), np.where(valid[..., None, None], tail, 0)
    mask = np.where(valid[..., None], mask, np.arange(p) == 0)
    feats = PresearchFeatures(jnp.asarray(first, jnp.float32), jnp.asarray(tail, jnp.float32), jnp.asarray(mask),
                              jnp.zeros((e, k), jnp.float32))
    cost = np.asarray(jax.vmap(gap_costs, in_axes=(None, 0))(params, feats), np.float64)
    noisy = np.where(valid, -cost / float(temperature) + rng.gumbel(size=(e, k)), -np.inf)
    target = np.eye(k, dtype=np.float32)[np.argmax(noisy, axis=1)]
    return RankingData(feats, jnp.asarray(valid), jnp.asarray(target), jnp.ones(e, jnp.float32))


def validate_ranking_data(data: RankingData) -> None:
    """Raise ValueError naming the first malformed field of ``data``."""
    if not isinstance(data, RankingData):
        raise ValueError(f"data: expected a RankingData (jaxplan.tune.ranking_data(records)); "
                         f"got {type(data).__name__}.")
    if not isinstance(data.features, PresearchFeatures):
        raise ValueError(f"data.features: expected a PresearchFeatures; got {type(data.features).__name__}.")
    first = np.asarray(data.features.first)
    if first.ndim != 3 or first.shape[2] != 2 or first.shape[0] < 1 or first.shape[1] < 1:
        raise ValueError(f"data.features.first: expected shape [E, K, 2] with E, K >= 1; got {first.shape}.")
    e, k = first.shape[:2]
    tail = np.asarray(data.features.tail)
    if tail.ndim != 4 or tail.shape[:2] != (e, k) or tail.shape[3] != 3 or tail.shape[2] < 1:
        raise ValueError(f"data.features.tail: expected shape [E, K, P, 3] = [{e}, {k}, P >= 1, 3]; got {tail.shape}.")
    expect = {"features.mask": (e, k, tail.shape[2]), "features.penalty": (e, k), "valid": (e, k),
              "target": (e, k), "weight": (e,)}
    for name, shape in expect.items():
        v = np.asarray(data.features.mask if name == "features.mask" else
                       data.features.penalty if name == "features.penalty" else getattr(data, name))
        if v.shape != shape:
            raise ValueError(f"data.{name}: expected shape {list(shape)}; got {list(v.shape)}.")
    if not np.all(np.isfinite(np.asarray(data.features.penalty))):
        raise ValueError("data.features.penalty: must be finite.")
    for name, v in (("features.first", first), ("features.tail", tail), ("target", np.asarray(data.target)),
                    ("weight", np.asarray(data.weight))):
        if not np.all(np.isfinite(v)) or np.any(v < 0):
            raise ValueError(f"data.{name}: must be finite and >= 0.")
    valid, mask = np.asarray(data.valid, bool), np.asarray(data.features.mask, bool)
    if not np.all(np.any(mask, axis=2)):
        raise ValueError("data.features.mask: every gap slot (padding too) needs at least one leaf in the "
                         "minimum (padding: one zero leaf).")
    target = np.asarray(data.target)
    if np.any(target[~valid] > 0):
        raise ValueError("data.target: puts weight on a padded gap slot (valid False).")
    sums = target.sum(axis=1)
    used = np.asarray(data.weight) > 0
    if not np.any(used) or not np.allclose(sums[used], 1.0, atol=1e-4):
        raise ValueError("data.target: every expansion with weight > 0 needs a label distribution summing to 1 "
                         "(and at least one expansion needs weight > 0).")


# ---------------------------------------------------------------------------------------------------
# Model and loss
# ---------------------------------------------------------------------------------------------------

def ranking_logits(params: RankingParams, data: RankingData, temperature):
    """f[E, K]: ``-Cost / T`` per gap (padded slots: a large negative constant). Pure JAX in the
    weights and ``temperature``."""
    cost = jax.vmap(gap_costs, in_axes=(None, 0))(params, data.features)
    return jnp.where(data.valid, -cost / temperature, _PAD_LOGIT)


def ranking_loss(params: RankingParams, data: RankingData, temperature):
    """f[]: the weighted listwise cross-entropy of the module docstring (nats per expansion)."""
    logp = jax.nn.log_softmax(ranking_logits(params, data, temperature), axis=-1)
    per = -jnp.sum(data.target * logp, axis=-1)
    return jnp.sum(data.weight * per) / jnp.maximum(jnp.sum(data.weight), 1e-12)


def fit_ranking(data: RankingData, init: RankingParams | None = None, *, fit: Sequence = ("lambda_p", "eta"),
                temperature: float = 1.0, steps: int = 400, learning_rate: float = 0.05) -> RankingFit:
    """Fit the weights named in ``fit`` (of :data:`WEIGHTS`) and the temperature to ``data``.

    The others keep ``init``'s values (default ``RankingParams()``, the paper's weights; fitting all
    three leaves their common factor to the temperature's trade-off, see the module docstring).
    temperature: the start of ``T`` [cost units]. ``steps`` of Adam on the logs, the learning rate
    cosine-decayed from ``learning_rate`` to 1% of it. Raises ValueError naming a malformed argument
    or field of ``data``.
    """
    init = RankingParams() if init is None else init
    validate_ranking_params(init)
    validate_ranking_data(data)
    fit = tuple(fit)
    bad = [w for w in fit if w not in WEIGHTS]
    if bad or len(set(fit)) != len(fit):
        raise ValueError(f"fit: names among {list(WEIGHTS)}, each once; got {list(fit)}.")
    if not (isinstance(temperature, (int, float, np.floating, np.integer)) and np.isfinite(temperature)
            and temperature > 0):
        raise ValueError(f"temperature: must be a finite number > 0; got {temperature!r}.")
    if not isinstance(steps, (int, np.integer)) or isinstance(steps, bool) or steps < 1:
        raise ValueError(f"steps: must be an int >= 1; got {steps!r}.")
    if not (isinstance(learning_rate, (int, float, np.floating)) and learning_rate > 0):
        raise ValueError(f"learning_rate: must be a number > 0; got {learning_rate!r}.")
    free = jnp.asarray([w in fit for w in WEIGHTS] + [True], jnp.float32)
    start = jnp.log(jnp.asarray([float(np.asarray(getattr(init, w))) for w in WEIGHTS] + [float(temperature)],
                                jnp.float32))
    data = RankingData(PresearchFeatures(*(jnp.asarray(x) for x in data.features)),
                       *(jnp.asarray(x) for x in data[1:]))
    theta, losses, traj = _fit_jit(data, start, free, init, int(steps), float(learning_rate))
    values = np.exp(np.asarray(theta, np.float64))
    params = init.replace(**{w: float(values[i]) for i, w in enumerate(WEIGHTS)})
    return RankingFit(params, float(values[3]), losses, traj)


def _params_of(theta, init: RankingParams) -> tuple:
    v = jnp.exp(theta)
    return init.replace(lambda_t=v[0], lambda_p=v[1], eta=v[2]), v[3]


def _fit(data, theta0, free, init, steps, learning_rate):
    def loss_of(theta):
        params, t = _params_of(theta, init)
        return ranking_loss(params, data, t)

    adam = optax.adam(optax.cosine_decay_schedule(learning_rate, steps, alpha=0.01))

    def step(carry, _):
        theta, state = carry
        loss, grad = jax.value_and_grad(loss_of)(theta)
        updates, state = adam.update(grad * free, state, theta)
        return (optax.apply_updates(theta, updates * free), state), (loss, jnp.exp(theta))

    (theta, _), (losses, traj) = jax.lax.scan(step, (theta0, adam.init(theta0)), None, length=steps)
    return theta, losses, traj


_fit_jit = jax.jit(_fit, static_argnums=(4, 5))
