"""The rover world: a Scene turned into an MJCF model (floor, target, rover, gravel particles).

Units: lengths in world units with the grid cell size ``s`` as the scale (the builtin scenes have
``s = 1``, read as metres); masses in kg; the rover's shovel width is ``s`` by default (the paper:
"shovel width sets the grid cell size").

Particles: every object of the grid becomes ``particles_per_object`` spheres (default 1) of radius
``particle_radius * s`` placed on a 3 x 3 jittered lattice in its cell, stacked in layers of 9; a
particle carries ``1 / particles_per_object`` objects of mass. Only the cells a check needs get
particles (:func:`particle_layout`); the rest of the grid stays as counts. One model serves a whole
batch of routes: it has ``n_particles`` particle bodies, and a route that needs fewer parks the
others in a strip outside the grid, where nothing reaches them.

Several rovers (``build_world(..., n_rovers=N)``, a fleet's world): rover i's names carry the prefix
``rover_prefix(i, N)`` ("r{i}_"; none for one rover, whose model is unchanged), its hull, wheels and
casters get collision bit 8 so that rovers collide with (and touch) each other, and the qpos holds
the N rovers' free joints and wheels first (``rover_qpos_adr``), then the particles.

Contact caps (MJX has no real broadphase; ``docs/physics.md``): with N particle bodies,

    max_geom_pairs     = max(hull_boxes * N, pair_factor * N)
    max_contact_points = (N + 4) + pair_factor * N + hull_factor * N

``hull_boxes * N`` keeps every particle-hull pair (MJX culls pairs by bounding spheres, which for a
long blade would prefer a nearby non-touching particle to a touching one at the blade's end), the
``pair_factor * N`` closest particle pairs are kept (a sphere on the floor touches at most 6
neighbours in a layer, 3 per particle counting each pair once; ``pair_factor = 4`` leaves room for a
second layer against the blade), and the contact budget adds one floor contact per particle plus the
2 wheels and the 2 casters. ``contact_usage`` measures the real counts with the C engine so a test can
check that nothing is dropped.

Blocked cells (``scene.blocked``: buildings, equipment, no-go zones) are static boxes of the world
body, one per rectangle of ``blocked_rectangles`` (maximal runs of blocked cells in a row, runs of
equal columns in consecutive rows merged), ``obstacle_height(s, cfg)`` tall (at least 4 particle
diameters and twice the rover's hull), named ``"blocked{k}"``. Their collision bits, contype 1 (the
floor's) and conaffinity 4 (the hull's), make particles, wheels, casters and hulls collide with them.
With B boxes the caps grow by what B walls can add: ``B * (N + 4 R)`` pairs (every particle-box and
wheel/caster-box pair, so no hull-particle pair is culled for a wall's large bounding sphere) and
``N + R * (4 + 4 * hull_boxes)`` contacts (each particle, wheel and caster against one wall, each hull
box a 4-point box-box manifold). A scene without blocked cells gets exactly the world it got before.
"""
from __future__ import annotations

import dataclasses
import math
import numbers
from typing import NamedTuple

import mujoco
import numpy as np

from mjx_models import MODEL_DIR

__all__ = ["RoverConfig", "World", "build_world", "particle_layout", "contact_usage", "rover_pose",
           "rover_prefix", "rover_xml", "rover_geometry", "Geometry", "MODEL_DIR", "OBSTACLE_PREFIX",
           "blocked_rectangles", "obstacle_height"]

HULL_BOXES = 4           # chassis, blade, two wings
ROVER_QPOS = 9           # qpos per rover: free joint (7) and the two wheel hinges
_OTHER_ROVER_BIT = 8     # collision bit of the other rovers in a world of several (template comment)
_SLOTS = 3               # particles per cell side in one layer
_PARK_GAP = 3.0          # parked particles are this many radii apart
_SOLVERS = ("CG", "Newton")   # the constraint solvers both MJX and the C engine run
OBSTACLE_PREFIX = "blocked"   # geom names of the blocked cells' boxes: blocked0, blocked1, ...
_OBSTACLE_CELLS = 0.5         # box height in cells (twice the rover's hull, 0.25 s) ...
_OBSTACLE_RADII = 8.0         # ... and at least this many particle radii (4 diameters)
_OBSTACLE_CONTYPE = 1         # the floor's bit: particles, wheels and casters collide with it
_OBSTACLE_CONAFFINITY = 4     # the hull's bit: chassis, blade and wings collide with it


