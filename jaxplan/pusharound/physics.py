"""The PushAround world in MuJoCo: a :class:`PushScene` as an ``MjModel`` for MJX and the C engine.

:func:`build_push_world` writes an MJCF string and compiles it:

- floor: a plane (contact bit 1). Optional boundary walls: four thin boxes just outside the
  workspace (``PushPhysicsConfig.walls``), so the workspace is bounded as in the paper.
- fixed obstacles: static geoms of the world body (bit 4), one per convex piece.
- movables: one free body each (bit 2), a prism of height ``height`` per convex piece. A piece that
  is a rectangle becomes a ``box``; any other convex piece a convex ``mesh`` (a prism of 2n vertices,
  n <= 16, so <= 32 mesh vertices as MJX needs; a piece with more vertices is simplified first).
  Cylinders and curved shapes arrive as polygons (``shapes.cylinder`` is a 12-gon), so they become
  meshes: MJX does not collide ``cylinder`` geoms with boxes or meshes (docs/pusharound.md).
  The body's inertial is explicit: the scene's mass, the scene's yaw inertia ``I_zz`` and
  ``I_xx = I_yy = I_zz / 2 + m h^2 / 12`` (thin lamina, perpendicular axis, plus the height), centre
  of mass at half height above the area centroid. Friction with the floor: the movable's ``friction``.
- robots: vertical capsules of the scene's ``robot_radius`` (bit 8) on two slide joints (world x, y)
  at mid-height of the movables, driven by velocity actuators (``kv``, force limited). They do not
  touch the floor (the slides carry their weight), they touch movables, fixed obstacles and each other.

Collision bits (a pair collides when ``contype_a & conaffinity_b`` or the reverse is non-zero):
floor (1, 0), movable (2, 15), fixed and walls (4, 0), robot (8, 12). Fixed pieces do not collide
with the floor or each other.

MJX gets its own model (``PushWorld.mjx_model``, same bodies, joints and actuators): every geom has
contype = conaffinity = 0 and the contacts that can happen are declared as explicit ``<pair>`` elements
(:func:`contact_pairs`: every movable piece with the floor; robots with every movable piece, fixed
piece, wall and each other; movable pieces of two bodies, and a movable piece and a fixed piece or
wall, whose outlines at the scene's poses are within ``config.push_reach`` + ``config.pair_margin``).
MJX compiles one collision routine per (geom types, mesh, mesh) group, so identical convex pieces
(a ring's segments, equal shapes) share one mesh asset, placed by the geom's yaw. Contact points are
capped from the scene (:func:`mjx_caps`). docs/physics.md states the rule; a test counts on the C engine
that the contacts pushes make are declared and within the cap.

Units: metres, kilograms, seconds, radians. ``qpos`` layout: every movable's free joint (x, y, z,
quaternion), then every robot's (x, y) slides; the addresses are in :class:`PushWorld`.
"""
from __future__ import annotations

import dataclasses
import math
import re
from typing import NamedTuple

import mujoco
import numpy as np
import shapely
import shapely.affinity
from shapely.geometry import Polygon

from jaxplan.pusharound.scene import PushScene

__all__ = ["PushPhysicsConfig", "PushWorld", "build_push_world", "contact_pairs", "contact_usage", "initial_state",
           "mjx_caps", "movable_poses", "yaw_quat"]

MAX_PRISM_SIDES = 16    # 2 x 16 = 32 mesh vertices (MJX convex-mesh limit)
_RECT_TOL = 1e-6        # |cos| of a rectangle's corner angles [-]


