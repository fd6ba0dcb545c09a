"""Switches and budgets of the search (:class:`SearchConfig`), its default ranking weights, and the
validation of :func:`plan_pushes`'s inputs."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from jaxplan.pusharound.modetable import ModeTable
from jaxplan.pusharound.physics import PushWorld
from jaxplan.pusharound.push import MAX_BATCH
from jaxplan.pusharound.ranking import RankingParams, validate_ranking_params
from jaxplan.pusharound.scene import PushScene
from jaxplan.pusharound.wccg import check_feasible

__all__ = ["SEARCH_RANKING", "SearchConfig", "check_inputs"]

# The search's default ranking: Eq. 8-9 weights as RankingParams(), a smaller presearch (beam 2,
# depth 2: the same first three gaps as beam 4, depth 3 on nominal seeds 0-3 at about half the time).
SEARCH_RANKING = RankingParams(beam=2, depth=2)


@dataclasses.dataclass(frozen=True)
class SearchConfig:
    """Switches and budgets of :func:`plan_pushes` (docstring of :mod:`jaxplan.pusharound.search`).

    presearch: Eq. 9 ranking (False: one-hop cost Eq. 8 only); presearch_mode: "graph" (Eq. 9's
    continuation by Dijkstra over the face graph, :func:`face_graph`) or "beam" (``rank_gaps``, its
    beam and depth from the ``ranking`` argument); mode_table: ModeTable priors;
    quick_pass: geometric rejection before physics; reinsertion: deferred expansion / reinsertion of
    partly expanded nodes; max_batch: candidates per physics call (<= 64); batch_size: candidates an
    expansion simulates (capped by max_batch; 16 on the 2-core CPU: the paper's 64 cost four times
    the physics per expansion, and the deferred expansion reaches the rest later); time_limit_s: wall-clock
    budget [s]; max_expansions: batches simulated at most; backend: "c" | "mjx" | "warp" | "auto"; seed: gap
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
        if self.backend not in ("c", "mjx", "warp", "auto"):
            raise ValueError(f"SearchConfig.backend: expected 'c', 'mjx', 'warp' or 'auto'; got {self.backend!r}.")
        if not isinstance(self.seed, (int, np.integer)) or isinstance(self.seed, bool) or self.seed < 0:
            raise ValueError(f"SearchConfig.seed: must be an int >= 0 (it seeds numpy's default_rng); "
                             f"got {self.seed!r}.")
        if not self.speeds or any(not (isinstance(s, (int, float)) and 0 <= s <= 0.8) for s in self.speeds):
            raise ValueError("SearchConfig.speeds: need speeds in [0, 0.8] m/s (0: just opening); "
                             f"got {self.speeds!r}.")
        if any(not (isinstance(w, (int, float)) and math.isfinite(w)) for w in self.omegas):
            raise ValueError(f"SearchConfig.omegas: must be finite numbers [rad/s]; got {self.omegas!r}.")
        if not self.team_sizes or any(not isinstance(n, int) or n < 1 for n in self.team_sizes):
            raise ValueError(f"SearchConfig.team_sizes: must be ints >= 1; got {self.team_sizes!r}.")

    def replace(self, **changes) -> SearchConfig:
        return dataclasses.replace(self, **changes)


def check_inputs(scene, config, ranking, mode_table, world, sim) -> None:
    """Raise ValueError naming the first argument of :func:`plan_pushes` that is malformed."""
    if not isinstance(scene, PushScene):
        raise TypeError(f"scene: expected a PushScene; got {type(scene).__name__}. Build one with PushScene(...) or "
                        "PushScene.load(path).")
    if not isinstance(config, SearchConfig):
        raise TypeError(f"config: expected a SearchConfig; got {type(config).__name__}. Pass SearchConfig(...) "
                        "or None.")
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
    if sim is not None and world is not None and sim.model is not world.model:
        raise ValueError("sim: built for another world; use make_push_simulator(world).")
    check_feasible(scene)   # memory of the pairwise kernels, then geometry no push can change
