"""Push tasks, their P-controlled execution in physics and the cost of Eq. 11.

A push task (Section III-C, ``tau = (g, v, xi)`` without the gap, which the search keeps) is a
:class:`PushTask`: the movable to push, a contact mode (one body-frame contact point and inward push
direction per robot, and which robots take part) and a short-horizon body velocity
``v = (v_x, v_y, omega)`` of the movable's centroid in the world frame, held for ``duration``.

Execution (Section III-D, pushing phase only; the transition to the contacts is not simulated: the
robots start ``standoff`` behind their contact points). The body velocity is integrated into a
reference pose ``q_ref(t) = q_0 + v min(t, duration)``, mapped to per-robot contact references
``p_ref,n(t) = x_ref + R(psi_ref) (c_n - (r - press) d_n)`` (robot centre one radius behind the
contact point along the push direction ``d_n``, ``press`` inside so the robot keeps pressing), and
each robot applies ``u_n = dp_ref,n/dt + K_p (p_ref,n - p_n)``, clipped to ``vmax`` (the paper's
P-control plus the reference's own velocity as feed-forward). Robots not taking part hold their
positions. After ``duration`` the references stop and the robots hold; the rollout runs a fixed
horizon (``config.horizon`` ticks of ``substeps`` steps, 80 x 1/40 s as the paper) so that one
compiled program serves every batch.

:func:`simulate_pushes` runs a batch of candidates (up to 64) from one scene state in ONE
``Simulator.run`` call and returns a :class:`PushOutcome` per candidate; :func:`push_cost` is Eq. 11's
``delta_T + alpha delta_J``. The geometric rejection before physics is
:func:`jaxplan.pusharound.quickpass.quick_pass`.
"""
from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import shapely
from shapely.geometry import LineString

from jaxplan.physics import FAST_COMPILE, Simulator
from jaxplan.pusharound.budget import touch_chunk
from jaxplan.pusharound.kernels import pair_distances, point_distances
from jaxplan.pusharound.physics import PushWorld, initial_state, movable_poses

__all__ = ["MAX_BATCH", "PushTask", "PushOutcome", "check_tasks", "direction_tasks", "face_contacts",
           "make_push_simulator", "posed_vertices", "push_cost", "push_policy", "rollout_outcome", "simulate_pushes",
           "stack_tasks", "start_positions"]

MAX_BATCH = 64      # candidates per physics call (the paper's 64 per expansion)


class PushTask(NamedTuple):
    """One candidate push (or a batch: every field with a leading B axis, see :func:`stack_tasks`).

    movable: i32[] index into scene.movables; contacts: f[N, 2] body-frame contact points [m];
    directions: f[N, 2] body-frame unit push directions (into the body) [-]; active: bool[N] robots
    taking part; velocity: f[3] world-frame (v_x [m/s], v_y [m/s], omega [rad/s]) of the centroid;
    duration: f[] seconds the velocity is held (<= horizon).
    """

    movable: np.ndarray
    contacts: np.ndarray
    directions: np.ndarray
    active: np.ndarray
    velocity: np.ndarray
    duration: np.ndarray


class PushOutcome(NamedTuple):
    """Per candidate (leading axis B; numpy).

    poses: f[B, M, 3] final (x, y, yaw) of every movable; robots: f[B, N, 2] final robot positions;
    finite: bool[B] physics stayed finite and in the world box; displacement: f[B] planar distance
    the pushed movable's centroid moved [m]; rotation: f[B] its yaw change [rad]; moved: f[B, M]
    every movable's displacement [m]; hit_fixed: bool[B] a moved movable or a robot came within
    contact_tol of a fixed obstacle (scene.fixed; the boundary walls count as leaving) that it was
    not touching at the start; left_workspace: bool[B] a movable vertex ended more than contact_tol
    outside the workspace; tipped: bool[B] a movable tilted (z axis z-component < tip_cos);
    valid: bool[B] finite and none of the three; effort: f[B] delta_J, actuator work sum |F v| dt [J];
    duration: f[B] the task's push duration [s]; first_bad: i32[B] the rollout's first bad tick (-1).
    """

    poses: np.ndarray
    robots: np.ndarray
    finite: np.ndarray
    displacement: np.ndarray
    rotation: np.ndarray
    moved: np.ndarray
    hit_fixed: np.ndarray
    left_workspace: np.ndarray
    tipped: np.ndarray
    valid: np.ndarray
    effort: np.ndarray
    duration: np.ndarray
    first_bad: np.ndarray