@dataclasses.dataclass(frozen=True)
class PushPhysicsConfig:
    """Model and controller constants (all static).

    timestep [s] (1/240 as the paper); substeps per control tick (6: 40 Hz control, the paper's
    1/40 s); iterations, ls_iterations: solver (>= 10 for MJX, ANCHORS); height: movable prism height
    [m]; robot_mass [kg]; kv: robot velocity-actuator gain [N s/m]; force: actuator force limit [N];
    robot_friction: robot-movable Coulomb coefficient; walls: bounding walls around the workspace;
    wall_thickness [m]; kp: P gain of the contact reference [1/s]; vmax: robot speed limit [m/s];
    press: how far the reference sits inside the contact [m] (keeps the robot pressing);
    standoff: gap between robot and body at the start of a push [m]; horizon: control ticks per push
    rollout (80 as the paper; a push shorter than the horizon is followed by the robots holding still);
    transit_speed: robot speed for the transition term of Eq. 11 [m/s]; alpha: weight of the effort
    in Eq. 11 [1/J]; contact_tol: distance that counts as touching a fixed obstacle [m];
    move_tol: displacement below which a movable counts as not moved [m]; tip_cos: a movable whose
    body z axis has ``z_z`` below this has tipped over; world_margin: a free body farther than this
    outside the workspace [m] (or below z = -1 m / above 2 m) makes the rollout element not finite;
    sleep: MuJoCo's island sleeping (C engine: bodies at rest stop being integrated until something
    touches them: much faster on cluttered scenes at rest; it moved the final poses of 11 of 192
    nominal-scene pushes by more than 1 cm / 2 degrees, docs/physics.md; MJX ignores the flag);
    push_reach: the longest push (|v| duration, m) the MJX model's declared contact pairs cover
    from the scene's poses (the search's pushes are at most 0.6 m/s for 2 s); pair_margin [m]:
    added to the reach (sliding after release, rotation of long bodies).
    """

    timestep: float = 1.0 / 240.0
    substeps: int = 6
    iterations: int = 10
    ls_iterations: int = 10
    height: float = 0.3
    robot_mass: float = 20.0
    kv: float = 800.0
    force: float = 400.0
    robot_friction: float = 0.3
    walls: bool = True
    wall_thickness: float = 0.1
    kp: float = 4.0
    vmax: float = 0.8
    press: float = 0.01
    standoff: float = 0.01
    horizon: int = 80
    transit_speed: float = 0.5
    alpha: float = 0.01
    contact_tol: float = 0.01
    move_tol: float = 0.01
    tip_cos: float = 0.9
    world_margin: float = 1.0
    sleep: bool = True
    push_reach: float = 1.2
    pair_margin: float = 0.1

    def replace(self, **changes) -> PushPhysicsConfig:
        return dataclasses.replace(self, **changes)


class PushWorld(NamedTuple):
    """A compiled world. model: MjModel; scene: the PushScene it was built from; config;
    mov_adr: i32[M] qpos address of each movable's free joint; mov_dof: i32[M] its dof address;
    robot_adr: i32[N, 2] qpos addresses of each robot's x, y slides; robot_dof: i32[N, 2] dof addresses;
    bounds: (lo f[3], hi f[3]) world box given to the Simulator (workspace + world_margin, z in [-1, 2]);
    pieces_body: f[P, V, 2] every movable piece in its body frame (CCW, padded); piece_owner: i32[P];
    fixed_verts: f[F, V2, 2] every fixed piece (world); xml: the MJCF text; mjx_model: the model MJX
    steps (declared contact pairs, module docstring); pairs: the declared (geom name, geom name) pairs;
    reach: the pairs' push reach [m] (config.push_reach); poses: f[M, 3] the poses the pairs were
    chosen at."""

    model: mujoco.MjModel
    scene: PushScene
    config: PushPhysicsConfig
    mov_adr: np.ndarray
    mov_dof: np.ndarray
    robot_adr: np.ndarray
    robot_dof: np.ndarray
    bounds: tuple
    pieces_body: np.ndarray
    piece_owner: np.ndarray
    fixed_verts: np.ndarray
    xml: str
    mjx_model: mujoco.MjModel | None = None
    pairs: tuple = ()
    reach: float = 0.0
    poses: np.ndarray | None = None


