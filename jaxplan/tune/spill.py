"""Fit the spill model (``SpillParams.lam``, ``.threshold``) to observed routes by gradient descent.

Observations are routes given as waypoints (as ``execute.waypoints`` makes them: cell centres, world
units), the objects picked up at each waypoint, and the measured delivered and spilled mass. The model
is ``spillage.evaluate_route`` with the soft threshold (``SpillParams.temperature > 0``), so the loss is
differentiable in both parameters. The temperature is a fixed property of the model being fitted (not
fitted itself); the parameters are optimised in log space (both are positive) with optax's Adam, then
polished with optax's L-BFGS, each phase one ``lax.scan`` under ``jit``.

Loss: the mean over routes of ``(delivered_pred - delivered_obs)^2 + (spilled_pred - spilled_obs)^2``
divided by the mean collected mass squared (dimensionless, so one learning rate fits any load scale).
"""
from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxplan.transport.spillage import (
    FEATURES,
    LearnedSpillParams,
    SpillParams,
    evaluate_route,
    validate_learned_params,
    validate_spill_params,
)

_DIRS = np.array([(1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1)], np.float32)


class SpillData(NamedTuple):
    """Observed routes, B of them, S waypoint slots each.

    waypoints: f32[B, S, 2], world (x, y); rows past ``n_points`` ignored.
    n_points: i32[B], waypoints used (>= 2 for a route that moves).
    pickup: f32[B, S], objects picked up at each waypoint (0 at the final target waypoint).
    delivered: f32[B], objects delivered (observed).  spilled: f32[B], objects spilled (observed).
    """

    waypoints: jax.Array
    n_points: jax.Array
    pickup: jax.Array
    delivered: jax.Array
    spilled: jax.Array


class SpillFit(NamedTuple):
    """Result of ``fit_spill``.

    params: the fitted ``SpillParams`` (lam, threshold as f32[]; temperature and statics as given).
    losses: f32[steps + polish_steps], the loss at each step (before that step's update).
    trajectory: f32[steps + polish_steps, 2], (lam, threshold) at each step.
    """

    params: SpillParams
    losses: jax.Array
    trajectory: jax.Array


def predict_spill(params: SpillParams, data: SpillData):
    """``(delivered f32[B], spilled f32[B])`` objects predicted by the spill model for ``data``'s routes."""
    def one(points, n, pickup):
        delivered, spill, _ = evaluate_route(points, n, pickup, params)
        return delivered, jnp.sum(spill)

    return jax.vmap(one)(data.waypoints, data.n_points, data.pickup)


def spill_loss(params: SpillParams, data: SpillData):
    """f32[], dimensionless: squared errors of delivered and spilled mass over the mean collected mass^2."""
    delivered, spilled = predict_spill(params, data)
    scale = jnp.maximum(jnp.mean(jnp.sum(data.pickup, -1)), 1e-6)
    err = (delivered - data.delivered) ** 2 + (spilled - data.spilled) ** 2
    return jnp.mean(err) / scale ** 2


def _validate(data: SpillData, init: SpillParams, steps, learning_rate):
    validate_spill_params(init)
    _validate_data(data)
    for name in ("lam", "threshold"):
        if not float(np.asarray(getattr(init, name))) > 0:
            raise ValueError(f"init.{name}: the fit works in log space and needs a start > 0; "
                             f"got {getattr(init, name)!r}.")
    _validate_schedule(steps, learning_rate)


def _validate_data(data: SpillData):
    if not isinstance(data, SpillData):
        raise ValueError(f"data: expected a SpillData, got {type(data).__name__}. "
                         "Build one with jaxplan.tune.SpillData(waypoints, n_points, pickup, delivered, spilled).")
    b = np.shape(data.n_points)[0] if np.ndim(data.n_points) else 0
    if b < 1 or np.shape(data.waypoints)[:1] != (b,) or np.shape(data.delivered) != (b,):
        raise ValueError("data: waypoints [B, S, 2], n_points [B], pickup [B, S], delivered [B] and spilled [B] "
                         f"must share B >= 1; got n_points shape {np.shape(data.n_points)}, waypoints "
                         f"{np.shape(data.waypoints)}, delivered {np.shape(data.delivered)}.")


def _validate_schedule(steps, learning_rate):
    if not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ValueError(f"steps: must be an int >= 1; got {steps!r}.")
    if not float(learning_rate) > 0:
        raise ValueError(f"learning_rate: must be > 0; got {learning_rate!r}.")


