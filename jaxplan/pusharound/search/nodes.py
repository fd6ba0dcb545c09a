"""The search's state types: what a node tries to open (:class:`Target`), a candidate push
(:class:`Candidate`), a search node (:class:`SearchNode`) and its Eq. 7 test (:class:`Eq7Check`),
with the node's priority (Eq. 10) and the de-duplication key of a state."""
from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import numpy as np

from jaxplan.pusharound.modetable import ModeKey
from jaxplan.pusharound.push import PushTask
from jaxplan.pusharound.search.config import SearchConfig

__all__ = ["EMPTY_CHECK", "Candidate", "Eq7Check", "SearchNode", "Target", "priority", "remaining_estimate",
           "state_key"]


class Target(NamedTuple):
    """What an expansion tries to open: a gap (bodies = WCCG body pair) or an endpoint disk
    (bodies = (body,)). movables: the movables to push; width: current gap width [m] (endpoint: the
    intruder's clearance [m]); cost: Cost(g); tail: Cost(g) - C(g); one_hop: C(g); away: per movable a
    unit world direction away from the gap; final: crossing it is predicted to connect; terms: the
    :class:`~jaxplan.pusharound.search.records.TargetTerms` of its cost when the search records gaps
    (``plan_pushes(..., record=True)``), else None."""

    kind: str
    bodies: tuple
    movables: tuple
    width: float
    cost: float
    tail: float
    one_hop: float
    away: dict
    final: bool
    terms: Any = None


class Candidate(NamedTuple):
    """A candidate push: target index, movable, spec = (world angle [rad], team size, speed [m/s],
    omega [rad/s]), its ModeTable key, whether the table had validated it, and the task (built when first needed)."""

    target: int
    movable: int
    spec: tuple
    key: ModeKey
    hit: bool
    task: PushTask | None = None
    passed: bool = False      # survived the quick-pass (or it is off)
    deferred: bool = False    # its start was walled off from the robots once: moved to the list's end


class Eq7Check(NamedTuple):
    """Algorithm 1's termination test of a node: its WCCG, Eq. 7's :class:`Connectivity`, the W-clear
    path f64[P, 2] (None unless connected) and the skeleton the query built (shared with the face
    graph). All None once the node is evaluated: its targets hold what the search still needs."""

    g: Any
    conn: Any
    path: np.ndarray | None
    skeleton: Any


EMPTY_CHECK = Eq7Check(None, None, None, None)


@dataclasses.dataclass
class SearchNode:
    """A node ``nu = (s, pi)`` (package docstring). Mutable: it is evaluated lazily, its candidate
    list is consumed in batches across pops, and its estimate is corrected on the way.

    nid: creation index; poses f64[M, 3] (x [m], y [m], yaw [rad]) and robots f64[N, 2] [m]: the
    state ``s``; schedule: tuple of ``ScheduledPush`` (``pi``); chi: realised cost of the schedule
    (sum of Eq. 11); h: the estimate (Eq. 10's bracket before the bonus; cost units of Eq. 9);
    evaluated: Eq. 7 tested and targets ranked; targets: list of :class:`Target`, cheapest first;
    cands: list of :class:`Candidate` in the order they are tried, cursor: the next one; children:
    children made so far; expansions: batches simulated; opened: gaps (or endpoint disks) the
    schedule opened that lowered the estimate; parent_h: the parent's estimate when this node was
    made; check: its :class:`Eq7Check` once tested; origin: (parent nid, target index), which siblings
    share (they share their estimate's error); corrected: the siblings' error was applied; stuck_at:
    gap bodies -> the stuck penalty its target's cost includes.
    """

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
    opened: int = 0
    parent_h: float = math.inf
    check: Eq7Check | None = None
    origin: tuple = ()
    corrected: bool = False
    stuck_at: dict | None = None

    @property
    def depth(self) -> int:
        return len(self.schedule)


def priority(node: SearchNode, cfg: SearchConfig) -> float:
    """Eq. 10 with the heuristic factor, less ``progress_bonus`` per gap the schedule opened."""
    return node.chi + cfg.heuristic_weight * (node.h - cfg.progress_bonus * node.opened)


def remaining_estimate(node: SearchNode, cfg: SearchConfig) -> float:
    """A partly expanded node's estimate: the best cost among the gaps whose candidates are not used
    up, plus ``reinsert_penalty`` per batch it already had (its children come first)."""
    left = {c.target for c in node.cands[node.cursor:]}
    return min((node.targets[t].cost for t in left), default=math.inf) + cfg.reinsert_penalty * node.expansions


def state_key(poses, robots, cfg: SearchConfig) -> tuple:
    """The de-duplication key of a state: movable poses ``poses`` f[M, 3] rounded to ``dedup_m`` [m] and
    ``dedup_rad`` [rad]. ``robots`` is not part of it (the same obstacles with the team elsewhere are
    one state)."""
    p = np.asarray(poses, np.float64)
    yaw = np.round(np.angle(np.exp(1j * p[:, 2])) / cfg.dedup_rad).astype(np.int64)
    xy = np.round(p[:, :2] / cfg.dedup_m).astype(np.int64)
    return tuple(np.concatenate([xy.reshape(-1), yaw]).tolist())
