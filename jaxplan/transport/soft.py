"""Soft (differentiable) fabric kernels: every hard decision of the fabric with a temperature.

``build_fabric(scene, FabricParams(temperature=t))`` with ``t > 0`` runs these kernels and returns a
``SoftFabric``; ``temperature=None`` (or a concrete 0) runs the exact hard kernels of
``jaxplan.transport.fabric``, untouched. ``jax.grad`` of any scalar of a ``SoftFabric`` is defined w.r.t.
``theta_tol_deg``, ``tau_h``, ``anchor_lambda``, ``temperature`` and the grid counts ``scene.obj``.

One rule softens every decision (docs/conventions.md, "Soft kernels"):

- a **gate** (a hard ``x >= 0`` test: cone, monotone, highway threshold) becomes the probability
  ``p = sigmoid(x / t)``, ``x`` in the test's own unit (cosine for the cone, cell sizes for the
  monotone rule, fractions of the heat scale for highways);
- a **max / argmax** over options becomes ``t * logsumexp(score / t)`` / ``softmax(score / t)``;
  a gated option's score gets ``+ log p`` (in the score's unit) before that, so a closed gate
  (``log p ~ x / t``) drops out as ``t -> 0`` and the soft result tends to the hard one.

The dynamic program is a fixed-round **soft Bellman recursion** (``soft_rounds``, static) over
walks: soft gates open every neighbour a little, so the soft successor graph can have cycles. It
does not build the K-best table. Target membership, occupancy (``obj > 0``) and grid edges stay
hard (they carry no parameter); counts enter the values smoothly.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.core import lattice
from jaxplan.core.compilation import grid_jit
from jaxplan.transport import visibility
from jaxplan.transport.params import FabricParams

MIN_TEMPERATURE = 1e-6   # a traced temperature is floored here, so t = 0 under vmap/grad cannot divide by 0
_TINY = 1e-30            # floor inside logs of probabilities (gradient 0 where it binds)

N_OPTIONS = lattice.N_DIRS + 1   # 8 directions and the boundary fallback


class SoftFabric(NamedTuple):
    """What the soft kernels compute for one H x W grid (``build_fabric`` with a temperature).

    value: f32[H, W], soft Bellman value (objects) of the utility ``raw - sqrt(t) * length / s``:
      ``obj(C) + t logsumexp`` over the gated options; tends to J as t -> 0. 0 where not occupied.
    raw: f32[H, W], expected raw mass (objects) collected by the soft policy from C (C included).
    length: f32[H, W], expected path length (world units) of the soft policy.
    policy: f32[H, W, 9], probability of each first step (8 directions, then the fallback); 0 where
      not occupied. heading: f32[H, W, 2], expected unit step (x, y) of the policy (the fallback's
      best-aligned direction for the fallback option).
    feasible: f32[H, W, 8], soft edge probability (cone gate x monotone gate; 0 where the hard rules
      exclude the neighbour: off grid, empty, or C not occupied).
    occupied: bool[H, W], non-target cells with obj > 0.
    psi: f32[H, W], soft propagated mass (objects). heat: f32[H, W], soft heatmap (objects); 0 on
      target cells. highways: f32[H, W], soft highway membership in [0, 1].
    root: f32[H, W], soft root weight occupied * (1 - highways). candidate: f32[H, W], soft anchor
      candidate weight highways * occupied.
    anchor_weights: f32[H, W, H*W], softmax over candidates h (row-major flat index) of the Eq. 12
      scores for every occupied cell as root (rows sum to 1; 0 where not occupied).
    temperature: f32[], the temperature used (after the floor).
    """

    value: jax.Array
    raw: jax.Array
    length: jax.Array
    policy: jax.Array
    heading: jax.Array
    feasible: jax.Array
    occupied: jax.Array
    psi: jax.Array
    heat: jax.Array
    highways: jax.Array
    root: jax.Array
    candidate: jax.Array
    anchor_weights: jax.Array
    temperature: jax.Array


# ----------------------------------------------------------------------------------------------
# Soft max / argmax over masked options


def soft_max(score, mask, t, axis=0):
    """``t * logsumexp(score / t)`` over ``mask``ed entries along ``axis`` and the softmax weights.

    score: f32[...] (finite everywhere, also where masked); mask: bool, same shape. Returns
    ``(value, weights)``; value is ``-inf``-free: 0 where no entry is unmasked (weights all 0 there).
    """
    masked = jnp.where(mask, score, -jnp.inf)
    top = jnp.max(masked, axis=axis, keepdims=True)
    top = jnp.where(jnp.isfinite(top), top, 0.0)
    e = jnp.where(mask, jnp.exp((jnp.where(mask, score, top) - top) / t), 0.0)
    total = jnp.sum(e, axis=axis, keepdims=True)
    safe = jnp.maximum(total, _TINY)
    value = jnp.where(total > 0, top + t * jnp.log(safe), 0.0)
    return jnp.squeeze(value, axis), e / safe


def _log1mexp(logp):
    """``log(1 - exp(logp))`` for ``logp <= 0``, floored at ``log(_TINY)``."""
    return jnp.log(jnp.maximum(-jnp.expm1(jnp.minimum(logp, 0.0)), _TINY))


# ----------------------------------------------------------------------------------------------
# Soft successor gates (Eqs. 1-2)


def edge_log_prob(occupied, goal, dist, tvec, theta_tol_deg, monotone: bool, cell_size, t):
    """``(log_p f32[8, H, W], allowed bool[8, H, W])``: soft feasibility of every step.

    The hard rules that carry no parameter stay hard (``allowed``: C occupied, the neighbour in grid
    and occupied or a goal). On allowed steps ``log p = log sigmoid(x_cone / t)`` (+ ``log sigmoid(
    x_mono / t)`` with the monotone rule), ``x_cone = t(C) . step - cos(theta_tol) + 1e-6`` (cosine
    units), ``x_mono = (d(C) - d(N)) / s - 1e-5`` (cell sizes). Arguments as in
    ``visibility.feasible_successors``.
    """
    in_grid = jnp.asarray(lattice.in_grid(occupied.shape))
    allowed = occupied[None] & in_grid & lattice.neighbours(occupied | goal, False)
    x_cone = visibility.cone_alignment(tvec) - visibility.cone_cos(theta_tol_deg)
    log_p = jax.nn.log_sigmoid(x_cone / t)
    if monotone:
        # The monotone rule's hard part stays: a step must go strictly closer, so the soft graph is
        # the hard DAG and the recursion cannot gain mass around a cycle. Its sigmoid then only
        # smooths the steps that barely get closer (margin in cell sizes; tends to 1 as t -> 0).
        nb_dist = lattice.neighbours(dist, 0.0)   # off-grid neighbours are masked by ``allowed``
        x_mono = (dist[None] - nb_dist) / cell_size - lattice.MONOTONE_EPS
        allowed = allowed & (x_mono > 0)
        log_p = log_p + jax.nn.log_sigmoid(x_mono / t)
    return jnp.where(allowed, log_p, 0.0), allowed


# ----------------------------------------------------------------------------------------------
# The soft Bellman recursion


def soft_dp(obj, occupied, goal, dist, tvec, log_p, allowed, cell_size, t, rounds: int):
    """Fixed-round soft value iteration toward ``goal``.

    Per occupied cell C, options: step i (allowed) with score ``V(N_i) - eta |step_i| - t^(3/4) i + log p_i``
    (``V = 0`` for a goal neighbour: entering it ends the path) and the fallback with score
    ``sum_i log(1 - p_i) - eta d(C)`` (all steps closed), ``eta = sqrt(t) / s`` (the length
    tie-break; ``t^(3/4) i`` breaks the remaining ties toward the lower direction index).
    ``V(C) = obj(C) + t logsumexp(score / t)``, ``pi = softmax(score / t)``,
    expected raw ``R(C) = obj(C) + sum_i pi_i [N_i not goal] R(N_i)``, expected length
    ``L(C) = sum_i pi_i (|step_i| + [N_i not goal] L(N_i)) + pi_fb d(C)``. Rounds start from the
    0-step fallback (``V = R = obj``, ``L = d``) and run ``rounds`` times (static).

    obj: f32[H, W] objects; occupied, goal: bool[H, W]; dist: f32[H, W] world units; tvec unused
    here (kept for symmetry); log_p, allowed: from ``edge_log_prob``; t: f32[] temperature.
    Returns ``(value, raw, length, policy f32[9, H, W])``.
    """
    del tvec
    obj = jnp.where(occupied, obj, 0.0)
    step_len = (jnp.asarray(lattice.STEP_CELLS) * cell_size)[:, None, None]
    nb_goal = lattice.neighbours(goal, False)
    log_fb = jnp.sum(jnp.where(allowed, _log1mexp(log_p), 0.0), axis=0)
    mask = jnp.concatenate([allowed, occupied[None]], 0)
    cont = allowed & ~nb_goal                        # steps that continue with the neighbour's path

    # Ties in raw are common (entering either of two target cells collects the same mass); the
    # hard kernel breaks them toward the shorter path. Here the utility is raw - eta * length with
    # eta = sqrt(t) per cell size: it vanishes as t -> 0 while eta / t (the tie's weight) grows.
    # Exact ties in (raw, length) remain (two target cells entered by equal steps); the hard kernel
    # takes the lower direction index. A bias of -t^(3/4) per direction index does the same as
    # t -> 0 (t^(3/4) / t grows) and is smaller than the length tie-break's sqrt(t) scale.
    eta = jnp.sqrt(t) / cell_size
    fb_cost = eta * dist
    order = (t ** 0.75) * jnp.arange(lattice.N_DIRS, dtype=jnp.float32)[:, None, None]

    def scores(value):
        nb_v = lattice.neighbours(value, 0.0)
        step = jnp.where(nb_goal, 0.0, nb_v) - eta * step_len - order + log_p
        return jnp.concatenate([step, (log_fb - fb_cost)[None]], 0)

    def body(carry, _):
        value, raw, length = carry
        v, pi = soft_max(scores(value), mask, t)
        nb_r, nb_l = lattice.neighbours(raw, 0.0), lattice.neighbours(length, 0.0)
        new_raw = obj + jnp.sum(pi[:8] * jnp.where(cont, nb_r, 0.0), 0)
        new_len = jnp.sum(pi[:8] * (step_len + jnp.where(cont, nb_l, 0.0)), 0) + pi[8] * dist
        new_value = jnp.where(occupied, obj + v, 0.0)
        return (new_value, jnp.where(occupied, new_raw, 0.0), jnp.where(occupied, new_len, 0.0)), None

    start = (jnp.where(occupied, obj - fb_cost, 0.0), obj, jnp.where(occupied, dist, 0.0))
    (value, raw, length), _ = jax.lax.scan(body, start, None, length=rounds)
    _, pi = soft_max(scores(value), mask, t)     # the policy of the final values
    return value, raw, length, jnp.where(occupied[None], pi, 0.0)


# ----------------------------------------------------------------------------------------------
# Soft psi, heatmap, highways, anchors


def soft_psi(raw, occupied, policy, t, rounds: int):
    """Soft propagated mass: ``psi(U) = t logsumexp(0, [U occupied] R(U), psi(P) + log pi_P(P->U))``.

    The hard psi is ``max(J(U), max over P whose path steps into U of psi(P))``; here every
    predecessor P counts, gated by the probability of its step into U. raw: f32[H, W] expected raw
    mass (objects); policy: f32[9, H, W]; ``rounds`` static.
    """
    own = jnp.where(occupied, raw, 0.0)
    log_pi = jnp.log(jnp.maximum(policy[:8], _TINY))
    # predecessor of U in direction i: the cell P = U - DIRS[i], stepping with direction i into U
    pred_log_pi = jnp.stack([lattice.shift(log_pi[i], -dr, -dc, 0.0) for i, (dr, dc) in enumerate(lattice.DIRS)])
    pred_ok = jnp.stack([lattice.shift(policy[i] > 0, -dr, -dc, False) for i, (dr, dc) in enumerate(lattice.DIRS)])
    mask = jnp.concatenate([jnp.ones((1,) + own.shape, bool), occupied[None], pred_ok], 0)

    def body(psi, _):
        pred = jnp.stack([lattice.shift(psi, -dr, -dc, 0.0) for dr, dc in lattice.DIRS]) + pred_log_pi
        score = jnp.concatenate([jnp.zeros((1,) + own.shape), own[None], pred], 0)
        value, _ = soft_max(score, mask, t)
        return value, None

    psi, _ = jax.lax.scan(body, own, None, length=rounds)
    return psi


def _heat_kernel() -> jnp.ndarray:
    """``f32[8, 8]``: ``G[i, j] = a`` for a hop in direction i and a look-back step j (Eq. 10 gates)."""
    unit = lattice.STEP_UNIT.astype("float64")
    cells = lattice.STEP_CELLS.astype("float64")
    align = unit @ unit.T                                              # v(C) . unit(x - c)
    near = cells[None, :] <= cells[:, None] + lattice.GATE_EPS           # |x - c| <= |c1 - c|
    forward = align * cells[None, :] > lattice.GATE_EPS
    return jnp.asarray(align * near * forward, jnp.float32)


def soft_heat(psi, occupied, policy, tvec, target, t):
    """Soft heatmap: ``H(X) = t logsumexp(0, E_pi[a(C, X)] psi(C))`` over the 8 sources ``C = X - step``.

    ``E_pi[a]`` averages Eq. 10's gated alignment over the source's first-step distribution (the
    fallback option uses the best-aligned direction, as in the hard kernel). At ``t -> 0`` the policy
    is one-hot and this is the hard stencil. 0 on target cells.
    """
    g = _heat_kernel()
    fb_dir = visibility.fallback_direction(tvec)
    fb_row = jnp.where((fb_dir >= 0)[..., None], g[jnp.maximum(fb_dir, 0)], 0.0)     # [H, W, 8]
    expected = jnp.einsum("ihw,ij->jhw", policy[:8], g) + policy[8][None] * jnp.moveaxis(fb_row, -1, 0)
    contrib = jnp.where(occupied[None], expected * psi[None], 0.0)                   # source C, look j
    at_x = jnp.stack([lattice.shift(contrib[j], -dr, -dc, 0.0) for j, (dr, dc) in enumerate(lattice.DIRS)])
    src_ok = jnp.stack([lattice.shift(occupied, -dr, -dc, False) for dr, dc in lattice.DIRS])
    score = jnp.concatenate([jnp.zeros((1,) + psi.shape), at_x], 0)
    mask = jnp.concatenate([jnp.ones((1,) + psi.shape, bool), src_ok], 0)
    value, _ = soft_max(score, mask, t)
    return jnp.where(target, 0.0, value)


def _soft_ridge(h, t, scale):
    nb = lattice.neighbours(h, 0.0)
    axes = ((3, 4), (1, 6), (0, 7), (2, 5))
    s = lambda a: jax.nn.sigmoid((h - nb[a]) / (t * scale))   # noqa: E731
    miss = jnp.prod(jnp.stack([1.0 - s(a) * s(b) for a, b in axes]), axis=0)
    return 1.0 - miss


def heat_scale(h):
    """The heat unit of the soft highway and anchor gates: ``max h``, floored so an empty map is safe."""
    return jnp.maximum(jnp.max(h), 1e-6)


def soft_highways(heat_map, target, tau_h, t, *, relative: bool = True, smoothing: bool = False,
                  nms: bool = False):
    """Soft highway membership ``f32[H, W]`` in [0, 1] (Eq. 11).

    ``sigmoid((H_s - thr) / (t k)) * sigmoid(H_s / (t k))`` on non-target cells, ``k = max H_s`` when
    ``relative`` (so the gate is in fractions of the maximum) else 1 object; times a soft ridge test
    when ``nms``.
    """
    from jaxplan.transport.heatmap import smooth_3x3
    h = smooth_3x3(heat_map) if smoothing else heat_map
    scale = heat_scale(h) if relative else jnp.float32(1.0)
    threshold = tau_h * scale if relative else tau_h
    m = jax.nn.sigmoid((h - threshold) / (t * scale)) * jax.nn.sigmoid(h / (t * scale))
    if nms:
        m = m * _soft_ridge(h, t, scale)
    return jnp.where(target, 0.0, m)


def soft_anchors(heat_map, candidate, occupied, centers, anchor_lambda, t):
    """``f32[H, W, H*W]``: softmax over candidates h of ``(H(h) - lambda |c_R - c_h|) / k + log w_h``.

    candidate: f32[H, W] soft candidate weight w (highway x occupied); k = max heat (the score in
    units of the heat scale, like the highway gate). Rows of non-occupied cells are 0.
    """
    h, w = heat_map.shape
    scale = heat_scale(heat_map)
    flat = centers.reshape(-1, 2)
    d = jnp.sqrt(jnp.sum((flat[:, None, :] - flat[None, :, :]) ** 2, axis=-1) + 1e-12)   # [R, h]
    cand = candidate.reshape(-1)
    ok = jnp.broadcast_to(cand > 0, d.shape)
    score = (heat_map.reshape(-1)[None] - anchor_lambda * d) / scale + jnp.log(jnp.maximum(cand, _TINY))[None]
    _, weights = soft_max(score, ok, t, axis=1)
    return jnp.where(occupied.reshape(-1, 1), weights, 0.0).reshape(h, w, h * w)


# ----------------------------------------------------------------------------------------------
# The soft fabric


def _soft_build(scene, params: FabricParams) -> SoftFabric:
    obj = jnp.asarray(scene.obj, jnp.float32)
    target = jnp.asarray(scene.target_mask, bool)
    occupied = ~target & (obj > 0)
    t = jnp.maximum(jnp.asarray(params.temperature, jnp.float32), MIN_TEMPERATURE)
    rounds = params.resolved_soft_rounds(obj.shape)
    log_p, allowed = edge_log_prob(occupied, target, scene.dist, scene.tvec, params.theta_tol_deg,
                                   params.monotone, scene.cell_size, t)
    value, raw, length, policy = soft_dp(obj, occupied, target, scene.dist, scene.tvec, log_p, allowed,
                                         scene.cell_size, t, rounds)
    fb_dir = visibility.fallback_direction(scene.tvec)
    fb_unit = jnp.where((fb_dir >= 0)[..., None], jnp.asarray(lattice.STEP_UNIT)[jnp.maximum(fb_dir, 0)], 0.0)
    heading = jnp.einsum("ihw,ix->hwx", policy[:8], jnp.asarray(lattice.STEP_UNIT)) + policy[8][..., None] * fb_unit
    psi = soft_psi(raw, occupied, policy, t, rounds)
    heat = soft_heat(psi, occupied, policy, scene.tvec, target, t)
    highways = soft_highways(heat, target, params.tau_h, t, relative=params.highway_relative,
                             smoothing=params.highway_smoothing, nms=params.highway_nms)
    candidate = highways * occupied
    centers = lattice.cell_centers(obj.shape, scene.cell_size, scene.origin)
    anchors = soft_anchors(heat, candidate, occupied, centers, params.anchor_lambda, t)
    return SoftFabric(value, raw, length, jnp.moveaxis(policy, 0, -1), heading,
                      jnp.moveaxis(jnp.where(allowed, jnp.exp(log_p), 0.0), 0, -1), occupied, psi, heat,
                      highways, occupied * (1.0 - highways), candidate, anchors, t)


_soft_build_jit = grid_jit(_soft_build)


def build_soft_fabric(scene, params: FabricParams) -> SoftFabric:
    """The soft fabric of ``scene`` (jitted; one trace per grid shape and static options, whatever
    the temperature). Call through ``jaxplan.build_fabric`` with ``FabricParams(temperature=t)``."""
    if params.temperature is None:
        raise ValueError("FabricParams.temperature: the soft kernels need a temperature > 0; got None.")
    return _soft_build_jit(scene, params)
