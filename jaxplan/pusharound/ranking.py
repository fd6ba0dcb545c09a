"""Ranking of blocking gaps (Section III-B): frontier gaps, one-hop cost (Eq. 8), presearch (Eq. 9).

Pipeline of :func:`rank_gaps`:

1. Frontier extraction: :func:`jaxplan.pusharound.wccg.connectivity` returns the blocking loop L.
2. Candidate gaps: the bottleneck bridges on L, grouped by the pair of bodies they join (a gap is
   "the opening between bodies a and b"); pairs of immovable bodies and pieces of one body are not
   gaps. Each :class:`Gap` carries its adjacent movables (what the search pushes), its width (the
   narrowest bridge of the pair on L) and its outside insertion point ``o_g``.
3. One-hop cost (Eq. 8): ``C(g) = lambda_t C_t + lambda_p C_p`` with
   ``C_t = max_i |x_Ri - o_g|`` (the team assembles at the gap: the farthest robot sets the time;
   straight-line distance, a lower bound of the collision-free one) and
   ``C_p = (W - w_g) * m_g / mass_ref`` (the opening still needed times the lightest adjacent
   movable's mass: the work against floor friction of pushing it aside, in units of mass_ref).
4. Goal heuristic ``h(g) = eta |o_g - goal|``.
5. Presearch (Eq. 9): from each first-hop gap, a beam search virtually crosses gaps (removes the
   pair's bridges and recomputes the frontier; the robots move to ``o_g``) for at most ``depth``
   further gaps, keeping ``beam`` states per level ranked by their accumulated cost. Leaves are the
   states whose start face reaches the goal (preferred) or the states left at the depth limit.
   ``Cost(g) = C(g) + min_leaves sum_{g' in leaf} (C(g') + h(g'))``.

The geometry (which leaves exist) is computed once with concrete weights; the cost is then the JAX
function :func:`gap_costs` of ``RankingParams``'s traced weights over the fixed leaf features,
differentiable (a.e.) and ``vmap``-able: a tuner may fit ``lambda_t, lambda_p, eta`` to realised costs
by gradient, rebuilding the leaves when the weights move far (the beam's pruning uses them).
"""
from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import shapely
from shapely.geometry import Polygon

from jaxplan.pusharound.faces import BRIDGE_EPS
from jaxplan.pusharound.scene import PushScene
from jaxplan.pusharound.wccg import MOVABLE, WCCG, Frontier, build_wccg, connectivity, frontier_bridges

__all__ = ["Gap", "PresearchFeatures", "Ranking", "RankingParams", "candidate_gaps", "gap_costs",
           "one_hop_terms", "rank_gaps"]

# Added to the cost of a first-hop gap whose every presearch branch dead-ends (no crossable gap on
# the next frontier). Finite, so that gradients stay finite (see ANCHORS: jaxscape's trick).
DEAD_END_PENALTY = 1e3


@dataclasses.dataclass(frozen=True)
class RankingParams:
    """Weights of Eqs. 8-9 (traced) and the presearch's size (static).

    Traced: lambda_t (per metre of robot travel), lambda_p (per unit of C_p), eta (per metre to the
    goal), all > 0. Static: beam (states kept per level, >= 1), depth (gaps crossed after the first,
    >= 0), mass_ref [kg] (the mass that makes C_p dimensionless).
    """

    lambda_t: Any = 1.0
    lambda_p: Any = 1.0
    eta: Any = 0.5
    beam: int = 4
    depth: int = 3
    mass_ref: float = 10.0

    def replace(self, **changes) -> RankingParams:
        return dataclasses.replace(self, **changes)


jax.tree_util.register_dataclass(RankingParams, data_fields=["lambda_t", "lambda_p", "eta"],
                                 meta_fields=["beam", "depth", "mass_ref"])