def fit_spill(data: SpillData, init: SpillParams | None = None, *, steps: int = 300,
              learning_rate: float = 0.1, polish_steps: int = 50) -> SpillFit:
    """Fit ``lam`` and ``threshold`` of ``init`` (its temperature and statics are kept) to ``data``.

    Two phases on ``log(lam), log(threshold)``: ``steps`` of Adam (learning rate cosine-decayed from
    ``learning_rate`` to 1% of it) find the valley from a rough start, then ``polish_steps`` of optax's
    L-BFGS (zoom line search) walk along it: lam and threshold trade off against each other, a narrow
    curved valley where Adam alone crawls. Use ``init.temperature > 0`` for a gradient in the
    threshold (at 0 the threshold's gradient is 0 almost everywhere and only ``lam`` moves). Start the
    threshold at or above its expected size (default 0.1 objects): far below the per-sample spills the
    sigmoid saturates, its gradient vanishes and the fit can settle at threshold ~ 0.
    """
    init = SpillParams(lam=0.1, threshold=0.1, temperature=0.01) if init is None else init
    _validate(data, init, steps, learning_rate)
    if not isinstance(polish_steps, (int, np.integer)) or polish_steps < 0:
        raise ValueError(f"polish_steps: must be an int >= 0; got {polish_steps!r}.")
    data = SpillData(*(jnp.asarray(x) for x in data))
    return _fit_jit(data, init, int(steps), float(learning_rate), int(polish_steps))


def _fit(data, init, steps, learning_rate, polish_steps):
    theta0 = jnp.log(jnp.stack([jnp.asarray(init.lam, jnp.float32), jnp.asarray(init.threshold, jnp.float32)]))

    def params_of(theta):
        return init.replace(lam=jnp.exp(theta[0]), threshold=jnp.exp(theta[1]))

    def loss_of(theta):
        return spill_loss(params_of(theta), data)

    adam = optax.adam(optax.cosine_decay_schedule(learning_rate, steps, alpha=0.01))

    def adam_step(carry, _):
        theta, state = carry
        loss, grad = jax.value_and_grad(loss_of)(theta)
        updates, state = adam.update(grad, state, theta)
        return (optax.apply_updates(theta, updates), state), (loss, jnp.exp(theta))

    (theta, _), (losses, traj) = jax.lax.scan(adam_step, (theta0, adam.init(theta0)), None, length=steps)

    lbfgs = optax.lbfgs()
    value_and_grad = optax.value_and_grad_from_state(loss_of)

    def lbfgs_step(carry, _):
        theta, state = carry
        loss, grad = value_and_grad(theta, state=state)
        updates, state = lbfgs.update(grad, state, theta, value=loss, grad=grad, value_fn=loss_of)
        return (optax.apply_updates(theta, updates), state), (loss, jnp.exp(theta))

    (theta, _), (losses2, traj2) = jax.lax.scan(lbfgs_step, (theta, lbfgs.init(theta)), None, length=polish_steps)
    return SpillFit(params_of(theta), jnp.concatenate([losses, losses2]), jnp.concatenate([traj, traj2]))


_fit_jit = jax.jit(_fit, static_argnums=(2, 3, 4))


def synthetic_routes(seed: int, n_routes: int, n_points: int = 12, max_count: int = 6):
    """Random 8-neighbour grid walks: ``(waypoints f32[B, S, 2], n_points i32[B], pickup f32[B, S])``.

    Each walk turns by 0 or +-45 degrees (sometimes +-90) at each cell, so routes cover a range of
    curvatures; route lengths vary between 4 and ``n_points`` waypoints; every waypoint but the last
    picks up 0..``max_count`` objects (the last is the target and carries nothing).
    """
    rng = np.random.default_rng(seed)
    way = np.zeros((n_routes, n_points, 2), np.float32)
    pickup = np.zeros((n_routes, n_points), np.float32)
    counts = rng.integers(4, n_points + 1, n_routes).astype(np.int32)
    for b in range(n_routes):
        d = rng.integers(8)
        pos = np.array([0.5, 0.5], np.float32)
        for i in range(n_points):
            way[b, i] = pos
            d = (d + rng.choice([-2, -1, 0, 0, 0, 1, 2], p=[.05, .2, .25, .25, 0, .2, .05])) % 8
            pos = pos + _DIRS[d]
        pickup[b, :counts[b] - 1] = rng.integers(0, max_count + 1, counts[b] - 1)
    return way, counts, pickup


