"""Seeded scene generators: the paper's nominal setting (Section IV-A).

:func:`nominal_scene`: an 8 x 5 m workspace, two fixed bars forming bottlenecks (one rising from the
floor on the left, one hanging from the ceiling on the right, so the corridor zig-zags), 10-15
movables drawn from the paper's menu (rings, ellipses, X/T/L, diamonds, arrows, rectangles,
cylinders) with masses uniform in [5, 15] kg, placed uniformly at random with a minimum separation,
the first few inside the two bottleneck openings; two robots in the lower left; start (1, 4) and goal
(7, 2) as in Fig. 6. With ``require_blocked`` the draw is repeated (same seed stream) until Eq. 7
fails, so that the scene needs pushing.

Choices the paper leaves open (documented in docs/pusharound.md): W = 0.8 m, the bar geometry, shape
sizes, 0.15 m separation, 0.05 m margin around the endpoint disks, friction 0.5.

:func:`dense_scene`: the scalability scene of Section IV-A.3 (Fig. 9), the nominal layout with 30
movables (exactly ``n_movables``: a shape that finds no room is replaced by a fresh draw).
:func:`corridor_scene`: a tiny one-blocker scene (6 x 2.4 m, a wall with a 1 m opening, one box
in it) for smoke runs and tests.
:func:`density_scene`: the density sweep of the RA-L version (8 x 8 m, 15-45 movables). As there,
denser instances of one seed add objects to the same layout: ``density_scene(s, n)``'s movables are
the first ``n`` of ``density_scene(s, n + k)``'s (the draw is chosen blocked at ``base`` movables;
adding obstacles never reconnects start and goal, so every larger count is blocked too).
"""
from __future__ import annotations

import math

import numpy as np
import shapely
from shapely.geometry import Point
from shapely.geometry import box as _box

from jaxplan.pusharound import shapes
from jaxplan.pusharound.scene import Fixed, Movable, PushScene, validate_scene

__all__ = ["nominal_scene", "dense_scene", "density_scene", "corridor_scene", "random_shape", "check_seed",
           "NOMINAL", "DENSITY"]

NOMINAL = dict(workspace=(0.0, 0.0, 8.0, 5.0), width=0.8, start=(1.0, 4.0), goal=(7.0, 2.0),
               bars=((2.6, 0.0, 2.8, 3.3), (5.2, 1.7, 5.4, 5.0)),
               openings=((2.3, 3.3, 3.1, 5.0), (4.9, 0.0, 5.7, 1.7)),
               robots=((0.5, 0.5), (1.0, 0.5)), robot_radius=0.15, mass=(5.0, 15.0))

# The density sweep's 8 x 8 m layout (our choice; the RA-L text gives only the size): the nominal
# bars stretched to the taller room, start top left, goal bottom right, robots lower left.
DENSITY = dict(workspace=(0.0, 0.0, 8.0, 8.0), width=0.8, start=(1.0, 7.0), goal=(7.0, 1.0),
               bars=((2.6, 0.0, 2.8, 5.3), (5.2, 2.7, 5.4, 8.0)),
               openings=((2.3, 5.3, 3.1, 8.0), (4.9, 0.0, 5.7, 2.7)),
               robots=((0.5, 0.5), (1.0, 0.5)), robot_radius=0.15, mass=(5.0, 15.0))


def random_shape(rng: np.random.Generator) -> shapes.Shape:
    """One shape from the paper's menu with random sizes [m] (a uniform choice of kind)."""
    u = rng.uniform
    kind = rng.choice(["ring", "ellipse", "x", "t", "l", "diamond", "arrow", "rectangle", "cylinder"])
    if kind == "ring":
        r = u(0.3, 0.45)
        return shapes.ring(r, 0.6 * r, n=10)
    if kind == "ellipse":
        return shapes.ellipse(u(0.3, 0.5), u(0.2, 0.3), n=14)
    if kind in ("x", "t", "l"):
        maker = {"x": shapes.x_shape, "t": shapes.t_shape, "l": shapes.l_shape}[kind]
        return maker(u(0.6, 0.9), u(0.6, 0.9), 0.2)
    if kind == "diamond":
        return shapes.diamond(u(0.6, 0.9), u(0.5, 0.7))
    if kind == "arrow":
        return shapes.arrow(u(0.8, 1.1), 0.2, 0.3, 0.45)
    if kind == "rectangle":
        return shapes.rectangle(u(0.4, 1.0), u(0.3, 0.6))
    return shapes.cylinder(u(0.2, 0.35), n=12)


def _place(rng, shape, region, taken, keep_out, min_sep, tries=60):
    """A pose inside ``region`` (x0, y0, x1, y1) where the shape is min_sep away from ``taken`` and
    clear of ``keep_out``; None after ``tries`` draws."""
    for _ in range(tries):
        x, y, psi = rng.uniform(region[0], region[2]), rng.uniform(region[1], region[3]), rng.uniform(0, 2 * math.pi)
        poly = shapely.affinity.translate(shapely.affinity.rotate(shape.outline, psi, origin=(0, 0),
                                                                  use_radians=True), x, y)
        if not keep_out[0].contains(poly):  # keep_out[0]: the workspace shrunk by min_sep
            continue
        if poly.intersects(keep_out[1]):
            continue
        if any(poly.distance(t) < min_sep for t in taken):
            continue
        return (x, y, psi), poly
    return None


