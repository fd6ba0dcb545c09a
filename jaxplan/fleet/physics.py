"""Concurrent pushes in physics: N shovel rovers push N routes at once in ONE MuJoCo world.

The fleet's pushes run at the same time on disjoint footprints. This check drives them together
through gravel, as the single-rover bridge (``jaxplan.transport.physics.bridge``) drives one route per
world, and reports what the 2D fleet model assumes but cannot see:

- rover-rover contacts: every (physics step, rover pair) with at least one contact between bodies of
  the two rovers in MuJoCo's contact list (geom -> its root body -> rover id). Rovers of one world
  collide with each other (``rover.model``, collision bit 8), so a contact is a real touch; with
  disjoint footprints and rovers started on their routes there must be none;
- per route: the 2D model's delivered mass (``execute.execute_push`` with ``spill``, as the bridge
  predicts) against the simulated delivered mass, and whether they agree within ``tolerance``
  (15%: the fleet issue's target).

The world (``build_world(..., n_rovers=N)``; the scene's blocked cells are static boxes in it, which
rovers and particles collide with, and a rover's contact with one is no rover-rover contact) holds the
particles of every route's non-target cells (``particle_layout``, seeded by the route's index); a
cell on several routes gets its particles once, for the lowest-index route (only crossing routes
share cells). A particle is attributed to the route
whose cell it started on and ends in exactly one of: delivered (a target cell), left behind (a cell
of its own route), spilled (another in-grid cell, possibly another route's), lost (off the grid, or
the physics diverged): ``bridge.particle_fates``. Other cells keep their counts and have no
particles.

Control: every rover tracks its route's spline with the bridge's pure pursuit
(``bridge.route_path``, ``bridge.pursuit_policy``; the blade driven ``push_in`` cells past the end),
starting at its route's start pose (or at ``starts_xy``, heading along the route's first segment).
A rover whose route ends early parks: the controller latches ``done`` and its wheels get 0. The C
engine steps the one world with ``mj_step`` one physics step at a time, so contacts are read at every
step; the controller runs once per control tick of ``RoverConfig.substeps`` steps. The rollout ends
``settle_ticks`` after the last rover parked, or at the horizon (the longest path at ``speed`` times
``horizon_factor``, plus 20 ticks, as the bridge's).
"""
from __future__ import annotations

import copy
import dataclasses
import math
import numbers

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from jaxplan.transport import Route, execute_jit, route_from_path
from jaxplan.transport.physics import (
    PUSH_IN,
    PursuitParams,
    RoverConfig,
    World,
    build_world,
    cells_of,
    friction_fields,
    initial_qpos,
    pad_paths,
    particle_fates,
    particle_layout,
    pursuit_params,
    pursuit_policy,
    route_mask,
    route_path,
    rover_geometry,
    rover_prefix,
    rover_qpos_adr,
)
from jaxplan.transport.spillage import Evaluator, SpillParams, evaluator_for

__all__ = ["ConcurrentCheck", "check_concurrent_pushes", "fleet_policy", "route_footprint", "disjoint_routes",
           "relative_error", "within_tolerance", "TOLERANCE"]

TOLERANCE = 0.15          # relative error of simulated vs predicted delivery that counts as agreement
_SETTLE_TICKS = 20        # control ticks the world runs on after the last rover parked (1 s by default)
_LOOKAHEAD = 0.8          # cells: the bridge's default pure-pursuit lookahead