# ------------------------------------------------------------------------------------------ tasks

def stack_tasks(tasks) -> PushTask:
    """Stack a list of single :class:`PushTask` into a batch (leading axis B), as numpy arrays."""
    tasks = list(tasks)
    if not tasks:
        raise ValueError("tasks: need at least one PushTask.")
    return PushTask(*(np.stack([np.asarray(getattr(t, f)) for t in tasks]) for f in PushTask._fields))


def face_contacts(world: PushWorld, movable: int, direction, n_robots: int | None = None,
                  spread: float = 0.6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A contact mode pushing ``movable`` along the body-frame ``direction f[2]``: ``n_robots`` (default
    all) contact points on the body's back face, spaced across it by ``spread`` times its width seen
    along ``direction`` (but at least a robot diameter plus twice the standoff apart). Returns
    ``(contacts f[N, 2], directions f[N, 2], active bool[N])``, N the scene's robot count (robots
    beyond ``n_robots`` inactive, their rows a copy of the first)."""
    scene = world.scene
    n_all = len(world.robot_adr)
    n = n_all if n_robots is None else int(n_robots)
    if not 0 <= int(movable) < len(scene.movables):
        raise ValueError(f"movable: index out of range 0..{len(scene.movables) - 1}; got {movable!r}.")
    if not 1 <= n <= n_all:
        raise ValueError(f"n_robots: must be in 1..{n_all}; got {n_robots!r}.")
    d = np.asarray(direction, np.float64).reshape(2)
    if not np.linalg.norm(d) > 0:
        raise ValueError(f"direction: must be a non-zero 2-vector; got {direction!r}.")
    d = d / np.linalg.norm(d)
    perp = np.array([-d[1], d[0]])
    body = shapely.union_all(scene.movables[int(movable)].pieces)
    xy = np.asarray(body.exterior.coords)[:, :2]
    lat = xy @ perp
    reach = float(np.max(np.abs(xy @ d))) + 1.0
    # Spacing: the spread share of the face, but never closer than the robots' diameter.
    gap = max(spread * (lat.max() - lat.min()) / n, 2.0 * (float(scene.robot_radius) + world.config.standoff))
    offsets = gap * (np.arange(n) - 0.5 * (n - 1)) + 0.5 * (lat.max() + lat.min())
    contacts = []
    for s in offsets:
        line = LineString([s * perp - reach * d, s * perp + reach * d])
        hit = line.intersection(body.boundary)
        pts = [np.asarray(g.coords)[:, :2] for g in getattr(hit, "geoms", [hit]) if not g.is_empty]
        if not pts:
            raise ValueError(f"face_contacts: no contact on movable {movable} at lateral offset {s:.3f} m.")
        pts = np.concatenate(pts)
        contacts.append(pts[np.argmin(pts @ d)])
    contacts = np.asarray(contacts)
    contacts = np.concatenate([contacts, np.repeat(contacts[:1], n_all - n, 0)])
    active = np.arange(n_all) < n
    return contacts, np.repeat(d[None], n_all, 0), active


def direction_tasks(world: PushWorld, movable: int, angles, speed: float, duration: float,
                    n_robots=(1, 2), omega: float = 0.0, poses=None) -> list:
    """Candidate pushes of ``movable`` along world directions ``angles`` (radians) at ``speed`` [m/s]
    for ``duration`` [s], with each team size in ``n_robots`` (one :func:`face_contacts` mode per
    direction and size) and yaw rate ``omega`` [rad/s]. Directions whose face has no room for the
    team are skipped. Returns a list of :class:`PushTask` (stack with :func:`stack_tasks`)."""
    if not speed > 0 or not duration > 0:
        raise ValueError(f"speed, duration: must be > 0; got {speed!r}, {duration!r}.")
    poses = world.scene.poses if poses is None else np.asarray(poses, np.float64)
    psi = float(poses[int(movable), 2])
    out = []
    for a in np.atleast_1d(np.asarray(angles, np.float64)):
        d_world = np.array([np.cos(a), np.sin(a)])
        d_body = np.array([np.cos(a - psi), np.sin(a - psi)])
        for n in n_robots:
            try:
                c, d, act = face_contacts(world, movable, d_body, n)
            except ValueError:
                continue
            out.append(PushTask(int(movable), c, d, act, np.r_[speed * d_world, omega], float(duration)))
    return out


def _rot(psi):
    c, s = jnp.cos(psi), jnp.sin(psi)
    return jnp.array([[c, -s], [s, c]])


def _robot_reference(pose0, velocity, contacts, directions, duration, offset, t):
    """Robot-centre references f[N, 2] at time ``t`` (module docstring)."""
    pose = pose0 + velocity * jnp.clip(t, 0.0, duration)
    r = _rot(pose[2])
    return pose[:2] + (contacts - offset * directions) @ r.T


def push_policy(robot_adr: tuple, kp: float, vmax: float, offset: float, params, pstate, qpos, qvel, time):
    """The pushing controller as a rollout policy (bind the first four with ``functools.partial``).

    robot_adr: tuple of 2N qpos addresses (x0, y0, x1, y1, ...); kp [1/s]; vmax [m/s]; offset: robot
    centre behind the contact, r - press [m]. params: dict with pose0 f[3], velocity f[3], contacts
    f[N, 2], directions f[N, 2], active f[N] (0/1), hold f[N, 2], duration f[]. Returns
    ``(ctrl f[2N] robot velocities [m/s], pstate)``.
    """
    adr = jnp.asarray(robot_adr)
    pos = qpos[adr].reshape(-1, 2)

    def ref(t):
        return _robot_reference(params["pose0"], params["velocity"], params["contacts"],
                                params["directions"], params["duration"], offset, t)

    p_ref, v_ff = jax.jvp(ref, (time,), (jnp.ones_like(time),))
    active = params["active"][:, None] > 0.5
    target = jnp.where(active, p_ref, params["hold"])
    u = jnp.where(active, v_ff, 0.0) + kp * (target - pos)
    speed = jnp.linalg.norm(u, axis=-1, keepdims=True)
    u = u * jnp.minimum(1.0, vmax / jnp.maximum(speed, 1e-9))
    return u.reshape(-1).astype(qpos.dtype), pstate


def make_push_simulator(world: PushWorld, backend: str = "auto", nthread: int | None = None,
                        compiler_options: dict | None = FAST_COMPILE) -> Simulator:
    """The :class:`Simulator` for ``world`` with :func:`push_policy`; build once and pass it to every
    :func:`simulate_pushes` call (MJX compiles once per batch size)."""
    cfg = world.config
    policy = functools.partial(push_policy, tuple(int(a) for a in world.robot_adr.reshape(-1)), float(cfg.kp),
                               float(cfg.vmax), float(world.scene.robot_radius - cfg.press))
    return Simulator(world.model, policy, substeps=cfg.substeps, bounds=world.bounds, backend=backend,
                     nthread=nthread, mjx_model=world.mjx_model, compiler_options=compiler_options)


def check_tasks(world: PushWorld, tasks: PushTask) -> PushTask:
    """Validate a batched :class:`PushTask` for ``world`` (B in 1..MAX_BATCH tasks, N robots) and return
    it as numpy: movable i64[B], contacts f64[B, N, 2] [m, body frame], directions f64[B, N, 2] (unit),
    active bool[B, N], velocity f64[B, 3] [m/s, m/s, rad/s], duration f64[B] [s] within the horizon.
    Raises ValueError naming the first bad field."""
    if not isinstance(tasks, PushTask):
        raise ValueError(f"tasks: expected a PushTask (batched); got {type(tasks).__name__}.")
    n, m = len(world.robot_adr), len(world.scene.movables)
    mov = np.asarray(tasks.movable, np.int64).reshape(-1)
    b = len(mov)
    horizon_s = world.config.horizon * world.config.substeps * world.config.timestep
    shapes = {"contacts": (b, n, 2), "directions": (b, n, 2), "active": (b, n), "velocity": (b, 3), "duration": (b,)}
    out = {"movable": mov}
    for f, shape in shapes.items():
        a = np.asarray(getattr(tasks, f))
        if a.shape != shape:
            raise ValueError(f"tasks.{f}: expected shape {list(shape)} (batch of {b}, {n} robots); "
                             f"got {list(a.shape)}.")
        out[f] = a
    if not 1 <= b <= MAX_BATCH:
        raise ValueError(f"tasks: batch size must be in 1..{MAX_BATCH}; got {b}.")
    if np.any((mov < 0) | (mov >= m)):
        raise ValueError(f"tasks.movable: indices must be in 0..{m - 1}; got {mov.tolist()}.")
    if not np.all(np.isfinite(out["velocity"])) or not np.all(np.isfinite(out["contacts"])):
        raise ValueError("tasks.velocity / tasks.contacts: must be finite.")
    dur = out["duration"].astype(np.float64)
    if np.any(~np.isfinite(dur)) or np.any(dur <= 0) or np.any(dur > horizon_s + 1e-9):
        raise ValueError(f"tasks.duration: must be in (0, {horizon_s:.3f}] s (the horizon); got {dur.tolist()}.")
    norms = np.linalg.norm(out["directions"], axis=-1)
    if np.any(np.abs(norms - 1) > 1e-6):
        raise ValueError("tasks.directions: must be unit vectors.")
    if not np.all(np.any(out["active"], axis=-1)):
        raise ValueError("tasks.active: every task needs at least one active robot.")
    return PushTask(mov, out["contacts"].astype(np.float64), out["directions"].astype(np.float64),
                    out["active"].astype(bool), out["velocity"].astype(np.float64), dur)


_OUTLINES: dict = {}   # id(movable.pieces) -> (pieces, body-frame outline): kept alive with their key


def _body_outline(movable):
    key = id(movable.pieces)
    hit = _OUTLINES.get(key)
    if hit is None or hit[0] is not movable.pieces:
        if len(_OUTLINES) > 4096:
            _OUTLINES.clear()
        hit = (movable.pieces, shapely.union_all(list(movable.pieces)))
        _OUTLINES[key] = hit
    return hit[1]


def _clear_of_body(world: PushWorld, tasks: PushTask, local: np.ndarray, clearance: float) -> np.ndarray:
    """Body-frame robot starts ``local f[B, N, 2]`` moved back along their push directions until
    the robot disk clears the pushed body by ``standoff`` (a contact on a slanted edge or next to a
    re-entrant corner of a non-convex body puts the disk ``r + standoff`` behind the contact inside the
    body's other edges). Starts already clear are unchanged; at most 0.3 m of extra backing."""
    act = np.nonzero(tasks.active)
    if len(act[0]) == 0:
        return local
    out = local.copy()
    mov = tasks.movable[act[0]]
    pts = out[act]
    d = tasks.directions[act]
    outlines = np.asarray([_body_outline(world.scene.movables[int(m)]) for m in mov], dtype=object)
    back = np.zeros(len(pts))
    for _ in range(6):
        dist = shapely.distance(outlines, shapely.points(pts))
        deficit = clearance - dist
        need = (deficit > 1e-6) & (back < 0.3)
        if not np.any(need):
            break
        step = np.where(need, np.minimum(deficit + 1e-4, 0.3 - back), 0.0)
        pts = pts - step[:, None] * d
        back += step
    out[act] = pts
    return out


def start_positions(world: PushWorld, tasks: PushTask, poses) -> np.ndarray:
    """Robot start positions f[B, N, 2] [m, world] of checked ``tasks`` with the movables at ``poses``
    f[M, 3]: active robots ``r + standoff`` behind their contacts (farther
    back along the push direction where the disk would otherwise touch the pushed body)."""
    cfg, r = world.config, float(world.scene.robot_radius)
    pose0 = poses[tasks.movable]                                       # [B, 3]
    c, s = np.cos(pose0[:, 2]), np.sin(pose0[:, 2])
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)    # [B, 2, 2]
    local = _clear_of_body(world, tasks, tasks.contacts - (r + cfg.standoff) * tasks.directions,
                           r + cfg.standoff - 1e-6)
    world_xy = pose0[:, None, :2] + np.einsum("bij,bnj->bni", rot, local)
    home = np.broadcast_to(np.asarray(world.scene.robots, np.float64), world_xy.shape)
    return np.where(tasks.active[..., None], world_xy, home)


