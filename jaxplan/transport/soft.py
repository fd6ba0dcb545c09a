"""Soft (differentiable) fabric kernels: every hard decision of the fabric with a temperature.

``build_fabric(scene, FabricParams(temperature=t))`` with ``t > 0`` runs these kernels and returns a
``SoftFabric``; ``temperature=None`` (or a concrete 0) runs the exact hard kernels of
``jaxplan.transport.fabric``, untouched. ``jax.grad`` of any scalar of a ``SoftFabric`` is defined w.r.t.
``theta_tol_deg``, ``tau_h``, ``anchor_lambda``, ``temperature`` and the grid counts ``scene.obj``.

The temperature is dimensionless: every softened decision divides its score by its own scene scale
(docs/transport.md, "Soft kernels"):

- masses (values, raw, psi, heat) by the scene's **mass scale** ``M`` (``mass_scale``: the mean
  count of the occupied cells), so a max over options becomes a softmax at ``T = t M`` objects;
- cosines (the cone gate) by ``CONE_SCALE``, fractions of the maximum heat (highways) by
  ``HIGHWAY_SCALE``, lengths (the tie-breaks) by the cell size.

A **gate** (a hard ``x >= 0`` test) becomes a logit ``z`` (cone: ``x / (t^2 CONE_SCALE)``; highways:
``x / (t HIGHWAY_SCALE)``), its probability ``sigmoid(z)`` and, on the score it gates, the penalty
``(M / t) log sigmoid(z)`` objects: in the softmax's own units a closed cone gate costs about
``|x| / (t^4 CONE_SCALE)``, so a step outside the cone is worse than any path it could open, and an
open one (``x`` a few ``t^2 CONE_SCALE`` inside) costs nothing.

The dynamic program is a fixed-round **softmax-weighted Bellman recursion** (``soft_rounds``, static). Ties in
mass go to the shorter path, then to the lower first-step index, through costs that vanish relative
to ``M``. psi and the heatmap follow the **sharpened policy** (the policy's scores at temperature
``t^2 T``) and reduce their options by a softmax-weighted mean (``soft_mean``), which lies between the
mean and the max, so no upward log-sum-exp bias accumulates along paths. Target membership,
occupancy (``obj > 0``), grid edges and the monotone rule stay hard (they carry no parameter);
counts enter the values smoothly.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.core import grid_jit, lattice
from jaxplan.transport import obstacles, visibility
from jaxplan.transport.params import FabricParams
from jaxplan.transport.scene import occupied_cells

MIN_TEMPERATURE = 1e-6   # a traced temperature is floored here, so t = 0 under vmap/grad cannot divide by 0
_TINY = 1e-30            # floor inside logs of probabilities (gradient 0 where it binds)

N_OPTIONS = lattice.N_DIRS + 1   # 8 directions and the boundary fallback

CONE_SCALE = 0.05
"""Cosine units of the cone gate: its logit is ``(t(C) . step - cos theta_tol) / (t^2 CONE_SCALE)``."""
HIGHWAY_SCALE = 0.1
"""Fractions of the heat scale of the highway gate: logit ``(H - tau_h k) / (t * HIGHWAY_SCALE * k)``."""
LENGTH_EXPONENT = 1.5
"""The length tie-break costs ``M t^LENGTH_EXPONENT`` per cell size of path: ``t^(1/2)`` per cell in
the policy's softmax units (small: mass decides), ``t^(-3/2)`` in the sharpened policy's (which psi
and heat follow: exact ties in mass go to the shorter path)."""
ORDER_EXPONENT = 2.25
"""The direction-index tie-break (of the first step only) costs ``M t^ORDER_EXPONENT`` per index:
``t^(-3/4)`` per index in the sharpened policy's units, below the length tie-break."""