@dataclasses.dataclass(frozen=True)
class ConcurrentCheck:
    """What :func:`check_concurrent_pushes` found. N routes / rovers; masses in objects.

    contacts: int, (physics step, rover pair) contacts over the rollout (0 = the rovers never touched).
    contact_events: i32[K, 3], (step, rover a, rover b) of each, a < b; steps count from 1.
    min_axle_distance: f[], the closest two rovers' axle midpoints came, in cells (inf for N = 1).
    collected, delivered, left_behind, spilled, lost: f64[N], simulated, per route (the particles that
      started on its cells); delivered + left_behind + spilled + lost == collected.
    predicted_collected, predicted_delivered: f64[N], the 2D model on the same routes.
    relative_error: f64[N], |delivered - predicted_delivered| / predicted_delivered (inf when the
      prediction is 0 and the simulation delivered something, 0 when both are 0).
    within: bool[N], relative_error <= tolerance.  tolerance: float.
    reached: bool[N], the rover parked at its route's end.  finish_time: f64[N], seconds until it
      parked (nan if it never did).
    finite: bool, the physics stayed finite and inside the world box.
    n_ticks: control ticks run; n_steps: physics steps run; tick_seconds: seconds per tick.
    rover_xy: f64[n_ticks + 1, N, 2], axle midpoints per tick (world units).
    final_qpos: f64[nq].  world: the built ``rover.model.World``.
    particle_route: i32[P], route index of every particle; particle_cells: i32[P, 2] its start cell.
    """

    contacts: int
    contact_events: np.ndarray
    min_axle_distance: float
    collected: np.ndarray
    delivered: np.ndarray
    left_behind: np.ndarray
    spilled: np.ndarray
    lost: np.ndarray
    predicted_collected: np.ndarray
    predicted_delivered: np.ndarray
    relative_error: np.ndarray
    within: np.ndarray
    tolerance: float
    reached: np.ndarray
    finish_time: np.ndarray
    finite: bool
    n_ticks: int
    n_steps: int
    tick_seconds: float
    rover_xy: np.ndarray
    final_qpos: np.ndarray
    world: World
    particle_route: np.ndarray
    particle_cells: np.ndarray

    @property
    def fraction_within(self) -> float:
        """Share of routes whose simulated delivery is within ``tolerance`` of the prediction."""
        return float(np.mean(self.within)) if self.within.size else float("nan")

    def rows(self) -> list[dict]:
        """One dict per route (python scalars; a non-finite number as None), e.g. for strict JSON."""
        keys = ("collected", "delivered", "left_behind", "spilled", "lost", "predicted_collected",
                "predicted_delivered", "relative_error", "within", "reached", "finish_time")
        out = []
        for i in range(self.collected.shape[0]):
            row = {"route": i}
            for key in keys:
                v = getattr(self, key)[i]
                row[key] = bool(v) if isinstance(v, (bool, np.bool_)) else (float(v) if np.isfinite(v) else None)
            out.append(row)
        return out

    def summary(self) -> dict:
        """Fleet-level numbers (python scalars; the closest approach None for one rover): contacts,
        closest approach, agreement, stability."""
        return {"rovers": int(self.collected.shape[0]), "contacts": int(self.contacts),
                "min_axle_distance_cells": (float(self.min_axle_distance / self.world.cell_size)
                                            if math.isfinite(self.min_axle_distance) else None),
                "fraction_within": self.fraction_within, "tolerance": float(self.tolerance),
                "finite": bool(self.finite), "all_reached": bool(np.all(self.reached)),
                "ticks": int(self.n_ticks), "steps": int(self.n_steps),
                "simulated_seconds": float(self.n_ticks * self.tick_seconds)}


def fleet_policy(rover_adr, params: PursuitParams, pstate, qpos):
    """The bridge's pure pursuit for every rover of one world: ``(wheels f[N, 2], pstate)``.

    rover_adr: i32[N] qpos address of each rover's free joint; params: ``PursuitParams`` with
    leading axis N; pstate: (progress f[N], done bool[N]); qpos: f[nq] of the whole world.
    """
    q = qpos[rover_adr[:, None] + jnp.arange(7)]
    return jax.vmap(lambda p, s, qq: pursuit_policy(p, s, qq, None, None))(params, pstate, q)


_fleet_policy_jit = jax.jit(fleet_policy)


def route_footprint(scene, route: Route, radius: int = 1, *, swept: bool = False,
                    config: RoverConfig | None = None, push_in: float = PUSH_IN) -> np.ndarray:
    """``bool[H, W]``: the cells a push may touch, dilated by ``radius`` cells (Chebyshev), clipped.

    swept=False: the route's cells (target cells included). swept=True: also the cells the rover
    itself passes over (``_swept_points``): its body at the start pose, the tracked spline with a
    fallback route's straight run to the boundary, and the blade's ``push_in`` past the end with the
    side plates reaching beyond. A fallback route's cells stop where its straight run to the target
    starts, so the route cells alone miss where the rover drives to deliver.
    """
    h, w = scene.shape
    cells = np.asarray(route.cells)[: int(route.n_cells)]
    core = np.zeros((h, w), bool)
    core[cells[:, 0], cells[:, 1]] = True
    if swept:
        row, col, inside = cells_of(scene, _swept_points(scene, route, config, push_in))
        core[row[inside], col[inside]] = True
    mask = np.zeros((h + 2 * radius, w + 2 * radius), bool)
    rows, cols = np.nonzero(core)
    for dr in range(2 * radius + 1):
        for dc in range(2 * radius + 1):
            mask[rows + dr, cols + dc] = True
    return mask[radius: radius + h, radius: radius + w]