def posed_vertices(body_verts, poses):
    """World vertices f[..., V, 2] of body-frame vertices f[..., V, 2] at poses f[..., 3]."""
    c, s = np.cos(poses[..., 2])[..., None], np.sin(poses[..., 2])[..., None]
    x = body_verts[..., 0] * c - body_verts[..., 1] * s + poses[..., 0:1]
    y = body_verts[..., 0] * s + body_verts[..., 1] * c + poses[..., 1:2]
    return np.stack([x, y], -1)


def _touching(verts, fixed_verts, tol: float) -> np.ndarray:
    """bool[K]: polygon k of ``verts f[K, V, 2]`` is within ``tol`` of a fixed polygon ``f[F, V2, 2]``.

    A bounding-box prefilter on the host, then the exact :func:`pair_distances` kernel on the pairs
    left (padded to a power of two so that few shapes compile)."""
    k, f = len(verts), len(fixed_verts)
    if k == 0 or f == 0:
        return np.zeros(k, bool)
    lo, hi = verts.min(1), verts.max(1)
    flo, fhi = fixed_verts.min(1), fixed_verts.max(1)
    gap = np.maximum(0.0, np.maximum(lo[:, None] - fhi[None], flo[None] - hi[:, None])).max(-1)   # [K, F]
    ki, fi = np.nonzero(gap < tol)
    out = np.zeros(k, bool)
    if len(ki) == 0:
        return out
    v = max(verts.shape[1], fixed_verts.shape[1])

    def pad(a):
        return np.concatenate([a, np.repeat(a[:, -1:], v - a.shape[1], 1)], 1)

    # Shapes are bucketed so that few programs compile, shared across scenes and batches: vertex
    # counts to a power of two >= 16, pair counts to a power of two in [256, chunk] (larger sets in
    # chunks; chunk = budget.touch_chunk(v): 4096, smaller for large pieces so that one call stays
    # within budget.TOUCH_BYTES).
    v = max(16, 1 << int(np.ceil(np.log2(v))))
    chunk = touch_chunk(v)
    a, b = pad(verts[ki]), pad(fixed_verts[fi])
    d = np.empty(len(ki))
    for s0 in range(0, len(ki), chunk):
        s1 = min(s0 + chunk, len(ki))
        n = max(min(256, chunk), 1 << int(np.ceil(np.log2(s1 - s0))))
        aa = np.concatenate([a[s0:s1], np.repeat(a[s1 - 1:s1], n - (s1 - s0), 0)])
        bb = np.concatenate([b[s0:s1], np.repeat(b[s1 - 1:s1], n - (s1 - s0), 0)])
        with jax.enable_x64(True):
            d[s0:s1] = np.asarray(pair_distances(jnp.asarray(aa), jnp.asarray(bb))[0])[:s1 - s0]
    np.logical_or.at(out, ki, d < tol)
    return out


