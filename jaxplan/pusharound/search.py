"""Physics-informed hybrid search (Section III-C, Algorithm 1): which obstacles to push, and how.

Best-first search over nodes ``nu = (s, pi)``: ``s`` the poses of every movable and the robot
positions, ``pi`` the partial schedule. Priority (Eq. 10)::

    f(nu) = chi(nu) + heuristic_weight * (min_{g in Rank(nu), unexplored} Cost(g) - progress_bonus * opened)

``chi`` the realised cost of the schedule (sum of Eq. 11 over its pushes), ``Cost(g)`` the predicted
cost-to-connect of gap g: Eq. 8's one-hop cost plus Eq. 9's continuation, by default minimised
exactly over the skeleton's face graph (:func:`face_graph`, ``presearch_mode="graph"``), or by
:func:`jaxplan.pusharound.ranking.rank_gaps`'s beam (``"beam"``); with ``presearch=False`` the
one-hop cost only. ``heuristic_weight`` is the paper's "heuristic factor" (10); ``opened`` counts
the schedule's pushes that opened a gap and lowered the estimate.

Loop (one iteration = one pop):

1. Pop the node of least ``f``. A child is *evaluated lazily*, when it is first popped: its WCCG,
   Eq. 7 (termination: success if a W-clear path exists) and its ranking. Its priority, until then
   estimated from its parent's ranking (below), is corrected and the node goes back to the queue if
   another node is now better (siblings from the same gap are shifted by the error seen first).
2. Expansion: the node's candidate pushes ``tau = (g, v, xi)`` are generated once (for the movables
   adjacent to each ranked gap, gaps in a seeded softmax order over their normalised costs,
   temperature 0.05; per movable, world directions around "away from the gap", team sizes, speeds,
   and yaw rates; the contact mode ``xi`` from :func:`push.face_contacts`), ordered by the ModeTable's
   prior, and consumed in batches: candidates pass the geometric quick-pass until ``batch_size``
   (<= ``max_batch``) survive, and ALL survivors are simulated in ONE :func:`push.simulate_pushes`
   call.
3. Every valid rollout that widened its gap (by ``min_progress``, or opened it: the two bodies are
   ``>= W + open_margin`` apart) becomes a child ``nu' = (s', pi + tau)``, ``chi' = chi + delta_T + alpha delta_J``
   (Eq. 11). Its estimate: the gap's ``Cost(g)`` minus the part of the one-hop cost it achieved
   (opened: the presearch tail ``Cost(g) - C(g)``). Children that opened a gap whose crossing the
   presearch predicts to connect are checked against Eq. 7 at once (Algorithm 1, line 5.5).
4. Deferred expansion and reinsertion: a node whose candidate list is not used up goes back to the
   queue with the priority of its best unexplored gap. Without ``reinsertion`` a node is expanded
   once (its first batch) and dropped.

States are de-duplicated on rounded poses (``dedup_m``, ``dedup_rad``). The ModeTable
(:mod:`jaxplan.pusharound.modetable`) records every simulated mode and orders later candidates on
obstacles with the same shape signature: validated modes first, modes that failed twice or more last.

Endpoint disks (Remark 5): when start and goal share a face but a disk ``B(., W/2)`` is not free, the
movables that intrude are the targets (pushed away from the endpoint).
"""
from __future__ import annotations

import dataclasses
import heapq
import math
import time
from typing import Callable, NamedTuple

import numpy as np
import shapely
from shapely import affinity

from jaxplan.pusharound.modetable import ModeKey, ModeTable
from jaxplan.pusharound.physics import PushWorld, build_push_world
from jaxplan.pusharound.push import (MAX_BATCH, PushTask, face_contacts, make_push_simulator, push_cost, quick_pass,
                                     simulate_pushes, stack_tasks)
from jaxplan.pusharound.ranking import (DEAD_END_PENALTY, Gap, RankingParams, candidate_gaps, one_hop_terms,
                                        rank_gaps, validate_ranking_params)
from jaxplan.pusharound.scene import PushScene
from jaxplan.pusharound.wccg import (_BRIDGE_EPS, MOVABLE, WCCG, _cluster_region, _rings, _skeleton, build_wccg,
                                     connectivity, w_clear_path)

__all__ = ["SEARCH_RANKING", "FaceGraph", "ScheduledPush", "face_graph", "SearchConfig", "SearchResult", "SearchStats", "plan_pushes"]

_BUCKETS = (16, 64)   # physics batch sizes (the C engine's policy is jitted once per size and scene)

# The search's default ranking: Eq. 8-9 weights as RankingParams(), a smaller presearch (beam 2,
# depth 2: the same first three gaps as beam 4, depth 3 on nominal seeds 0-3 at about half the time).
SEARCH_RANKING = RankingParams(beam=2, depth=2)