_REAR = 0.4               # cells from the axle to the rover's back (rear caster: 0.32 + 0.05 in rover.model)
_SWEEP_STEP = 0.25        # cells between the points sampled along the swept centre line


def _swept_points(scene, route, config, push_in: float) -> np.ndarray:
    """``f[K, 2]`` world points, at most ``_SWEEP_STEP`` cells apart, along the rover's centre line
    from its back at the start pose to the side plates' tips past the end of the tracked path."""
    cfg = RoverConfig() if config is None else config
    s = float(np.asarray(scene.cell_size))
    g = rover_geometry(s, cfg)
    poly, _, _, end_dir, axle, yaw = route_path(scene, route, g, push_in)
    back = np.asarray(axle) - _REAR * s * np.array([math.cos(yaw), math.sin(yaw)])
    line = np.concatenate([back[None], poly, (poly[-1] + end_dir * g.wing_reach)[None]], 0)
    out = [line[:1]]
    for a, b in zip(line[:-1], line[1:]):
        k = max(1, int(math.ceil(np.linalg.norm(b - a) / (_SWEEP_STEP * s))))
        out.append(a + (b - a) * (np.arange(1, k + 1)[:, None] / k))
    return np.concatenate(out, 0)


def disjoint_routes(scene, routes: Route, k: int, radius: int = 1, *, swept: bool = False,
                    config: RoverConfig | None = None, push_in: float = PUSH_IN) -> np.ndarray:
    """``i32[<=k]``: greedily, in the given order (best first), the indices of up to ``k`` routes of
    the batch ``routes`` whose footprints (:func:`route_footprint` with ``radius``, ``swept``)
    overlap no route taken before."""
    routes = jax.tree_util.tree_map(np.asarray, routes)
    taken = np.zeros(scene.shape, bool)
    chosen = []
    for i in range(int(routes.n_cells.shape[0])):
        if len(chosen) == int(k):
            break
        foot = route_footprint(scene, _index(routes, i), radius, swept=swept, config=config, push_in=push_in)
        if not np.any(foot & taken):
            chosen.append(i)
            taken |= foot
    return np.asarray(chosen, np.int32)


def _index(routes, i):
    return jax.tree_util.tree_map(lambda a: a[i], routes)


def _validate(n_cells, starts_xy, speed, settle_ticks, n: int):
    """Raise ``ValueError`` naming the argument for bad inputs (before any world is built)."""
    if n_cells.ndim != 1 or n < 1:
        raise ValueError(f"routes: expected a batch of routes (n_cells i32[N], N >= 1); got n_cells of shape "
                         f"{n_cells.shape}. Stack single routes with jax.tree.map(lambda *a: np.stack(a), ...).")
    if np.any(n_cells < 1):
        raise ValueError(f"routes.n_cells: {n_cells.tolist()} has a route without cells; every route needs >= 1 "
                         "cell. Drop empty routes before the check.")
    speeds = np.asarray(speed, np.float64)
    if speeds.ndim > 1 or speeds.size not in (1, n) or not np.all(np.isfinite(speeds) & (speeds > 0)):
        raise ValueError(f"speed: {speed!r} is not a positive finite blade speed in cells/s (one value or one per "
                         f"route, {n} routes). Use e.g. speed=0.8.")
    if starts_xy is not None:
        xy = np.asarray(starts_xy, np.float64)
        if xy.shape != (n, 2) or not np.all(np.isfinite(xy)):
            raise ValueError(f"starts_xy: expected finite world (x, y) f[{n}, 2], one per route; got shape {xy.shape}. "
                             "Pass None to start every rover on its route's start.")
    if not (isinstance(settle_ticks, numbers.Integral) and settle_ticks >= 0):
        raise ValueError(f"settle_ticks: {settle_ticks!r} must be an int >= 0 (control ticks run after every rover "
                         "parked). Use e.g. 20.")


def _particles(scene, routes, n: int, cfg: RoverConfig):
    """Particles of every route's non-target cells, each cell once (lowest route index first).

    Returns ``(xyz f[P, 3], cells i32[P, 2], route i32[P], masks bool[N, H, W])``, masks being each
    route's own non-target cells (for the particles' fates).
    """
    claimed = np.zeros(scene.shape, bool)
    xyz, cells, owner, masks = [], [], [], []
    for i in range(n):
        mask = route_mask(scene, _index(routes, i))
        masks.append(mask)
        p_xyz, p_cells, _ = particle_layout(scene, mask & ~claimed, cfg, seed=i)
        claimed |= mask
        xyz.append(p_xyz)
        cells.append(p_cells)
        owner.append(np.full(len(p_xyz), i, np.int32))
    return np.concatenate(xyz), np.concatenate(cells), np.concatenate(owner), np.stack(masks)