def simulate_pushes(world: PushWorld, tasks: PushTask, *, sim: Simulator | None = None, backend: str = "auto",
                    poses=None, robots=None, check_every: int = 4, trajectory: bool = False):
    """Simulate a batch of candidate pushes from one state in ONE ``Simulator.run`` call.

    world: from :func:`build_push_world`; tasks: a batched :class:`PushTask` (B <= 64); sim: a
    :func:`make_push_simulator` to reuse (else one is built for ``backend``); poses f[M, 3] and
    robots f[N, 2]: the state to start from (default: the world's scene; inactive robots start at
    ``robots``); check_every: ticks between the fixed-obstacle clearance checks; trajectory: also
    return the rollout's ``Trajectory`` (``(outcome, trajectory)``).

    On MJX the world's declared contact pairs (docs/physics.md) hold for pushes no longer than
    ``world.reach`` from the world's poses: a batch whose longest push (``|v| duration``) plus the
    farthest any movable has moved from them exceeds it raises ``ValueError``.
    """
    tasks = check_tasks(world, tasks)
    cfg, scene = world.config, world.scene
    poses = scene.poses if poses is None else np.asarray(poses, np.float64)
    home = np.asarray(scene.robots if robots is None else robots, np.float64)
    if sim is None:
        sim = make_push_simulator(world, backend)
    elif sim.model is not world.model:
        raise ValueError("sim: built for another world; use make_push_simulator(world).")
    if sim.backend != "c" and world.pairs:
        push = float(np.max(np.linalg.norm(tasks.velocity[:, :2], axis=-1) * tasks.duration))
        drift = float(np.max(np.linalg.norm(poses[:, :2] - world.poses[:, :2], axis=-1)))
        if push + drift > world.reach + 1e-9:
            raise ValueError(f"tasks: a push of {push:.2f} m from poses {drift:.2f} m away from the world's exceeds "
                             f"the MJX contact pairs' reach {world.reach:.2f} m; build the world at these poses "
                             "(build_push_world(scene.with_poses(poses))) or raise PushPhysicsConfig.push_reach.")
    scene_home = scene.replace(robots=home) if robots is not None else scene
    starts = start_positions(world._replace(scene=scene_home), tasks, poses)
    b = len(tasks.movable)
    q0 = np.stack([initial_state(world, starts[i], poses)[0] for i in range(b)])
    v0 = np.zeros((b, world.model.nv))
    params = {"pose0": jnp.asarray(poses[tasks.movable], jnp.float32),
              "velocity": jnp.asarray(tasks.velocity, jnp.float32),
              "contacts": jnp.asarray(tasks.contacts, jnp.float32),
              "directions": jnp.asarray(tasks.directions, jnp.float32),
              "active": jnp.asarray(tasks.active, jnp.float32),
              "hold": jnp.asarray(starts, jnp.float32),
              "duration": jnp.asarray(tasks.duration, jnp.float32)}
    traj = sim.run(q0, v0, params, jnp.zeros((b,), jnp.float32), cfg.horizon)
    out = rollout_outcome(world, tasks, traj, poses, check_every)
    return (out, traj) if trajectory else out