@dataclasses.dataclass(frozen=True)
class RoverConfig:
    """Static physics settings (all lengths in cell sizes unless noted).

    shovel_width: blade width in cells (1 = the cell size).  particles_per_object: spheres per
    object.  particle_radius: sphere radius in cells.  particle_mass: kg per particle.
    rover_mass: kg (chassis; blade, wings, wheels and caster add about 20%).
    timestep: seconds per physics step.  substeps: physics steps per control tick.
    iterations, ls_iterations: solver iterations. MJX (float32) flips the rover with 10; 30 is
    stable on the demo routes and costs little where the solver converges early.
    solver: "CG" (default) or "Newton", MuJoCo's constraint solver on both engines. Newton factorises
    an nv x nv matrix every iteration (nv = 6 per particle), so CG steps faster on a CPU with
    either engine, with the same deliveries; on a GPU MJX runs faster with Newton (fewer, larger
    kernels per step), so use Newton for MJX there (docs/physics.md, docs/benchmarks.md).
    pair_factor, hull_factor: contact-cap sizing (module docstring).  friction: floor and
    particle sliding friction.  roll_stop: seconds for a rolling particle to stop (joint
    damping stands in for rolling resistance).  wheel_kv: velocity-actuator gain (N m s / rad), moderate on purpose.
    wing_length: how far the shovel's side plates reach forward of the blade, in cells. With 1 cell
    the shovel holds its load like the 2D model's shovel (most of what it collects arrives); with
    short wings (0.24) it behaved like a flat blade with a fixed capacity (docs/physics.md).
    """

    shovel_width: float = 1.0
    particles_per_object: int = 1
    particle_radius: float = 0.06
    particle_mass: float = 0.2
    rover_mass: float = 60.0
    timestep: float = 0.005
    substeps: int = 10
    iterations: int = 30
    ls_iterations: int = 10
    pair_factor: int = 4
    hull_factor: int = 1
    friction: float = 0.6
    wheel_kv: float = 4.0
    roll_stop: float = 0.1
    wing_length: float = 1.0
    solver: str = "CG"

    def __post_init__(self):
        if self.solver not in _SOLVERS:
            raise ValueError(f"RoverConfig.solver: expected one of {', '.join(_SOLVERS)}; got {self.solver!r}.")
        positive = ("shovel_width", "particle_radius", "particle_mass", "rover_mass", "timestep",
                    "wheel_kv", "roll_stop", "wing_length")
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, numbers.Real) and math.isfinite(value) and value > 0):
                raise ValueError(f"RoverConfig.{name}: must be a positive number; got {value!r}.")
        for name in ("particles_per_object", "substeps", "iterations", "ls_iterations"):
            value = getattr(self, name)
            if not (isinstance(value, numbers.Integral) and value >= 1):
                raise ValueError(f"RoverConfig.{name}: must be an integer >= 1; got {value!r}.")

    def replace(self, **changes) -> RoverConfig:
        return dataclasses.replace(self, **changes)


class Geometry(NamedTuple):
    """Rover dimensions in world units (derived from the cell size)."""

    wheel_r: float
    half_track: float      # axle midpoint to a wheel centre
    blade_front: float     # axle midpoint to the blade's front face (the tracked point)
    blade_half_width: float
    wing_reach: float      # blade's front face to the side plates' tips


@dataclasses.dataclass(frozen=True)
class World:
    """A built rover world. ``model`` is the compiled MjModel; ``xml`` its MJCF text.

    n_particles: particle bodies (N). qpos layout: rover free joint [0:7], wheels [7:9], then
    particle k at ``[9 + 7k : 16 + 7k]``. bounds: (lo f[3], hi f[3]) world box for the divergence
    check. parking: f[N, 3] positions of parked particles. caps: the MJX caps written into the model.
    n_rovers: rovers in the world (R); with R > 1 rover i's free joint and wheels are qpos
    ``[9i : 9i + 9]`` and the particles start at ``9 R`` (``rover_qpos_adr``).
    n_obstacles: static boxes of the scene's blocked cells (B; geoms ``"blocked{k}"``, one per
    ``blocked_rectangles`` row).
    """

    model: mujoco.MjModel
    xml: str
    config: RoverConfig
    geometry: Geometry
    n_particles: int
    cell_size: float
    origin: tuple
    shape: tuple
    bounds: tuple
    parking: np.ndarray
    caps: dict
    n_rovers: int = 1
    n_obstacles: int = 0

    def particle_xyz(self, qpos):
        """``f[..., N, 3]`` particle positions from ``qpos f[..., nq]``."""
        first = ROVER_QPOS * self.n_rovers
        q = np.asarray(qpos)[..., first: first + 7 * self.n_particles]
        return q.reshape(q.shape[:-1] + (self.n_particles, 7))[..., :3]