def _geom_rover(world: World) -> np.ndarray:
    """``i32[ngeom]``: the rover each geom belongs to (its root body's), -1 for the floor, the blocked
    cells' boxes and the particles (a rover against a wall is no rover-rover contact)."""
    m = world.model
    roots = {int(m.body_rootid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY,
                                                 rover_prefix(i, world.n_rovers) + "rover")]): i
             for i in range(world.n_rovers)}
    return np.array([roots.get(int(m.body_rootid[b]), -1) for b in m.geom_bodyid], np.int32)


def _rover_pairs(d: mujoco.MjData, geom_rover: np.ndarray) -> set:
    """The rover pairs (a < b) with a contact in ``d``'s contact list."""
    if d.ncon == 0:
        return set()
    r = geom_rover[np.asarray(d.contact.geom[: d.ncon])]
    hit = (r[:, 0] >= 0) & (r[:, 1] >= 0) & (r[:, 0] != r[:, 1])
    return {(int(min(a, b)), int(max(a, b))) for a, b in r[hit]}


def _state_ok(world: World, free_adr, d: mujoco.MjData) -> bool:
    """The state is finite and every free body lies inside the world box."""
    if not (np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))):
        return False
    lo, hi = world.bounds
    pos = np.asarray(d.qpos)[free_adr[:, None] + np.arange(3)]
    return bool(np.all((pos >= lo) & (pos <= hi)))


def relative_error(sim, pred) -> np.ndarray:
    """``f64[...]``: |sim - pred| / pred; 0 where both are 0, inf where only the prediction is 0."""
    sim, pred = np.asarray(sim, np.float64), np.asarray(pred, np.float64)
    err = np.abs(sim - pred) / np.where(pred > 0, pred, 1.0)
    return np.where(pred > 0, err, np.where(sim == pred, 0.0, np.inf))


def within_tolerance(sim, pred, tolerance: float = TOLERANCE) -> np.ndarray:
    """``bool[...]``: the simulated delivery ``sim`` is within ``tolerance`` of the prediction ``pred``."""
    return relative_error(sim, pred) <= float(tolerance)


