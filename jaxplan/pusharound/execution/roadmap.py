"""Transition paths for one robot centre: grid A* (8-connected) over the free region at the current
poses, optionally through cells near a movable at a cost ("brushing"), shortcut by line of sight.
Units: m."""
from __future__ import annotations

import heapq
import math

import numpy as np
import shapely
from shapely.geometry import LineString

from jaxplan.pusharound.scene import PushScene

__all__ = ["Roadmap", "free_region", "transition_path"]


def free_region(scene: PushScene, poses, clearance: float, extra=()):
    """Where a robot centre may be: the workspace shrunk by ``clearance`` minus every obstacle at
    ``poses`` (and the ``extra`` polygons) inflated by it."""
    obstacles = scene.with_poses(poses).obstacle_polygons() + list(extra)
    blocked = shapely.union_all([o.buffer(clearance, 8) for o in obstacles]) if obstacles else None
    free = scene.workspace_polygon.buffer(-clearance)
    return free.difference(blocked) if blocked is not None else free


class Roadmap:
    """The free region of :func:`free_region` and its grid, built once and queried for many paths.

    With ``brush_weight`` finite, a cell that is within ``clearance`` of a movable but clear of the
    fixed obstacles, the workspace edge and the ``extra`` polygons by ``hard_clearance`` is passable
    at a cost (``_cell_costs``): in clutter where no clear route exists the robot brushes past, or
    shoves, a light movable rather than drive straight into a wall. Clear cells cost 1, so a detour
    through them is taken while it is cheaper than the brush. ``brush_weight`` inf (this class's
    default; ``ExecutionConfig``'s is 10): clear cells only, and the straight segment when they hold no route.
    """

    def __init__(self, scene: PushScene, poses, clearance: float, grid: float, extra=(),
                 hard_clearance: float | None = None, brush_weight: float = math.inf):
        if not grid > 0:
            raise ValueError(f"grid: must be > 0 m; got {grid!r}.")
        self.free = free_region(scene, poses, clearance, extra)
        shapely.prepare(self.free)
        x0, y0, x1, y1 = (float(v) for v in scene.workspace)
        nx, ny = max(1, int(math.ceil((x1 - x0) / grid))), max(1, int(math.ceil((y1 - y0) / grid)))
        self.xs, self.ys = x0 + (np.arange(nx) + 0.5) * grid, y0 + (np.arange(ny) + 0.5) * grid
        self.cx, self.cy = np.meshgrid(self.xs, self.ys, indexing="ij")           # [nx, ny]
        self.ok = shapely.contains_xy(self.free, self.cx, self.cy)
        self.passable, self.cost = self.ok, None
        if math.isfinite(brush_weight) and hard_clearance is not None:
            self.cost = _cell_costs(scene, poses, self.cx, self.cy, self.ok, clearance, hard_clearance,
                                    brush_weight, extra)
            self.passable = np.isfinite(self.cost)

    def _nearest(self, p, mask):
        d = np.where(mask, (self.cx - p[0]) ** 2 + (self.cy - p[1]) ** 2, np.inf)
        return np.unravel_index(int(np.argmin(d)), d.shape)

    def path(self, start, goal) -> np.ndarray:
        s, gl = np.asarray(start, np.float64).reshape(2), np.asarray(goal, np.float64).reshape(2)
        if self.free.covers(LineString([s, gl])) or not self.passable.any():
            return np.stack([s, gl])
        cells = _astar(self.passable, self._nearest(s, self.passable), self._nearest(gl, self.passable), self.cost)
        if cells is None:
            return np.stack([s, gl])
        pts = np.stack([self.xs[[c[0] for c in cells]], self.ys[[c[1] for c in cells]]], -1)
        pts = np.concatenate([s[None], _turning_points(pts), gl[None]])
        return _shortcut(pts, self.free)


def _cell_costs(scene: PushScene, poses, cx, cy, ok, clearance: float, hard_clearance: float,
                brush_weight: float, extra=()) -> np.ndarray:
    """f[nx, ny] cost per metre of driving through each grid cell (centres ``cx, cy``): 1 on clear
    cells (``ok``); ``1 + brush_weight * depth / clearance`` where the cell is ``depth`` metres deeper
    than ``clearance`` towards the nearest movable but at least ``hard_clearance`` from every fixed
    obstacle, the workspace edge and the ``extra`` polygons; inf elsewhere."""
    hard = [f.polygon for f in scene.fixed] + list(extra)
    room = scene.workspace_polygon.buffer(-hard_clearance)
    if hard:
        room = room.difference(shapely.union_all([o.buffer(hard_clearance, 8) for o in hard]))
    cost = np.where(ok, 1.0, np.inf)
    tight = ~ok & shapely.contains_xy(room, cx, cy)
    movables = [m.polygon for m in scene.with_poses(poses).movables]
    if tight.any() and movables:
        d = shapely.distance(shapely.union_all(movables), shapely.points(cx[tight], cy[tight]))
        cost[tight] = 1.0 + brush_weight * np.clip(clearance - d, 0.0, None) / clearance
    return cost