def validate_ranking_params(params: RankingParams) -> None:
    if not isinstance(params, RankingParams):
        raise ValueError(f"params: expected a RankingParams, got {type(params).__name__}.")
    for name in ("lambda_t", "lambda_p", "eta"):
        v = getattr(params, name)
        if isinstance(v, jax.core.Tracer):
            continue
        arr = np.asarray(v, np.float64)
        if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
            raise ValueError(f"RankingParams.{name}: must be finite and > 0; got {v!r}.")
    for name, lo in (("beam", 1), ("depth", 0)):
        v = getattr(params, name)
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < lo:
            raise ValueError(f"RankingParams.{name}: must be an int >= {lo}; got {v!r}.")
    if not params.mass_ref > 0:
        raise ValueError(f"RankingParams.mass_ref: must be > 0 kg; got {params.mass_ref!r}.")


class Gap(NamedTuple):
    """A candidate gap. bodies: (a, b) WCCG body indices (a < b); movables: scene.movables indices
    of the movable ones (what a push task may move); bridges: i32[k] its bridges on the frontier;
    width: w_g [m] (narrowest); points: f64[2, 2] that bridge's nodes; insertion: o_g f64[2] (W/2 off
    the bridge midpoint, on the start's side); mass: lightest adjacent movable [kg]."""

    bodies: tuple
    movables: tuple
    bridges: np.ndarray
    width: float
    points: np.ndarray
    insertion: np.ndarray
    mass: float


class PresearchFeatures(NamedTuple):
    """Per first-hop gap k and presearch leaf p: first f[K, 2] = (C_t, C_p) of the gap itself;
    tail f[K, P, 3] = (sum C_t, sum C_p, sum h/eta) over the leaf's later gaps; mask bool[K, P] the
    leaves the minimum runs over; penalty f[K] (DEAD_END_PENALTY when every branch dead-ends)."""

    first: Any
    tail: Any
    mask: Any
    penalty: Any


class Ranking(NamedTuple):
    """Output of :func:`rank_gaps`. connected: Eq. 7 already holds (then no gaps). frontier: the loop
    L. gaps: the first-hop candidates; cost f64[K]: Cost(g) of Eq. 9; order i32[K]: argsort (ascending);
    sequences: for each gap, the gaps of its best leaf Pi*(g); features: the JAX inputs of
    :func:`gap_costs`."""

    connected: bool
    frontier: Frontier | None
    gaps: tuple
    cost: np.ndarray
    order: np.ndarray
    sequences: tuple
    features: PresearchFeatures | None

    def ranked(self) -> list:
        """The gaps in ascending predicted cost."""
        return [self.gaps[k] for k in self.order]


# ---------------------------------------------------------------------------------------------------
# Candidate gaps
# ---------------------------------------------------------------------------------------------------

def candidate_gaps(g: WCCG, frontier: Frontier, removed=()) -> list:
    """The gaps on the frontier loop (step 2 of the module docstring), in body-pair order."""
    br = frontier_bridges(g, frontier, removed)
    bodies = g.bridge_bodies[br]
    kinds = g.body_kind[bodies]
    ok = (bodies[:, 0] != bodies[:, 1]) & np.any(kinds == MOVABLE, axis=1)
    region = frontier.region()
    gaps = []
    for pair in sorted({tuple(int(v) for v in b) for b in bodies[ok]}):
        mine = br[ok][np.all(bodies[ok] == pair, axis=1)]
        e = mine[np.argmin(g.bridge_width[mine])]
        gaps.append(Gap(bodies=pair,
                        movables=tuple(int(g.body_index[b]) for b in pair if g.body_kind[b] == MOVABLE),
                        bridges=mine, width=float(g.bridge_width[e]), points=g.bridge_pts[e].copy(),
                        insertion=_insertion(g, e, region, frontier.encloses_start),
                        mass=float(min(g.body_mass[b] for b in pair if g.body_kind[b] == MOVABLE))))
    return gaps