def yaw_quat(psi) -> np.ndarray:
    """Quaternion (w, x, y, z) f[..., 4] of a rotation by ``psi`` [rad] about world z."""
    psi = np.asarray(psi, np.float64)
    return np.stack([np.cos(psi / 2), np.zeros_like(psi), np.zeros_like(psi), np.sin(psi / 2)], -1)


def _ring(poly: Polygon) -> np.ndarray:
    xy = np.asarray(poly.exterior.coords, np.float64)[:-1, :2]
    x, y = xy[:, 0], xy[:, 1]
    if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0:
        xy = xy[::-1]
    return xy


def _limit_sides(poly: Polygon) -> np.ndarray:
    """CCW vertices of ``poly`` with at most MAX_PRISM_SIDES (simplified by a growing tolerance)."""
    xy = _ring(poly)
    tol = 1e-4 * math.sqrt(poly.area)
    while len(xy) > MAX_PRISM_SIDES:
        xy = _ring(shapely.simplify(poly, tol).convex_hull)
        tol *= 2.0
    return xy


def _as_rectangle(xy: np.ndarray):
    """``(centre f[2], half f[2], angle)`` when the CCW quad ``xy`` is a rectangle, else None."""
    if len(xy) != 4:
        return None
    e = np.roll(xy, -1, axis=0) - xy
    lens = np.linalg.norm(e, axis=1)
    if np.any(lens <= 0):
        return None
    u = e / lens[:, None]
    if np.any(np.abs(np.sum(u * np.roll(u, -1, axis=0), axis=1)) > _RECT_TOL):
        return None
    return xy.mean(0), 0.5 * lens[:2], math.atan2(e[0, 1], e[0, 0])


def _f(v) -> str:
    return " ".join(f"{float(x):.9g}" for x in np.atleast_1d(v))


def _canonical(rel: np.ndarray):
    """``(key, angle, verts f[n, 2])``: the CCW polygon ``rel`` (about its vertex mean) rotated so that
    one of its edges lies along +x, choosing the edge whose rounded vertex list is smallest; congruent
    polygons (up to rotation) get the same key. ``rel = R(angle) verts``."""
    best = None
    for k in range(len(rel)):
        e = rel[(k + 1) % len(rel)] - rel[k]
        a = math.atan2(e[1], e[0])
        c, s = math.cos(-a), math.sin(-a)
        v = np.roll(rel @ np.array([[c, s], [-s, c]]), -k, axis=0)
        key = tuple(np.round(v, 6).ravel().tolist())
        if best is None or key < best[0]:
            best = (key, a, v)
    return best


def _piece_xml(xy: np.ndarray, name: str, z0: float, z1: float, attrs: str, assets: list,
               meshes: dict | None = None) -> str:
    """One prism geom (box or mesh) over ``z0..z1`` for the CCW piece ``xy`` (frame of its body).
    ``meshes``: {canonical key: mesh name}, shared by congruent pieces (one mesh asset each)."""
    rect = _as_rectangle(xy)
    zc, hz = 0.5 * (z0 + z1), 0.5 * (z1 - z0)
    if rect is not None:
        c, half, ang = rect
        return (f'<geom name="{name}" type="box" pos="{_f(c)} {zc:.9g}" size="{_f(half)} {hz:.9g}" '
                f'quat="{_f(yaw_quat(ang))}" {attrs}/>')
    # Mesh vertices relative to the piece's vertex mean, in a canonical orientation, placed with the
    # geom's pos and yaw: MuJoCo recentres a mesh on its own centre of mass and moves the geom's frame
    # to match, so the vertices land where the piece is.
    c = xy.mean(0)
    key, ang, rel = _canonical(xy - c)
    key = (key, round(hz, 9))
    if meshes is None:
        meshes = {}
    mesh = meshes.get(key)
    if mesh is None:
        mesh = meshes[key] = f"{name}_m"
        verts = np.concatenate([np.c_[rel, np.full(len(rel), -hz)], np.c_[rel, np.full(len(rel), hz)]])
        assets.append(f'<mesh name="{mesh}" vertex="{_f(verts.reshape(-1))}"/>')
    return (f'<geom name="{name}" type="mesh" mesh="{mesh}" pos="{_f(c)} {zc:.9g}" quat="{_f(yaw_quat(ang))}" '
            f'{attrs}/>')