@dataclasses.dataclass(frozen=True)
class SearchConfig:
    """Switches and budgets of :func:`plan_pushes` (module docstring).

    presearch: Eq. 9 ranking (False: one-hop cost Eq. 8 only); presearch_mode: "graph" (Eq. 9's
    continuation by Dijkstra over the face graph, :func:`face_graph`) or "beam" (``rank_gaps``, its
    beam and depth from the ``ranking`` argument); mode_table: ModeTable priors;
    quick_pass: geometric rejection before physics; reinsertion: deferred expansion / reinsertion of
    partly expanded nodes; max_batch: candidates per physics call (<= 64); batch_size: candidates an
    expansion simulates (capped by max_batch; 16 on the 2-core CPU: the paper's 64 cost four times
    the physics per expansion, and the deferred expansion reaches the rest later); time_limit_s: wall-clock
    budget [s]; max_expansions: batches simulated at most; backend: "c" | "mjx" | "auto"; seed: gap
    sampling. heuristic_weight: factor on the estimate in Eq. 10; temperature: softmax temperature of
    the gap order over costs normalised to [0, 1]; gaps_per_node: ranked gaps whose movables get
    candidates in the first pass (the rest follow after a node is re-popped); n_directions: push
    directions per movable; first_directions: of those, how many (nearest "away from the gap") enter
    the first pass, at the first speed only; speeds: candidate body speeds [m/s] (0: the speed that opens the gap in
    ``duration``); omegas: yaw rates [rad/s] of the second pass; team_sizes: robots per push;
    duration: push duration [s] (<= the 2 s horizon); min_progress: widening [m] that makes a child;
    dedup_m, dedup_rad: state de-duplication grid; terminal_checks: children checked against Eq. 7 at
    once per expansion (those predicted to connect); open_margin: a gap counts as opened at W + this [m];
    reinsert_penalty: added to a reinserted node's estimate per batch it already
    had (cost units of Eq. 9); progress_bonus: subtracted from the estimate per gap the node's
    schedule opened that lowered the estimate (cost units; without it the search goes
    breadth-first over equally rated states); stuck_penalty: added to a gap's cost (one-hop and in
    the face graph) for the rest of the search each time a batch's pushes on it all fail to widen it;
    refresh_stuck: an evaluated node popped again first takes the stuck penalties added since its
    evaluation into its targets' one-hop costs (and goes back to the queue if it is no longer best).
    """

    presearch: bool = True
    presearch_mode: str = "graph"
    mode_table: bool = True
    quick_pass: bool = True
    reinsertion: bool = True
    max_batch: int = 64
    batch_size: int = 16
    time_limit_s: float = 60.0
    max_expansions: int = 200
    backend: str = "auto"
    seed: int = 0
    heuristic_weight: float = 10.0
    temperature: float = 0.05
    gaps_per_node: int = 3
    first_directions: int = 5
    n_directions: int = 8
    speeds: tuple = (0.0, 0.45)
    omegas: tuple = (0.35, -0.35)
    team_sizes: tuple = (2, 1)
    duration: float = 2.0
    min_progress: float = 0.05
    dedup_m: float = 0.02
    dedup_rad: float = 0.05
    terminal_checks: int = 4
    open_margin: float = 0.01
    reinsert_penalty: float = 1.0
    progress_bonus: float = 1.0
    stuck_penalty: float = 0.5
    refresh_stuck: bool = True

    def __post_init__(self):
        for name in ("presearch", "mode_table", "quick_pass", "reinsertion", "refresh_stuck"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"SearchConfig.{name}: must be a bool; got {getattr(self, name)!r}.")
        for name, lo, hi in (("max_batch", 1, MAX_BATCH), ("max_expansions", 1, None), ("gaps_per_node", 1, None),
                             ("n_directions", 1, 64), ("terminal_checks", 0, None),
                             ("first_directions", 1, 64), ("batch_size", 1, MAX_BATCH)):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < lo or (hi is not None and v > hi):
                raise ValueError(f"SearchConfig.{name}: must be an int in [{lo}, {hi or 'inf'}]; got {v!r}.")
        for name in ("time_limit_s", "temperature", "duration", "dedup_m", "dedup_rad"):
            v = getattr(self, name)
            if not isinstance(v, (int, float, np.floating, np.integer)) or not math.isfinite(v) or not v > 0:
                raise ValueError(f"SearchConfig.{name}: must be a finite number > 0; got {v!r}.")
        for name in ("heuristic_weight", "min_progress", "reinsert_penalty", "open_margin", "progress_bonus",
                     "stuck_penalty"):
            v = getattr(self, name)
            if not isinstance(v, (int, float, np.floating, np.integer)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"SearchConfig.{name}: must be a finite number >= 0; got {v!r}.")
        if self.presearch_mode not in ("graph", "beam"):
            raise ValueError(f"SearchConfig.presearch_mode: expected 'graph' or 'beam'; got {self.presearch_mode!r}.")
        if self.backend not in ("c", "mjx", "auto"):
            raise ValueError(f"SearchConfig.backend: expected 'c', 'mjx' or 'auto'; got {self.backend!r}.")
        if not isinstance(self.seed, (int, np.integer)) or isinstance(self.seed, bool):
            raise ValueError(f"SearchConfig.seed: must be an int; got {self.seed!r}.")
        if not self.speeds or any(not (isinstance(s, (int, float)) and 0 <= s <= 0.8) for s in self.speeds):
            raise ValueError(f"SearchConfig.speeds: need speeds in [0, 0.8] m/s (0: just opening); got {self.speeds!r}.")
        if any(not (isinstance(w, (int, float)) and math.isfinite(w)) for w in self.omegas):
            raise ValueError(f"SearchConfig.omegas: must be finite numbers [rad/s]; got {self.omegas!r}.")
        if not self.team_sizes or any(not isinstance(n, int) or n < 1 for n in self.team_sizes):
            raise ValueError(f"SearchConfig.team_sizes: must be ints >= 1; got {self.team_sizes!r}.")

    def replace(self, **changes) -> "SearchConfig":
        return dataclasses.replace(self, **changes)


class ScheduledPush(NamedTuple):
    """One push of the schedule. task: the :class:`PushTask` (unbatched); gap: the WCCG body pair it
    opens (``(body,)`` for an endpoint-disk push, Remark 5); cost: Eq. 11; poses_before / after
    f64[M, 3]: every movable before / after (the validating rollout); robots_before / after f64[N, 2]."""

    task: PushTask
    gap: tuple
    cost: float
    poses_before: np.ndarray
    poses_after: np.ndarray
    robots_before: np.ndarray
    robots_after: np.ndarray


class SearchStats(NamedTuple):
    """planning_time_s: wall clock; expansions: batches simulated; simulated_pushes: rollouts run
    (padding excluded); physics_calls: ``simulate_pushes`` calls; mode_table_hits: candidates
    simulated whose mode the table had validated on that shape; evaluations: nodes ranked (targets
    and estimate); checks: Eq. 7 tests (WCCG + connectivity); nodes: nodes created; quick_pass_rejected: candidates the quick-pass removed;
    valid_rollouts: rollouts physics validated; children: children pushed to the queue; rank_calls;
    max_depth: longest schedule seen; time_*_s: time in ranking (incl. WCCG and Eq. 7), the
    quick-pass, physics, and candidate generation."""

    planning_time_s: float
    expansions: int
    simulated_pushes: int
    physics_calls: int
    mode_table_hits: int
    evaluations: int = 0
    checks: int = 0
    nodes: int = 0
    quick_pass_rejected: int = 0
    valid_rollouts: int = 0
    children: int = 0
    rank_calls: int = 0
    max_depth: int = 0
    time_rank_s: float = 0.0
    time_quick_pass_s: float = 0.0
    time_physics_s: float = 0.0
    time_candidates_s: float = 0.0


