"""Tuning the fabric parameters (theta_tol, tau_H, anchor lambda) by gradient through the soft fabric.

The objective (``soft_efficiency``) is a differentiable stand-in for what an episode achieves: the
soft **delivered mass per unit driven** over the whole job. Every cell's objects are taken to ride on
that cell's own route, which costs its length plus the drive back from the target (``d(C, T)``), so
the job's ratio is the total count over the count-weighted sum of cost per delivered object. For
every occupied source C the soft fabric gives the expected raw mass ``R(C)``, length ``L(C)`` and
first-step distribution, the policy choosing among each source's first steps by predicted delivered
mass (Eq. 6 through the soft fabric, ``build_fabric(..., SpillParams(lam=spill_lam))``, so heat,
highways and anchors depend on the spill lambda); the curvature spill idea (``jaxplan.transport.spillage``: a fraction
``spill_lam`` of the load per radian of turning) turns the policy's expected total turning ``Θ(C)``
into a kept fraction ``exp(-spill_lam Θ(C))``. A root may instead go via a highway (Eq. 12): its
soft anchor weights give the expected via route (straight approach to the anchor, then the
anchor's path), chosen softly when it carries ``(1 + margin)`` times the direct route's mass, as
the episode's Rearrange rule does. Parameters are optimised in an unconstrained space with optax.

``evaluate_hard`` measures the same parameters with the hard episode loop (``jaxplan.run_episode``).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxplan.core import lattice
from jaxplan.transport import FabricParams, Scene, build_fabric, random_scene, stack_scenes
from jaxplan.transport.spillage import SpillParams

TUNED = ("theta_tol_deg", "tau_h", "anchor_lambda")


# ---------------------------------------------------------------------------------------------- scenes


def random_scenes(n: int, shape=(16, 16), seed: int = 0) -> list[Scene]:
    """``n`` scenes of ``jaxplan.random_scene``'s "piles" layout (seeds ``seed * n`` to ``seed * n + n - 1``)."""
    return [random_scene(seed * n + i, shape, layout="piles") for i in range(n)]


# ---------------------------------------------------------------------------------------------- objective


def _turn_matrix() -> np.ndarray:
    """``f64[8, 8]``: the angle (radians) between step directions i and j."""
    unit = lattice.STEP_UNIT.astype(np.float64)
    return np.arccos(np.clip(unit @ unit.T, -1.0, 1.0))


def expected_turning(soft_fabric, scene, rounds: int):
    """``f32[H, W]`` radians: expected total turning of the soft policy's path from every cell.

    ``Θ(C) = sum_i pi_i(C) [N_i continues] (sum_j pi_j(N_i) angle(i, j) + Θ(N_i))``; a fallback
    at N_i turns by the angle between step i and ``t(N_i)``. Fixed ``rounds`` (static).
    """
    policy = jnp.moveaxis(soft_fabric.policy, -1, 0)                       # [9, H, W]
    target = jnp.asarray(scene.target_mask, bool)
    nb_goal = lattice.neighbours(target, False)
    turn = jnp.asarray(_turn_matrix(), jnp.float32)
    unit = jnp.asarray(lattice.STEP_UNIT)
    nb_pol = lattice.neighbours(jnp.moveaxis(policy, 0, -1), 0.0)            # [8 (i), H, W, 9 (j)]
    nb_t = lattice.neighbours(scene.tvec, 0.0)                               # [8, H, W, 2]
    fb_angle = jnp.arccos(jnp.clip(jnp.einsum("ihwx,ix->ihw", nb_t, unit), -1.0, 1.0))
    local = jnp.einsum("ihwj,ij->ihw", nb_pol[..., :8], turn) + nb_pol[..., 8] * fb_angle   # [8, H, W]
    cont = ~nb_goal & (policy[:8] > 0)

    def body(theta, _):
        nb = lattice.neighbours(theta, 0.0)
        return jnp.sum(jnp.where(cont, policy[:8] * (local + nb), 0.0), 0), None

    theta, _ = jax.lax.scan(body, jnp.zeros(target.shape), None, length=rounds)
    return theta


AGGREGATES = ("job", "source")


class ObjectiveConfig(NamedTuple):
    """Static settings of the objective: spill_lam (fraction per radian, as ``SpillParams.lam``),
    rearrange_margin (as ``EpisodeParams``), temperature of the soft kernels (dimensionless,
    docs/transport.md "Soft kernels"; 0.5: the cone gate's logit is ``x / (t^2 CONE_SCALE)``, so
    theta's gradient comes from the steps within a few ``t^2 CONE_SCALE`` cosine of the cone's edge,
    0.0125 at t = 0.5 but 0.0005 at t = 0.1, where the objective is nearly flat in theta).

    approach: charge every route the drive back from the target to its source (``d(C, T)``), as the
    episode's distance driven does. aggregate: ``"job"`` (default) delivered per driven over the
    whole job, i.e. total count over the count-weighted sum of length per delivered object of each
    cell's route (a harmonic mean); ``"source"`` the count-weighted arithmetic mean of each route's
    delivered per length. Both are compared under the hard episodes in
    ``experiments/results/tune_fabric.md``.
    """

    temperature: float = 0.5
    spill_lam: float = 0.05
    rearrange_margin: float = 0.1
    approach: bool = True
    aggregate: str = "job"