def rover_geometry(s: float, cfg: RoverConfig) -> Geometry:
    """The rover's dimensions (world units) for cell size ``s`` and ``cfg``."""
    wheel_r = 0.12 * s
    blade_x = 0.42 * s
    blade_hx = 0.02 * s
    return Geometry(wheel_r, 0.3 * s, blade_x + blade_hx, 0.5 * cfg.shovel_width * s,
                    cfg.wing_length * s - blade_hx)


def rover_prefix(i: int, n_rovers: int) -> str:
    """The name prefix of rover ``i`` in a world of ``n_rovers``: "" for one rover, else "r{i}_"
    (its body, joints, geoms and actuators are ``prefix + "rover"``, ``prefix + "wheel_left"``, ...)."""
    return "" if int(n_rovers) == 1 else f"r{int(i)}_"


def rover_xml(s: float, cfg: RoverConfig, prefix: str = "", collide_rovers: bool = False) -> str:
    """The rover's MJCF body for cell size ``s``: the template ``rover.xml`` filled in.

    prefix: put before every name (``rover_prefix``). collide_rovers: add collision bit 8 to the
    hull, wheels and casters so that rovers of one world collide with each other (the template's
    comment); without it the body is exactly the single-rover world's.
    """
    g = rover_geometry(s, cfg)
    template = (MODEL_DIR / "rover.xml").read_text()
    body = template[template.index("<body"):]
    # a chassis fifth of the blade height above the floor; the blade clears the floor by 0.01 s
    fields = dict(
        wheel_r=g.wheel_r, chassis_x=-0.05 * s, chassis_z=0.06 * s, chassis_hx=0.3 * s,
        chassis_hy=0.22 * s, chassis_hz=0.06 * s, chassis_mass=cfg.rover_mass,
        blade_x=g.blade_front - 0.02 * s, blade_z=0.13 * s - g.wheel_r, blade_hx=0.02 * s,
        blade_hy=g.blade_half_width, blade_hz=0.12 * s, blade_mass=0.1 * cfg.rover_mass,
        wing_x=g.blade_front + (0.5 * cfg.wing_length - 0.02) * s, wing_y=g.blade_half_width - 0.02 * s,
        wing_hx=0.5 * cfg.wing_length * s,
        wing_mass=0.02 * cfg.rover_mass,
        caster_x=-0.32 * s, caster_front_x=0.3 * s, caster_r=0.05 * s, caster_z=0.05 * s - g.wheel_r,
        caster_mass=0.02 * cfg.rover_mass,
        wheel_y=g.half_track, wheel_mass=0.04 * cfg.rover_mass, wheel_damping=0.05,
    )
    extra = _OTHER_ROVER_BIT if collide_rovers else 0
    bits = dict(hull_contype=4 | extra, hull_conaffinity=extra, gear_contype=extra, gear_conaffinity=1 | extra)
    return body.format(prefix=prefix, **{k: str(v) for k, v in bits.items()},
                       **{k: f"{v:.6g}" for k, v in fields.items()})


def caps_for(n_particles: int, cfg: RoverConfig, n_rovers: int = 1, n_obstacles: int = 0) -> dict:
    """The MJX contact caps for N particle bodies, R rovers and B obstacle boxes (module docstring;
    every rover's hull may touch every particle, each rover has 4 floor contacts, and the boxes add
    their pairs and contacts; B = 0 gives the caps of a world without blocked cells)."""
    n, r, b = int(n_particles), int(n_rovers), int(n_obstacles)
    pairs = max(HULL_BOXES * r * n + b * (n + 4 * r), cfg.pair_factor * n, 1)
    points = (n + 4 * r) + cfg.pair_factor * n + cfg.hull_factor * r * n
    if b:
        points += n + r * (4 + 4 * HULL_BOXES)
    return {"max_geom_pairs": int(pairs), "max_contact_points": int(points)}


