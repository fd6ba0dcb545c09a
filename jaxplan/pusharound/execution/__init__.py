"""Executing a pushing schedule in physics with online replanning (Section III-D).

:func:`execute_schedule` takes the schedule of the hybrid search (``SearchResult.schedule``, a list
of scheduled pushes with ``task``, ``poses_after`` f[M, 3], ...) and runs it in ONE continuous
physics state (the MuJoCo world of :func:`build_push_world`; the C engine by default), alternating
the two phases of the paper's hybrid controller:

1. **Transition.** The active robots drive to their push start points (``r + standoff`` behind
   their contacts, as in :func:`simulate_pushes`). Paths: an 8-connected grid A* (``grid`` metres)
   in the instantaneous free space (workspace shrunk, every obstacle at its current pose and every
   robot that does not take part inflated by ``r + transit_margin``), shortcut by line of sight
   against the same free region; short straight escape / approach segments join the robot and the
   start point to the nearest free cells (a robot that has just pushed touches its body). In clutter
   with no clear route (a pocket of the robots' free space, a start point between bodies) the grid
   also holds the cells too close to a movable but clear of fixed obstacles, at a cost growing with
   the depth (``brush_weight``): the robot brushes past or shoves a light body, and a movable that
   ends off its predicted pose fails the push, which replanning then absorbs. Contacts
   are assigned to the active robots so that no robot's path crosses another's start point after
   that robot has arrived there (it would shove it off its contact: a deadlock), then by least total
   path length (:func:`transit.plan_transit`; the paper swaps contacts on colliding paths). Robots track the
   path at ``transit_speed`` with
   ``u = dp_ref/dt + K_p (p_ref - p)`` (:func:`transit_policy`, same gain and speed limit as the
   push controller); the phase fails after a timeout (1.5 x the path time + ``transit_slack``).
2. **Push.** The task's P-control of the contact references, i.e. :func:`push_policy` of
   ``push.py`` via :func:`make_push_simulator`, from the actual current pose of the target. **Early
   stop** at the first tick where the target is within ``pos_tol`` / ``yaw_tol`` of its planned
   pose, or has stalled (moved less than ``stall_eps`` over ``stall_window`` after
   ``min_push_time``). The rollout is causal, so cutting the trajectory at that tick is the same as
   stopping the robots there.

After each push the outcome is compared with the plan: the push **fails** when it is invalid
(:class:`PushOutcome` checks: fixed-obstacle hit, left the workspace, tipped, not finite) or some
part of a movable ended more than ``deviation_tol`` from where the plan put it (Hausdorff distance
between the outlines at the predicted and the reached pose: a translation counts fully, a rotation
by how far it moves the outline, so a turned cylinder costs nothing and a turned bar its tip's
displacement). On a failure (also a transition timeout, or a schedule that ran out without Eq. 7), control
returns to the planner: ``replan(scene_now) -> SearchResult`` from the current state, at most
``max_replans`` times. With no replanning left (none given, budget used, or a replan that found
nothing) the rest of the schedule runs open loop (``open_loop``; a push whose transition timed out is
skipped), every failure recorded. After every push the WCCG is rebuilt; execution ends as soon as
Eq. 7 holds
after the robots of that push have backed off ``retreat`` (they end pressing on the body): a body
still sliding after the early stop can close a corridor the plan left just W wide, which then counts
as a failure ("corridor closed during the retreat") like a failed push.

Both phases run in chunks of ``config.horizon`` ticks (one compiled program per policy on MJX);
the time offset of a chunk enters through the policy parameters. Units: m, s, rad.

Modules: ``config`` (:class:`ExecutionConfig`), ``results`` (what an execution returns), ``roadmap``
(grid paths of one robot), ``transit`` (contact assignment and the transition phase), ``control``
(path tracking, the push with early stop, the retreat), ``state`` (the running physical state),
``run`` (:func:`execute_schedule`), ``io`` (:func:`load_schedule`).
"""
from jaxplan.pusharound.execution.config import ExecutionConfig
from jaxplan.pusharound.execution.control import transit_policy
from jaxplan.pusharound.execution.io import load_schedule
from jaxplan.pusharound.execution.results import ExecutedPush, Execution, Frames, plan_frames
from jaxplan.pusharound.execution.roadmap import transition_path
from jaxplan.pusharound.execution.run import EXTRA_PUSHES, execute_schedule

__all__ = ["EXTRA_PUSHES", "ExecutionConfig", "ExecutedPush", "Execution", "Frames", "execute_schedule",
           "load_schedule", "plan_frames", "transit_policy", "transition_path"]
