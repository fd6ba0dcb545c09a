"""Rec-NAMO (Table I): grid routing through movables and recursive local push decomposition.

:func:`rec_namo`: Dijkstra routing on a grid where cells within W/2 of a movable cost extra
(proportional to its mass) and cells within W/2 of a fixed obstacle or the walls are impassable; the
route's blockers are decomposed into local pushes perpendicular to the route, recursively pushing a
movable that the displaced one would overlap (depth 2); a blocker whose displacement is
geometrically impossible (into a fixed obstacle or out of the workspace) prunes its cells from the
graph and Dijkstra runs again. No physics during planning; executed open loop.
"""
from __future__ import annotations

import heapq
import math
import time

import numpy as np
import shapely
from shapely.geometry import LineString

from jaxplan.pusharound.baselines.common import (
    BaselineConfig,
    Env,
    check_config,
    displacements,
    make_result,
    moved_polygon,
    open_loop_result,
    route_blockers,
    sweep_ok,
)
from jaxplan.pusharound.scene import PushScene
from jaxplan.pusharound.search import SearchResult

__all__ = ["rec_namo"]


def _grid_costs(scene: PushScene, poses, cfg: BaselineConfig, pruned: set):
    """Cell centres f[H, W, 2], per-cell entry cost f[H, W] (inf: impassable) and the movable a cell
    lies within W/2 of (i32[H, W], -1 none; the heaviest when several)."""
    x0, y0, x1, y1 = scene.workspace
    xs = np.arange(x0 + 0.5 * cfg.grid, x1, cfg.grid)
    ys = np.arange(y0 + 0.5 * cfg.grid, y1, cfg.grid)
    gx, gy = np.meshgrid(xs, ys)
    pts = shapely.points(gx.ravel(), gy.ravel())
    r = 0.5 * scene.width
    wall = np.minimum.reduce([gx.ravel() - x0, x1 - gx.ravel(), gy.ravel() - y0, y1 - gy.ravel()])
    blocked = wall < r
    for f in scene.fixed:
        blocked |= shapely.distance(pts, f.polygon) < r
    owner = np.full(len(pts), -1)
    penalty = np.zeros(len(pts))
    placed = scene.with_poses(poses)
    for m, mov in enumerate(placed.movables):
        near = shapely.distance(pts, mov.polygon) < r
        if m in pruned:
            blocked |= near
            continue
        heavier = near & (cfg.mass_penalty * mov.mass > penalty)
        penalty[heavier] = cfg.mass_penalty * mov.mass
        owner[heavier] = m
    cost = np.where(blocked, np.inf, penalty)
    shape = gx.shape
    return np.stack([gx, gy], -1), cost.reshape(shape), owner.reshape(shape)


def _dijkstra(centres, cost, owner, start, goal, grid: float) -> list | None:
    """8-connected Dijkstra from the cell of ``start`` to that of ``goal``: step length plus the entry
    cost of a movable when the path enters its region (once per movable region entered)."""
    h, w = cost.shape
    x0, y0 = centres[0, 0] - 0.5 * grid

    def cell(p):
        return (int(np.clip((p[1] - y0) // grid, 0, h - 1)), int(np.clip((p[0] - x0) // grid, 0, w - 1)))

    s, g = cell(start), cell(goal)
    dist = {s: 0.0}
    prev = {}
    heap = [(0.0, s)]
    steps = [(di, dj, math.hypot(di, dj) * grid) for di in (-1, 0, 1) for dj in (-1, 0, 1) if di or dj]
    while heap:
        d, u = heapq.heappop(heap)
        if u == g:
            break
        if d > dist.get(u, np.inf):
            continue
        for di, dj, ln in steps:
            v = (u[0] + di, u[1] + dj)
            if not (0 <= v[0] < h and 0 <= v[1] < w) or not np.isfinite(cost[v]):
                continue
            # A movable's mass penalty is paid when entering its region from outside it.
            enter = cost[v] if owner[v] >= 0 and owner[u] != owner[v] else 0.0
            nd = d + ln + enter
            if nd < dist.get(v, np.inf):
                dist[v], prev[v] = nd, u
                heapq.heappush(heap, (nd, v))
    if g not in dist:
        return None
    out, u = [g], g
    while u != s:
        u = prev[u]
        out.append(u)
    return [tuple(centres[i, j]) for i, j in reversed(out)]


def _recursive_push(scene: PushScene, poses, m: int, angle: float, dist: float, depth: int, margin: float,
                    moved: set) -> list | None:
    """Geometric push of ``m`` with recursion into movables it would overlap; a list of
    ``(movable, angle, distance)`` (the recursive ones first) applied to ``poses`` in place, or None."""
    poly, pose = moved_polygon(scene, poses, m, angle, dist)
    if not sweep_ok(scene, poses, m, angle, dist):
        return None
    plan = []
    placed = scene.with_poses(poses)
    for k, other in enumerate(placed.movables):
        if k == m or k in moved or not poly.intersects(other.polygon):
            continue
        if depth <= 0:
            return None
        # Push the other body on along the same direction by its overlap extent plus the margin.
        d = np.array([math.cos(angle), math.sin(angle)])
        a_ext = np.asarray(poly.exterior.coords)[:, :2] @ d
        b_ext = np.asarray(other.polygon.exterior.coords)[:, :2] @ d
        sub = _recursive_push(scene, poses, k, angle, float(a_ext.max() - b_ext.min()) + margin, depth - 1, margin,
                              moved | {m})
        if sub is None:
            return None
        plan += sub
    poses[m] = pose
    return plan + [(m, angle, dist)]


def rec_namo(scene: PushScene, config: BaselineConfig = BaselineConfig(), world=None, sim=None) -> SearchResult:
    """Rec-NAMO (module docstring): Dijkstra routing through movables, local recursive push
    decomposition, edge pruning; executed open loop in physics."""
    check_config(config)
    env = Env(scene, config, world, sim)
    t0 = time.perf_counter()
    half, clear = 0.5 * scene.width, 0.5 * scene.width + config.margin
    pruned: set = set()
    while True:
        if time.perf_counter() - t0 > config.time_limit_s:
            return make_result(env, False, [], scene.poses, "time limit")
        env.expansions += 1
        centres, cost, owner = _grid_costs(scene, scene.poses, config, pruned)
        cells = _dijkstra(centres, cost, owner, scene.start, scene.goal, config.grid)
        if cells is None:
            return make_result(env, False, [], scene.poses, "no route after pruning")
        route = LineString([scene.start] + cells + [scene.goal]).simplify(0.5 * config.grid)
        poses = scene.poses.copy()
        plan, failed = [], None
        for m in route_blockers(scene, poses, route, half):
            poly = scene.with_poses(poses).movables[m].polygon
            if poly.distance(route) >= half:
                continue    # already moved out by a recursive push
            for angle, dist in displacements(poly, route, clear):
                trial = poses.copy()
                sub = _recursive_push(scene, trial, m, angle, dist, config.recursion, config.margin, set())
                if sub is not None:
                    plan += sub
                    poses = trial
                    break
            else:
                failed = m
                break
        if failed is None:
            return open_loop_result(env, plan, time.perf_counter() - t0, "")
        pruned.add(failed)
