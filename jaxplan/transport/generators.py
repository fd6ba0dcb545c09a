"""Scenes to plan on: the built-in ones (built in code from fixed seeds; no data files) and THE
random-scene generator that every benchmark, sweep, tuner and test draws from."""
from __future__ import annotations

import functools

import numpy as np
from shapely.geometry import MultiPolygon

from jaxplan.transport.scene import Scene, box, circle

__all__ = ["BUILTIN_SCENES", "DEFAULT_SCENE", "LAYOUTS", "builtin_scene", "random_scene"]


DEFAULT_SCENE = "default"
BUILTIN_SCENES: tuple[str, ...] = ("default", "corridor", "two_targets", "sparse65", "yard")


def _piles(shape, piles, max_count: int = 6) -> np.ndarray:
    """Integer counts (as float) from gaussian piles ``(cx, cy, amplitude, sigma)``, cell units."""
    h, w = shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    obj = np.zeros(shape)
    for cx, cy, amp, sigma in piles:
        obj += amp * np.exp(-((xs - cx) ** 2 + (ys - cy) ** 2) / (2.0 * sigma ** 2))
    return np.clip(np.rint(obj), 0, max_count)


def _random_piles(rng, n, x_range, y_range):
    return [(rng.uniform(*x_range), rng.uniform(*y_range), rng.uniform(4.0, 6.5),
             rng.uniform(1.2, 2.5)) for _ in range(n)]


def _with_target_cleared(obj, target, name) -> Scene:
    """Scene whose target cells hold no counts (material there is already delivered)."""
    scene = Scene.from_arrays(np.zeros_like(obj), target, name=name)
    return scene.with_obj(np.where(np.asarray(scene.target_mask), 0.0, obj))


def _scene_default() -> Scene:
    rng = np.random.default_rng(20260525)
    obj = _piles((25, 25), _random_piles(rng, 4, (2.0, 14.0), (2.0, 23.0)))
    return _with_target_cleared(obj, circle((20.5, 12.5), 3.0), "default")


def _scene_corridor() -> Scene:
    rng = np.random.default_rng(45)
    # A corridor of material along y = 22.5 toward the target on the right edge, plus side piles.
    along = [(x, 22.5 + rng.normal(0, 0.8), rng.uniform(3.0, 5.0), 1.3) for x in range(4, 36, 4)]
    side = _random_piles(rng, 3, (3.0, 30.0), (4.0, 41.0))
    obj = _piles((45, 45), along + side)
    return _with_target_cleared(obj, box(40.0, 15.0, 45.0, 30.0), "corridor")


def _scene_two_targets() -> Scene:
    rng = np.random.default_rng(30)
    target = MultiPolygon([circle((5.5, 24.5), 3.0), circle((24.5, 5.5), 3.5)])
    piles = _random_piles(rng, 3, (3.0, 13.0), (3.0, 13.0)) + \
        _random_piles(rng, 3, (16.0, 27.0), (16.0, 27.0))
    return _with_target_cleared(_piles((30, 30), piles), target, "two_targets")


def _scene_sparse65() -> Scene:
    rng = np.random.default_rng(65)
    occupied = rng.random((65, 65)) < 0.15
    obj = np.where(occupied, rng.integers(1, 7, size=(65, 65)), 0).astype(np.float64)
    return _with_target_cleared(obj, circle((32.5, 32.5), 6.0), "sparse65")


# (row, col, rows, cols) of the yard's blocked rectangles: two buildings, a fence with a gate, a
# parked machine
_YARD_BLOCKED = ((14, 6, 8, 10), (24, 24, 9, 7), (10, 20, 1, 16), (30, 8, 3, 4))


def _scene_yard() -> Scene:
    rng = np.random.default_rng(40)
    blocked = np.zeros((40, 40), bool)
    for r, c, n_rows, n_cols in _YARD_BLOCKED:
        blocked[r:r + n_rows, c:c + n_cols] = True
    piles = _random_piles(rng, 6, (3.0, 37.0), (14.0, 38.0))
    obj = np.where(blocked, 0.0, _piles((40, 40), piles))
    target = box(14.0, 0.0, 24.0, 4.0)
    free = Scene.from_arrays(np.zeros_like(obj), target)
    return Scene.from_arrays(np.where(np.asarray(free.target_mask), 0.0, obj), target, name="yard", blocked=blocked)


