"""The geometric quick pass: cheap shapely rejection of candidate pushes before physics.

:func:`quick_pass` checks each candidate of a batched :class:`~jaxplan.pusharound.push.PushTask`
(the pushed movable's sweep against the fixed obstacles and the workspace, the robots' start disks
and sweeps, and, given the robots' positions, whether every start can be reached through the free
space) and returns a :class:`QuickPass` with the reason for each rejection. :func:`swept_hulls` is
the region a movable sweeps along a push (convex pieces); :func:`free_components` the connected
pieces of the robots' free space.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import shapely
from shapely.geometry import LineString, Point

from jaxplan.pusharound.kernels import pack_polygons
from jaxplan.pusharound.physics import PushWorld
from jaxplan.pusharound.push import PushTask, check_tasks, posed_vertices, start_positions

__all__ = ["REACH_MARGIN", "QuickPass", "free_components", "quick_pass", "swept_hulls"]

REACH_MARGIN = 0.03   # m beyond the robot radius; the clearance of execution's transition paths
_SWEEP_SAMPLES = 8    # poses along a push for the swept-polygon quick-pass


class QuickPass(NamedTuple):
    """ok: bool[B] candidates worth simulating; reason: list of B strings ("" when ok); walled_off:
    bool[B] rejected only because a push start is walled off from every robot (check 4)."""

    ok: np.ndarray
    reason: list
    walled_off: np.ndarray


def free_components(scene, poses, clearance: float) -> list:
    """The connected pieces (shapely Polygons) of where a robot centre may be: the workspace shrunk
    by ``clearance`` [m] minus every obstacle at ``poses`` f[M, 3] inflated by it."""
    blocked = shapely.union_all([o.buffer(clearance, 8) for o in scene.with_poses(poses).obstacle_polygons()])
    free = scene.workspace_polygon.buffer(-clearance).difference(blocked)
    return [g for g in getattr(free, "geoms", [free]) if not g.is_empty]


def _component_of(components: list, point) -> int:
    """Index of the component nearest to ``point`` (a robot at a contact lies just inside the inflated
    obstacle, so 'nearest', not 'containing'); -1 when there is none."""
    if not components:
        return -1
    p = Point(float(point[0]), float(point[1]))
    return int(np.argmin([g.distance(p) for g in components]))


def quick_pass(world: PushWorld, tasks: PushTask, poses=None, robots=None) -> QuickPass:
    """Cheap geometric rejection before physics (shapely), per candidate:

    1. the pushed movable swept along its reference (``_SWEEP_SAMPLES`` poses, convex hulls of
       consecutive ones per piece) must not intersect a fixed obstacle and must stay in the workspace;
    2. every active robot's start disk (``r + standoff`` behind its contact) must lie in the workspace
       and not overlap any obstacle or another active robot's disk;
    3. every active robot's swept disk (start to end of its reference) must not meet a fixed obstacle;
    4. with ``robots`` f[N, 2] (their current positions): every active start point must lie in a
       piece of the free space (:func:`free_components`, clearance ``r + REACH_MARGIN``, the one that
       execution's transition paths use) that holds a robot; a start walled off from every robot
       (behind a bottleneck narrower than a robot) cannot be reached in execution.
    """
    tasks = check_tasks(world, tasks)
    scene, cfg = world.scene, world.config
    poses = scene.poses if poses is None else np.asarray(poses, np.float64)
    r = float(scene.robot_radius)
    ws = scene.workspace_polygon
    ws_loose = ws.buffer(1e-9)
    shapely.prepare(ws_loose)
    fixed = shapely.union_all([f.polygon for f in scene.fixed]) if scene.fixed else None
    starts = start_positions(world, tasks, poses)
    placed_scene = scene.with_poses(poses)
    obstacles = placed_scene.obstacle_polygons()
    shapely.prepare(obstacles)
    if fixed is not None:
        shapely.prepare(fixed)
    reach = None
    if robots is not None:
        pieces = free_components(scene, poses, r + REACH_MARGIN)
        reach = (pieces, {_component_of(pieces, p) for p in np.asarray(robots, np.float64).reshape(-1, 2)})
    ok, reasons, walled = [], [], []
    for i in range(len(tasks.movable)):
        m = int(tasks.movable[i])
        hulls = swept_hulls(scene.movables[m], poses[m], tasks.velocity[i], float(tasks.duration[i]))
        reason, walled_off = "", False
        hit = shapely.intersects(fixed, hulls) if fixed is not None else np.zeros(len(hulls), bool)
        if np.any(hit) and shapely.union_all(hulls[hit]).intersection(fixed).area > 1e-9:
            reason = "sweep hits a fixed obstacle"
        elif not np.all(shapely.contains(ws_loose, hulls)):
            reason = "sweep leaves the workspace"
        else:
            act = np.nonzero(tasks.active[i])[0]
            disks = [Point(*starts[i, n]).buffer(r, 16) for n in act]
            for n, disk in zip(act, disks):
                if not ws.contains(disk):
                    reason = f"robot {n} starts outside the workspace"
                elif any(o.intersects(disk) and disk.intersection(o).area > 1e-9 for o in obstacles):
                    reason = f"robot {n} start overlaps an obstacle"
                if reason:
                    break
            if not reason and any(a.intersection(b).area > 1e-9 for k, a in enumerate(disks) for b in disks[k + 1:]):
                reason = "robot starts overlap"
            if not reason and fixed is not None:
                for n in act:
                    path = [_robot_reference_np(poses[m], tasks, i, n, t, r - cfg.press)
                            for t in (0.0, tasks.duration[i])]
                    swept = LineString(path).buffer(r, 8)
                    if fixed.intersects(swept) and swept.intersection(fixed).area > 1e-9:
                        reason = f"robot {n} sweep hits a fixed obstacle"
                        break
            if not reason and reach is not None:
                pieces, held = reach
                cut_off = [n for n in act if _component_of(pieces, starts[i, n]) not in held]
                if cut_off:
                    reason = f"robot {cut_off[0]} start is walled off from every robot"
                    walled_off = True
        ok.append(not reason)
        reasons.append(reason)
        walled.append(walled_off)
    return QuickPass(np.asarray(ok, bool), reasons, np.asarray(walled, bool))


def swept_hulls(movable, pose0, velocity, duration: float, samples: int = _SWEEP_SAMPLES) -> np.ndarray:
    """The region a movable sweeps along a constant-velocity push, as convex pieces.

    movable: a :class:`~jaxplan.pusharound.scene.Movable` (convex body-frame pieces); pose0 f[3] its
    pose (x [m], y [m], yaw [rad]); velocity f[3] its body velocity ([m/s], [m/s], [rad/s]) over
    ``duration`` [s]. Returns an object array of ``(samples - 1) x pieces`` polygons: per piece and
    pair of consecutive poses of ``samples`` evenly spaced ones, the convex hull of the piece at both.
    Their union is the swept polygon (``jaxplan.reference.pusharound.swept_polygon``); built with one
    vectorised shapely call instead of a union, since the quick-pass needs only intersection and
    containment tests, which distribute over the pieces.
    """
    ts = np.linspace(0.0, float(duration), samples)
    seq = np.asarray(pose0, np.float64)[None] + np.asarray(velocity, np.float64)[None] * ts[:, None]   # [S, 3]
    body, _ = pack_polygons(movable.pieces)        # [P, V, 2]; padding repeats a vertex (same hull)
    placed = posed_vertices(body[:, None], seq[None])   # [P, S, V, 2]
    pairs = np.concatenate([placed[:, :-1], placed[:, 1:]], axis=2)   # [P, S-1, 2V, 2]
    owner = np.repeat(np.arange(pairs.shape[0] * pairs.shape[1]), pairs.shape[2])
    return shapely.convex_hull(shapely.multipoints(pairs.reshape(-1, 2), indices=owner))


def _robot_reference_np(pose0, tasks, i, n, t, offset):
    """Numpy twin of the push policy's robot reference (the module docstring of
    :mod:`jaxplan.pusharound.push`) for candidate i, robot n at time t: f[2]."""
    pose = pose0 + tasks.velocity[i] * min(max(float(t), 0.0), float(tasks.duration[i]))
    c, s = np.cos(pose[2]), np.sin(pose[2])
    local = tasks.contacts[i, n] - offset * tasks.directions[i, n]
    return pose[:2] + np.array([c * local[0] - s * local[1], s * local[0] + c * local[1]])