def blocked_rectangles(blocked) -> np.ndarray:
    """``i32[K, 4]`` rows ``(row, col, n_rows, n_cols)``: disjoint rectangles that cover exactly the
    True cells of ``blocked: bool[H, W]`` (rows = y). Each row's maximal runs of blocked cells, a run
    merged with the one of the same columns in the row below it; ordered by (row, col)."""
    mask = np.asarray(blocked, bool)
    if mask.ndim != 2:
        raise ValueError(f"blocked: expected a bool [H, W] mask; got shape {mask.shape}.")
    done, growing = [], {}          # growing: (col, n_cols) -> [row, n_rows] of a rectangle still open
    for row in range(mask.shape[0] + 1):
        runs = set()
        if row < mask.shape[0]:
            edges = np.flatnonzero(np.diff(np.concatenate([[0], mask[row].astype(np.int8), [0]])))
            runs = {(int(c0), int(c1 - c0)) for c0, c1 in zip(edges[::2], edges[1::2])}
        for key in [k for k in growing if k not in runs]:      # not continued in this row: closed
            first, n_rows = growing.pop(key)
            done.append((first, key[0], n_rows, key[1]))
        for key in runs:
            if key in growing:
                growing[key][1] += 1
            else:
                growing[key] = [row, 1]
    return np.asarray(sorted(done), np.int32).reshape(-1, 4)


def obstacle_height(s: float, cfg: RoverConfig) -> float:
    """Height (world units) of the blocked cells' boxes for cell size ``s``: half a cell (twice the
    rover's hull) and at least 4 particle diameters."""
    return max(_OBSTACLE_CELLS * s, _OBSTACLE_RADII * cfg.particle_radius * s)