def soft_efficiency(scene: Scene, params: FabricParams, config: ObjectiveConfig | None = None, plan_lam=None):
    """``f32[]`` objects per world unit: the soft delivered mass per unit driven (``config.aggregate``).

    params: the (traced) fabric parameters; its temperature is replaced by ``config.temperature``.
    config: None means ``ObjectiveConfig()``. plan_lam: f32[] (traced) the spill lambda the planner
    selects routes with (Eq. 6 through the soft fabric); None means ``config.spill_lam``. The world
    spills with ``config.spill_lam`` whatever the planner assumes.
    """
    if config is None:
        config = ObjectiveConfig()
    if config.aggregate not in AGGREGATES:
        raise ValueError(f"ObjectiveConfig.aggregate: must be one of {AGGREGATES}; got {config.aggregate!r}.")
    t = config.temperature
    # spill through the fabric: Eq. 6 picks each source's first step by predicted delivered mass
    plan_lam = config.spill_lam if plan_lam is None else plan_lam
    f = build_fabric(scene, params.replace(temperature=t), SpillParams(lam=plan_lam))
    obj = jnp.where(f.occupied, jnp.asarray(scene.obj, jnp.float32), 0.0)
    rounds = params.resolved_soft_rounds(obj.shape)
    keep = jnp.exp(-config.spill_lam * expected_turning(f, scene, rounds))
    direct_mass = f.raw * keep
    # the rover drives back from the target to every source it pushes from: charge that approach
    approach = jnp.asarray(scene.dist, jnp.float32) if config.approach else jnp.zeros(obj.shape)
    direct_len = jnp.maximum(f.length + approach, 1e-3)
    # via-highway route: a straight approach to the anchor h, then h's soft path (Section 3.4)
    h, w = obj.shape
    centers = lattice.cell_centers((h, w), scene.cell_size, scene.origin).reshape(-1, 2)
    d = jnp.sqrt(jnp.sum((centers[:, None] - centers[None]) ** 2, -1) + 1e-12).reshape(h, w, h * w)
    wts = f.anchor_weights
    via_mass = obj + jnp.sum(wts * direct_mass.reshape(-1), -1)
    via_len = jnp.maximum(jnp.sum(wts * (d + f.length.reshape(-1)), -1) + approach, 1e-3)
    scale = jnp.maximum(jnp.max(f.raw), 1e-3)
    rearrange = f.root * jnp.sum(wts, -1) * jax.nn.sigmoid(
        (via_mass - (1.0 + config.rearrange_margin) * direct_mass) / (t * scale))
    if config.aggregate == "source":
        eff = (1.0 - rearrange) * direct_mass / direct_len + rearrange * via_mass / via_len
        return jnp.sum(obj * eff) / jnp.maximum(jnp.sum(obj), 1e-6)
    # "job": every cell's objects ride on its own route, so they cost length/mass of that route per
    # object; delivered per driven over the whole job is then a count-weighted harmonic mean
    safe = lambda m: jnp.maximum(m, 1e-3)  # noqa: E731
    cost = (1.0 - rearrange) * direct_len / safe(direct_mass) + rearrange * via_len / safe(via_mass)
    return jnp.sum(obj) / jnp.maximum(jnp.sum(obj * cost), 1e-6)


soft_efficiency_jit = jax.jit(soft_efficiency, static_argnums=2)

SPILL = "spill_lam"   # the planner's spill lambda, tuned with ``fit_fabric(tune_spill=True)``


# ---------------------------------------------------------------------------------------------- fitting


def to_unconstrained(params: FabricParams) -> dict:
    """``{name: f32[]}``: theta in (5, 175) deg via a logit, tau_h in (0, 1) via a logit, lambda >= 0
    via an inverse softplus."""
    logit = lambda p: math.log(p / (1.0 - p))  # noqa: E731
    return dict(theta_tol_deg=jnp.float32(logit((float(params.theta_tol_deg) - 5.0) / 170.0)),
                tau_h=jnp.float32(logit(float(params.tau_h))),
                anchor_lambda=jnp.float32(math.log(math.expm1(max(float(params.anchor_lambda), 1e-4)))))


def from_unconstrained(u: dict, base: FabricParams) -> FabricParams:
    return base.replace(theta_tol_deg=5.0 + 170.0 * jax.nn.sigmoid(u["theta_tol_deg"]),
                        tau_h=jax.nn.sigmoid(u["tau_h"]), anchor_lambda=jax.nn.softplus(u["anchor_lambda"]))


class FitResult(NamedTuple):
    """params: the tuned FabricParams (floats); history: one dict per step (objective, parameters);
    spill_lam: the tuned planner spill lambda (``tune_spill``), else None."""

    params: FabricParams
    history: list
    spill_lam: float | None = None