def _pack(rings: list) -> np.ndarray:
    v = max((len(r) for r in rings), default=3)
    out = np.zeros((len(rings), v, 2))
    for i, r in enumerate(rings):
        out[i, :len(r)], out[i, len(r):] = r, r[-1]
    return out


def contact_pairs(geoms: list, robots: list, reach: float) -> list:
    """The declared contact pairs of the MJX model (module docstring), as (geom name, geom name).

    geoms: ``(name, kind, owner, polygon)`` for every collision geom but the floor and the robots,
    kind "movable" (owner: movable index) or "fixed" (fixed pieces and walls; owner -1), polygon:
    its world outline at the scene's poses; robots: robot geom names; reach [m]: outlines closer than
    this are paired. Movable pieces of one body are never paired (one rigid body)."""
    out = [("floor", name) for name, kind, _, _ in geoms if kind == "movable"]
    names = [g[0] for g in geoms]
    out += [(r, name) for r in robots for name in names]
    out += [(a, b) for i, a in enumerate(robots) for b in robots[i + 1:]]
    polys = np.asarray([g[3] for g in geoms], dtype=object)
    for i, (name, kind, owner, _) in enumerate(geoms):
        if kind != "movable":
            continue
        # fixed geoms (any index) and movable pieces of other bodies after this one
        rest = np.array([j for j, g in enumerate(geoms) if g[1] == "fixed" or (j > i and g[2] != owner)], int)
        if rest.size == 0:
            continue
        near = shapely.distance(polys[i], polys[rest]) <= reach
        out += [(name, geoms[j][0]) for j in rest[near]]
    return out


def mjx_caps(pairs: list, n_mov_geoms: int) -> dict:
    """MJX contact cap from the declared pairs: 4 points per movable piece on the floor, plus 4 per
    non-floor pair up to 2 such pairs per movable piece (a piece rests against at most a couple of
    neighbours at once); MJX keeps the deepest points when more arise. No broad-phase pair cap (the
    declared pairs are few)."""
    other = sum(1 for a, _ in pairs if a != "floor")
    return {"max_contact_points": int(4 * n_mov_geoms + 4 * min(other, 2 * n_mov_geoms))}


def _posed_polygon(piece: Polygon, pose) -> Polygon:
    x, y, psi = (float(v) for v in pose)
    c, s = math.cos(psi), math.sin(psi)
    return shapely.affinity.affine_transform(piece, [c, -s, s, c, x, y])