def _movable(rng: np.random.Generator, k: int, shape, pose, layout: dict) -> Movable:
    """Movable number ``k`` of ``shape`` at ``pose``, its mass drawn uniformly from ``layout["mass"]`` [kg]."""
    mass = float(rng.uniform(*layout["mass"]))
    return Movable(name=f"{shape.kind}{k}", pieces=shape.pieces, pose=pose, mass=mass,
                   inertia=shapes.polygon_inertia(shape.outline, mass), friction=0.5,
                   shape={"kind": shape.kind, **shape.params})


def _fixed_and_reserved(layout: dict, width: float):
    """The layout's bars as fixed obstacles, and the region no movable may cover: the endpoint disks
    (vehicle radius plus 5 cm) and the robots (plus their radius)."""
    fixed = tuple(Fixed(name=f"bar{k}", pieces=(shapely.orient_polygons(_box(*b), exterior_cw=False),))
                  for k, b in enumerate(layout["bars"]))
    r = 0.5 * width
    reserved = shapely.union_all([Point(layout["start"]).buffer(r + 0.05), Point(layout["goal"]).buffer(r + 0.05)]
                                 + [Point(p).buffer(2 * layout["robot_radius"]) for p in layout["robots"]])
    return fixed, reserved


def check_seed(seed) -> None:
    """Raise ``ValueError`` unless ``seed`` is an int >= 0 (what numpy's ``default_rng`` accepts)."""
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed: must be an int >= 0; got {seed!r}.")


def nominal_scene(seed: int, n_movables: int | None = None, width: float = NOMINAL["width"],
                  min_sep: float = 0.15, require_blocked: bool = True, max_draws: int = 50) -> PushScene:
    """The nominal scenario of Section IV-A, seeded (see the module docstring).

    n_movables: 10-15 drawn from the seed when None. Raises ``ValueError`` if ``max_draws`` draws
    never gave a blocked scene.
    """
    from jaxplan.pusharound.wccg import build_wccg, connectivity  # noqa: PLC0415 (cycle-free import)

    check_seed(seed)
    rng = np.random.default_rng(seed)
    n = int(rng.integers(10, 16)) if n_movables is None else int(n_movables)
    ws = NOMINAL["workspace"]
    fixed, reserved = _fixed_and_reserved(NOMINAL, width)
    for _ in range(max_draws):
        taken = [f.pieces[0] for f in fixed]
        keep = (_box(*ws).buffer(-0.05), reserved)
        movables = []
        for k in range(n):
            region = NOMINAL["openings"][k % 2] if k < 4 else (0.3, 0.3, 7.7, 4.7)
            shape = random_shape(rng)
            placed = _place(rng, shape, region, taken, keep, min_sep)
            if placed is None:
                continue
            taken.append(placed[1])
            movables.append(_movable(rng, k, shape, placed[0], NOMINAL))
        scene = PushScene(workspace=ws, width=width, start=NOMINAL["start"], goal=NOMINAL["goal"],
                          fixed=fixed, movables=tuple(movables),
                          robots=np.asarray(NOMINAL["robots"], np.float64),
                          robot_radius=NOMINAL["robot_radius"])
        validate_scene(scene)
        if not require_blocked or not connectivity(build_wccg(scene), scene.start, scene.goal).connected:
            return scene
    raise ValueError(f"nominal_scene: no blocked scene in {max_draws} draws (seed {seed}); raise "
                     "n_movables or max_draws, or pass require_blocked=False.")


def _layout_scene(rng: np.random.Generator, layout: dict, n: int, min_sep: float, width: float,
                  shape_tries: int) -> PushScene:
    """Exactly ``n`` movables placed one after another on ``layout`` (NOMINAL / DENSITY keys): the
    first four in the two bottleneck openings, the rest anywhere; a shape that finds no room after
    ``_place``'s draws is replaced by a new shape, up to ``shape_tries`` times (then ``ValueError``).
    The rng is consumed object by object, so the first k movables do not depend on ``n``."""
    ws = layout["workspace"]
    fixed, reserved = _fixed_and_reserved(layout, width)
    taken = [f.pieces[0] for f in fixed]
    keep = (_box(*ws).buffer(-0.05), reserved)
    inner = (ws[0] + 0.3, ws[1] + 0.3, ws[2] - 0.3, ws[3] - 0.3)
    movables = []
    for k in range(n):
        region = layout["openings"][k % 2] if k < 4 else inner
        for _ in range(shape_tries):
            shape = random_shape(rng)
            placed = _place(rng, shape, region, taken, keep, min_sep)
            if placed is None and k < 4:   # a crowded opening: anywhere instead
                placed = _place(rng, shape, inner, taken, keep, min_sep)
            if placed is not None:
                break
        else:
            raise ValueError(f"n_movables: no room for movable {k} after {shape_tries} shapes; lower n_movables "
                             f"(got {n}) or min_sep (got {min_sep}).")
        taken.append(placed[1])
        movables.append(_movable(rng, k, shape, placed[0], layout))
    scene = PushScene(workspace=ws, width=width, start=layout["start"], goal=layout["goal"], fixed=fixed,
                      movables=tuple(movables), robots=np.asarray(layout["robots"], np.float64),
                      robot_radius=layout["robot_radius"])
    validate_scene(scene)
    return scene