class SoftFabric(NamedTuple):
    """What the soft kernels compute for one H x W grid (``build_fabric`` with a temperature).

    value: f32[H, W], objects: the softmax-weighted Bellman value with its expected length and gate
      costs added back (the expected raw mass under the value's weights); tends to J as t -> 0. 0
      where not occupied.
    raw: f32[H, W], expected raw mass (objects) collected by the soft policy from C (C included).
    length: f32[H, W], expected path length (world units) of the soft policy.
    policy: f32[H, W, 9], probability of each first step (8 directions, then the fallback); 0 where
      not occupied. heading: f32[H, W, 2], expected unit step (x, y) of the policy (the fallback's
      best-aligned direction for the fallback option).
    feasible: f32[H, W, 8], soft edge probability (the cone gate; 0 where the hard rules exclude the
      neighbour: off grid, empty, not strictly closer, or C not occupied).
    occupied: bool[H, W], non-target cells with obj > 0.
    psi: f32[H, W], soft propagated mass (objects). heat: f32[H, W], soft heatmap (objects); 0 on
      target cells. highways: f32[H, W], soft highway membership in [0, 1].
    root: f32[H, W], soft root weight occupied * (1 - highways). candidate: f32[H, W], soft anchor
      candidate weight highways * occupied.
    anchor_weights: f32[H, W, H*W], softmax over candidates h (row-major flat index) of the Eq. 12
      scores for every occupied cell as root (rows sum to 1; 0 where not occupied).
    temperature: f32[], the temperature used (after the floor).
    mass_scale: f32[], objects: the scene's mass scale M (``mass_scale``).
    delivered: f32[H, W], objects: the predicted delivered mass of each source's route under the
      policy (``soft_select``; equal to ``raw`` without ``SpillParams``).

    With ``SpillParams`` (Eq. 6, ``soft_select``) ``policy``, ``heading``, ``psi``, ``heat``,
    ``highways``, ``root``, ``candidate`` and ``anchor_weights`` follow the spill-aware choice, as the
    hard fabric's do after ``selection.reselect``; ``value``, ``raw`` and ``length`` stay Eq. 5's.
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
    mass_scale: jax.Array
    delivered: jax.Array


# ----------------------------------------------------------------------------------------------
# Soft max / argmax over masked options


def soft_max(score, mask, t, axis=0):
    """``t * logsumexp(score / t)`` over ``mask``ed entries along ``axis`` and the softmax weights.

    score: f32[...] (finite everywhere, also where masked); mask: bool, same shape; t: the
    temperature in the score's units. Returns ``(value, weights)``; value is ``-inf``-free: 0 where
    no entry is unmasked (weights all 0 there).
    """
    value, weights, _ = _soft_max_log(score, mask, t, axis)
    return value, weights


def _soft_max_log(score, mask, t, axis):
    """``soft_max`` and the log of its weights (finite, very negative where a weight underflows;
    0 where masked)."""
    masked = jnp.where(mask, score, -jnp.inf)
    top = jnp.max(masked, axis=axis, keepdims=True)
    top = jnp.where(jnp.isfinite(top), top, 0.0)
    z = (jnp.where(mask, score, top) - top) / t
    e = jnp.where(mask, jnp.exp(z), 0.0)
    total = jnp.sum(e, axis=axis, keepdims=True)
    safe = jnp.maximum(total, _TINY)
    value = jnp.where(total > 0, top + t * jnp.log(safe), 0.0)
    log_w = jnp.where(mask, z - jnp.log(safe), 0.0)
    return jnp.squeeze(value, axis), e / safe, log_w


def soft_mean(score, mask, t, axis=0):
    """The softmax-weighted mean ``sum_i w_i score_i``, ``w = softmax(score / t)`` over ``mask``ed
    entries: between the mean and the max of the scores (no upward bias), the max as ``t -> 0``.
    0 where no entry is unmasked."""
    _, weights = soft_max(score, mask, t, axis)
    return jnp.sum(weights * jnp.where(mask, score, 0.0), axis=axis)


def mass_scale(obj, occupied):
    """``f32[]`` objects: the scene's mass scale M, the mean count of the occupied cells (1 when none).

    The soft kernels divide every mass score by ``t M``, so one temperature means the same on
    every scene. Differentiable in the counts."""
    n = jnp.sum(occupied)
    mean = jnp.sum(jnp.where(occupied, obj, 0.0)) / jnp.maximum(n, 1)
    return jnp.where(n > 0, jnp.maximum(mean, 1e-6), 1.0)


# ----------------------------------------------------------------------------------------------
# Soft successor gates (Eqs. 1-2)


def edge_logits(occupied, goal, dist, tvec, theta_tol_deg, monotone: bool, cell_size, t, blocked=None):
    """``(z f32[8, H, W], allowed bool[8, H, W])``: the cone gate's logit of every step.

    The rules that carry no parameter stay hard (``allowed``: C occupied, the neighbour in grid and
    occupied or a goal and, with the monotone rule, strictly closer to the goal by more than
    ``MONOTONE_EPS`` cell sizes). ``z = (t(C) . step - cos(theta_tol) + 1e-6) / (t^2 CONE_SCALE)``,
    the step's probability is ``sigmoid(z)``. Arguments as in ``visibility.feasible_successors``.
    """
    in_grid = jnp.asarray(lattice.in_grid(occupied.shape))
    allowed = occupied[None] & in_grid & lattice.neighbours(occupied | goal, False)
    if blocked is not None:
        allowed = allowed & obstacles.corner_free(blocked)
    if monotone:
        # steps that do not get strictly closer stay forbidden: the soft graph is the hard DAG, so
        # the recursion cannot gain mass around a cycle
        nb_dist = lattice.neighbours(dist, 0.0)   # off-grid neighbours are masked by ``allowed``
        allowed = allowed & ((dist[None] - nb_dist) / cell_size - lattice.MONOTONE_EPS > 0)
    x_cone = visibility.cone_alignment(tvec) - visibility.cone_cos(theta_tol_deg)
    return jnp.where(allowed, x_cone / (t * t * CONE_SCALE), 0.0), allowed


# ----------------------------------------------------------------------------------------------
# The soft Bellman recursion


def soft_dp(obj, occupied, goal, dist, z, allowed, cell_size, t, mass, rounds: int):
    """Fixed-round soft value iteration toward ``goal``, at ``T = t M`` objects.

    Per occupied cell C, options: step i (allowed) with score
    ``Q_i = V(N_i) - eta |step_i| + (M / t) log sigmoid(z_i)`` (``V = 0`` for a goal neighbour:
    entering it ends the path) and the fallback with ``Q_fb = (M / t) sum_i log sigmoid(-z_i) - eta d(C)``
    (every step closed); ``eta = M t^1.5 / s`` (length tie-break). ``V(C) = obj(C) + sum_i w_i Q_i``,
    ``w = softmax(Q / T)`` (a weighted mean, not log-sum-exp: exact ties add no entropy bonus, which
    would steer the tie-break toward branching paths);
    the policy ``pi = softmax((Q - o i) / T)``, ``o = M t^2.25`` per direction index i (the hard
    kernel's tie-break by the first step's index: in the policy only, not in V). Expected raw
    ``R(C) = obj(C) + sum_i pi_i [N_i not goal] R(N_i)``, expected length
    ``L(C) = sum_i pi_i (|step_i| + [N_i not goal] L(N_i)) + pi_fb d(C)``, and the expected costs
    ``B(C)`` (length and gate terms, under ``w``), so that ``V + B`` tends to J.
    Rounds start from the 0-step fallback and run ``rounds`` times (static).

    obj: f32[H, W] objects; occupied, goal: bool[H, W]; dist: f32[H, W] world units; z, allowed:
    from ``edge_logits``; t: f32[] temperature; mass: f32[] the mass scale M (objects).
    Returns ``(V + B, raw, length, policy f32[9, H, W], log_sharp f32[9, H, W])``: log_sharp is the
    log of the sharpened policy ``softmax((Q - o i) / (t^2 T))``, 0 where masked.
    """
    obj = jnp.where(occupied, obj, 0.0)
    temp = t * mass
    step_len = (jnp.asarray(lattice.STEP_CELLS) * cell_size)[:, None, None]
    nb_goal = lattice.neighbours(goal, False)
    gate = (mass / t) * jax.nn.log_sigmoid(z)
    log_fb = (mass / t) * jnp.sum(jnp.where(allowed, jax.nn.log_sigmoid(-z), 0.0), axis=0)
    mask = jnp.concatenate([allowed, occupied[None]], 0)
    cont = allowed & ~nb_goal                        # steps that continue with the neighbour's path

    # Ties in raw are common (entering either of two target cells collects the same mass); the
    # hard kernel breaks them toward the shorter path, then the lower first-step direction index.
    # Both costs vanish relative to M as t -> 0 while their weight in the softmax (cost / T) grows.
    # The index cost is lexicographic (the first step only), so it enters the policy, not the value.
    eta = mass * t ** LENGTH_EXPONENT / cell_size
    fb_cost = eta * dist
    order = (mass * t ** ORDER_EXPONENT) * jnp.arange(N_OPTIONS, dtype=jnp.float32).at[-1].set(0.0)[:, None, None]
    cost_here = jnp.concatenate([eta * step_len - gate, (fb_cost - log_fb)[None]], 0)   # [9, H, W]

    def scores(value):
        nb_v = lattice.neighbours(value, 0.0)
        return jnp.concatenate([jnp.where(nb_goal, 0.0, nb_v), jnp.zeros((1,) + obj.shape)], 0) - cost_here

    def body(carry, _):
        value, raw, length, cost = carry
        q = scores(value)
        _, w = soft_max(q, mask, temp)
        v = jnp.sum(w * jnp.where(mask, q, 0.0), 0)   # the weighted mean: ties add no entropy bonus
        _, pi = soft_max(q - order, mask, temp)
        nb = lambda a: jnp.where(cont, lattice.neighbours(a, 0.0), 0.0)  # noqa: E731
        new_raw = obj + jnp.sum(pi[:8] * nb(raw), 0)
        new_len = jnp.sum(pi[:8] * (step_len + nb(length)), 0) + pi[8] * dist
        new_cost = jnp.sum(w * cost_here, 0) + jnp.sum(w[:8] * nb(cost), 0)
        keep = lambda a: jnp.where(occupied, a, 0.0)  # noqa: E731
        return (keep(obj + v), keep(new_raw), keep(new_len), keep(new_cost)), None

    start = (jnp.where(occupied, obj - cost_here[8], 0.0), obj, jnp.where(occupied, dist, 0.0),
             jnp.where(occupied, cost_here[8], 0.0))
    (value, raw, length, cost), _ = jax.lax.scan(body, start, None, length=rounds)
    final = scores(value) - order                    # the policy of the final values
    _, pi = soft_max(final, mask, temp)
    _, _, log_sharp = _soft_max_log(final, mask, temp * t * t, 0)
    return (value + cost, raw, length, jnp.where(occupied[None], pi, 0.0),
            jnp.where(mask & occupied[None], log_sharp, 0.0))


# ----------------------------------------------------------------------------------------------
# Eq. 6: the choice among each source's candidates by predicted delivered mass


def _turn_matrix():
    """``f32[8, 8]``: the angle (radians) between step directions i and j."""
    unit = lattice.STEP_UNIT.astype("float64")
    return jnp.asarray(np.arccos(np.clip(unit @ unit.T, -1.0, 1.0)), jnp.float32)


def option_turning(policy, allowed, target, tvec, rounds: int):
    """``(theta f32[H, W], theta_opt f32[8, H, W])`` radians: the expected total turning of the
    policy's path from every cell, and of option i's path (step i, then the neighbour's policy).

    ``theta_i(C) = [N_i continues] (sum_j pi_j(N_i) angle(i, j) + pi_fb(N_i) angle(i, t(N_i)) +
    theta(N_i))``, ``theta(C) = sum_i pi_i(C) theta_i(C)``; fixed ``rounds`` (static).
    policy: f32[9, H, W]; allowed: bool[8, H, W] (``edge_logits``); target: bool[H, W]; tvec: f32[H, W, 2].
    """
    nb_goal = lattice.neighbours(target, False)
    unit = jnp.asarray(lattice.STEP_UNIT)
    nb_pol = lattice.neighbours(jnp.moveaxis(policy, 0, -1), 0.0)            # [8 (i), H, W, 9 (j)]
    nb_t = lattice.neighbours(tvec, 0.0)                                     # [8, H, W, 2]
    fb_angle = jnp.arccos(jnp.clip(jnp.einsum("ihwx,ix->ihw", nb_t, unit), -1.0, 1.0))
    local = jnp.einsum("ihwj,ij->ihw", nb_pol[..., :8], _turn_matrix()) + nb_pol[..., 8] * fb_angle
    cont = ~nb_goal & allowed

    def options(theta):
        return jnp.where(cont, local + lattice.neighbours(theta, 0.0), 0.0)

    def body(theta, _):
        return jnp.sum(policy[:8] * options(theta), 0), None

    theta, _ = jax.lax.scan(body, jnp.zeros(target.shape), None, length=rounds)
    return theta, options(theta)


def soft_select(obj, occupied, target, tvec, raw, z, allowed, policy, spill, slack_tau, t, mass, rounds: int):
    """Eq. 6 softened: ``(policy6 f32[9, H, W], log_sharp6 f32[9, H, W], delivered f32[H, W])``.

    Each source's candidates are its first-step options (step i then the Eq. 5 policy, or the
    fallback), option i with raw mass ``R_i = obj(C) + [N_i continues] R(N_i)``. Its predicted spill
    ``S_i = R_i (1 - exp(-lam theta_i))`` (``option_turning``: the curvature model's fraction ``lam``
    per radian over the expected turning) counts above ``threshold`` objects through
    ``sigmoid((S_i - threshold) / T)`` (the route's total spill rather than each spline sample's),
    so ``D_i = R_i - S_i sigmoid(...)``. Candidate weight (Eq. 6's slack set):
    ``c_i = sigmoid((R_i - max_j R_j + slack_tau) / T)``. The choice is
    ``softmax((D_i + gate_i) / T + log(c_i) / t)`` (gate_i: the cone gate's penalty, as in
    ``soft_dp``), its sharpened form at ``t^2`` of those units. spill: ``SpillParams`` (lam,
    threshold traced); the rest as in ``soft_dp``; policy: the Eq. 5 policy f32[9, H, W].
    """
    temp = t * mass
    obj = jnp.where(occupied, obj, 0.0)
    nb_goal = lattice.neighbours(target, False)
    cont = allowed & ~nb_goal
    r_opt = jnp.concatenate([obj[None] + jnp.where(cont, lattice.neighbours(raw, 0.0), 0.0), obj[None]], 0)
    _, theta_opt = option_turning(policy, allowed, target, tvec, rounds)
    theta_opt = jnp.concatenate([theta_opt, jnp.zeros((1,) + obj.shape)], 0)
    spilled = r_opt * -jnp.expm1(-spill.lam * theta_opt)
    d_opt = r_opt - spilled * jax.nn.sigmoid((spilled - spill.threshold) / temp)
    mask = jnp.concatenate([allowed, occupied[None]], 0)
    best = jnp.max(jnp.where(mask, r_opt, -jnp.inf), 0)
    best = jnp.where(jnp.isfinite(best), best, 0.0)
    log_c = jax.nn.log_sigmoid((r_opt - best[None] + slack_tau) / temp)
    gate = jnp.concatenate([(mass / t) * jax.nn.log_sigmoid(z),
                            ((mass / t) * jnp.sum(jnp.where(allowed, jax.nn.log_sigmoid(-z), 0.0), 0))[None]], 0)
    score = (d_opt + gate) / temp + log_c / t
    _, pi = soft_max(score, mask, 1.0)
    _, _, log_sharp = _soft_max_log(score, mask, t * t, 0)
    pi = jnp.where(occupied[None], pi, 0.0)
    return pi, jnp.where(mask & occupied[None], log_sharp, 0.0), jnp.where(occupied, jnp.sum(pi * d_opt, 0), 0.0)


# ----------------------------------------------------------------------------------------------
# Soft psi, heatmap, highways, anchors


def soft_psi(raw, occupied, allowed, log_sharp, t, mass, rounds: int):
    """Soft propagated mass: ``psi(U) = soft_mean_T(0, [U occupied] R(U), psi(P) + M log pi'_P(P->U))``.

    The hard psi is ``max(J(U), max over P whose path steps into U of psi(P))``; here every allowed
    predecessor P counts, its score lowered by ``M log pi'`` (pi': the sharpened policy, ~1 for P's
    best step, tiny for the others), reduced by ``soft_mean`` at ``T = t M``. raw: f32[H, W]
    expected raw mass (objects); allowed: bool[8, H, W]; log_sharp: f32[9, H, W]; ``rounds`` static.
    """
    own = jnp.where(occupied, raw, 0.0)
    shift = lambda a, i, fill: lattice.shift(a, -lattice.DIRS[i][0], -lattice.DIRS[i][1], fill)  # noqa: E731
    # predecessor of U in direction i: the cell P = U - DIRS[i], stepping with direction i into U
    pred_gate = jnp.stack([shift(mass * log_sharp[i], i, 0.0) for i in range(lattice.N_DIRS)])
    pred_ok = jnp.stack([shift(allowed[i], i, False) for i in range(lattice.N_DIRS)])
    # the first option is the empty one (0: no path visits U), as in the hard max
    mask = jnp.concatenate([jnp.ones((1,) + own.shape, bool), occupied[None], pred_ok], 0)
    zero = jnp.zeros((1,) + own.shape)

    def body(psi, _):
        pred = jnp.stack([shift(psi, i, 0.0) for i in range(lattice.N_DIRS)]) + pred_gate
        return soft_mean(jnp.concatenate([zero, own[None], pred], 0), mask, t * mass), None

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


def soft_heat(psi, occupied, sharp, tvec, target, t, mass):
    """Soft heatmap: ``H(X) = soft_mean_T(E'[a(C, X)] psi(C))`` over the 8 sources ``C = X - step``.

    ``E'[a]`` averages Eq. 10's gated alignment over the source's sharpened first-step distribution
    ``sharp: f32[9, H, W]`` (the fallback option uses the best-aligned direction, as in the hard
    kernel); ``T = t M``. At ``t -> 0`` the policy is one-hot and this is the hard stencil. 0 on
    target cells and where no source is occupied.
    """
    g = _heat_kernel()
    fb_dir = visibility.fallback_direction(tvec)
    fb_row = jnp.where((fb_dir >= 0)[..., None], g[jnp.maximum(fb_dir, 0)], 0.0)     # [H, W, 8]
    expected = jnp.einsum("ihw,ij->jhw", sharp[:8], g) + sharp[8][None] * jnp.moveaxis(fb_row, -1, 0)
    contrib = jnp.where(occupied[None], expected * psi[None], 0.0)                   # source C, look j
    at_x = jnp.stack([lattice.shift(contrib[j], -dr, -dc, 0.0) for j, (dr, dc) in enumerate(lattice.DIRS)])
    src_ok = jnp.stack([lattice.shift(occupied, -dr, -dc, False) for dr, dc in lattice.DIRS])
    return jnp.where(target, 0.0, soft_mean(at_x, src_ok, t * mass))


def _soft_ridge(h, width):
    nb = lattice.neighbours(h, 0.0)
    axes = ((3, 4), (1, 6), (0, 7), (2, 5))
    s = lambda a: jax.nn.sigmoid((h - nb[a]) / width)   # noqa: E731
    miss = jnp.prod(jnp.stack([1.0 - s(a) * s(b) for a, b in axes]), axis=0)
    return 1.0 - miss


def heat_scale(h):
    """The heat unit of the soft highway and anchor gates: ``max h``, floored so an empty map is safe."""
    return jnp.maximum(jnp.max(h), 1e-6)


def highway_logit(heat_map, tau_h, t, *, relative: bool = True, smoothing: bool = False):
    """``(z, z0, width, h_s)``: the highway gate's logits ``z = (H_s - thr) / width`` and
    ``z0 = H_s / width`` (f32[H, W]), ``width = t HIGHWAY_SCALE k`` (f32[]; ``k = max H_s`` when
    ``relative``, else 1 object) and the (smoothed) heat ``H_s`` (f32[H, W], objects)."""
    from jaxplan.transport.heatmap import smooth_3x3
    h = smooth_3x3(heat_map) if smoothing else heat_map
    scale = heat_scale(h) if relative else jnp.float32(1.0)
    threshold = tau_h * scale if relative else tau_h
    width = t * HIGHWAY_SCALE * scale
    return (h - threshold) / width, h / width, width, h


def soft_highways(heat_map, target, tau_h, t, *, relative: bool = True, smoothing: bool = False,
                  nms: bool = False):
    """Soft highway membership ``f32[H, W]`` in [0, 1] (Eq. 11).

    ``sigmoid(z) * sigmoid(z0)`` on non-target cells (``highway_logit``: the threshold and the
    positive-heat gates, in fractions ``t HIGHWAY_SCALE`` of the maximum when ``relative``); times a
    soft ridge test when ``nms``.
    """
    z, z0, width, h = highway_logit(heat_map, tau_h, t, relative=relative, smoothing=smoothing)
    m = jax.nn.sigmoid(z) * jax.nn.sigmoid(z0)
    if nms:
        m = m * _soft_ridge(h, width)
    return jnp.where(target, 0.0, m)


def soft_anchors(heat_map, candidate, occupied, centers, anchor_lambda, t):
    """``f32[H, W, H*W]``: softmax over candidates h of ``(H(h) - lambda |c_R - c_h|) / k + log(w_h) / t``
    at temperature ``t``.

    candidate: f32[H, W] soft candidate weight w (highway x occupied); k = max heat (the score in
    units of the heat scale, like the highway gate; a closed candidate's ``log w / t`` costs ~|z| / t
    heat scales). Rows of non-occupied cells are 0.
    """
    h, w = heat_map.shape
    scale = heat_scale(heat_map)
    flat = centers.reshape(-1, 2)
    d = jnp.sqrt(jnp.sum((flat[:, None, :] - flat[None, :, :]) ** 2, axis=-1) + 1e-12)   # [R, h]
    cand = candidate.reshape(-1)
    ok = jnp.broadcast_to(cand > 0, d.shape)
    score = ((heat_map.reshape(-1)[None] - anchor_lambda * d) / scale
             + jnp.log(jnp.maximum(cand, _TINY))[None] / t)
    _, weights = soft_max(score, ok, t, axis=1)
    return jnp.where(occupied.reshape(-1, 1), weights, 0.0).reshape(h, w, h * w)


# ----------------------------------------------------------------------------------------------
# The soft fabric


def _soft_build(scene, params: FabricParams, spill=None) -> SoftFabric:
    obj = jnp.asarray(scene.obj, jnp.float32)
    target = jnp.asarray(scene.target_mask, bool)
    occupied = occupied_cells(obj, target, scene.dist)
    # blocked and cut-off cells (d = inf) are never entered; a finite stand-in keeps inf - inf out of
    # the masked arithmetic (and its gradients)
    dist = jnp.where(occupied, scene.dist, 0.0)
    t = jnp.maximum(jnp.asarray(params.temperature, jnp.float32), MIN_TEMPERATURE)
    mass = mass_scale(obj, occupied)
    rounds = params.resolved_soft_rounds(obj.shape)
    z, allowed = edge_logits(occupied, target, dist, scene.tvec, params.theta_tol_deg,
                             params.monotone, scene.cell_size, t, scene.blocked)
    value, raw, length, policy, log_sharp = soft_dp(obj, occupied, target, dist, z, allowed,
                                                    scene.cell_size, t, mass, rounds)
    delivered = raw
    if spill is not None and spill.enabled:
        policy, log_sharp, delivered = soft_select(obj, occupied, target, scene.tvec, raw, z, allowed, policy, spill,
                                                   params.slack_tau, t, mass, rounds)
    fb_dir = visibility.fallback_direction(scene.tvec)
    fb_unit = jnp.where((fb_dir >= 0)[..., None], jnp.asarray(lattice.STEP_UNIT)[jnp.maximum(fb_dir, 0)], 0.0)
    heading = jnp.einsum("ihw,ix->hwx", policy[:8], jnp.asarray(lattice.STEP_UNIT)) + policy[8][..., None] * fb_unit
    # Phi(R): the raw mass of the selected route (Eq. 5: R; Eq. 6: the policy's expected option raw)
    own = raw if spill is None or not spill.enabled else _selected_raw(obj, occupied, target, raw, allowed, policy)
    psi = soft_psi(own, occupied, allowed, log_sharp, t, mass, rounds)
    options = jnp.concatenate([allowed, occupied[None]], 0)
    sharp = jnp.where(options, jnp.exp(log_sharp), 0.0)
    heat = soft_heat(psi, occupied, sharp, scene.tvec, target, t, mass)
    highways = soft_highways(heat, target, params.tau_h, t, relative=params.highway_relative,
                             smoothing=params.highway_smoothing, nms=params.highway_nms)
    candidate = highways * occupied
    centers = lattice.cell_centers(obj.shape, scene.cell_size, scene.origin)
    anchors = soft_anchors(heat, candidate, occupied, centers, params.anchor_lambda, t)
    feasible = jnp.where(allowed, jax.nn.sigmoid(z), 0.0)
    return SoftFabric(value, raw, length, jnp.moveaxis(policy, 0, -1), heading, jnp.moveaxis(feasible, 0, -1),
                      occupied, psi, heat, highways, occupied * (1.0 - highways), candidate, anchors, t, mass,
                      delivered)


def _selected_raw(obj, occupied, target, raw, allowed, policy):
    """``f32[H, W]``: the policy's expected raw mass over the first-step options (step i then R(N_i))."""
    cont = allowed & ~lattice.neighbours(target, False)
    r_opt = jnp.where(occupied, obj, 0.0)[None] + jnp.where(cont, lattice.neighbours(raw, 0.0), 0.0)
    return jnp.where(occupied, jnp.sum(policy[:8] * r_opt, 0) + policy[8] * obj, 0.0)


_soft_build_jit = grid_jit(_soft_build)


def build_soft_fabric(scene, params: FabricParams, spill=None) -> SoftFabric:
    """The soft fabric of ``scene`` (jitted; one trace per grid shape and static options, whatever
    the temperature). Call through ``jaxplan.build_fabric`` with ``FabricParams(temperature=t)``.
    spill: None (Eq. 5) or ``SpillParams`` (Eq. 6 softened, ``soft_select``; lam and threshold traced)."""
    if params.temperature is None:
        raise ValueError("FabricParams.temperature: the soft kernels need a temperature > 0; got None.")
    return _soft_build_jit(scene, params, spill)
