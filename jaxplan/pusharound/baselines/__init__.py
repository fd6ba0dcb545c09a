"""Baseline planners of Table I (Section IV-A.2), in the same harness and contact models as the search.

Every planner takes a :class:`PushScene` and returns the search's result type (``SearchResult`` with
``ScheduledPush`` entries and ``SearchStats``; see ``jaxplan.pusharound.search``), so
``experiments/table1.py`` treats all planners alike. Pushes are the physics module's
:class:`PushTask` (``direction_tasks`` face contacts, the P-controlled rollout of
``simulate_pushes``, Eq. 11's ``push_cost``); ``ScheduledPush.gap`` is ``(m,)``, the WCCG body of
the pushed movable (these planners reason about movables, not gaps).

One module per planner (each module's docstring gives its algorithm):

- :func:`dfs_wccg` (**DFS-WCCG**, ``dfs.py``): simulation-in-the-loop depth-first search guided by
  the WCCG, four axis-aligned pushes per frontier movable, every candidate simulated.
- :func:`sl_push_offline` (**SL-Push, offline**, ``sl_push.py``): a route around the fixed obstacles,
  its blockers displaced geometrically, then executed open loop in physics
  (:func:`execute_open_loop`), which may fail.
- :func:`sl_push_sim` (**SL-Push, sim**, ``sl_push.py``): the same route and blockers, every
  displacement validated in physics while planning.
- :func:`rec_namo` (**Rec-NAMO**, ``namo.py``): Dijkstra routing on a grid through movables (mass
  penalty), recursive local push decomposition, pruning; executed open loop.

``common.py`` holds what they share: :class:`BaselineConfig`, the per-run environment, open-loop
execution, the result types and the route geometry.

Execution time (``SearchResult`` does not carry it): :func:`schedule_duration` sums Eq. 11's
``delta_T`` (robot transition at ``transit_speed`` plus the push duration) over a schedule, the same
measure for every planner. Success of the open-loop planners is judged after execution: every
executed push physically valid (``PushOutcome.valid``) and Eq. 7 holding on the final physical
state.

The paper's baselines are described in two sentences each; the concrete choices (distances,
speeds, grid resolution, mass penalty, recursion depth) are ours and listed in ``BaselineConfig``.
"""
from __future__ import annotations

from collections.abc import Callable

from jaxplan.pusharound.baselines.common import BaselineConfig, execute_open_loop, schedule_duration
from jaxplan.pusharound.baselines.dfs import dfs_wccg
from jaxplan.pusharound.baselines.namo import rec_namo
from jaxplan.pusharound.baselines.sl_push import sl_push_offline, sl_push_sim

__all__ = ["BASELINES", "BaselineConfig", "dfs_wccg", "execute_open_loop", "rec_namo", "schedule_duration",
           "sl_push_offline", "sl_push_sim"]

BASELINES: dict[str, Callable] = {"DFS-WCCG": dfs_wccg, "SL-Push (offline)": sl_push_offline,
                                  "SL-Push (sim)": sl_push_sim, "Rec-NAMO": rec_namo}
