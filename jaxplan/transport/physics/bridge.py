"""The 3D <-> 2D bridge of Section 4.2: check planned routes by driving the rover through gravel.

The paper's four steps, as functions of this module:

(i)   :func:`rasterise` turns particle centroids (and the rover pose) into a grid ``obj``;
(ii)  the planner (``build_fabric`` + ``extract_paths``; :func:`plan_routes`) gives routes;
(iii) each route's waypoints become a smooth spline (``spillage.sample_route``, the same
      centripetal Catmull-Rom spline the 2D spill model uses), tracked by a pure-pursuit controller
      (:func:`pursuit_policy`) that steers the *blade* (its front-face midpoint) along it;
      :func:`check_routes` rolls out a batch of routes at once on either engine;
(iv)  :func:`project` puts the final particles back on the grid so that
      ``rebuild.selective_rebuild`` can update the fabric.

Only the route's own non-target cells get particles (the 2D model's collected mass); every other
cell keeps its count untouched. Per route, the collected particle mass ends up in exactly one of:
delivered (in a target cell), left behind (still on a route cell), spilled (another in-grid cell),
lost (off the grid, or the rollout failed). Lateral error is the distance from the blade point to
the spline polyline at every control tick until the rover stops, in cells.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from jaxplan.physics import Simulator, Trajectory
from jaxplan.transport import execute, spillage
from jaxplan.transport.physics import model as rover_mod

__all__ = ["PursuitParams", "RouteOutcome", "Check", "pursuit_policy", "pursuit_params", "route_path", "pad_paths",
           "check_routes", "route_mask", "cells_of", "particle_fates", "friction_fields", "rasterise", "project",
           "plan_routes", "tracking_error", "world_for_routes", "PUSH_IN"]

_SAMPLES = 8            # spline samples per waypoint segment (as spillage's default)
_TIP_GAP = 0.68         # the shovel's wing tips start this many cells behind the source cell's
                        # centre: they clear a diagonal source cell's corner particles (with 1-cell
                        # wings a blade start 0.9 cell behind put the tips among the source's particles)
_MAX_SEGMENT = 1.5      # cells: longer waypoint segments are split before the spline (_split_long_segments)
_PATH_PAD = 64          # tracked paths are padded to a multiple of this many points (fewer shapes to compile)
_STOP_TOL = 0.05        # cells: the rover stops once the blade is this close to the path's end
PUSH_IN = 1.0           # cells the blade drives on past a route's end by default: stopping on a
                        # fallback route's boundary point left the carried load straddling the
                        # boundary, mostly outside the target cells (docs/physics.md, "Pushing in")


class PursuitParams(NamedTuple):
    """Per-route parameters of :func:`pursuit_policy` (world units, seconds, radians).

    path: f[M, 2] polyline of the spline (padded by repeating the end); arc: f[M] arc length at each
    vertex; total: f[], path length; end_dir: f[2], unit tangent at the end.
    speed: f[], blade speed; lookahead: f[], pursuit distance; offset: f[], axle-to-blade distance;
    half_track: f[], wheel_r: f[], omega_max: f[] yaw-rate limit; stop_tol: f[].
    """

    path: jax.Array
    arc: jax.Array
    total: jax.Array
    end_dir: jax.Array
    speed: jax.Array
    lookahead: jax.Array
    offset: jax.Array
    half_track: jax.Array
    wheel_r: jax.Array
    omega_max: jax.Array
    stop_tol: jax.Array


def _yaw(qpos):
    w, x, y, z = qpos[3], qpos[4], qpos[5], qpos[6]
    return jnp.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def pursuit_policy(p: PursuitParams, pstate, qpos, qvel, time):
    """Pure pursuit on the blade point. pstate = (progress f[] arc length, done bool[]).

    The goal is the path point ``lookahead`` ahead of the blade's progress (past the end: straight
    on along the end tangent, so the load is pushed home). The blade point is driven toward it at
    ``speed`` (slower over the last lookahead); a point ahead of the axle of a differential drive is
    fully controllable, ``[v, offset * omega] = R(-yaw) u``. ``done`` latches once the blade is
    within ``stop_tol`` of the end, and the wheels then get 0.
    """
    del qvel, time
    progress, done = pstate
    yaw = _yaw(qpos)
    head = jnp.stack([jnp.cos(yaw), jnp.sin(yaw)])
    normal = jnp.stack([-head[1], head[0]])
    blade = qpos[:2] + p.offset * head
    # closest point on the polyline's segments whose projection lies in a window around the last
    # progress (paths may pass near themselves). Segments, not vertices: a fallback route's last
    # spline segment can be many cells long, and a vertex-only search then found nothing in the
    # window and froze the progress (the rover parked mid-route).
    a, b = p.path[:-1], p.path[1:]
    ab = b - a
    len2 = jnp.sum(ab * ab, -1)
    t = jnp.clip(jnp.sum((blade - a) * ab, -1) / jnp.maximum(len2, 1e-12), 0.0, 1.0)
    d2 = jnp.sum((a + t[:, None] * ab - blade) ** 2, -1)
    s_proj = p.arc[:-1] + t * (p.arc[1:] - p.arc[:-1])
    window = (s_proj >= progress - p.lookahead) & (s_proj <= progress + p.lookahead)
    near = jnp.argmin(jnp.where(window, d2, jnp.inf))
    progress = jnp.maximum(progress, jnp.where(window[near], s_proj[near], progress))
    remaining = p.total - progress
    done = done | (remaining < p.stop_tol)
    s_goal = progress + p.lookahead
    on_path = jnp.stack([jnp.interp(s_goal, p.arc, p.path[:, 0]), jnp.interp(s_goal, p.arc, p.path[:, 1])])
    goal = on_path + p.end_dir * jnp.maximum(s_goal - p.total, 0.0)
    to_goal = goal - blade
    u = to_goal / jnp.maximum(jnp.linalg.norm(to_goal), 1e-9)
    speed = p.speed * jnp.clip(remaining / p.lookahead, 0.3, 1.0)
    v = jnp.clip(speed * jnp.dot(u, head), -0.25 * p.speed, p.speed)
    omega = jnp.clip(speed * jnp.dot(u, normal) / p.offset, -p.omega_max, p.omega_max)
    wheels = jnp.stack([v - omega * p.half_track, v + omega * p.half_track]) / p.wheel_r
    return jnp.where(done, 0.0, wheels), (progress, done)


# Compiled once per shape: run eagerly, these dozens of tiny array operations cost ~20 ms per route,
# which at a batch of 1,024 routes outweighed the physics itself (docs/physics.md, "On a GPU").
_waypoints_jit = jax.jit(execute.waypoints)
_sample_route_jit = jax.jit(spillage.sample_route, static_argnums=2)
_WAY_PAD = 16           # spline inputs are padded to a multiple of this many waypoints (fewer compiles)


def route_path(scene, route: execute.Route, world_geom: rover_mod.Geometry, push_in: float = 0.0):
    """The tracked path of one route: ``(path f[M, 2], arc f[M], total, end_dir f[2], start_xy, yaw)``.

    Waypoints are the start point (the blade's front face placed so that the wing tips are
    ``_TIP_GAP`` cells behind the source, on the line to the next waypoint), then the route's
    waypoints (``execute.waypoints``), with segments longer than 1.5 cells split into pieces of at
    most one cell (``_split_long_segments``). The spline is sampled like the 2D spill model's and
    closed with the end point, then extended straight on by ``push_in`` cells along the end tangent
    (the blade stops there: with 0 it stops on a fallback route's boundary point, and the load it
    carries straddles the boundary). Numpy; M = (S + 1) * _SAMPLES + 2 (S waypoint slots), or the
    next multiple of ``_PATH_PAD`` above the sample count where the split made more.
    """
    s = float(np.asarray(scene.cell_size))
    pts, n = _waypoints_jit(scene, route)
    pts, n = np.asarray(pts, np.float64), int(n)
    first = pts[1] - pts[0] if n > 1 else np.asarray(route.end, np.float64) - pts[0]
    norm = np.linalg.norm(first)
    dir0 = first / norm if norm > 0 else np.array([1.0, 0.0])
    start = pts[0] - dir0 * (_TIP_GAP * s + world_geom.wing_reach)
    way = _split_long_segments(np.concatenate([start[None], pts[:n]], 0), _MAX_SEGMENT * s, s)
    padded = _pad_end(way, _WAY_PAD * -(-way.shape[0] // _WAY_PAD))   # rows past n_points are ignored
    samples = _sample_route_jit(jnp.asarray(padded, jnp.float32), way.shape[0], _SAMPLES)
    pos = np.asarray(samples.pos, np.float64)
    valid = np.asarray(samples.valid)
    end = way[-1]
    poly = np.concatenate([start[None], pos[valid], end[None]], 0)
    tail = poly[valid.sum()] - poly[max(valid.sum() - 1, 0)]
    end_dir = tail / max(np.linalg.norm(tail), 1e-12)
    stop = end + end_dir * float(push_in) * s
    poly = np.concatenate([poly, stop[None]], 0)
    m = (len(pts) + 1) * _SAMPLES + 2
    if poly.shape[0] > m:
        m = _PATH_PAD * -(-poly.shape[0] // _PATH_PAD)
    poly = _pad_end(poly, m)
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    axle = start - dir0 * world_geom.blade_front
    return poly, arc, float(arc[-1]), end_dir, axle, math.atan2(dir0[1], dir0[0])


def _split_long_segments(way, max_length, piece):
    """``f[K, 2]``: the polyline ``way f[J, 2]`` with every segment longer than ``max_length`` cut
    into equal pieces no longer than ``piece`` (world units).

    The uniform Catmull-Rom spline (the spill model's spline before it became centripetal) takes its
    tangent at a waypoint from the two neighbours, so a one-cell step followed by a long fallback
    segment (tens of cells on ``sparse65``) got a tangent of half the long segment and looped on the
    short one: the rover drove the loop and swept its load out (3 of 20 objects delivered). The
    centripetal spline does not loop but still bows off a long straight segment; equal spacing keeps
    the tracked path on the polyline.
    """
    out = [way[0]]
    for a, b in zip(way[:-1], way[1:]):
        length = float(np.linalg.norm(b - a))
        k = int(math.ceil(length / piece)) if length > max_length else 1
        out.extend(a + (b - a) * (j / k) for j in range(1, k + 1))
    return np.asarray(out)


def pursuit_params(paths, geometry: rover_mod.Geometry, speed, lookahead: float, cell_size: float) -> PursuitParams:
    """``PursuitParams`` with leading axis B for ``paths`` (B ``route_path`` tuples, padded to one
    length: ``pad_paths``). speed: blade speed in cells/s (scalar or f[B]); lookahead: cells."""
    b = len(paths)
    s = float(cell_size)
    speeds = np.broadcast_to(np.asarray(speed, np.float64), (b,)) * s
    f32 = lambda x: jnp.asarray(np.asarray(x), jnp.float32)  # noqa: E731
    return PursuitParams(
        path=f32([p[0] for p in paths]), arc=f32([p[1] for p in paths]), total=f32([p[2] for p in paths]),
        end_dir=f32([p[3] for p in paths]), speed=f32(speeds), lookahead=f32(np.full(b, lookahead * s)),
        offset=f32(np.full(b, geometry.blade_front)), half_track=f32(np.full(b, geometry.half_track)),
        wheel_r=f32(np.full(b, geometry.wheel_r)), omega_max=f32(np.full(b, 2.0)),
        stop_tol=f32(np.full(b, _STOP_TOL * s)))


class RouteOutcome(NamedTuple):
    """Per-route physics verdicts (arrays [B]); masses in objects, lengths in cells, time in s.

    collected: particle mass generated on the route's cells.  delivered / left_behind / spilled /
    lost: where it ended (module docstring).  predicted_delivered / predicted_spilled: the 2D model
    (``execute.execute_push``) on the same route.  mean_lateral / max_lateral: blade-to-path distance.
    time: seconds until the rover stopped (the horizon if it never did).  reached: it stopped at
    the end.  finite: the physics stayed finite and in bounds.  max_contacts: largest number of
    penetrating contacts at a tick.
    """

    collected: np.ndarray
    delivered: np.ndarray
    left_behind: np.ndarray
    spilled: np.ndarray
    lost: np.ndarray
    predicted_delivered: np.ndarray
    predicted_spilled: np.ndarray
    mean_lateral: np.ndarray
    max_lateral: np.ndarray
    time: np.ndarray
    reached: np.ndarray
    finite: np.ndarray
    max_contacts: np.ndarray

    def rows(self) -> list[dict]:
        """One dict per route (python floats / bools), e.g. for JSON."""
        out = []
        for i in range(self.collected.shape[0]):
            row = {}
            for key, value in self._asdict().items():
                v = value[i]
                row[key] = (bool(v) if isinstance(v, (bool, np.bool_))
                            else (int(v) if key == "max_contacts" else float(v)))
            out.append(row)
        return out


class Check(NamedTuple):
    """Everything :func:`check_routes` computed: outcomes, the rollout, the world and the inputs."""

    outcome: RouteOutcome
    trajectory: Trajectory
    world: rover_mod.World
    params: PursuitParams
    particle_cells: list          # per route: i32[P_i, 2] cell each particle started in
    represented: list             # per route: f[H, W] count the particles stand for
    route_masks: np.ndarray       # bool[B, H, W] the route's non-target cells
    n_ticks: int


def route_mask(scene, route) -> np.ndarray:
    """``bool[H, W]``: the non-target cells of one route (the cells whose count it collects)."""
    cells = np.asarray(route.cells)[: int(route.n_cells)]
    mask = np.zeros(scene.shape, bool)
    mask[cells[:, 0], cells[:, 1]] = True
    return mask & ~np.asarray(scene.target_mask)


def _index(routes, i):
    return jax.tree_util.tree_map(lambda a: a[i], routes)


def _point_polyline_distance(points, poly):
    """``f[T]`` distance of ``points f[T, 2]`` to the polyline ``poly f[M, 2]``."""
    a, b = poly[:-1], poly[1:]
    ab = b - a
    ll = np.maximum(np.sum(ab * ab, -1), 1e-18)
    t = np.clip(np.einsum("tmk,mk->tm", points[:, None] - a[None], ab) / ll, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.sqrt(np.min(np.sum((points[:, None] - closest) ** 2, -1), -1))


def cells_of(scene, xy):
    """``(row, col, inside)`` of world points ``xy f[..., 2]`` (numpy twin of execute._cell_of)."""
    h, w = scene.shape
    s = float(np.asarray(scene.cell_size))
    rc = np.floor((xy - np.asarray(scene.origin, np.float64)) / s).astype(np.int64)
    col, row = rc[..., 0], rc[..., 1]
    inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
    return np.clip(row, 0, h - 1), np.clip(col, 0, w - 1), inside


def rasterise(scene, xy, mass):
    """Step (i): ``(obj f[H, W], off_grid f[])`` from particle centroids ``xy f[P, 2]`` carrying
    ``mass f[P]`` objects each; mass off the grid is returned separately."""
    row, col, inside = cells_of(scene, np.asarray(xy, np.float64))
    obj = np.zeros(scene.shape)
    np.add.at(obj, (row[inside], col[inside]), np.asarray(mass, np.float64)[inside])
    return obj, float(np.sum(np.asarray(mass, np.float64)[~inside]))


def project(scene, represented, final_xy, mass):
    """Step (iv): the grid after a push. ``represented f[H, W]`` = the counts that became particles
    (removed), ``final_xy f[P, 2]`` their end positions (added back where they lie).

    Returns ``(obj f[H, W], lost f[])`` with ``sum(obj) + lost == sum(scene.obj)`` (float64).
    """
    placed, lost = rasterise(scene, final_xy, mass)
    return np.asarray(scene.obj, np.float64) - np.asarray(represented, np.float64) + placed, lost


def plan_routes(scene, params=None, n_routes: int = 4):
    """Step (ii): the selected routes ``P*(C)`` of the ``n_routes`` sources with the largest J.

    Returns ``(fabric, routes: execute.Route with leading axis B, sources i32[B, 2])``.
    """
    from jaxplan.transport.fabric import build_fabric, extract_paths
    from jaxplan.transport.params import FabricParams

    params = FabricParams() if params is None else params
    fabric = build_fabric(scene, params)
    value = np.where(np.asarray(fabric.occupied), np.asarray(fabric.value), -np.inf)
    order = np.argsort(-value, axis=None, kind="stable")[: int(n_routes)]
    order = order[np.isfinite(value.reshape(-1)[order])]
    if order.size == 0:
        raise ValueError("scene: no occupied cell outside the target, so there is no route to check.")
    w = scene.shape[1]
    sources = np.stack([order // w, order % w], -1).astype(np.int32)
    paths = extract_paths(fabric, sources, detour=scene.detour)
    return fabric, execute.routes_from_paths(scene, paths), sources


def check_routes(scene, routes: execute.Route, *, config: rover_mod.RoverConfig | None = None,
                 spill: spillage.SpillParams | None = None, evaluator: spillage.Evaluator | None = None,
                 speed=0.8, lookahead: float = 0.8,
                 backend: str = "auto", horizon_factor: float = 1.5, n_ticks: int | None = None,
                 push_in: float = PUSH_IN, friction=None,
                 simulator: Simulator | None = None, world: rover_mod.World | None = None) -> Check:
    """Roll out every route of ``routes`` (leading axis B) in one batch and score it.

    spill / evaluator: the 2D model of ``predicted_delivered`` (default ``SpillParams()``; the
    evaluator defaults to the one ``spill`` is for: ``capacity_spill`` for ``CapacitySpillParams``).

    friction: None (the world's, ``RoverConfig.friction``) or sliding friction per route (scalar or
    f[B]) of the floor, the particles and the hull; the wheels keep theirs. Per element on both
    engines (``Simulator.run``'s ``model_fields``), so a batch can sweep it.

    speed: blade speed in cells/s (scalar or f[B], a per-route parameter); lookahead: cells.
    push_in: cells the blade drives on past the route's end, along its end tangent (``route_path``).
    n_ticks: control ticks (default: the longest path at ``speed`` times ``horizon_factor``).
    world / simulator: reuse a built world (its particle count must suffice) and its compiled
    rollout; by default one world with as many particle bodies as the largest route needs.
    """
    cfg = rover_mod.RoverConfig() if config is None else config
    spill = spillage.SpillParams() if spill is None else spill
    evaluator = spillage.evaluator_for(spill) if evaluator is None else evaluator
    s = float(np.asarray(scene.cell_size))
    routes = jax.tree_util.tree_map(np.asarray, routes)   # per-route slices below: numpy, not device ops
    b = int(routes.n_cells.shape[0])
    masks, layouts = _route_layouts(scene, routes, cfg)
    need = max(len(lay[0]) for lay in layouts)
    if world is None:
        world = rover_mod.build_world(scene, need, cfg)
    elif world.n_particles < need:
        raise ValueError(f"world: has {world.n_particles} particle bodies, the routes need {need}.")
    g = world.geometry
    speeds = np.broadcast_to(np.asarray(speed, np.float64), (b,)) * s
    paths = [route_path(scene, _index(routes, i), g, push_in) for i in range(b)]
    paths = pad_paths(paths)
    q0 = np.stack([rover_mod.initial_qpos(world, p[4], p[5], lay[0]) for p, lay in zip(paths, layouts)])
    qv0 = np.zeros((b, world.model.nv))
    params = pursuit_params(paths, g, speeds / s, lookahead, s)
    pstate0 = (jnp.zeros(b, jnp.float32), jnp.zeros(b, bool))
    if simulator is None:
        simulator = Simulator(world.model, pursuit_policy, substeps=cfg.substeps, bounds=world.bounds,
                              backend=backend)
    if n_ticks is None:
        longest = max(p[2] for p in paths) / max(float(speeds.min()), 1e-9)
        n_ticks = int(math.ceil(horizon_factor * longest / simulator.tick_seconds)) + 20
    traj = simulator.run(q0, qv0, params, pstate0, n_ticks,
                         model_fields=None if friction is None else friction_fields(world, friction, b))
    outcome = _score(scene, routes, world, traj, paths, layouts, masks, spill, evaluator)
    return Check(outcome, traj, world, params, [lay[1] for lay in layouts], [lay[2] for lay in layouts],
                 np.stack(masks), n_ticks)


def _route_layouts(scene, routes: execute.Route, cfg: rover_mod.RoverConfig):
    """Per route i of ``routes``: its cell mask and its particle layout (seeded by i)."""
    masks = [route_mask(scene, _index(routes, i)) for i in range(int(np.asarray(routes.n_cells).shape[0]))]
    return masks, [rover_mod.particle_layout(scene, m, cfg, seed=i) for i, m in enumerate(masks)]


def world_for_routes(scene, routes: execute.Route, config: rover_mod.RoverConfig | None = None) -> rover_mod.World:
    """The rover world ``check_routes`` builds for ``routes``: as many particle bodies as the largest
    route needs (particle counts follow the cells' counts, not the layout seed). Pass it as
    ``check_routes(world=...)`` to share one world (and its compiled rollout) between calls."""
    cfg = rover_mod.RoverConfig() if config is None else config
    _, layouts = _route_layouts(scene, jax.tree_util.tree_map(np.asarray, routes), cfg)
    return rover_mod.build_world(scene, max(len(lay[0]) for lay in layouts), cfg)


def friction_fields(world: rover_mod.World, friction, b: int) -> dict:
    """``{"geom_friction": f[B, ngeom, 3]}``: the world's geom frictions with the sliding
    coefficient of every geom but the wheels (of every rover) set to ``friction`` (scalar or f[B])
    per batch element."""
    mu = np.broadcast_to(np.asarray(friction, np.float64), (b,))
    if not np.all(np.isfinite(mu) & (mu > 0)):
        raise ValueError(f"friction: must be positive and finite, one value or one per route; got {friction!r}.")
    model = world.model
    wheels = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, rover_mod.rover_prefix(i, world.n_rovers) + name)
              for i in range(world.n_rovers) for name in ("wheel_left", "wheel_right")]
    sliding = np.ones(model.ngeom, bool)
    sliding[wheels] = False
    table = np.repeat(np.asarray(model.geom_friction, np.float64)[None], b, 0)
    table[:, sliding, 0] = mu[:, None]
    return {"geom_friction": table}


def _pad_end(a, m: int):
    """``a`` (leading axis >= 1) extended to length ``m`` by repeating its last row."""
    return np.concatenate([a, np.repeat(a[-1:], m - a.shape[0], 0)], 0)


def pad_paths(paths):
    """Route paths (``route_path``) padded to one length by repeating their end point."""
    m = max(p[0].shape[0] for p in paths)
    return [(_pad_end(p[0], m), _pad_end(p[1], m)) + tuple(p[2:]) for p in paths]


def particle_fates(scene, final_xy, own_mask, finite: bool = True):
    """Where each particle ended: ``(delivered, left, spilled, lost)``, bool[P] each, exactly one
    true per particle (module docstring). final_xy: f[P, 2] world positions; own_mask: bool[H, W],
    the cells of the route the particles started on; finite: the rollout stayed finite (else all lost)."""
    final_xy = np.asarray(final_xy, np.float64)
    row, col, inside = cells_of(scene, final_xy)
    target = np.asarray(scene.target_mask)
    own = np.asarray(own_mask, bool)
    ok = bool(finite) & np.all(np.isfinite(final_xy), -1)
    delivered = ok & inside & target[row, col]
    left = ok & inside & ~target[row, col] & own[row, col]
    spilled = ok & inside & ~target[row, col] & ~own[row, col]
    return delivered, left, spilled, ~(delivered | left | spilled)


def _score(scene, routes, world, traj: Trajectory, paths, layouts, masks, spill, evaluator) -> RouteOutcome:
    s = float(np.asarray(scene.cell_size))
    ppo = world.config.particles_per_object
    cols = {k: [] for k in RouteOutcome._fields}
    for i, (path, (xyz, _cells, _), mask) in enumerate(zip(paths, layouts, masks)):
        n_p = len(xyz)
        mass = np.full(n_p, 1.0 / ppo)
        final = world.particle_xyz(traj.qpos[i, -1])[:n_p, :2]
        delivered, left, spilled, lost = particle_fates(scene, final, mask, bool(traj.finite[i]))
        # blade point per tick, until the rover stopped (ctrl latched to exactly 0)
        qp = traj.qpos[i]
        yaw = np.arctan2(2 * (qp[:, 3] * qp[:, 6] + qp[:, 4] * qp[:, 5]), 1 - 2 * (qp[:, 5] ** 2 + qp[:, 6] ** 2))
        blade = qp[:, :2] + world.geometry.blade_front * np.stack([np.cos(yaw), np.sin(yaw)], -1)
        stopped = np.nonzero(np.all(traj.ctrl[i] == 0.0, -1))[0]
        reached = stopped.size > 0
        last = int(stopped[0]) if reached else traj.ctrl.shape[1]
        track = blade[: last + 1]
        good = np.all(np.isfinite(track), -1)
        lateral = _point_polyline_distance(track[good], path[0]) / s if good.any() else np.array([np.nan])
        pushed, push = execute.execute_jit(scene, _index(routes, i), spill, evaluator)
        del pushed
        cols["collected"].append(mass.sum())
        cols["delivered"].append(mass[delivered].sum())
        cols["left_behind"].append(mass[left].sum())
        cols["spilled"].append(mass[spilled].sum())
        cols["lost"].append(mass[lost].sum())
        cols["predicted_delivered"].append(float(push.delivered))
        cols["predicted_spilled"].append(float(push.spilled))
        cols["mean_lateral"].append(float(np.mean(lateral)))
        cols["max_lateral"].append(float(np.max(lateral)))
        cols["time"].append(last * (traj.time[1] - traj.time[0]))
        cols["reached"].append(reached)
        cols["finite"].append(bool(traj.finite[i]))
        cols["max_contacts"].append(int(traj.ncon[i].max()))
    return RouteOutcome(**{k: np.asarray(v) for k, v in cols.items()})


def tracking_error(scene, check: Check, i: int):
    """``(time f[T], lateral f[T])`` of route ``i``: blade point to the tracked path, in cells, at every
    control tick until the rover stopped (as ``RouteOutcome.mean_lateral`` / ``max_lateral`` average)."""
    s = float(np.asarray(scene.cell_size))
    qp = check.trajectory.qpos[i]
    yaw = np.arctan2(2 * (qp[:, 3] * qp[:, 6] + qp[:, 4] * qp[:, 5]), 1 - 2 * (qp[:, 5] ** 2 + qp[:, 6] ** 2))
    blade = qp[:, :2] + check.world.geometry.blade_front * np.stack([np.cos(yaw), np.sin(yaw)], -1)
    stopped = np.nonzero(np.all(check.trajectory.ctrl[i] == 0.0, -1))[0]
    last = int(stopped[0]) if stopped.size else check.trajectory.ctrl.shape[1]
    track = blade[: last + 1]
    good = np.all(np.isfinite(track), -1)
    time = np.asarray(check.trajectory.time)[: last + 1][good]
    return time, _point_polyline_distance(track[good], np.asarray(check.params.path[i], np.float64)) / s


def projected_obj(scene, check: Check, i: int):
    """Step (iv) for route ``i`` of a :class:`Check`: ``(obj f[H, W], lost f[])``."""
    world = check.world
    n_p = check.particle_cells[i].shape[0]
    final = world.particle_xyz(check.trajectory.qpos[i, -1])[:n_p, :2]
    if not bool(check.trajectory.finite[i]):   # a failed rollout changes nothing on the grid
        final = world.particle_xyz(check.trajectory.qpos[i, 0])[:n_p, :2]
    mass = np.full(n_p, 1.0 / world.config.particles_per_object)
    return project(scene, check.represented[i], final, mass)