def rollout_outcome(world: PushWorld, tasks: PushTask, traj, poses0, check_every: int) -> PushOutcome:
    """The :class:`PushOutcome` of the rollout ``traj`` (a ``Trajectory`` with leading axis B, T+1
    states) of the checked ``tasks`` from movable poses ``poses0`` f[M, 3]; fixed-obstacle contact is
    tested every ``check_every`` ticks (and at the last)."""
    cfg, scene = world.config, world.scene
    b = len(tasks.movable)
    qp = np.asarray(traj.qpos, np.float64)
    pose_t, upright = movable_poses(world, qp)                          # [B, T+1, M, 3], [B, T+1, M]
    final = pose_t[:, -1]
    robots = qp[:, -1][:, world.robot_adr]                              # [B, N, 2]
    moved = np.linalg.norm(final[..., :2] - poses0[None, :, :2], axis=-1)
    target = np.arange(b), tasks.movable
    rot = np.angle(np.exp(1j * (final[target][:, 2] - poses0[tasks.movable, 2])))
    tipped = np.any(upright < cfg.tip_cos, axis=(1, 2))

    # Leaving the workspace: any movable vertex outside by more than contact_tol at the end.
    x0, y0, x1, y1 = scene.workspace
    owner = world.piece_owner
    fp = final[:, owner]                                                 # [B, P, 3]
    c, s = np.cos(fp[..., 2])[..., None], np.sin(fp[..., 2])[..., None]
    vx = world.pieces_body[None, ..., 0] * c - world.pieces_body[None, ..., 1] * s + fp[..., 0:1]
    vy = world.pieces_body[None, ..., 0] * s + world.pieces_body[None, ..., 1] * c + fp[..., 1:2]
    tol = cfg.contact_tol
    left = np.any((vx < x0 - tol) | (vx > x1 + tol) | (vy < y0 - tol) | (vy > y1 + tol), axis=(1, 2))

    # Touching fixed obstacles (scene.fixed): pieces of movables that moved, and robots, at every
    # check_every-th tick; contacts already present at the start do not count.
    hit = np.zeros(b, bool)
    if len(world.fixed_verts):
        ticks = np.unique(np.r_[np.arange(0, qp.shape[1], max(1, int(check_every))), qp.shape[1] - 1])
        pb, pp = np.nonzero(moved[:, owner] > cfg.move_tol)             # moved (candidate, piece) pairs
        before = _touching(posed_vertices(world.pieces_body, poses0[owner]), world.fixed_verts, tol)
        keep = ~before[pp]
        pb, pp = pb[keep], pp[keep]
        sampled = np.nan_to_num(pose_t[pb[:, None], ticks[None, :], owner[pp][:, None]])   # [K, S, 3]
        verts = posed_vertices(np.repeat(world.pieces_body[pp][:, None], len(ticks), 1), sampled)  # [K, S, V, 2]
        touch = _touching(verts.reshape(-1, *verts.shape[2:]), world.fixed_verts, tol)
        np.logical_or.at(hit, pb, touch.reshape(len(pb), len(ticks)).any(-1))
        rob = np.nan_to_num(qp[:, ticks][:, :, world.robot_adr])         # [B, S, N, 2]
        with jax.enable_x64(True):
            rd = np.asarray(point_distances(jnp.asarray(rob.reshape(-1, 2)), jnp.asarray(world.fixed_verts)))
        hit |= np.any(rd.min(-1).reshape(rob.shape[:3]) < float(scene.robot_radius) + tol, axis=(1, 2))

    # Effort: actuator work, F = clip(kv (u - qdot)), summed |F qdot| over ticks.
    qv = np.asarray(traj.qvel, np.float64)[:, 1:][..., world.robot_dof.reshape(-1)]   # [B, T, 2N]
    force = np.clip(cfg.kv * (np.asarray(traj.ctrl, np.float64) - qv), -cfg.force, cfg.force)
    effort = np.sum(np.abs(force * qv), axis=(1, 2)) * cfg.substeps * cfg.timestep

    finite = np.asarray(traj.finite, bool)
    valid = finite & ~hit & ~left & ~tipped
    return PushOutcome(final, robots, finite, moved[target], rot, moved, hit, left, tipped, valid,
                       np.nan_to_num(effort, nan=np.inf), tasks.duration.astype(np.float64),
                       np.asarray(traj.first_bad, np.int32))