def synthetic_spill_data(true: SpillParams, seed: int = 0, n_routes: int = 64, noise: float = 0.0,
                         n_points: int = 12) -> SpillData:
    """Routes from ``synthetic_routes`` observed under the model ``true``, plus noise.

    noise: relative standard deviation of independent gaussian noise on each route's delivered and
    spilled mass (``obs = model * (1 + noise * N(0, 1))``); 0 = clean data.
    """
    if not float(noise) >= 0:
        raise ValueError(f"noise: must be >= 0 (a relative standard deviation); got {noise!r}.")
    way, counts, pickup = synthetic_routes(seed, n_routes, n_points)
    clean = SpillData(jnp.asarray(way), jnp.asarray(counts), jnp.asarray(pickup), jnp.zeros(n_routes),
                      jnp.zeros(n_routes))
    delivered, spilled = (np.asarray(x, np.float64) for x in jax.jit(predict_spill)(true, clean))
    rng = np.random.default_rng(seed + 1)
    delivered = delivered * (1 + noise * rng.standard_normal(n_routes))
    spilled = spilled * (1 + noise * rng.standard_normal(n_routes))
    return clean._replace(delivered=jnp.asarray(delivered, jnp.float32), spilled=jnp.asarray(spilled, jnp.float32))


class LearnedFit(NamedTuple):
    """Result of ``fit_learned``.

    params: the fitted ``LearnedSpillParams``.  losses: f32[steps], the training loss at each step
    (before that step's update).
    """

    params: LearnedSpillParams
    losses: np.ndarray


def learned_loss(params: SpillParams, data: SpillData, delta: float = 0.1):
    """f32[], dimensionless: the mean Huber loss (``delta``) of ``log(1 + delivered)`` predicted against
    observed, over ``data``'s routes. A relative error, as the targets are (within 10% of physics);
    the Huber tail keeps a few routes that physics delivers almost nothing of (the load pushed past a
    thin target) from pulling the fit."""
    delivered, _ = predict_spill(params, data)
    err = jnp.log1p(jnp.maximum(delivered, 0.0)) - jnp.log1p(data.delivered)
    return jnp.mean(optax.huber_loss(err, delta=delta))


def _initial_learned(hidden: int, seed: int, base: LearnedSpillParams) -> LearnedSpillParams:
    k1, k2 = jax.random.split(jax.random.PRNGKey(seed))
    f = len(FEATURES)
    return base.replace(w1=0.3 * jax.random.normal(k1, (f, hidden)), b1=jnp.zeros(hidden),
                        w2=0.1 * jax.random.normal(k2, (hidden, 3)), b2=jnp.asarray(base.b2, jnp.float32),
                        load_w=jnp.zeros(2))


def fit_learned(data: SpillData, *, hidden: int = 8, steps: int = 1500, learning_rate: float = 0.01,
                seed: int = 0, init: LearnedSpillParams | None = None, chunk: int = 100,
                progress: bool = False) -> LearnedFit:
    """Fit the learned spill model to observed routes (``data``: e.g. MuJoCo rollouts of your rover).

    Adam (optax) on ``learned_loss`` for ``steps`` steps, its learning rate cosine-decayed from
    ``learning_rate`` to 5% of it, from random weights (``seed``, ``hidden`` units) or from ``init``.
    The steps run ``chunk`` at a time in one jitted ``lax.scan`` each, with a progress bar when
    ``progress``. Give it routes of many scenes: the network has ~100 weights.
    """
    from tqdm.auto import tqdm

    _validate_data(data)
    _validate_schedule(steps, learning_rate)
    for name, value in (("hidden", hidden), ("chunk", chunk)):
        if not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{name}: must be an int >= 1; got {value!r}.")
    params = _initial_learned(int(hidden), int(seed), LearnedSpillParams()) if init is None else init
    validate_learned_params(params)
    data = SpillData(*(jnp.asarray(x) for x in data))
    opt = _learned_adam(float(learning_rate), int(steps))
    state = opt.init(params)
    losses = []
    with tqdm(total=int(steps), desc="fit", disable=not progress) as bar:
        done = 0
        while done < steps:
            n = min(int(chunk), int(steps) - done)
            params, state, part = _learned_steps(params, state, data, opt, n)
            losses.append(np.asarray(part))
            done += n
            bar.update(n)
    return LearnedFit(params, np.concatenate(losses))


@functools.cache
def _learned_adam(learning_rate: float, steps: int) -> optax.GradientTransformation:
    # one optimiser object per schedule: it is a static argument of _learned_steps, so a new object
    # each call would compile the steps again
    return optax.adam(optax.cosine_decay_schedule(learning_rate, steps, alpha=0.05))


@jax.jit(static_argnums=(3, 4))
def _learned_steps(params, state, data, opt, n):
    def step(carry, _):
        params, state = carry
        loss, grad = jax.value_and_grad(learned_loss)(params, data)
        updates, state = opt.update(grad, state, params)
        return (optax.apply_updates(params, updates), state), loss
    (params, state), losses = jax.lax.scan(step, (params, state), None, length=n)
    return params, state, losses