def _blocked(scene: PushScene) -> bool:
    from jaxplan.pusharound.wccg import build_wccg, connectivity  # noqa: PLC0415 (cycle-free import)
    return not connectivity(build_wccg(scene), scene.start, scene.goal).connected


def dense_scene(seed: int, n_movables: int = 30, width: float = NOMINAL["width"], min_sep: float = 0.1,
                max_draws: int = 50, shape_tries: int = 40) -> PushScene:
    """The 30-movable scalability scene (Section IV-A.3, Fig. 9): the nominal 8 x 5 m layout with
    exactly ``n_movables`` movables (``min_sep`` 0.1 m: 30 shapes with the nominal 0.15 m leave too
    little room), redrawn (seed stream ``[seed, draw]``) until Eq. 7 fails."""
    check_seed(seed)
    if not isinstance(n_movables, (int, np.integer)) or n_movables < 1:
        raise ValueError(f"n_movables: must be a positive int; got {n_movables!r}.")
    for d in range(max_draws):
        scene = _layout_scene(np.random.default_rng([seed, d]), NOMINAL, int(n_movables), min_sep, width, shape_tries)
        if _blocked(scene):
            return scene
    raise ValueError(f"dense_scene: no blocked scene in {max_draws} draws (seed {seed}); raise max_draws.")


def density_scene(seed: int, n_movables: int, width: float = DENSITY["width"], min_sep: float = 0.15,
                  base: int = 15, max_draws: int = 50, shape_tries: int = 40) -> PushScene:
    """The density sweep (RA-L version, Section IV-A): an 8 x 8 m room (``DENSITY``) with exactly
    ``n_movables`` movables (the paper sweeps 15-45). Nested in ``n_movables`` for one seed (module
    docstring): the draw ``[seed, d]`` is the first whose ``min(base, n_movables)``-movable prefix is
    blocked (Eq. 7 fails), hence blocked at every larger count."""
    check_seed(seed)
    if not isinstance(n_movables, (int, np.integer)) or n_movables < 1:
        raise ValueError(f"n_movables: must be a positive int; got {n_movables!r}.")
    n0 = min(int(base), int(n_movables))
    for d in range(max_draws):
        prefix = _layout_scene(np.random.default_rng([seed, d]), DENSITY, n0, min_sep, width, shape_tries)
        if _blocked(prefix):
            if n0 == n_movables:
                return prefix
            return _layout_scene(np.random.default_rng([seed, d]), DENSITY, int(n_movables), min_sep, width,
                                 shape_tries)
    raise ValueError(f"density_scene: no blocked scene in {max_draws} draws (seed {seed}); raise max_draws.")


def corridor_scene(seed: int = 0, width: float = 0.8) -> PushScene:
    """A tiny blocked scene: 6 x 2.4 m, a fixed wall at x in [2.9, 3.1] with an opening y in [0.7, 1.7],
    one box (0.4 x 0.5 m, mass U[5, 15] kg) in the opening (centre jittered by up to 5 cm), start
    (0.6, 1.2), goal (5.4, 1.2), robots (0.4, 0.4) and (0.4, 0.9). Pushing the box about 1.1 m along
    +x (or -x) opens the corridor; pushing it along y runs it into the wall."""
    check_seed(seed)
    rng = np.random.default_rng(seed)
    wall = tuple(Fixed(name=f"wall{k}", pieces=(shapely.orient_polygons(_box(*b), exterior_cw=False),))
                 for k, b in enumerate(((2.9, 0.0, 3.1, 0.7), (2.9, 1.7, 3.1, 2.4))))
    shape = shapes.rectangle(0.4, 0.5)
    mass = float(rng.uniform(5.0, 15.0))
    pose = (3.0 + rng.uniform(-0.05, 0.05), 1.2 + rng.uniform(-0.05, 0.05), 0.0)
    mov = Movable(name="box0", pieces=shape.pieces, pose=pose, mass=mass,
                  inertia=shapes.polygon_inertia(shape.outline, mass), friction=0.5,
                  shape={"kind": shape.kind, **shape.params})
    scene = PushScene(workspace=(0.0, 0.0, 6.0, 2.4), width=width, start=(0.6, 1.2), goal=(5.4, 1.2), fixed=wall,
                      movables=(mov,), robots=np.array([[0.4, 0.4], [0.4, 0.9]]), robot_radius=0.15)
    validate_scene(scene)
    return scene