# ------------------------------------------------------------------------------------------- cost

def push_cost(world: PushWorld, tasks: PushTask, outcome: PushOutcome, robots=None, poses=None,
              alpha: float | None = None):
    """Eq. 11's realised cost ``C = delta_T + alpha delta_J`` f[B] of validated candidates.

    delta_T [s] = transition (the farthest active robot's straight-line distance from ``robots``
    f[N, 2] (default: the scene's) to its start for movable poses ``poses`` f[M, 3] (default: the
    scene's), over ``transit_speed``) + the push duration;
    delta_J [J] = the outcome's actuator work; alpha [1/J] defaults to ``config.alpha``. Invalid
    candidates (``outcome.valid`` false) cost ``inf``. Returns ``(cost, delta_T, delta_J)``.
    """
    tasks = check_tasks(world, tasks)
    cfg = world.config
    alpha = cfg.alpha if alpha is None else float(alpha)
    if not alpha >= 0:
        raise ValueError(f"alpha: must be >= 0; got {alpha!r}.")
    home = np.asarray(world.scene.robots if robots is None else robots, np.float64)
    poses = world.scene.poses if poses is None else np.asarray(poses, np.float64)
    starts = start_positions(world, tasks, poses)
    dist = np.where(tasks.active, np.linalg.norm(starts - home[None], axis=-1), 0.0).max(-1)
    delta_t = dist / cfg.transit_speed + tasks.duration
    delta_j = np.asarray(outcome.effort, np.float64)
    cost = np.where(outcome.valid, delta_t + alpha * delta_j, np.inf)
    return cost, delta_t, delta_j