def build_push_world(scene: PushScene, config: PushPhysicsConfig | None = None) -> PushWorld:
    """Compile the MuJoCo model of ``scene`` (module docstring). Raises ``ValueError`` for a scene
    without movables or robots, or a non-positive ``config`` field."""
    cfg = PushPhysicsConfig() if config is None else config
    if not isinstance(scene, PushScene):
        raise ValueError(f"scene: expected a PushScene; got {type(scene).__name__}.")
    if not scene.movables:
        raise ValueError("scene.movables: a push world needs at least one movable.")
    robots = np.asarray(scene.robots, np.float64).reshape(-1, 2)
    if len(robots) == 0:
        raise ValueError("scene.robots: a push world needs at least one robot.")
    for name in ("timestep", "height", "world_margin", "robot_mass", "kv", "force", "kp", "vmax", "wall_thickness",
                 "transit_speed"):
        if not getattr(cfg, name) > 0:
            raise ValueError(f"config.{name}: must be > 0; got {getattr(cfg, name)!r}.")
    for name in ("push_reach", "pair_margin"):
        if not getattr(cfg, name) >= 0:
            raise ValueError(f"config.{name}: must be >= 0 [m]; got {getattr(cfg, name)!r}.")
    for name, lo in (("substeps", 1), ("iterations", 1), ("ls_iterations", 1), ("horizon", 1)):
        if int(getattr(cfg, name)) < lo:
            raise ValueError(f"config.{name}: must be an int >= {lo}; got {getattr(cfg, name)!r}.")

    h, r = cfg.height, float(scene.robot_radius)
    x0, y0, x1, y1 = (float(v) for v in scene.workspace)
    assets, statics, bodies, actuators = [], [], [], []
    fixed_rings, body_rings, owner = [], [], []
    n_mov_geoms = n_fixed_geoms = 0

    meshes: dict = {}
    colliders: list = []     # (name, kind, owner, world polygon) for contact_pairs
    fixed_attr = 'contype="4" conaffinity="0" rgba="0.35 0.35 0.4 1"'
    for fi, f in enumerate(scene.fixed):
        for pi, piece in enumerate(f.world_pieces()):
            xy = _limit_sides(piece)
            fixed_rings.append(_ring(piece))
            statics.append(_piece_xml(xy, f"fixed{fi}_{pi}", 0.0, h, fixed_attr, assets, meshes))
            colliders.append((f"fixed{fi}_{pi}", "fixed", -1, piece))
            n_fixed_geoms += 1
    if cfg.walls:
        t = cfg.wall_thickness
        for k, (cx, cy, hx, hy) in enumerate((
                (0.5 * (x0 + x1), y0 - t / 2, 0.5 * (x1 - x0) + t, t / 2),
                (0.5 * (x0 + x1), y1 + t / 2, 0.5 * (x1 - x0) + t, t / 2),
                (x0 - t / 2, 0.5 * (y0 + y1), t / 2, 0.5 * (y1 - y0)),
                (x1 + t / 2, 0.5 * (y0 + y1), t / 2, 0.5 * (y1 - y0)))):
            statics.append(f'<geom name="wall{k}" type="box" pos="{cx:.9g} {cy:.9g} {h / 2:.9g}" '
                           f'size="{hx:.9g} {hy:.9g} {h / 2:.9g}" {fixed_attr}/>')
            colliders.append((f"wall{k}", "fixed", -1, shapely.box(cx - hx, cy - hy, cx + hx, cy + hy)))
            n_fixed_geoms += 1

    for mi, m in enumerate(scene.movables):
        geoms = []
        attr = (f'contype="2" conaffinity="15" friction="{float(m.friction):.9g} 0.005 0.0001" '
                f'rgba="0.85 0.55 0.2 1"')
        for pi, piece in enumerate(m.pieces):
            xy = _limit_sides(piece)
            body_rings.append(_ring(piece))
            owner.append(mi)
            geoms.append(_piece_xml(xy, f"mov{mi}_{pi}", 0.0, h, attr, assets, meshes))
            colliders.append((f"mov{mi}_{pi}", "movable", mi, _posed_polygon(piece, m.pose)))
            n_mov_geoms += 1
        izz = float(m.inertia)
        ixy = 0.5 * izz + float(m.mass) * h * h / 12.0
        x, y, psi = (float(v) for v in m.pose)
        bodies.append(
            f'<body name="mov{mi}" pos="{x:.9g} {y:.9g} 0" quat="{_f(yaw_quat(psi))}">'
            f'<freejoint name="mov{mi}"/>'
            f'<inertial pos="0 0 {h / 2:.9g}" mass="{float(m.mass):.9g}" diaginertia="{ixy:.9g} {ixy:.9g} {izz:.9g}"/>'
            + "".join(geoms) + "</body>")

    for ri in range(len(robots)):
        bodies.append(
            f'<body name="robot{ri}" pos="0 0 {h / 2:.9g}">'
            f'<joint name="robot{ri}_x" type="slide" axis="1 0 0"/>'
            f'<joint name="robot{ri}_y" type="slide" axis="0 1 0"/>'
            f'<geom name="robot{ri}" type="capsule" fromto="0 0 {-h / 4:.9g} 0 0 {h / 4:.9g}" size="{r:.9g}" '
            f'mass="{cfg.robot_mass:.9g}" contype="8" conaffinity="12" '
            f'friction="{cfg.robot_friction:.9g} 0.005 0.0001" rgba="0.2 0.45 0.85 1"/></body>')
        for ax in "xy":
            actuators.append(f'<velocity name="robot{ri}_{ax}" joint="robot{ri}_{ax}" kv="{cfg.kv:.9g}" '
                             f'forcelimited="true" forcerange="{-cfg.force:.9g} {cfg.force:.9g}"/>')

    span = max(x1 - x0, y1 - y0)
    xml = f"""<mujoco model="pusharound">
  <option timestep="{cfg.timestep:.9g}" integrator="implicitfast" iterations="{cfg.iterations}"
          ls_iterations="{cfg.ls_iterations}" cone="pyramidal"/>
  <asset>{''.join(assets)}</asset>
  <worldbody>
    <geom name="floor" type="plane" pos="{0.5 * (x0 + x1):.9g} {0.5 * (y0 + y1):.9g} 0"
          size="{span:.9g} {span:.9g} 0.1" contype="1" conaffinity="0" friction="1 0.005 0.0001"/>
    {''.join(statics)}
    {''.join(bodies)}
  </worldbody>
  <actuator>{''.join(actuators)}</actuator>
</mujoco>"""
    reach = float(cfg.push_reach) + float(cfg.pair_margin)
    pairs = contact_pairs(colliders, [f"robot{i}" for i in range(len(robots))], reach)
    caps = mjx_caps(pairs, n_mov_geoms)
    mjx_xml = re.sub(r'contype="\d+" conaffinity="\d+"', 'contype="0" conaffinity="0"', xml)
    model = mujoco.MjModel.from_xml_string(xml)

    def pair_xml(a: str, b: str) -> str:
        # MuJoCo's mixing for dynamic contacts (friction: the larger of the two geoms'; condim: the
        # larger), which explicit pairs do not apply by themselves: sliding, sliding, torsional, rolling x2.
        ga, gb = (mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in (a, b))
        f = np.maximum(model.geom_friction[ga], model.geom_friction[gb])
        dim = max(int(model.geom_condim[ga]), int(model.geom_condim[gb]))
        return f'<pair geom1="{a}" geom2="{b}" condim="{dim}" friction="{_f(f[[0, 0, 1, 2, 2]])}"/>'

    mjx_xml = mjx_xml.replace("<asset>", f"""<custom>
    <numeric name="max_contact_points" data="{caps['max_contact_points']}"/>
  </custom>
  <asset>""", 1).replace("</mujoco>", "<contact>" + "".join(
        pair_xml(a, b) for a, b in pairs) + "</contact>\n</mujoco>")
    mjx_model = mujoco.MjModel.from_xml_string(mjx_xml)
    if cfg.sleep:
        model.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)

    def jadr(name, field):
        return int(getattr(model, field)[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)])

    n_mov, n_rob = len(scene.movables), len(robots)
    mov_adr = np.array([jadr(f"mov{i}", "jnt_qposadr") for i in range(n_mov)], np.int32)
    mov_dof = np.array([jadr(f"mov{i}", "jnt_dofadr") for i in range(n_mov)], np.int32)
    robot_adr = np.array([[jadr(f"robot{i}_{a}", "jnt_qposadr") for a in "xy"] for i in range(n_rob)], np.int32)
    robot_dof = np.array([[jadr(f"robot{i}_{a}", "jnt_dofadr") for a in "xy"] for i in range(n_rob)], np.int32)
    e = cfg.world_margin
    bounds = (np.array([x0 - e, y0 - e, -1.0]), np.array([x1 + e, y1 + e, 2.0]))
    fixed_verts = _pack(fixed_rings) if fixed_rings else np.zeros((0, 3, 2))
    return PushWorld(model, scene, cfg, mov_adr, mov_dof, robot_adr, robot_dof, bounds,
                     _pack(body_rings), np.asarray(owner, np.int32), fixed_verts, xml, mjx_model, tuple(pairs),
                     float(cfg.push_reach), np.asarray(scene.poses, np.float64).copy())