def _insertion(g: WCCG, e: int, region: Polygon, encloses_start: bool) -> np.ndarray:
    """o_g: the bridge midpoint moved W/2 along the bridge normal, to the start's side of L."""
    pu, pv = g.bridge_pts[e]
    mid = 0.5 * (pu + pv)
    d = pv - pu
    if np.linalg.norm(d) < 1e-9:  # touching bodies: the contact normal joins the two components
        u, v = g.bridge_uv[e]
        d = g.centroids[v] - g.centroids[u]
    n = np.array([-d[1], d[0]]) / max(np.linalg.norm(d), 1e-12)
    # Probe just off the strip when the gap is open, farther when the bodies touch (the probe must
    # leave the crack between them).
    tau = 3.0 * BRIDGE_EPS * g.width if g.bridge_width[e] > 10 * BRIDGE_EPS * g.width else 0.25 * g.width
    inside = bool(shapely.contains_xy(region, *(mid + tau * n)))
    side = n if inside == encloses_start else -n
    return mid + 0.5 * g.width * side


def one_hop_terms(gap: Gap, team, width: float, mass_ref: float) -> tuple:
    """(C_t, C_p) of Eq. 8 for ``gap`` with robots at ``team: f[N, 2]`` (see the module docstring)."""
    team = np.asarray(team, np.float64).reshape(-1, 2)
    c_t = float(np.max(np.linalg.norm(team - gap.insertion, axis=1))) if len(team) else 0.0
    c_p = max(width - gap.width, 0.0) * gap.mass / mass_ref
    return c_t, c_p


# ---------------------------------------------------------------------------------------------------
# Presearch
# ---------------------------------------------------------------------------------------------------

class _Frontiers:
    """Memo of (removed gaps) -> (same_face, candidate gaps): Remark 3's cached transitions."""

    def __init__(self, g: WCCG, start, goal):
        self.g, self.start, self.goal, self.memo = g, start, goal, {}

    def __call__(self, removed: frozenset):
        if removed not in self.memo:
            conn = connectivity(self.g, self.start, self.goal, removed=removed)
            cands = [] if conn.same_face else candidate_gaps(self.g, conn.frontier, removed)
            self.memo[removed] = (conn.same_face, cands, conn.frontier)
        return self.memo[removed]


def _presearch(frontiers: _Frontiers, first: Gap, goal, params: RankingParams, width: float):
    """Leaves of the beam search after crossing ``first``: list of (features f[3], seq, status),
    status 2 = connected, 1 = depth limit, 0 = dead end."""
    lt, lp, eta = (float(np.asarray(v)) for v in (params.lambda_t, params.lambda_p, params.eta))
    goal = np.asarray(goal, np.float64)
    beam = [(frozenset([first.bodies]), first.insertion, np.zeros(3), ())]
    leaves = []
    for level in range(params.depth + 1):
        children = []
        for removed, team, feats, seq in beam:
            same_face, cands, _ = frontiers(removed)
            if same_face:
                leaves.append((feats, seq, 2))
            elif level == params.depth:
                leaves.append((feats, seq, 1))
            elif not cands:
                leaves.append((feats, seq, 0))
            else:
                for gap in cands:
                    c_t, c_p = one_hop_terms(gap, team, width, params.mass_ref)
                    h = float(np.linalg.norm(gap.insertion - goal))
                    children.append((removed | {gap.bodies}, gap.insertion,
                                     feats + np.array([c_t, c_p, h]), seq + (gap,)))
        if not children:
            break
        score = [lt * f[0] + lp * f[1] + eta * f[2] for _, _, f, _ in children]
        beam = [children[k] for k in np.argsort(score, kind="stable")[:params.beam]]
    return leaves


def _leaf_mask(status: np.ndarray) -> tuple:
    """Which leaves the minimum runs over: connected ones if any, else depth-limited ones, else all
    (dead ends, with the penalty)."""
    for level in (2, 1):
        if np.any(status == level):
            return status == level, 0.0
    return np.ones_like(status, bool), DEAD_END_PENALTY