def transition_path(scene: PushScene, start, goal, *, poses=None, clearance: float | None = None,
                    grid: float = 0.05, extra=()) -> np.ndarray:
    """A collision-free path ``f64[P, 2]`` for a robot centre from ``start`` to ``goal`` (both (x, y)).

    Grid A* (8-connected, cell ``grid`` m) over the free region of :func:`free_region` (obstacles at
    ``poses`` f[M, 3], default the scene's, inflated by ``clearance``, default ``robot_radius + 0.03``;
    ``extra``: more shapely polygons to avoid), then line-of-sight shortcuts. ``start`` and ``goal``
    may lie inside the inflated region (a robot at a contact): they are joined straight to their
    nearest free cells. When no grid route exists the straight segment is returned (the physics and
    the transition timeout then decide).
    """
    poses = scene.poses if poses is None else np.asarray(poses, np.float64)
    clearance = float(scene.robot_radius) + 0.03 if clearance is None else float(clearance)
    return Roadmap(scene, poses, clearance, grid, extra).path(start, goal)


_STEPS = [(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy]


def _astar(ok: np.ndarray, a, b, cost: np.ndarray | None = None):
    """Cells (i, j) from ``a`` to ``b`` through ``ok`` (bool[nx, ny]), 8-connected, corners not cut;
    None when unreachable. ``cost`` f[nx, ny] >= 1: per-cell cost per unit length (a step costs its
    length times the mean of its two cells'; default 1 everywhere, the heuristic stays admissible)."""
    nx, ny = ok.shape
    a, b = (int(a[0]), int(a[1])), (int(b[0]), int(b[1]))

    def h(c):
        dx, dy = abs(c[0] - b[0]), abs(c[1] - b[1])
        return max(dx, dy) + (math.sqrt(2) - 1) * min(dx, dy)

    g = {a: 0.0}
    parent = {a: None}
    heap = [(h(a), 0.0, a)]
    while heap:
        _, gc, c = heapq.heappop(heap)
        if c == b:
            out = []
            while c is not None:
                out.append(c)
                c = parent[c]
            return out[::-1]
        if gc > g[c]:
            continue
        for dx, dy in _STEPS:
            n = (c[0] + dx, c[1] + dy)
            if not (0 <= n[0] < nx and 0 <= n[1] < ny) or not ok[n]:
                continue
            if dx and dy and not (ok[c[0] + dx, c[1]] and ok[c[0], c[1] + dy]):
                continue                      # no corner cutting past a blocked cell
            step = math.sqrt(2) if dx and dy else 1.0
            ng = gc + (step if cost is None else step * 0.5 * (cost[c] + cost[n]))
            if ng < g.get(n, math.inf):
                g[n] = ng
                parent[n] = c
                heapq.heappush(heap, (ng + h(n), ng, n))
    return None


def _turning_points(pts: np.ndarray) -> np.ndarray:
    """Keep the first, last and every point where the grid path changes direction."""
    if len(pts) <= 2:
        return pts
    d = np.diff(pts, axis=0)
    turn = np.any(np.abs(d[1:] - d[:-1]) > 1e-12, axis=1)
    keep = np.r_[True, turn, True]
    return pts[keep]


def _shortcut(pts: np.ndarray, free) -> np.ndarray:
    """Greedy line-of-sight shortening: from each kept point jump to the farthest point visible in
    ``free`` (the first and last legs, which may start inside the inflated region, stay as they are)."""
    out = [pts[0]]
    i, n = 1, len(pts)
    if n > 2:
        out.append(pts[1])
    while i < n - 2:
        j = n - 2
        while j > i + 1 and not free.covers(LineString([pts[i], pts[j]])):
            j -= 1
        out.append(pts[j])
        i = j
    out.append(pts[-1])
    path = np.asarray(out)
    keep = np.r_[True, np.linalg.norm(np.diff(path, axis=0), axis=1) > 1e-9]
    return path[keep]