class SearchResult(NamedTuple):
    """success; schedule: list of :class:`ScheduledPush` (on failure: the partial schedule of the
    node closest to the goal by its estimate); final_scene: the scene after the schedule (poses and
    robots); path: f64[P, 2] W-clear path (None on failure); stats; reason: "" on success, else why
    the search stopped ("time limit", "expansion limit", "exhausted")."""

    success: bool
    schedule: list
    final_scene: PushScene
    path: np.ndarray | None
    stats: SearchStats
    reason: str


# --------------------------------------------------------------------------------------- internals

class _Target(NamedTuple):
    """What an expansion tries to open: a gap (bodies = WCCG body pair) or an endpoint disk
    (bodies = (body,)). movables: the movables to push; width: current gap width (endpoint: the
    intruder's clearance); cost: Cost(g); tail: Cost(g) - C(g); one_hop: C(g); away: per movable a
    unit world direction away from the gap; final: crossing it is predicted to connect."""

    kind: str
    bodies: tuple
    movables: tuple
    width: float
    cost: float
    tail: float
    one_hop: float
    away: dict
    final: bool


class _Cand(NamedTuple):
    """A candidate push: target index, movable, spec = (world angle, team size, speed, omega), its
    ModeTable key, whether the table had validated it, and the task (built when first needed)."""

    target: int
    movable: int
    spec: tuple
    key: ModeKey
    hit: bool
    task: PushTask | None = None
    passed: bool = False      # survived the quick-pass (or it is off)
    deferred: bool = False    # its start was walled off from the robots once: moved to the list's end


@dataclasses.dataclass
class _Node:
    nid: int
    poses: np.ndarray
    robots: np.ndarray
    schedule: tuple
    chi: float
    h: float
    evaluated: bool = False
    targets: list | None = None
    cands: list | None = None
    cursor: int = 0
    children: int = 0
    expansions: int = 0
    opened: int = 0             # gaps (or endpoint disks) the schedule opened that lowered the estimate
    parent_h: float = math.inf
    check: tuple | None = None  # (WCCG, Connectivity, path) once Eq. 7 was tested
    origin: tuple = ()        # (parent nid, target index): siblings share their estimate's error
    corrected: bool = False
    stuck_at: dict | None = None  # gap bodies -> the stuck penalty its target's cost includes

    @property
    def depth(self) -> int:
        return len(self.schedule)


class _Geometry:
    """Body outlines for the progress tests (body frame for movables, world for the rest)."""

    def __init__(self, scene: PushScene):
        self.scene = scene
        self.m = len(scene.movables)
        self.body_frame = [shapely.union_all(list(mv.pieces)) for mv in scene.movables]
        self.fixed = [f.polygon for f in scene.fixed]
        x0, y0, x1, y1 = scene.workspace
        t = 1.0
        self.walls = shapely.union_all([shapely.box(x0 - t, y0 - t, x0, y1 + t), shapely.box(x1, y0 - t, x1 + t, y1 + t),
                                        shapely.box(x0, y0 - t, x1, y0), shapely.box(x0, y1, x1, y1 + t)])

    def movable(self, m: int, pose):
        x, y, psi = (float(v) for v in pose)
        return affinity.translate(affinity.rotate(self.body_frame[m], psi, origin=(0, 0), use_radians=True), x, y)

    def body(self, b: int, poses):
        """World polygon of WCCG body ``b`` (movables 0..M-1, fixed M..M+F-1, walls M+F)."""
        if b < self.m:
            return self.movable(b, poses[b])
        if b < self.m + len(self.fixed):
            return self.fixed[b - self.m]
        return self.walls


def _softmax_order(costs: np.ndarray, temperature: float, rng: np.random.Generator) -> np.ndarray:
    """A seeded sample without replacement from softmax(-normalised cost / T) (Gumbel top-k)."""
    c = np.asarray(costs, np.float64)
    if len(c) <= 1:
        return np.arange(len(c))
    span = float(c.max() - c.min())
    z = (c - c.min()) / span if span > 0 else np.zeros_like(c)
    return np.argsort(z / temperature - rng.gumbel(size=len(c)), kind="stable")


def _state_key(poses, robots, cfg: SearchConfig) -> tuple:
    p = np.asarray(poses, np.float64)
    yaw = np.round(np.angle(np.exp(1j * p[:, 2])) / cfg.dedup_rad).astype(np.int64)
    xy = np.round(p[:, :2] / cfg.dedup_m).astype(np.int64)
    return tuple(np.concatenate([xy.reshape(-1), yaw]).tolist())


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-12 else np.array([1.0, 0.0])


def _check_inputs(scene, config, ranking, mode_table, world):
    if not isinstance(scene, PushScene):
        raise ValueError(f"scene: expected a PushScene; got {type(scene).__name__}.")
    if not isinstance(config, SearchConfig):
        raise ValueError(f"config: expected a SearchConfig; got {type(config).__name__}.")
    validate_ranking_params(ranking)
    if np.asarray(scene.robots).reshape(-1, 2).shape[0] == 0:
        raise ValueError("scene.robots: the search needs at least one robot.")
    if mode_table is not None and not isinstance(mode_table, ModeTable):
        raise ValueError(f"mode_table: expected a ModeTable or None; got {type(mode_table).__name__}.")
    if world is not None:
        if not isinstance(world, PushWorld):
            raise ValueError(f"world: expected a PushWorld (build_push_world); got {type(world).__name__}.")
        if len(world.scene.movables) != len(scene.movables) or len(world.robot_adr) != len(scene.robots):
            raise ValueError("world: built for another scene (movable or robot count differs); "
                             "use build_push_world(scene).")



# ------------------------------------------------------------------------------ face-graph presearch