def _parking(n: int, s: float, cfg: RoverConfig, origin, width_cells: int) -> np.ndarray:
    """Parked positions: rows along the grid's bottom edge, 1.5 cells outside it."""
    r = cfg.particle_radius * s
    gap = _PARK_GAP * r
    per_row = max(1, int((width_cells * s) // gap))
    k = np.arange(n)
    x = origin[0] + (k % per_row + 0.5) * gap
    y = origin[1] - 1.5 * s - (k // per_row) * gap
    return np.stack([x, y, np.full(n, r)], -1)


def build_world(scene, n_particles: int, config: RoverConfig | None = None, n_rovers: int = 1) -> World:
    """Build the MJCF model of ``scene`` with ``n_particles`` particle bodies and ``n_rovers`` rovers
    (module docstring) and compile it."""
    cfg = RoverConfig() if config is None else config
    if int(n_particles) < 0:
        raise ValueError(f"n_particles: must be >= 0; got {n_particles!r}.")
    if not (isinstance(n_rovers, numbers.Integral) and n_rovers >= 1):
        raise ValueError(f"n_rovers: must be an integer >= 1; got {n_rovers!r}.")
    n_rovers = int(n_rovers)
    s = float(np.asarray(scene.cell_size))
    ox, oy = (float(v) for v in np.asarray(scene.origin))
    h, w = scene.shape
    r = cfg.particle_radius * s
    n = int(n_particles)
    parking = _parking(n, s, cfg, (ox, oy), w)
    park_rows = 0 if n == 0 else int(math.ceil((oy - 1.5 * s - parking[:, 1].min()) / s)) + 1
    margin = 3.0 * s
    lo = np.array([ox - margin, oy - margin - 1.5 * s - park_rows * s, -0.5 * s])
    hi = np.array([ox + w * s + margin, oy + h * s + margin, 3.0 * s])
    blocked = getattr(scene, "blocked", None)
    rects = blocked_rectangles(np.zeros((h, w), bool) if blocked is None else blocked)
    caps = caps_for(n, cfg, n_rovers, len(rects))

    mask = np.asarray(scene.target_mask)
    target_geoms = []
    for row, col in zip(*np.nonzero(mask)):
        cx, cy = ox + (col + 0.5) * s, oy + (row + 0.5) * s
        target_geoms.append(f'<geom type="box" pos="{cx:.6g} {cy:.6g} 0.0005" size="{0.5 * s:.6g} {0.5 * s:.6g} '
                            f'0.0005" contype="0" conaffinity="0" rgba="0.23 0.51 0.96 0.45"/>')
    hz = 0.5 * obstacle_height(s, cfg)
    obstacle_geoms = []
    for k, (row, col, n_rows, n_cols) in enumerate(rects):   # static boxes of the world body
        cx, cy = ox + (col + 0.5 * n_cols) * s, oy + (row + 0.5 * n_rows) * s
        obstacle_geoms.append(f'<geom name="{OBSTACLE_PREFIX}{k}" type="box" pos="{cx:.6g} {cy:.6g} {hz:.6g}" '
                              f'size="{0.5 * n_cols * s:.6g} {0.5 * n_rows * s:.6g} {hz:.6g}" '
                              f'contype="{_OBSTACLE_CONTYPE}" conaffinity="{_OBSTACLE_CONAFFINITY}" '
                              'rgba="0.42 0.42 0.46 1"/>')
    # Gravel does not roll like a ball bearing: a free sphere would roll across the world once
    # pushed. Damping its joint (torque -d * omega) stops a rolling sphere in about
    # ``roll_stop`` seconds, d = I_contact / roll_stop with I_contact = 7/5 m r^2; on the
    # translation the same d is a negligible drag (time constant m / d of several seconds).
    damping = 1.4 * cfg.particle_mass * r * r / cfg.roll_stop
    particles = []
    for k in range(n):
        x, y, z = parking[k]
        particles.append(f'<body name="p{k}" pos="{x:.6g} {y:.6g} {z:.6g}"><joint type="free" damping="{damping:.6g}"/>'
                         f'<geom type="sphere" size="{r:.6g}" mass="{cfg.particle_mass:.6g}" contype="2" '
                         f'conaffinity="7" rgba="0.55 0.45 0.35 1"/></body>')
    fx, fy = ox + 0.5 * w * s, oy + 0.5 * h * s
    fsize = 0.5 * max(h, w) * s + margin + park_rows * s + 1.5 * s
    g = rover_geometry(s, cfg)
    vmax = 2.0 * s / g.wheel_r      # wheel rad/s: 2 cells/s top speed
    prefixes = [rover_prefix(i, n_rovers) for i in range(n_rovers)]
    rovers = "\n".join(rover_xml(s, cfg, p, collide_rovers=n_rovers > 1) for p in prefixes)
    actuators = "\n".join(
        f'    <velocity name="{p}{side}" joint="{p}{side}" kv="{cfg.wheel_kv:.6g}" ctrlrange="{-vmax:.6g} {vmax:.6g}"/>'
        for p in prefixes for side in ("wheel_left", "wheel_right"))
    xml = f"""<mujoco model="rover_world">
  <option timestep="{cfg.timestep:.6g}" integrator="implicitfast" iterations="{cfg.iterations}"
          ls_iterations="{cfg.ls_iterations}" cone="pyramidal" solver="{cfg.solver}"/>
  <custom>
    <numeric name="max_contact_points" data="{caps['max_contact_points']}"/>
    <numeric name="max_geom_pairs" data="{caps['max_geom_pairs']}"/>
  </custom>
  <default><geom friction="{cfg.friction:.6g} 0.005 0.0001" condim="3"/></default>
  <visual><global offwidth="800" offheight="600"/></visual>
  <worldbody>
    <light pos="{fx:.6g} {fy:.6g} {10 * s:.6g}" dir="0 0 -1" directional="true"/>
    <geom name="floor" type="plane" pos="{fx:.6g} {fy:.6g} 0" size="{fsize:.6g} {fsize:.6g} 0.1"
          contype="1" conaffinity="0" rgba="0.82 0.8 0.75 1"/>
    {''.join(target_geoms + obstacle_geoms)}
    {rovers}
    {''.join(particles)}
  </worldbody>
  <actuator>
{actuators}
  </actuator>
</mujoco>
"""
    model = mujoco.MjModel.from_xml_string(xml)
    world = World(model, xml, cfg, g, n, s, (ox, oy), (h, w), (lo, hi), parking, caps, n_rovers, len(rects))
    assert list(rover_qpos_adr(world)) == [ROVER_QPOS * i for i in range(n_rovers)]
    assert all(model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE for j in range(0, 3 * n_rovers, 3))
    return world


def rover_qpos_adr(world: World) -> np.ndarray:
    """``i32[R]``: qpos address of each rover's free joint (its x, y, z, quaternion follow)."""
    ids = [mujoco.mj_name2id(world.model, mujoco.mjtObj.mjOBJ_JOINT, rover_prefix(i, world.n_rovers) + "rover")
           for i in range(world.n_rovers)]
    return world.model.jnt_qposadr[ids].astype(np.int32)


def particle_layout(scene, cells_mask, config: RoverConfig | None = None, seed: int = 0):
    """Particles for the non-target cells in ``cells_mask: bool[H, W]``.

    Returns ``(xyz f[P, 3], cell i[P, 2] (row, col), represented f[H, W])``: positions (world units),
    the cell each particle was generated in, and the count each cell's particles represent
    (``round(obj * particles_per_object) / particles_per_object``; the remainder stays on the grid).
    """
    cfg = RoverConfig() if config is None else config
    s = float(np.asarray(scene.cell_size))
    ox, oy = (float(v) for v in np.asarray(scene.origin))
    obj = np.asarray(scene.obj, np.float64)
    mask = np.asarray(cells_mask, bool) & ~np.asarray(scene.target_mask) & (obj > 0)
    ppo = int(cfg.particles_per_object)
    counts = np.where(mask, np.rint(obj * ppo), 0).astype(np.int64)
    r = cfg.particle_radius * s
    rng = np.random.default_rng(seed)
    pitch = s / _SLOTS
    jitter = max(0.0, 0.5 * (pitch - 2 * r) - 1e-3 * s)     # never overlapping a neighbour slot
    xyz, cells = [], []
    for row, col in zip(*np.nonzero(counts)):
        for k in range(counts[row, col]):
            layer, slot = divmod(k, _SLOTS * _SLOTS)
            i, j = divmod(slot, _SLOTS)
            x = ox + col * s + (j + 0.5) * pitch + rng.uniform(-jitter, jitter)
            y = oy + row * s + (i + 0.5) * pitch + rng.uniform(-jitter, jitter)
            xyz.append((x, y, r * (1 + 2 * layer) + 1e-3 * s * layer))
            cells.append((row, col))
    xyz = np.asarray(xyz, np.float64).reshape(-1, 3)
    cells = np.asarray(cells, np.int32).reshape(-1, 2)
    return xyz, cells, counts / ppo


def rover_pose(xy, yaw, world: World) -> np.ndarray:
    """``f[7]`` free-joint qpos of the rover with its axle midpoint at ``xy`` heading ``yaw`` (rad)."""
    return np.array([xy[0], xy[1], world.geometry.wheel_r, math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


def initial_qpos(world: World, rover_xy, rover_yaw, particle_xyz) -> np.ndarray:
    """``f[nq]``: rover pose(s), wheels at 0, the given particles first and the rest parked.

    rover_xy: f[2] (one rover) or f[R, 2] (one per rover of the world); rover_yaw: f[] or f[R].
    """
    p = np.asarray(particle_xyz, np.float64).reshape(-1, 3)
    if p.shape[0] > world.n_particles:
        raise ValueError(f"particle_xyz: {p.shape[0]} particles but the world has {world.n_particles} bodies.")
    xy = np.asarray(rover_xy, np.float64).reshape(-1, 2)
    yaw = np.broadcast_to(np.asarray(rover_yaw, np.float64).reshape(-1), (xy.shape[0],))
    if xy.shape[0] != world.n_rovers:
        raise ValueError(f"rover_xy: {xy.shape[0]} poses but the world has {world.n_rovers} rovers.")
    q = np.zeros(world.model.nq)
    for adr, pos, heading in zip(rover_qpos_adr(world), xy, yaw):
        q[adr: adr + 7] = rover_pose(pos, heading, world)
    pos = world.parking.copy()
    pos[: p.shape[0]] = p
    blocks = np.zeros((world.n_particles, 7))
    blocks[:, :3] = pos
    blocks[:, 3] = 1.0
    q[ROVER_QPOS * world.n_rovers:] = blocks.reshape(-1)
    return q


_GROUPS = {"sphere-sphere": (mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_SPHERE),
           "sphere-box": (mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_BOX),
           "plane-sphere": (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_SPHERE)}


def contact_usage(world: World, qpos) -> dict:
    """Largest number of penetrating contacts (C engine, exact narrow phase) over states
    ``qpos f[..., nq]``, per geom-type group and in total: what the MJX caps must hold."""
    m = world.model
    d = mujoco.MjData(m)
    q = np.asarray(qpos, np.float64).reshape(-1, m.nq)
    worst = {key: 0 for key in _GROUPS} | {"total": 0}
    for row in q:
        if not np.all(np.isfinite(row)):
            continue
        d.qpos[:] = row
        mujoco.mj_forward(m, d)
        geoms = d.contact.geom[: d.ncon]
        active = d.contact.dist[: d.ncon] < 0
        types = np.sort(m.geom_type[geoms], axis=1) if d.ncon else np.zeros((0, 2), int)
        for key, pair in _GROUPS.items():
            want = np.sort(np.array([int(p) for p in pair]))
            n = int(np.sum(active & np.all(types == want, axis=1))) if d.ncon else 0
            worst[key] = max(worst[key], n)
        worst["total"] = max(worst["total"], int(np.sum(active)))
    return worst
