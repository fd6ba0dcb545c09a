"""What one run of the search holds: the fixed inputs (:class:`SearchContext`, immutable) and the
run's counters and caches (:class:`SearchRun`, the one mutable container the algorithm needs)."""
from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Callable

import numpy as np

from jaxplan.physics import Simulator
from jaxplan.pusharound.modetable import ModeTable
from jaxplan.pusharound.physics import PushWorld, build_push_world
from jaxplan.pusharound.push import make_push_simulator
from jaxplan.pusharound.ranking import RankingParams
from jaxplan.pusharound.scene import PushScene
from jaxplan.pusharound.search.bodies import BodyOutlines
from jaxplan.pusharound.search.config import SearchConfig
from jaxplan.pusharound.search.nodes import SearchNode

__all__ = ["SearchContext", "SearchRun", "new_context", "with_physics"]


@dataclasses.dataclass(frozen=True)
class SearchContext:
    """The inputs of a run. scene: the initial state; cfg, params: :class:`SearchConfig` and the
    Eqs. 8-9 weights; table: the :class:`ModeTable` read and updated (an object: it learns during the
    run), use_table: whether its priors order candidates; bodies: outlines of the scene's bodies;
    n_robots: N. world, sim, duration: the MuJoCo world, its push simulator and the push duration
    [s] (the configured one capped by the horizon); None until :func:`with_physics` (a scene that is
    already connected needs no physics)."""

    scene: PushScene
    cfg: SearchConfig
    params: RankingParams
    table: ModeTable
    use_table: bool
    bodies: BodyOutlines
    n_robots: int
    world: PushWorld | None = None
    sim: Simulator | None = None
    duration: float | None = None


def new_context(scene: PushScene, cfg: SearchConfig, params: RankingParams, world=None, sim=None,
                mode_table: ModeTable | None = None) -> SearchContext:
    """The context of a run on ``scene`` (a fresh ModeTable when ``mode_table`` is None); ``world`` and
    ``sim`` as given (None: built by :func:`with_physics` when the search first needs physics)."""
    return SearchContext(scene, cfg, params, mode_table if mode_table is not None else ModeTable(),
                         bool(cfg.mode_table), BodyOutlines(scene), len(np.asarray(scene.robots).reshape(-1, 2)),
                         world, sim)


def with_physics(ctx: SearchContext) -> SearchContext:
    """``ctx`` with its world and simulator (built when not given) and the push duration."""
    world = ctx.world if ctx.world is not None else build_push_world(ctx.scene)
    if ctx.sim is None:
        sim = make_push_simulator(world, ctx.cfg.backend)
    elif ctx.sim.model is not world.model:
        raise ValueError("sim: built for another world; use make_push_simulator(world).")
    else:
        sim = ctx.sim
    wc = world.config
    duration = min(float(ctx.cfg.duration), wc.horizon * wc.substeps * wc.timestep)
    return dataclasses.replace(ctx, world=world, sim=sim, duration=duration)


_STATS = dict(expansions=0, simulated_pushes=0, physics_calls=0, mode_table_hits=0, evaluations=0, checks=0,
              nodes=0, quick_pass_rejected=0, valid_rollouts=0, children=0, rank_calls=0, max_depth=0,
              time_rank_s=0.0, time_quick_pass_s=0.0, time_physics_s=0.0, time_candidates_s=0.0)


@dataclasses.dataclass
class SearchRun:
    """The run's mutable bookkeeping.

    stats: the counters of ``SearchStats`` (times in s); rng: the gap-order sampler (seeded);
    seen: state keys already made into nodes; stuck: gap bodies -> added cost (``stuck_penalty`` per
    batch that failed to widen it); corrections: node origin -> error of the estimate seen on an
    evaluated sibling; tail_memo: gap bodies -> (Eq. 9 tail, crossing it is predicted to connect),
    the "beam" presearch's cache; n_nodes: nodes made; t0: ``time.perf_counter()`` at the start;
    progress: the caller's callback or None; records: None, or the gap recorder's list of
    ``ExpansionRecord`` (``plan_pushes(..., record=True)``); leaf_memo: gap bodies -> (tail f[P, 3],
    mask bool[P]) of the "beam" presearch's leaves, kept only while recording.
    """

    rng: np.random.Generator
    progress: Callable[[dict], None] | None = None
    records: list | None = None
    stats: dict = dataclasses.field(default_factory=lambda: dict(_STATS))
    seen: set = dataclasses.field(default_factory=set)
    stuck: dict = dataclasses.field(default_factory=dict)
    corrections: dict = dataclasses.field(default_factory=dict)
    tail_memo: dict = dataclasses.field(default_factory=dict)
    leaf_memo: dict = dataclasses.field(default_factory=dict)
    n_nodes: int = 0
    t0: float = dataclasses.field(default_factory=time.perf_counter)

    @contextlib.contextmanager
    def timed(self, key: str):
        """Add the wall-clock seconds of the ``with`` block to ``stats[key]``."""
        t = time.perf_counter()
        try:
            yield
        finally:
            self.stats[key] += time.perf_counter() - t

    def new_node(self, poses, robots, schedule, chi, h) -> SearchNode:
        """A node at ``poses`` f[M, 3] / ``robots`` f[N, 2] with ``schedule``, realised cost ``chi`` and
        estimate ``h``, counted in the stats."""
        node = SearchNode(self.n_nodes, np.asarray(poses, np.float64), np.asarray(robots, np.float64),
                          tuple(schedule), float(chi), float(h))
        self.n_nodes += 1
        self.stats["nodes"] = self.n_nodes
        self.stats["max_depth"] = max(self.stats["max_depth"], node.depth)
        return node

    def emit(self, event: str, queue: int, **kw) -> None:
        """Report ``event`` to the progress callback with the elapsed time, the queue length and the
        counters (plus ``kw``)."""
        if self.progress is not None:
            info = dict(event=event, elapsed_s=time.perf_counter() - self.t0, queue=queue, **self.stats)
            info.update(kw)
            self.progress(info)