def check_concurrent_pushes(scene, routes: Route, starts_xy=None, *, spill: SpillParams,
                            evaluator: Evaluator | None = None,
                            config: RoverConfig | None = None, speed=0.8, friction=None,
                            push_in: float = PUSH_IN, lookahead: float = _LOOKAHEAD,
                            horizon_factor: float = 1.5, n_ticks: int | None = None,
                            settle_ticks: int = _SETTLE_TICKS, tolerance: float = TOLERANCE) -> ConcurrentCheck:
    """Drive N rovers along the N routes of ``routes`` at once in one MuJoCo world (module docstring).

    routes: ``execute.Route`` with leading axis N (``cells i32[N, S, 2]``, ``n_cells i32[N]``, ...).
    starts_xy: None (each rover at its route's start pose, as the bridge places it) or f[N, 2] world
      (x, y) of each rover's axle midpoint, heading along its route's first segment.
    spill / evaluator: the 2D model of the prediction (the evaluator defaults to ``spill``'s own).
    config: ``RoverConfig`` (default ``RoverConfig()``); speed: blade speed in cells/s (scalar or
      f[N]); friction: None (the world's) or the sliding friction of the floor, particles and hulls.
    push_in / lookahead: cells, as the bridge's. n_ticks: control ticks (default: the longest path at
      ``speed`` times ``horizon_factor``, plus 20); the rollout stops ``settle_ticks`` after every
      rover parked. tolerance: relative error that counts as agreement.
    """
    routes = jax.tree_util.tree_map(np.asarray, routes)
    n_cells = np.asarray(routes.n_cells)
    n = int(n_cells.shape[0]) if n_cells.ndim == 1 else 0
    _validate(n_cells, starts_xy, speed, settle_ticks, n)
    cfg = RoverConfig() if config is None else config
    evaluator = evaluator_for(spill) if evaluator is None else evaluator
    s = float(np.asarray(scene.cell_size))

    xyz, cells, owner, masks = _particles(scene, routes, n, cfg)
    world = build_world(scene, len(xyz), cfg, n_rovers=n)
    g = world.geometry
    paths = pad_paths([route_path(scene, _index(routes, i), g, push_in) for i in range(n)])
    params = pursuit_params(paths, g, speed, lookahead, s)
    axle = np.stack([p[4] for p in paths]) if starts_xy is None else np.asarray(starts_xy, np.float64)
    q0 = initial_qpos(world, axle, np.array([p[5] for p in paths]), xyz)
    if n_ticks is None:
        speeds = np.broadcast_to(np.asarray(speed, np.float64), (n,)) * s
        longest = max(p[2] / v for p, v in zip(paths, speeds))
        n_ticks = int(math.ceil(horizon_factor * longest / (cfg.timestep * cfg.substeps))) + 20
    roll = _rollout(world, q0, params, friction, int(n_ticks), int(settle_ticks))

    sim, pred_collected, pred_delivered = _masses(scene, routes, world, roll, owner, masks, spill, evaluator)
    err = relative_error(sim["delivered"], pred_delivered)
    xy = roll["rover_xy"]
    if n > 1:
        gaps = np.linalg.norm(xy[:, :, None] - xy[:, None, :], axis=-1)
        min_gap = float(np.min(gaps[:, ~np.eye(n, dtype=bool)]))
    else:
        min_gap = math.inf
    events = roll["events"]
    return ConcurrentCheck(
        contacts=len(events), contact_events=np.asarray(events, np.int32).reshape(-1, 3), min_axle_distance=min_gap,
        **sim, predicted_collected=pred_collected, predicted_delivered=pred_delivered, relative_error=err,
        within=err <= tolerance, tolerance=float(tolerance), reached=~np.isnan(roll["finish"]),
        finish_time=roll["finish"], finite=roll["finite"], n_ticks=roll["ticks"], n_steps=roll["steps"],
        tick_seconds=cfg.timestep * cfg.substeps, rover_xy=xy, final_qpos=roll["qpos"], world=world,
        particle_route=owner, particle_cells=cells)


def _rollout(world: World, q0, params: PursuitParams, friction, n_ticks: int,
             settle_ticks: int) -> dict:
    """Step the world on the C engine one physics step at a time (module docstring).

    Returns ``events`` (list of (step, a, b) rover contacts), ``rover_xy`` f[T+1, N, 2] per tick,
    ``finish`` f[N] seconds until each rover parked (nan: never), ``finite``, ``ticks``, ``steps`` and
    the final ``qpos`` f[nq].
    """
    cfg, n = world.config, world.n_rovers
    tick_seconds = cfg.timestep * cfg.substeps
    model = copy.copy(world.model)    # a copy: the world's model keeps its flags and frictions
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)   # a blow-up shows as NaN
    if friction is not None:
        model.geom_friction[:] = friction_fields(world, friction, 1)["geom_friction"][0]
    d = mujoco.MjData(model)
    d.qpos[:] = q0
    mujoco.mj_forward(model, d)
    rover_adr = rover_qpos_adr(world)
    xy_idx = rover_adr[:, None] + np.arange(2)
    ctrl_idx = np.array([[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, rover_prefix(i, n) + side)
                          for side in ("wheel_left", "wheel_right")] for i in range(n)]).reshape(-1)
    free_adr = model.jnt_qposadr[model.jnt_type == mujoco.mjtJoint.mjJNT_FREE]
    geom_rover = _geom_rover(world)
    adr_j = jnp.asarray(rover_adr)
    pstate = (jnp.zeros(n, jnp.float32), jnp.zeros(n, bool))
    events = [(0, a, b) for a, b in sorted(_rover_pairs(d, geom_rover))]   # rovers placed touching
    xy_ticks = [np.asarray(d.qpos)[xy_idx].copy()]
    finish = np.full(n, np.nan)
    finite, steps, ticks, parked_for = True, 0, 0, 0
    while ticks < n_ticks and parked_for <= settle_ticks:
        wheels, pstate = _fleet_policy_jit(adr_j, params, pstate, jnp.asarray(d.qpos, jnp.float32))
        d.ctrl[ctrl_idx] = np.asarray(wheels, np.float64).reshape(-1)
        for _ in range(cfg.substeps):
            with np.errstate(all="ignore"):
                mujoco.mj_step(model, d)
            steps += 1
            events.extend((steps, a, b) for a, b in sorted(_rover_pairs(d, geom_rover)))
        ticks += 1
        xy_ticks.append(np.asarray(d.qpos)[xy_idx].copy())
        done = np.asarray(pstate[1])
        finish = np.where(done & np.isnan(finish), ticks * tick_seconds, finish)
        if not _state_ok(world, free_adr, d):
            finite = False
            break
        parked_for = parked_for + 1 if done.all() else 0
    return {"events": events, "rover_xy": np.stack(xy_ticks), "finish": finish, "finite": finite, "ticks": ticks,
            "steps": steps, "qpos": np.asarray(d.qpos, np.float64).copy()}


