"""Small sites for the fleet's tests: random scenes (uniform and piles layouts, one target) and a
two-target scene, one grid shape per call site so that each test module compiles once."""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
from shapely.geometry import MultiPolygon

from jaxplan import Scene, circle, random_scene
from jaxplan.transport import site_from_map

LAYOUTS = ("uniform", "piles", "two_targets", "buildings")
YARD = Path(__file__).parents[1] / "data" / "yard16.map"
"""A 16 x 16 MovingAI map with buildings, trees and water: the map-made site of the tests."""


@functools.cache
def site(seed: int, shape: tuple, layout: str) -> Scene:
    """A deterministic small site: ``random_scene`` for "uniform" (density 0.4) and "piles", or two
    round targets in opposite corners with random counts on 40% of the other cells, or "buildings":
    the uniform site with two random buildings (blocked rectangles) and scattered blocked cells, or
    "map": ``site_from_map`` on ``YARD`` (16 x 16 only)."""
    if layout == "map":
        return site_from_map(YARD, seed, n_targets=1)
    if layout == "buildings":
        return _with_buildings(random_scene(seed, shape, 0.4, layout="uniform"), seed)
    if layout != "two_targets":
        return random_scene(seed, shape, 0.4, layout=layout)
    h, w = shape
    rng = np.random.default_rng([seed, h, w])
    target = MultiPolygon([circle((1.8, h - 1.8), 1.6, resolution=16), circle((w - 1.8, 1.8), 1.6, resolution=16)])
    obj = np.where(rng.random(shape) < 0.4, rng.integers(1, 6, shape), 0).astype(np.float32)
    scene = Scene.from_arrays(np.zeros(shape, np.float32), target, name=f"two_targets_{seed}")
    return scene.with_obj(np.where(np.asarray(scene.target_mask), 0.0, obj))


def _with_buildings(scene: Scene, seed: int) -> Scene:
    h, w = scene.shape
    rng = np.random.default_rng([seed, h, w, 7])
    blocked = rng.random((h, w)) < 0.04
    for _ in range(2):
        r, c = rng.integers(1, h - 3), rng.integers(1, w - 3)
        blocked[r:r + rng.integers(2, 4), c:c + rng.integers(2, 5)] = True
    blocked &= ~np.asarray(scene.target_mask)
    obj = np.where(blocked, 0.0, np.asarray(scene.obj))
    return Scene.from_arrays(obj, scene.target, blocked=blocked, name=f"buildings_{seed}")


def owner_map(rng, shape, n_rovers: int):
    """i32[H, W]: up to three random rectangles (1 to 4 cells a side) given to random rovers of
    ``n_rovers``; -1 elsewhere."""
    owner = np.full(shape, -1, np.int32)
    for _ in range(rng.integers(0, 4)):
        r, c = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        owner[r:r + rng.integers(1, 5), c:c + rng.integers(1, 5)] = rng.integers(0, n_rovers)
    return owner
