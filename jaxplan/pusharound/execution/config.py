"""Execution constants (:class:`ExecutionConfig`): tolerances of the early stop and of the push's
success, the transition planner's grid and margins, replanning and recording budgets."""
from __future__ import annotations

import dataclasses

__all__ = ["ExecutionConfig"]


@dataclasses.dataclass(frozen=True)
class ExecutionConfig:
    """Execution constants (all static).

    pos_tol [m], yaw_tol [rad]: early stop when the target is this close to its planned pose;
    stall_window [s], stall_eps [m]: the push stalled when the target moved less than stall_eps
    (translation + 0.3 m x yaw change) over the window; min_push_time [s] before a stall counts;
    deviation_tol [m]: a movable whose outline is this far (Hausdorff) from its predicted outline
    fails the push; max_replans: calls of ``replan`` at most; grid [m]: A* cell size; transit_margin [m]: extra
    clearance of transition paths beyond the robot radius; brush_weight: where no clear route exists, a
    transition path may pass closer than that to a movable (brushing or shoving it; never closer than
    r + 1 cm to a fixed obstacle, the workspace edge or an idle robot), each metre costing
    ``1 + brush_weight * depth / (r + transit_margin)`` for a path ``depth`` metres too close (inf:
    never; the straight segment is driven then); arrive_tol [m]: a robot within this of its
    push start point has arrived; transit_slack [s]: added to 1.5 x the path time for the timeout;
    max_pushes: executed pushes at most (guards a replanner that never converges); None: the
    schedule's own length plus ``EXTRA_PUSHES``, so that a long plan is never cut short; open_loop: when a
    push fails and no replanning is left (no ``replan``, ``max_replans`` used, or a replan found
    nothing), carry on with the rest of the schedule (True) or stop there (False); retreat [m]: at
    the end the robots of the last push back off this far against their push directions (0: not);
    record_every: ticks between recorded frames; backend: "c", "mjx" or "auto" (a single
    element: the C engine is the sensible choice on a CPU).
    """

    pos_tol: float = 0.03
    yaw_tol: float = 0.05
    stall_window: float = 0.5
    stall_eps: float = 0.005
    min_push_time: float = 0.5
    deviation_tol: float = 0.15
    max_replans: int = 3
    grid: float = 0.05
    transit_margin: float = 0.03
    arrive_tol: float = 0.03
    transit_slack: float = 4.0
    brush_weight: float = 10.0
    max_pushes: int | None = None
    open_loop: bool = True
    retreat: float = 0.1
    record_every: int = 4
    backend: str = "c"

    def replace(self, **changes) -> ExecutionConfig:
        return dataclasses.replace(self, **changes)