class FaceGraph(NamedTuple):
    """The faces of the WCCG skeleton and the gaps between them (the "graph" presearch).

    faces: per gap (body pair with a movable) the set of face ids its bottleneck bridges border;
    start_face, goal_face: the faces of the endpoints (-1: outside every ring, -2: inside an
    obstacle cluster); tail: per gap, the least cost of the gap sequence after crossing it to reach
    the goal face (Eq. 9's continuation, minimised by Dijkstra instead of a beam of limited depth;
    inf when no sequence reaches the goal); final: per gap, crossing it reaches the goal face.
    """

    faces: dict
    start_face: int
    goal_face: int
    tail: dict
    final: dict


def face_graph(g: WCCG, goal, params: RankingParams, extra: dict | None = None, _sk=None) -> FaceGraph:
    """Eq. 9's continuation costs for every gap of the scene, without beam or depth limit.

    Faces are the rings of the skeleton's clusters (a point lies in the face of the smallest ring
    polygon containing it when that ring is a hole; in an obstacle when it is a cluster's exterior).
    A gap (a body pair with at least one movable and bottleneck bridges) borders the faces found a
    hair off each of its bridges, on both sides. Two gaps are neighbours when they border a common
    face (crossing one then the other is a gap sequence; crossed gaps stay open, so the region only
    grows). Costs follow Eqs. 8-9 after the first gap: moving the team from gap to gap
    ``lambda_t |m - m'|`` (bridge midpoints, straight line), widening ``lambda_p C_p(g')`` and the
    goal term ``eta |m' - goal|``; ``tail(g)`` is the least sum over sequences from ``g`` to a gap
    bordering the goal face (0 if ``g`` borders it). One union per cluster (the same as Eq. 7's
    query) and a point location per bridge side: ~30-60 ms on a nominal scene. ``extra``: an added
    cost per gap (body pair), e.g. the search's penalty for gaps its pushes failed to widen.
    """
    lt, lp, eta = (float(np.asarray(v)) for v in (params.lambda_t, params.lambda_p, params.eta))
    w = float(g.width)
    goal = np.asarray(goal, np.float64)
    sk = _sk if _sk is not None else _skeleton(g)   # a connectivity query's skeleton shares its unions
    rings = []
    for c in np.unique(sk.labels):
        rings += _rings(_cluster_region(g, sk, int(c)), int(c))
    polys = np.asarray([r.region for r in rings], dtype=object)
    areas = shapely.area(polys)
    hole = np.asarray([r.is_hole for r in rings], bool)
    tree = shapely.STRtree(polys)

    def locate(points):
        points = np.asarray(points, np.float64).reshape(-1, 2)
        pi, ri = tree.query(shapely.points(points), predicate="within")
        face = np.full(len(points), -1, np.int64)
        best = np.full(len(points), np.inf)
        for p, r in zip(pi, ri):
            if areas[r] < best[p]:
                best[p] = areas[r]
                face[p] = r if hole[r] else -2
        return face

    # Bottleneck bridges between two bodies, one of them movable: the crossable gaps.
    bb = g.bridge_bodies
    kinds = g.body_kind[bb]
    ok = sk.active & (bb[:, 0] != bb[:, 1]) & np.any(kinds == MOVABLE, axis=1)
    edges = np.nonzero(ok)[0]
    pu, pv = g.bridge_pts[edges, 0], g.bridge_pts[edges, 1]
    mid = 0.5 * (pu + pv)
    d = pv - pu
    touch = np.linalg.norm(d, axis=1) < 10 * _BRIDGE_EPS * w
    if np.any(touch):   # touching bodies: across the line of their components' centroids
        uv = g.bridge_uv[edges[touch]]
        d[touch] = g.centroids[uv[:, 1]] - g.centroids[uv[:, 0]]
    n = np.stack([-d[:, 1], d[:, 0]], 1) / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    tau = np.where(touch, 0.05 * w, 3.0 * _BRIDGE_EPS * w)[:, None]
    side = locate(np.concatenate([mid + tau * n, mid - tau * n])).reshape(2, -1)
    goal_face = int(locate(goal[None])[0])
    faces, where, cp = {}, {}, {}
    for k, e in enumerate(edges):
        pair = (int(bb[e, 0]), int(bb[e, 1]))
        fs = faces.setdefault(pair, set())
        fs.update(int(f) for f in side[:, k] if f >= -1)
        if pair not in cp or g.bridge_width[e] < cp[pair][0]:
            cp[pair] = (float(g.bridge_width[e]), mid[k])
    for pair, (width_p, m) in cp.items():
        mass = min(g.body_mass[b] for b in pair if g.body_kind[b] == MOVABLE)
        where[pair] = (m, lp * max(w - width_p, 0.0) * mass / params.mass_ref + eta * float(np.linalg.norm(m - goal))
                       + (extra or {}).get(pair, 0.0))
    # Reverse Dijkstra from the gaps bordering the goal face.
    by_face: dict = {}
    for pair, fs in faces.items():
        for f in fs:
            by_face.setdefault(f, []).append(pair)
    tail = {pair: math.inf for pair in faces}
    heap = []
    for pair in by_face.get(goal_face, []):
        tail[pair] = 0.0
        heap.append((0.0, pair))
    heapq.heapify(heap)
    while heap:
        dist, pair = heapq.heappop(heap)
        if dist > tail[pair]:
            continue
        m, c = where[pair]
        for f in faces[pair]:
            for q in by_face[f]:
                nd = dist + c + lt * float(np.linalg.norm(where[q][0] - m))
                if nd < tail[q] - 1e-12:
                    tail[q] = nd
                    heapq.heappush(heap, (nd, q))
    final = {pair: goal_face in fs for pair, fs in faces.items()}
    return FaceGraph(faces, -1, goal_face, tail, final)

# ----------------------------------------------------------------------------------------- search