def fit_fabric(scenes: list[Scene], init: FabricParams | None = None, *, steps: int = 60,
               learning_rate: float = 0.05, config: ObjectiveConfig | None = None,
               on_step: Callable[[int, dict], None] | None = None, tune_spill: bool = False) -> FitResult:
    """Maximise the mean ``soft_efficiency`` over ``scenes`` (one shape) with optax Adam.

    Returns the tuned parameters and the loss curve (``history[i]["objective"]``, the value before
    step i's update). One jitted value-and-grad for the whole batch (``vmap`` over scenes).
    tune_spill: also tune the planner's spill lambda (>= 0 via a softplus; starts at
    ``config.spill_lam``), the gradient flowing through the soft fabric's Eq. 6; the world's spill
    stays ``config.spill_lam``.
    """
    if steps < 1:
        raise ValueError(f"steps: must be >= 1; got {steps!r}.")
    if config is None:
        config = ObjectiveConfig()
    base = FabricParams() if init is None else init
    batch = stack_scenes(scenes)

    def loss(u):
        p = from_unconstrained(u, base)
        lam = jax.nn.softplus(u[SPILL]) if tune_spill else None
        return -jnp.mean(jax.vmap(lambda s: soft_efficiency(s, p, config, lam))(batch))

    value_and_grad = jax.jit(jax.value_and_grad(loss))
    opt = optax.adam(learning_rate)
    u = to_unconstrained(base)
    if tune_spill:
        u[SPILL] = jnp.float32(math.log(math.expm1(max(float(config.spill_lam), 1e-4))))
    state = opt.init(u)
    history = []
    for i in range(steps):
        value, grad = value_and_grad(u)
        p = from_unconstrained(u, base)
        row = dict(step=i, objective=-float(value), **{k: float(getattr(p, k)) for k in TUNED})
        if tune_spill:
            row[SPILL] = float(jax.nn.softplus(u[SPILL]))
        history.append(row)
        if on_step is not None:
            on_step(i, row)
        updates, state = opt.update(grad, state, u)
        u = optax.apply_updates(u, updates)
    tuned = from_unconstrained(u, base)
    lam = float(jax.nn.softplus(u[SPILL])) if tune_spill else None
    return FitResult(base.replace(**{k: float(getattr(tuned, k)) for k in TUNED}), history, lam)


# ---------------------------------------------------------------------------------------------- hard check


def evaluate_hard(scenes: list[Scene], params: FabricParams, *, max_pushes: int = 40, spill_lam: float = 0.05,
                  rearrange_margin: float = 0.1, plan_lam: float | None = None) -> list[dict]:
    """Run the hard episode loop on every scene; one dict per scene with delivered mass, distance
    driven, pushes and delivered per unit driven (objects per world unit). The world spills with
    ``spill_lam``; the planner selects routes (Eq. 6) with ``plan_lam`` (None: ``spill_lam``)."""
    from jaxplan.transport import EpisodeParams, run_episode

    hard = params.replace(temperature=None)
    rows = []
    for scene in scenes:
        ep = run_episode(scene, hard, SpillParams(lam=spill_lam),
                         EpisodeParams(max_pushes=max_pushes, rearrange_margin=rearrange_margin),
                         plan_spill=None if plan_lam is None else SpillParams(lam=plan_lam))
        delivered = float(ep.delivered[-1]) if len(ep.delivered) else 0.0
        driven = float(ep.driven[-1]) if len(ep.driven) else 0.0
        rows.append(dict(delivered=delivered, driven=driven, pushes=int(len(ep.pushes)),
                         rearranges=int(np.sum(ep.mode)) if len(ep.mode) else 0,
                         initial_remaining=float(ep.initial_remaining), stop_reason=ep.stop_reason,
                         efficiency=delivered / driven if driven > 0 else 0.0))
    return rows


def gradient_probe(scene, theta, tau, lam, obj, t):
    """f32[]: one scalar that touches every output of the soft fabric (value, raw, psi, heat,
    highways and the anchor weights), for ``scene`` with counts ``obj: f32[H, W]``,
    ``theta_tol_deg=theta``, ``tau_h=tau``, ``anchor_lambda=lam`` and temperature ``t``.

    Differentiate it in ``theta``, ``tau``, ``lam`` and ``obj`` to check every output's gradient at
    once (the tests against finite differences; ``experiments/soft_convergence.py``'s table)."""
    f = build_fabric(scene.with_obj(obj), FabricParams(theta_tol_deg=theta, tau_h=tau, anchor_lambda=lam,
                                                       temperature=t))
    pos = jnp.arange(f.anchor_weights.shape[-1], dtype=jnp.float32)
    return (jnp.sum(f.value) + jnp.sum(f.raw) + jnp.sum(f.psi) + jnp.sum(f.heat)
            + jnp.sum(f.highways * f.heat) + jnp.sum(f.anchor_weights * pos) * 0.1)
