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
"""
from __future__ import annotations

import math

import numpy as np
import shapely
from shapely.geometry import Point
from shapely.geometry import box as _box

from jaxplan.pusharound import shapes
from jaxplan.pusharound.scene import Fixed, Movable, PushScene, validate_scene

__all__ = ["nominal_scene", "random_shape", "NOMINAL"]

NOMINAL = dict(workspace=(0.0, 0.0, 8.0, 5.0), width=0.8, start=(1.0, 4.0), goal=(7.0, 2.0),
               bars=((2.6, 0.0, 2.8, 3.3), (5.2, 1.7, 5.4, 5.0)),
               openings=((2.3, 3.3, 3.1, 5.0), (4.9, 0.0, 5.7, 1.7)),
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


def nominal_scene(seed: int, n_movables: int | None = None, width: float = NOMINAL["width"],
                  min_sep: float = 0.15, require_blocked: bool = True, max_draws: int = 50) -> PushScene:
    """The nominal scenario of Section IV-A, seeded (see the module docstring).

    n_movables: 10-15 drawn from the seed when None. Raises ``ValueError`` if ``max_draws`` draws
    never gave a blocked scene.
    """
    from jaxplan.pusharound.wccg import build_wccg, connectivity  # noqa: PLC0415 (cycle-free import)

    rng = np.random.default_rng(seed)
    n = int(rng.integers(10, 16)) if n_movables is None else int(n_movables)
    ws = NOMINAL["workspace"]
    fixed = tuple(Fixed(name=f"bar{k}", pieces=(shapely.orient_polygons(_box(*b), exterior_cw=False),))
                  for k, b in enumerate(NOMINAL["bars"]))
    r = 0.5 * width
    # Keep the endpoint disks (plus 5 cm) and the robots (plus their radius) free.
    reserved = shapely.union_all([Point(NOMINAL["start"]).buffer(r + 0.05), Point(NOMINAL["goal"]).buffer(r + 0.05)]
                                 + [Point(p).buffer(2 * NOMINAL["robot_radius"]) for p in NOMINAL["robots"]])
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
            pose, poly = placed
            taken.append(poly)
            mass = float(rng.uniform(*NOMINAL["mass"]))
            movables.append(Movable(name=f"{shape.kind}{k}", pieces=shape.pieces, pose=pose, mass=mass,
                                    inertia=shapes.polygon_inertia(shape.outline, mass), friction=0.5,
                                    shape={"kind": shape.kind, **shape.params}))
        scene = PushScene(workspace=ws, width=width, start=NOMINAL["start"], goal=NOMINAL["goal"],
                          fixed=fixed, movables=tuple(movables),
                          robots=np.asarray(NOMINAL["robots"], np.float64),
                          robot_radius=NOMINAL["robot_radius"])
        validate_scene(scene)
        if not require_blocked or not connectivity(build_wccg(scene), scene.start, scene.goal).connected:
            return scene
    raise ValueError(f"nominal_scene: no blocked scene in {max_draws} draws (seed {seed}); raise "
                     "n_movables or max_draws, or pass require_blocked=False.")