def initial_state(world: PushWorld, robot_xy=None, poses=None) -> tuple[np.ndarray, np.ndarray]:
    """``(qpos f[nq], qvel f[nv])`` with movables at ``poses f[M, 3]`` (default: the scene's) and robots
    at ``robot_xy f[N, 2]`` (default: the scene's), everything at rest."""
    m = world.model
    qpos = np.zeros(m.nq)
    poses = world.scene.poses if poses is None else np.asarray(poses, np.float64)
    robot_xy = np.asarray(world.scene.robots if robot_xy is None else robot_xy, np.float64)
    if poses.shape != (len(world.mov_adr), 3):
        raise ValueError(f"poses: expected shape [{len(world.mov_adr)}, 3]; got {poses.shape}.")
    if robot_xy.shape != world.robot_adr.shape:
        raise ValueError(f"robot_xy: expected shape {list(world.robot_adr.shape)}; got {robot_xy.shape}.")
    for a, (x, y, psi) in zip(world.mov_adr, poses):
        qpos[a:a + 3] = x, y, 0.0
        qpos[a + 3:a + 7] = yaw_quat(psi)
    qpos[world.robot_adr.reshape(-1)] = robot_xy.reshape(-1)
    return qpos, np.zeros(m.nv)


def movable_poses(world: PushWorld, qpos) -> tuple[np.ndarray, np.ndarray]:
    """From ``qpos f[..., nq]``: planar poses ``f[..., M, 3]`` (x, y, yaw) of the movables and the
    z component of each body's z axis ``f[..., M]`` (1 upright, < tip_cos tipped)."""
    qpos = np.asarray(qpos)
    idx = world.mov_adr[:, None] + np.arange(7)[None, :]
    q = qpos[..., idx]                                          # [..., M, 7]
    w, x, y, z = q[..., 3], q[..., 4], q[..., 5], q[..., 6]
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    upright = 1 - 2 * (x * x + y * y)
    return np.stack([q[..., 0], q[..., 1], yaw], -1), upright