def gap_costs(params: RankingParams, feats: PresearchFeatures):
    """Eq. 9 for every first-hop gap: f[K]. Pure JAX in the traced weights (jit / vmap / grad)."""
    # As JAX arrays (numpy float64 features become JAX's default float, which the fill value below
    # must fit).
    feats = PresearchFeatures(*(jnp.asarray(x) for x in feats))
    lt, lp, eta = params.lambda_t, params.lambda_p, params.eta
    one_hop = lt * feats.first[:, 0] + lp * feats.first[:, 1]
    tail = lt * feats.tail[..., 0] + lp * feats.tail[..., 1] + eta * feats.tail[..., 2]
    # Masked-out leaves get a large finite value, not inf: keeps gradients finite.
    best = jnp.min(jnp.where(feats.mask, tail, jnp.finfo(tail.dtype).max / 4), axis=-1)
    return one_hop + best + feats.penalty


def rank_gaps(scene: PushScene, params: RankingParams = RankingParams(), g: WCCG | None = None,
              robots=None, first=None) -> Ranking:
    """Rank the blocking gaps of ``scene`` (Section III-B). ``g``: a prebuilt WCCG of the scene;
    ``robots: f[N, 2]``: robot positions (default ``scene.robots``); ``first``: if given, a collection
    of body pairs ``(a, b)``: only the frontier gaps among them are presearched and returned (the
    hybrid search asks only for gaps whose cost it has not memoised)."""
    validate_ranking_params(params)
    g = build_wccg(scene) if g is None else g
    team = np.asarray(scene.robots if robots is None else robots, np.float64).reshape(-1, 2)
    frontiers = _Frontiers(g, scene.start, scene.goal)
    same_face, cands, frontier = frontiers(frozenset())
    conn = connectivity(g, scene.start, scene.goal) if same_face else None
    if same_face:
        return Ranking(bool(conn.connected), None, (), np.zeros(0), np.zeros(0, np.int32), (), None)
    if first is not None:
        wanted = {tuple(sorted(int(v) for v in pair)) for pair in first}
        cands = [gap for gap in cands if gap.bodies in wanted]
    if not cands:
        return Ranking(False, frontier, (), np.zeros(0), np.zeros(0, np.int32), (), None)
    all_leaves = [_presearch(frontiers, gap, scene.goal, params, g.width) for gap in cands]
    n_leaves = max(len(lv) for lv in all_leaves)
    k = len(cands)
    first = np.array([one_hop_terms(gap, team, g.width, params.mass_ref) for gap in cands])
    tail = np.zeros((k, n_leaves, 3))
    mask = np.zeros((k, n_leaves), bool)
    penalty = np.zeros(k)
    for i, leaves in enumerate(all_leaves):
        status = np.array([s for _, _, s in leaves])
        tail[i, :len(leaves)] = [f for f, _, _ in leaves]
        m, penalty[i] = _leaf_mask(status)
        mask[i, :len(leaves)] = m
    feats = PresearchFeatures(jnp.asarray(first), jnp.asarray(tail), jnp.asarray(mask), jnp.asarray(penalty))
    # The concrete costs from features padded to power-of-two sizes (padded rows are independent and
    # dropped): JAX compiles its primitives per shape, and the hybrid search ranks many frontiers.
    kp, pp = 1 << max(k - 1, 0).bit_length(), 1 << max(n_leaves - 1, 0).bit_length()
    padded = PresearchFeatures(jnp.asarray(np.pad(first, ((0, kp - k), (0, 0)))),
                               jnp.asarray(np.pad(tail, ((0, kp - k), (0, pp - n_leaves), (0, 0)))),
                               jnp.asarray(np.pad(mask, ((0, kp - k), (0, pp - n_leaves)))),
                               jnp.asarray(np.pad(penalty, (0, kp - k))))
    cost = np.asarray(gap_costs(params, padded), np.float64)[:k]
    tail_cost = (float(params.lambda_t) * tail[..., 0] + float(params.lambda_p) * tail[..., 1]
                 + float(params.eta) * tail[..., 2])
    best = np.argmin(np.where(mask, tail_cost, np.inf), axis=1)
    sequences = tuple(all_leaves[i][best[i]][1] for i in range(k))
    return Ranking(False, frontier, tuple(cands), cost, np.argsort(cost, kind="stable").astype(np.int32),
                   sequences, feats)