class _Search:
    def __init__(self, scene, config, ranking, world, sim, mode_table, progress):
        self.scene, self.cfg, self.params = scene, config, ranking
        self.world, self.sim = world, sim      # built in run() when the scene needs pushing
        if sim is not None and world is not None and sim.model is not world.model:
            raise ValueError("sim: built for another world; use make_push_simulator(world).")
        self.table = mode_table if mode_table is not None else ModeTable()
        self.use_table = bool(config.mode_table)
        self.progress = progress
        self.geom = _Geometry(scene)
        self.rng = np.random.default_rng(config.seed)
        self.n_robots = len(np.asarray(scene.robots).reshape(-1, 2))
        self.queue: list = []
        self.counter = 0
        self.seen: set = set()
        self.n_nodes = 0
        self.stats = dict(expansions=0, simulated_pushes=0, physics_calls=0, mode_table_hits=0, evaluations=0, checks=0,
                          nodes=0, quick_pass_rejected=0, valid_rollouts=0, children=0, rank_calls=0, max_depth=0,
                          time_rank_s=0.0, time_quick_pass_s=0.0, time_physics_s=0.0, time_candidates_s=0.0)
        self.best = None          # node with the least estimate (for failure reports)
        self.corrections: dict = {}   # origin -> error of the estimate seen on an evaluated sibling
        self.stuck: dict = {}         # gap bodies -> added cost (stuck_penalty per batch that failed it)
        self.tail_memo: dict = {}     # gap bodies -> (Eq. 9 tail, crossing it is predicted to connect)

    # ------------------------------------------------------------------ bookkeeping
    def _new_node(self, poses, robots, schedule, chi, h) -> _Node:
        node = _Node(self.n_nodes, np.asarray(poses, np.float64), np.asarray(robots, np.float64), tuple(schedule),
                     float(chi), float(h))
        self.n_nodes += 1
        self.stats["nodes"] = self.n_nodes
        self.stats["max_depth"] = max(self.stats["max_depth"], node.depth)
        return node

    def _push(self, node: _Node, f: float):
        self.counter += 1
        heapq.heappush(self.queue, (float(f), -node.depth, self.counter, node))

    def _f(self, node: _Node) -> float:
        """Eq. 10 with the heuristic factor, less ``progress_bonus`` per gap the schedule opened."""
        return node.chi + self.cfg.heuristic_weight * (node.h - self.cfg.progress_bonus * node.opened)

    def _emit(self, event: str, **kw):
        if self.progress is not None:
            info = dict(event=event, elapsed_s=time.perf_counter() - self.t0, queue=len(self.queue), **self.stats)
            info.update(kw)
            self.progress(info)

    # ------------------------------------------------------------------ evaluation (Eq. 7 + ranking)
    def _scene_at(self, node: _Node) -> PushScene:
        return self.scene.with_poses(node.poses).replace(robots=node.robots)

    def _check(self, node: _Node):
        """WCCG and Eq. 7 of ``node`` (Algorithm 1's termination test). Returns the W-clear path when
        Eq. 7 holds (and a path is found), else None; keeps the WCCG and frontier for ranking."""
        if node.check is not None:
            return node.check[2]
        t = time.perf_counter()
        self.stats["checks"] += 1
        state = self._scene_at(node)
        g = build_wccg(state)
        sk = _skeleton(g)
        conn = connectivity(g, state.start, state.goal, _sk=sk)
        path = w_clear_path(g, state.start, state.goal) if conn.connected else None
        node.check = (g, conn, path, sk)
        self.stats["time_rank_s"] += time.perf_counter() - t
        return path

    def _evaluate(self, node: _Node):
        """:meth:`_check`, then the targets of ``node`` and its estimate ``h`` (min Cost). Returns the
        W-clear path when Eq. 7 holds."""
        path = self._check(node)
        node.evaluated = True
        if path is not None:
            return path
        t = time.perf_counter()
        self.stats["evaluations"] += 1
        g, conn, _, sk = node.check
        state = self._scene_at(node)
        targets = []
        if not conn.same_face:
            gaps = candidate_gaps(g, conn.frontier)
            tails = {}
            if self.cfg.presearch and gaps and self.cfg.presearch_mode == "graph":
                self.stats["rank_calls"] += 1
                fg = face_graph(g, state.goal, self.params, self.stuck, _sk=sk)
                tails = {pair: (t if math.isfinite(t) else DEAD_END_PENALTY, fg.final[pair])
                         for pair, t in fg.tail.items()}
            elif self.cfg.presearch and gaps:
                # Eq. 9's tail of a gap (Cost - C: the predicted cost beyond it) depends on the region
                # behind the gap, not on where the robots are: memoised per gap (Remark 3's cached
                # transitions), and only gaps not seen before are presearched.
                new = [gap.bodies for gap in gaps if gap.bodies not in self.tail_memo]
                if new:
                    self.stats["rank_calls"] += 1
                    rk = rank_gaps(state, self.params, g=g, robots=node.robots, first=new)
                    for k, gap in enumerate(rk.gaps):
                        c_t, c_p = one_hop_terms(gap, node.robots, g.width, self.params.mass_ref)
                        one = float(self.params.lambda_t) * c_t + float(self.params.lambda_p) * c_p
                        cost = float(rk.cost[k])
                        self.tail_memo[gap.bodies] = (max(cost - one, 0.0),
                                                      len(rk.sequences[k]) == 0 and cost < DEAD_END_PENALTY)
                tails = self.tail_memo
            for gap in gaps:
                c_t, c_p = one_hop_terms(gap, node.robots, g.width, self.params.mass_ref)
                one = float(self.params.lambda_t) * c_t + float(self.params.lambda_p) * c_p + self.stuck.get(gap.bodies, 0.0)
                tail, final = tails.get(gap.bodies, (0.0, False))
                targets.append(self._gap_target(g, gap, node.poses, one + tail, tail, one, final))
            targets.sort(key=lambda tg: tg.cost)
        else:
            targets = self._endpoint_targets(node.poses)
        node.targets = targets
        node.stuck_at = {tg.bodies: self.stuck.get(tg.bodies, 0.0) for tg in targets if tg.kind == "gap"}
        node.h = min((tg.cost for tg in targets), default=math.inf)
        if node.opened and not node.h < node.parent_h - 1e-6:
            node.opened -= 1      # the gap it opened did not bring the goal closer: no bonus
        node.check = (None, None, None, None)      # the WCCG is not needed any more
        self.stats["time_rank_s"] += time.perf_counter() - t
        return None

    def _gap_target(self, g, gap: Gap, poses, cost, tail, one, final) -> _Target:
        away = {}
        pu, pv = gap.points
        for m in gap.movables:
            # Direction from the other body's bridge node to this body's (the push widens the gap).
            mine_first = int(g.comp_body[g.bridge_uv[gap.bridges[np.argmin(g.bridge_width[gap.bridges])], 0]]) == m
            d = (pu - pv) if mine_first else (pv - pu)
            if np.linalg.norm(d) < 1e-6:
                other = [b for b in gap.bodies if b != m]
                oc = self.geom.body(other[0], poses).centroid if other else shapely.Point(gap.insertion)
                d = np.asarray(poses[m][:2]) - np.array([oc.x, oc.y])
            away[m] = _unit(d)
        return _Target("gap", tuple(int(b) for b in gap.bodies), tuple(int(m) for m in gap.movables),
                       float(gap.width), float(cost), float(tail), float(one), away, bool(final))

    def _endpoint_targets(self, poses) -> list:
        r = 0.5 * float(self.scene.width)
        out = []
        for ep in (self.scene.start, self.scene.goal):
            pt = shapely.Point(ep)
            for m in range(self.geom.m):
                poly = self.geom.movable(m, poses[m])
                d = poly.distance(pt)
                if d < r:
                    c = np.asarray(poses[m][:2])
                    away = _unit(c - np.asarray(ep, np.float64))
                    cost = float(self.params.lambda_p) * (r - d) * self.scene.movables[m].mass / self.params.mass_ref
                    out.append(_Target("endpoint", (m,), (m,), float(d), cost + 1e-3, 0.0, cost + 1e-3, {m: away}, True))
        out.sort(key=lambda tg: tg.cost)
        return out

    # ------------------------------------------------------------------ candidates
    def _candidates(self, node: _Node) -> list:
        """Every candidate of ``node``, in the order they are tried (module docstring): the first
        pass (no yaw rate, the ``gaps_per_node`` first gaps of the sampled order) then the second
        (the other gaps, yaw rates); within a pass, round-robin over (gap, movable) so that a batch
        covers every gap's movables with their best modes; modes the ModeTable saw fail last."""
        t0 = time.perf_counter()
        cfg, targets = self.cfg, node.targets
        order = _softmax_order([tg.cost for tg in targets], cfg.temperature, self.rng)
        w = float(self.scene.width)
        step = 2 * math.pi / cfg.n_directions
        rel = [((k + 1) // 2) * step * (1 if k % 2 else -1) for k in range(cfg.n_directions)]  # 0, +d, -d, ...
        first, second, last = [], [], []
        for rank_pos, ti in enumerate(order):
            tg = targets[int(ti)]
            top = rank_pos < cfg.gaps_per_node
            for m in sorted(tg.movables, key=lambda m: self.scene.movables[m].mass):
                psi = float(node.poses[m, 2])
                need = (w - tg.width + 0.3) if tg.kind == "gap" else (0.5 * w - tg.width + 0.3)
                speeds = [round(min(max(need / self.duration, 0.1), 0.6), 3) if s == 0 else float(s)
                          for s in cfg.speeds]
                base = math.atan2(tg.away[m][1], tg.away[m][0])
                g1, g2 = [], []
                for omega in (0.0,) + tuple(om for om in cfg.omegas if om != 0):
                    for j, da in enumerate(rel):
                        ang = base + da
                        for n in cfg.team_sizes:
                            if n > self.n_robots:
                                continue
                            for si, s in enumerate(speeds):
                                key = self.table.key(ang - psi, n, s, omega)
                                rec = self.table.prior(self.scene.movables[m], key) if self.use_table else None
                                hit = rec is not None and rec.success > 0
                                bad = rec is not None and rec.trials >= 2 and rec.success == 0
                                # Reuse exactly a stored mode: the validated bin's centre.
                                ang_c = self.table.bin_angle(key.bin) + psi if hit else ang
                                score = (0 if hit else 1, -(rec.rate if rec else 0.5), j, si)
                                entry = (score, _Cand(int(ti), m, (ang_c, n, s, omega), key, bool(hit)))
                                if bad:
                                    last.append(entry)
                                elif top and (hit or (omega == 0 and si == 0 and j < cfg.first_directions)):
                                    g1.append(entry)
                                else:
                                    g2.append(entry)
                for grp, bucket in ((g1, first), (g2, second)):
                    if grp:
                        grp.sort(key=lambda x: x[0])
                        bucket.append([c for _, c in grp])
        last.sort(key=lambda x: x[0])

        def interleave(groups):
            out, k = [], 0
            while any(k < len(gr) for gr in groups):
                out += [gr[k] for gr in groups if k < len(gr)]
                k += 1
            return out

        self.stats["time_candidates_s"] += time.perf_counter() - t0
        return interleave(first) + interleave(second) + [c for _, c in last]

    def _task(self, node: _Node, cand: _Cand) -> PushTask | None:
        """The :class:`PushTask` of a candidate (None when the face has no room for the team)."""
        ang, n, s, omega = cand.spec
        psi = float(node.poses[cand.movable, 2])
        d_world = np.array([math.cos(ang), math.sin(ang)])
        d_body = np.array([math.cos(ang - psi), math.sin(ang - psi)])
        try:
            c, d, act = face_contacts(self.world, cand.movable, d_body, n)
        except ValueError:
            return None
        return PushTask(np.int64(cand.movable), c, d, act, np.r_[s * d_world, omega], np.float64(self.duration))

    # ------------------------------------------------------------------ expansion
    def _next_batch(self, node: _Node) -> list:
        """The next ``batch_size`` (<= max_batch) candidates of ``node`` that pass the quick-pass,
        in list order (first pass, second pass, modes the ModeTable saw fail)."""
        cfg = self.cfg
        limit = min(cfg.batch_size, cfg.max_batch)
        out = []
        while node.cursor < len(node.cands) and len(out) < limit:
            chunk = node.cands[node.cursor:node.cursor + 32]
            node.cursor += len(chunk)
            t = time.perf_counter()
            chunk = [c if c.task is not None else c._replace(task=self._task(node, c)) for c in chunk]
            chunk = [c for c in chunk if c.task is not None]
            self.stats["time_candidates_s"] += time.perf_counter() - t
            todo = [k for k, c in enumerate(chunk) if not c.passed]
            if cfg.quick_pass and todo:
                t = time.perf_counter()
                qp = quick_pass(self.world, stack_tasks([chunk[k].task for k in todo]), poses=node.poses,
                                robots=node.robots)
                self.stats["time_quick_pass_s"] += time.perf_counter() - t
                # A start walled off from the robots is not hopeless (in clutter the robots' own pocket
                # can be small): such candidates go once to the end of the list, behind every reachable one,
                # and are simulated when they come round again.
                walled = [k for k, w in zip(todo, qp.walled_off) if w]
                node.cands += [chunk[k]._replace(deferred=True) for k in walled if not chunk[k].deferred]
                self.stats["quick_pass_rejected"] += int(np.sum(~qp.ok)) - len(walled)
                bad = {k for k, o in zip(todo, qp.ok) if not o and not (k in walled and chunk[k].deferred)}
                chunk = [c for k, c in enumerate(chunk) if k not in bad]
            chunk = [c._replace(passed=True) for c in chunk]
            room = limit - len(out)
            if len(chunk) > room:   # survivors beyond the batch go back to the front of the list
                node.cands[node.cursor:node.cursor] = chunk[room:]
                chunk = chunk[:room]
            out += chunk
        return out

    def _expand(self, node: _Node):
        """One batch of ``node``: simulate, make children. Returns a success (path, child) or None."""
        cfg = self.cfg
        if node.cands is None:
            node.cands = self._candidates(node)
        batch = self._next_batch(node)
        self.stats["expansions"] += 1
        if not batch:
            return None
        b = len(batch)
        size = next((s for s in _BUCKETS if s >= b), b)
        padded = batch + [batch[-1]] * (size - b)
        tasks = stack_tasks([c.task for c in padded])
        t = time.perf_counter()
        out = simulate_pushes(self.world, tasks, sim=self.sim, poses=node.poses, robots=node.robots)
        cost, _, _ = push_cost(self.world, tasks, out, robots=node.robots, poses=node.poses)
        self.stats["time_physics_s"] += time.perf_counter() - t
        self.stats["physics_calls"] += 1
        self.stats["simulated_pushes"] += b
        self.stats["mode_table_hits"] += sum(c.hit for c in batch)
        self.stats["valid_rollouts"] += int(np.sum(out.valid[:b]))

        r = 0.5 * float(self.scene.width)
        ends = [shapely.Point(self.scene.start), shapely.Point(self.scene.goal)]
        children = []
        for i, cand in enumerate(batch):
            tg = node.targets[cand.target]
            tracked = bool(out.valid[i]) and out.displacement[i] >= 0.5 * np.linalg.norm(cand.task.velocity[:2]) * self.duration
            if self.use_table:
                self.table.record(self.scene.movables[cand.movable], cand.key, tracked,
                                  cand.task.contacts[cand.task.active] if tracked else None)
            if not out.valid[i] or not np.isfinite(cost[i]):
                continue
            poses = out.poses[i]
            # Progress on the target.
            if tg.kind == "gap":
                a, bb = (self.geom.body(x, poses) for x in tg.bodies)
                new_w = float(a.distance(bb))
                before = tg.width
                opened = new_w >= float(self.scene.width) + cfg.open_margin
                frac = 1.0 if opened else max(0.0, (new_w - before) / max(float(self.scene.width) - before, 1e-9))
                progress = new_w - before
            else:
                m = tg.movables[0]
                ep = ends[0] if self.geom.movable(m, node.poses[m]).distance(ends[0]) < r else ends[1]
                new_w = float(self.geom.movable(m, poses[m]).distance(ep))
                opened = new_w >= r
                frac = 1.0 if opened else max(0.0, (new_w - tg.width) / max(r - tg.width, 1e-9))
                progress = new_w - tg.width
            if not opened and progress < cfg.min_progress:
                continue
            # A gap push must not drop a moved movable onto an endpoint disk.
            if tg.kind == "gap":
                moved = np.nonzero(out.moved[i] > 0.01)[0]
                if any(self.geom.movable(mm, poses[mm]).distance(e) < r for mm in moved for e in ends):
                    continue
            key = _state_key(poses, out.robots[i], cfg)
            if key in self.seen:
                continue
            self.seen.add(key)
            sp = ScheduledPush(task=PushTask(*(np.asarray(getattr(cand.task, f)) for f in PushTask._fields)),
                               gap=tg.bodies, cost=float(cost[i]), poses_before=node.poses.copy(),
                               poses_after=np.asarray(poses, np.float64).copy(),
                               robots_before=node.robots.copy(), robots_after=np.asarray(out.robots[i], np.float64).copy())
            h = tg.tail if opened else max(tg.cost - frac * tg.one_hop, tg.tail)
            child = self._new_node(poses, out.robots[i], node.schedule + (sp,), node.chi + float(cost[i]), h)
            child.origin = (node.nid, cand.target)
            child.opened = node.opened + int(opened)
            child.parent_h = node.h
            children.append((opened, tg.final, child))
        node.children += len(children)
        # Gaps whose every simulated push in this batch failed to widen them get dearer (for the
        # rest of the search): the presearch then prefers routes around obstacles stuck in clutter.
        tried = {node.targets[c.target].bodies for c in batch}
        widened = {node.targets[ch.origin[1]].bodies for _, _, ch in children}
        for pair in tried - widened:
            self.stuck[pair] = self.stuck.get(pair, 0.0) + cfg.stuck_penalty
        self.stats["children"] += len(children)
        # Algorithm 1, line 5.5: children that opened their gap are tested against Eq. 7 at once,
        # those the presearch predicts to connect first (a WCCG and a connectivity query each).
        checks = sorted([c for c in children if c[0] and (c[1] or not cfg.presearch)], key=lambda c: self._f(c[2]))
        for opened, final, child in checks[:cfg.terminal_checks]:
            path = self._check(child)
            if path is not None:
                return path, child
        for opened, final, child in children:
            self._push(child, self._f(child))
        return None

    def _refresh_stuck(self, node: _Node) -> bool:
        """Raise the one-hop costs of an evaluated node's targets by the stuck penalties added since it
        was evaluated (the penalties only grow, and an estimate fixed at evaluation would make nodes
        evaluated early look cheaper than their later siblings). Returns whether any cost changed."""
        changed = False
        for k, tg in enumerate(node.targets or ()):
            if tg.kind != "gap":
                continue
            grown = self.stuck.get(tg.bodies, 0.0) - node.stuck_at.get(tg.bodies, 0.0)
            if grown > 0:
                node.targets[k] = tg._replace(cost=tg.cost + grown, one_hop=tg.one_hop + grown)
                node.stuck_at[tg.bodies] = self.stuck[tg.bodies]
                changed = True
        if changed:
            node.h = self._node_estimate(node) if node.cands is not None else min(tg.cost for tg in node.targets)
        return changed

    def _node_estimate(self, node: _Node) -> float:
        """A partly expanded node's estimate: the best cost among the gaps whose candidates are not used
        up, plus ``reinsert_penalty`` per batch it already had (its children come first)."""
        left = {c.target for c in node.cands[node.cursor:]}
        return min((node.targets[t].cost for t in left), default=math.inf) + self.cfg.reinsert_penalty * node.expansions

    # ------------------------------------------------------------------ main loop
    def run(self) -> SearchResult:
        cfg = self.cfg
        self.t0 = time.perf_counter()
        root = self._new_node(self.scene.poses, np.asarray(self.scene.robots, np.float64), (), 0.0, 0.0)
        self.seen.add(_state_key(root.poses, root.robots, cfg))
        path = self._evaluate(root)
        if path is not None:
            return self._result(True, root, path, "")
        if root.h == math.inf:       # blocked, and no movable borders the frontier
            return self._result(False, root, None, "exhausted")
        if self.world is None:
            self.world = build_push_world(self.scene)
        if self.sim is None:
            self.sim = make_push_simulator(self.world, cfg.backend)
        elif self.sim.model is not self.world.model:
            raise ValueError("sim: built for another world; use make_push_simulator(world).")
        wc = self.world.config
        self.duration = min(float(cfg.duration), wc.horizon * wc.substeps * wc.timestep)
        self.best = root
        if root.h < math.inf:
            self._push(root, self._f(root))
        self._emit("start", h=root.h)
        reason = "exhausted"
        while self.queue:
            if time.perf_counter() - self.t0 > cfg.time_limit_s:
                reason = "time limit"
                break
            if self.stats["expansions"] >= cfg.max_expansions:
                reason = "expansion limit"
                break
            f, _, _, node = heapq.heappop(self.queue)
            if not node.evaluated and not node.corrected and node.origin in self.corrections:
                # A sibling from the same gap was evaluated: shift this estimate by its error first.
                node.corrected = True
                node.h = max(node.h + self.corrections[node.origin], 0.0)
                if self.queue and self._f(node) > self.queue[0][0] + 1e-9:
                    self._push(node, self._f(node))
                    continue
            if not node.evaluated:
                h_est = node.h
                path = self._evaluate(node)
                if path is not None:
                    return self._result(True, node, path, "")
                if node.h == math.inf:
                    continue
                if node.origin and not node.corrected:
                    err = node.h - h_est
                    self.corrections[node.origin] = min(self.corrections.get(node.origin, err), err)
                f_new = self._f(node)
                if self.queue and f_new > self.queue[0][0] + 1e-9:
                    self._push(node, f_new)
                    continue
            elif self.cfg.refresh_stuck and self._refresh_stuck(node):
                if self.queue and self._f(node) > self.queue[0][0] + 1e-9:
                    self._push(node, self._f(node))
                    continue
            if self.best is None or node.h < self.best.h:
                self.best = node
            found = self._expand(node)
            node.expansions += 1
            self._emit("expand", node=node.nid, depth=node.depth, f=f, h=node.h, chi=node.chi,
                       batch_left=len(node.cands) - node.cursor)
            if found is not None:
                path, child = found
                return self._result(True, child, path, "")
            if cfg.reinsertion and node.cursor < len(node.cands):
                # Deferred expansion: back to the queue with its best unexplored gap.
                node.h = self._node_estimate(node)
                self._push(node, self._f(node))
        best = self.best if self.best is not None else root
        return self._result(False, best, None, reason)

    def _result(self, success, node: _Node, path, reason) -> SearchResult:
        self.stats["max_depth"] = max(self.stats["max_depth"], node.depth)
        stats = SearchStats(planning_time_s=time.perf_counter() - self.t0, **self.stats)
        final = self._scene_at(node)
        self._emit("done", success=success, reason=reason, pushes=node.depth)
        return SearchResult(bool(success), list(node.schedule), final, path, stats, reason)


def plan_pushes(scene: PushScene, config: SearchConfig = SearchConfig(), ranking: RankingParams = SEARCH_RANKING,
                *, world: PushWorld | None = None, sim=None, mode_table: ModeTable | None = None,
                progress: Callable[[dict], None] | None = None) -> SearchResult:
    """Plan a pushing schedule that opens a W-clear corridor (Algorithm 1; module docstring).

    scene: the initial state; config: :class:`SearchConfig`; ranking: Eqs. 8-9 weights and the
    presearch's beam / depth; world / sim: a prebuilt :func:`build_push_world` of ``scene`` and its
    :func:`make_push_simulator` (built here when None; pass them to reuse across calls); mode_table: a
    :class:`ModeTable` to read and update (a fresh one when None); progress: called with a dict after
    every expansion (``event``, ``elapsed_s``, ``queue``, the counters of :class:`SearchStats`, ...).

    Returns a :class:`SearchResult`. If Eq. 7 already holds: success with an empty schedule.
    """
    _check_inputs(scene, config, ranking, mode_table, world)
    return _Search(scene, config, ranking, world, sim, mode_table, progress).run()