def contact_usage(world: PushWorld, qpos) -> dict:
    """What the C engine's contacts need from the MJX model, over the states ``qpos f[..., nq]`` (e.g.
    every tick of a batch of push rollouts): ``{"pairs": set of (geom, geom) names in contact,
    "undeclared": the ones not in world.pairs, "max_contacts": most contact points in one state,
    "cap": the MJX model's max_contact_points}``. The full model (collision bits) finds the contacts."""
    m = world.model
    d = mujoco.MjData(m)
    declared = {frozenset(p) for p in world.pairs}
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) for g in range(m.ngeom)]
    seen, most = set(), 0
    for q in np.asarray(qpos, np.float64).reshape(-1, m.nq):
        if not np.all(np.isfinite(q)):
            continue
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        most = max(most, int(d.ncon))
        for c in d.contact[: d.ncon]:
            seen.add(tuple(sorted((names[c.geom1], names[c.geom2]))))
    mm = world.mjx_model
    nid = mujoco.mj_name2id(mm, mujoco.mjtObj.mjOBJ_NUMERIC, "max_contact_points")
    cap = int(mm.numeric_data[mm.numeric_adr[nid]]) if nid >= 0 else -1
    return {"pairs": seen, "undeclared": sorted(p for p in seen if frozenset(p) not in declared),
            "max_contacts": most, "cap": cap}
