"""Small sites for the fleet's tests: random scenes (uniform and piles layouts, one target) and a
two-target scene, one grid shape per call site so that each test module compiles once."""
from __future__ import annotations

import functools

import numpy as np
from shapely.geometry import MultiPolygon

from jaxplan import Scene, circle, random_scene

LAYOUTS = ("uniform", "piles", "two_targets")


@functools.cache
def site(seed: int, shape: tuple, layout: str) -> Scene:
    """A deterministic small site: ``random_scene`` for "uniform" (density 0.4) and "piles", or two
    round targets in opposite corners with random counts on 40% of the other cells."""
    if layout != "two_targets":
        return random_scene(seed, shape, 0.4, layout=layout)
    h, w = shape
    rng = np.random.default_rng([seed, h, w])
    target = MultiPolygon([circle((1.8, h - 1.8), 1.6, resolution=16), circle((w - 1.8, 1.8), 1.6, resolution=16)])
    obj = np.where(rng.random(shape) < 0.4, rng.integers(1, 6, shape), 0).astype(np.float32)
    scene = Scene.from_arrays(np.zeros(shape, np.float32), target, name=f"two_targets_{seed}")
    return scene.with_obj(np.where(np.asarray(scene.target_mask), 0.0, obj))