_BUILDERS = {
    "default": _scene_default,
    "corridor": _scene_corridor,
    "two_targets": _scene_two_targets,
    "sparse65": _scene_sparse65,
    "yard": _scene_yard,
}


@functools.cache
def _cached_builtin(name: str) -> Scene:
    return _BUILDERS[name]()  # Scenes are immutable, so sharing one instance is safe


def builtin_scene(name: str = DEFAULT_SCENE) -> Scene:
    """A built-in scene by name (one of :data:`BUILTIN_SCENES`); cell_size 1, origin (0, 0).

    default: 25x25, circle target (centre (20.5, 12.5), radius 3) at the right side, gaussian piles.
    corridor: 45x45, box target on the right edge, a band of piles leading to it.
    two_targets: 30x30, MultiPolygon of two circles in opposite corners.
    sparse65: 65x65, central circle target, ~15% of cells hold random counts 1..6.
    yard: 40x40, a box target on the bottom edge, two buildings, a fence and a parked machine
    (blocked cells), piles of material behind and between them.
    Counts are integers stored as floats, 0 on target cells.
    """
    if not isinstance(name, str) or name not in _BUILDERS:
        raise ValueError(f"builtin_scene: unknown scene {name!r}; choose one of "
                         f"{', '.join(BUILTIN_SCENES)}.")
    return _cached_builtin(name)


# --------------------------------------------------------------------------------------------------
# Random scenes
# --------------------------------------------------------------------------------------------------

LAYOUTS = ("uniform", "piles")


def _pile_side_target(rng, shape):
    """A round target near a random side of the grid (the ``piles`` layout)."""
    h, w = shape
    along = rng.uniform(0.3, 0.7)
    centre = [(w * along, 1.5), (w - 1.5, h * along), (w * along, h - 1.5), (1.5, h * along)][rng.integers(4)]
    return circle(centre, rng.uniform(1.2, 2.2), resolution=32)


def random_scene(seed: int, shape=(25, 25), density: float = 0.4, *, layout: str = "uniform",
                 max_count: int = 6) -> Scene:
    """A random scene, the same for the same arguments on every machine; cell size 1, origin (0, 0).

    layout "uniform" (the Table 2 protocol of the paper): integer counts 1..``max_count`` on a
    fraction ``density`` of the non-target cells, a central circular target of radius
    max(2.5, 0.1 min(H, W)) cells. layout "piles": gaussian piles of integer counts (at most
    ``max_count``; three piles, ``density`` unused) and a round target near a random side.
    Counts are 0 on target cells. Named ``random{H}x{W}_{layout}_d{density}_s{seed}``.
    """
    h, w = (int(s) for s in shape)
    if layout not in LAYOUTS:
        raise ValueError(f"random_scene: layout must be one of {LAYOUTS}; got {layout!r}.")
    if h < 3 or w < 3:
        raise ValueError(f"random_scene: shape must be at least 3 x 3 cells; got {tuple(shape)!r}.")
    if not 0.0 <= float(density) <= 1.0:
        raise ValueError(f"random_scene: density must lie in [0, 1]; got {density!r}.")
    rng = np.random.default_rng([h, w, int(round(float(density) * 1000)), int(seed), LAYOUTS.index(layout)])
    name = f"random{h}x{w}_{layout}_d{float(density):g}_s{int(seed)}"
    if layout == "uniform":
        target = circle((w / 2.0, h / 2.0), max(2.5, 0.1 * min(h, w)))
        occupied = rng.random((h, w)) < density
        obj = np.where(occupied, rng.integers(1, max_count + 1, size=(h, w)), 0).astype(np.float64)
    else:
        obj = _piles((h, w), [(rng.uniform(1.0, w - 1.0), rng.uniform(1.0, h - 1.0), rng.uniform(3.0, 6.0),
                               rng.uniform(1.0, 2.5)) for _ in range(3)], max_count)
        target = _pile_side_target(rng, (h, w))
    return _with_target_cleared(obj, target, name)