def _masses(scene, routes, world: World, roll: dict, owner, masks, spill, evaluator):
    """Per route: the simulated masses (dict of f64[N]: collected, delivered, left_behind, spilled,
    lost; ``bridge.particle_fates`` of the route's own particles) and the 2D model's collected and
    delivered mass (``execute.execute_push``)."""
    n = masks.shape[0]
    end_xy = world.particle_xyz(roll["qpos"])[:, :2]
    mass = np.full(len(owner), 1.0 / world.config.particles_per_object)
    sim = {k: np.zeros(n) for k in ("collected", "delivered", "left_behind", "spilled", "lost")}
    pred_collected, pred_delivered = np.zeros(n), np.zeros(n)
    for i in range(n):
        mine = owner == i
        fates = particle_fates(scene, end_xy[mine], masks[i], roll["finite"])
        sim["collected"][i] = mass[mine].sum()
        for key, fate in zip(("delivered", "left_behind", "spilled", "lost"), fates):
            sim[key][i] = mass[mine][fate].sum()
        _, push = execute_jit(scene, _index(routes, i), spill, evaluator)
        pred_collected[i], pred_delivered[i] = float(push.collected), float(push.delivered)
    return sim, pred_collected, pred_delivered


def first_round(run) -> list:
    """The pushes of a fleet run's first full round: the most pushes whose tasks were all running at
    one step (the earliest such step), so their footprints were pairwise disjoint; dicts of
    ``FleetRun.pushes``, in rover order (at most one per rover)."""
    if not run.pushes:
        return []
    first = np.asarray([p["first_step"] for p in run.pushes])
    last = np.asarray([p["last_step"] for p in run.pushes])
    steps = np.unique(first)
    running = (first[None] <= steps[:, None]) & (steps[:, None] <= last[None])
    at = int(np.argmax(running.sum(1)))          # the first step with the most tasks running
    return sorted((p for p, on in zip(run.pushes, running[at]) if on), key=lambda p: p["rover"])


def routes_of(scene, pushes) -> Route:
    """The ``execute.Route`` batch (leading axis = len(pushes)) of fleet push records: their cells, a
    fallback end where the last cell lies outside the targets (the route then ends on the boundary)."""
    slots = max(len(p["cells"]) for p in pushes)
    target = np.asarray(scene.target_mask)
    routes = []
    for p in pushes:
        cells = np.full((slots, 2), -1, np.int32)
        cells[:len(p["cells"])] = np.asarray(p["cells"], np.int32)
        last = cells[len(p["cells"]) - 1]
        fallback = not bool(target[last[0], last[1]])
        routes.append(route_from_path(scene, jnp.asarray(cells), jnp.int32(len(p["cells"])),
                                      jnp.bool_(fallback)))
    return jax.tree_util.tree_map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *routes)


def check_first_round(run, spill: SpillParams, **kwargs) -> dict:
    """Drive a fleet run's first round of concurrent pushes (``first_round``) in one MuJoCo world on the
    run's initial counts, each rover starting on its route's start (the approach is not simulated).

    Returns a JSON-ready dict: the fleet-level summary (contacts, fraction within tolerance, ...), one
    row per push with its rover, and the pushes' grid-model delivered mass from the fleet run.
    kwargs go to :func:`check_concurrent_pushes`.
    """
    pushes = first_round(run)
    if not pushes:
        return {"rovers": 0, "note": "the run made no push; nothing to check"}
    check = check_concurrent_pushes(run.scene, routes_of(run.scene, pushes), spill=spill, **kwargs)
    rows = [dict(row, rover=p["rover"], fleet_delivered=float(p["delivered"]))
            for row, p in zip(check.rows(), pushes)]
    return {**check.summary(), "first_step": pushes[0]["first_step"], "pushes": rows,
            "note": ("each rover starts on its route's start; particles stand on the routes' non-target "
                     "cells of the initial counts; predicted_delivered is the 2D model on the same route")}
