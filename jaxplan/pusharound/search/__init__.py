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

Units: m, s, rad; costs in the units of Eqs. 8-11.

Modules: ``config`` (:class:`SearchConfig`, input checks), ``results`` (:class:`SearchResult` and
its parts), ``nodes`` (node, target and candidate types; Eq. 10's priority), ``context`` (a run's
fixed inputs and its mutable counters and caches), ``facegraph`` (the "graph" presearch),
``evaluation`` (Eq. 7 and the targets of a node), ``candidates`` (candidate pushes and their order),
``expansion`` (quick-pass, physics, children), ``loop`` (the best-first loop, :func:`plan_pushes`),
``records`` (the optional gap recorder: :class:`ExpansionRecord`, one per expansion).
"""
from jaxplan.pusharound.search.config import SEARCH_RANKING, SearchConfig
from jaxplan.pusharound.search.facegraph import FaceGraph, face_graph
from jaxplan.pusharound.search.loop import plan_pushes
from jaxplan.pusharound.search.records import ExpansionRecord, TargetTerms
from jaxplan.pusharound.search.results import ScheduledPush, SearchResult, SearchStats

__all__ = ["SEARCH_RANKING", "ExpansionRecord", "FaceGraph", "ScheduledPush", "TargetTerms", "face_graph",
           "SearchConfig", "SearchResult", "SearchStats", "plan_pushes"]
