"""What the search returns: :class:`ScheduledPush` (one push of the schedule), :class:`SearchStats`
(counters and timings) and :class:`SearchResult`."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxplan.pusharound.push import PushTask
from jaxplan.pusharound.scene import PushScene

__all__ = ["ScheduledPush", "SearchResult", "SearchStats"]


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
    and estimate); checks: Eq. 7 tests (WCCG + connectivity); nodes: nodes created;
    quick_pass_rejected: candidates the quick-pass removed; valid_rollouts: rollouts physics
    validated; children: children pushed to the queue; rank_calls;
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
    the search stopped ("time limit", "expansion limit", "exhausted"); records: None, or with
    ``plan_pushes(..., record=True)`` a tuple of ``ExpansionRecord`` (one per expansion, labelled
    with the solution's path: ``jaxplan.pusharound.search.records``)."""

    success: bool
    schedule: list
    final_scene: PushScene
    path: np.ndarray | None
    stats: SearchStats
    reason: str
    records: tuple | None = None
