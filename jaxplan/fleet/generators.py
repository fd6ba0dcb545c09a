"""Built-in fleet sites: large deterministic scenes with several targets and many piles.

Every site is built in code from a fixed seed (no data files), so it is the same array on every
machine and in every run. The counts are integers (stored as floats, at most :data:`MAX_COUNT` per
cell) from gaussian piles spread over the whole site, as in ``random_scene``'s ``piles`` layout but
with many piles; target cells hold no counts (what lies there is already delivered).

- ``site128``: 128 x 128 cells, 2 targets (circles of radius 7 in opposite corners), 32 piles;
- ``site256``: 256 x 256 cells, 3 targets (circles of radius 10 and 9, a 20 x 16 box), 128 piles;
- ``site512``: 512 x 512 cells, 4 targets (circles of radius 14, 12, 12, a 32 x 26 box), 512 piles;
- ``site1024``: 1024 x 1024 cells, 8 targets (six circles of radius 12 to 18, two boxes), 2048
  piles, and 12 buildings (blocked rectangles, ``_BUILDINGS_1024``; 2.9% of the cells): halls,
  a long wall and a row of sheds. Piles do not reach into buildings.

Cell size 1, origin (0, 0); the exact shapes are the ``_targets_*`` functions below. One pile per
512 cells keeps the material density the same on every site (about 1 object per 4 cells, 1 cell in
8 occupied): a site four times larger holds about four times the mass (site128: 4182 objects,
site256: 15252, site512: 65867, site1024: about 4 times site512's).
"""
from __future__ import annotations

import functools

import numpy as np
from shapely.geometry import MultiPolygon

from jaxplan.transport import Scene, box, circle

__all__ = ["MAX_COUNT", "SITES", "build_site", "site"]

# Most objects one cell holds (the ``max_count`` of random_scene).
MAX_COUNT = 6
# Cells per pile: the piles' count grows with the site's area.
_CELLS_PER_PILE = 512
# A pile is evaluated within this many sigmas of its centre (exp(-18) ~ 1.5e-8: rounds to 0).
_PILE_REACH = 6.0
# No pile centre this close (cells) to the grid border: the border is where rovers start.
_BORDER = 3.0


def _targets_128():
    return MultiPolygon([circle((30.5, 96.5), 7.0), circle((100.5, 28.5), 7.0)])


def _targets_256():
    return MultiPolygon([circle((56.5, 196.5), 10.0), circle((200.5, 180.5), 9.0),
                         box(120.0, 40.0, 140.0, 56.0)])


def _targets_512():
    return MultiPolygon([circle((110.5, 400.5), 14.0), circle((400.5, 410.5), 12.0),
                         circle((130.5, 110.5), 12.0), box(360.0, 90.0, 392.0, 116.0)])


def _targets_1024():
    return MultiPolygon([circle((200.5, 820.5), 16.0), circle((820.5, 830.5), 14.0), circle((250.5, 220.5), 14.0),
                         circle((512.5, 520.5), 18.0), circle((110.5, 500.5), 12.0), circle((640.5, 120.5), 12.0),
                         box(740.0, 180.0, 780.0, 212.0), box(900.0, 480.0, 932.0, 512.0)])


# (row, col, rows, cols) of site1024's buildings: halls, a long wall with open ends, a row of sheds
_BUILDINGS_1024 = (
    (300, 380, 60, 90), (600, 300, 100, 40), (650, 600, 40, 160), (380, 700, 40, 100), (150, 450, 80, 70),
    (820, 420, 80, 60), (450, 150, 20, 180), (880, 620, 60, 80), (250, 860, 50, 80), (700, 880, 60, 40),
    (940, 120, 30, 30), (940, 200, 30, 30),
)


def _buildings(side: int, rects) -> np.ndarray:
    blocked = np.zeros((side, side), bool)
    for r, c, rows, cols in rects:
        blocked[r:r + rows, c:c + cols] = True
    return blocked


# name -> (side, targets builder, seed, buildings)
_LAYOUTS = {
    "site128": (128, _targets_128, 128_2026, ()),
    "site256": (256, _targets_256, 256_2026, ()),
    "site512": (512, _targets_512, 512_2026, ()),
    "site1024": (1024, _targets_1024, 1024_2026, _BUILDINGS_1024),
}
SITES: tuple[str, ...] = tuple(_LAYOUTS)


def _pile_counts(side: int, rng) -> np.ndarray:
    """Integer counts ``f64[side, side]`` (0..MAX_COUNT) from ``side**2 / _CELLS_PER_PILE`` piles.

    Each pile is a gaussian ``amp * exp(-r^2 / (2 sigma^2))`` with amp in [3, 6.5] objects and sigma
    in [1.2, 3] cells, centred uniformly at least ``_BORDER`` cells inside the grid; piles add, then
    the sum is rounded and clipped to MAX_COUNT. Each pile touches only its own window of cells, so
    building the counts costs O(piles * sigma^2), not O(piles * H * W).
    """
    n = side * side // _CELLS_PER_PILE
    cx = rng.uniform(_BORDER, side - _BORDER, n)
    cy = rng.uniform(_BORDER, side - _BORDER, n)
    amp = rng.uniform(3.0, 6.5, n)
    sigma = rng.uniform(1.2, 3.0, n)
    obj = np.zeros((side, side))
    for x, y, a, s in zip(cx, cy, amp, sigma):
        reach = _PILE_REACH * s
        c0, c1 = max(0, int(x - reach)), min(side, int(x + reach) + 1)
        r0, r1 = max(0, int(y - reach)), min(side, int(y + reach) + 1)
        ys, xs = np.mgrid[r0:r1, c0:c1] + 0.5
        obj[r0:r1, c0:c1] += a * np.exp(-((xs - x) ** 2 + (ys - y) ** 2) / (2.0 * s * s))
    return np.clip(np.rint(obj), 0, MAX_COUNT)


def _check_name(name) -> None:
    if not isinstance(name, str) or name not in _LAYOUTS:
        raise ValueError(f"site: unknown fleet site {name!r}; choose one of {', '.join(SITES)}.")


def build_site(name: str) -> Scene:
    """Build the fleet site ``name`` afresh (no cache; :func:`site` is the cached one).

    About a second on 2 CPU cores for ``site512`` or ``site1024`` once the geometry kernels are
    compiled.
    """
    _check_name(name)
    side, targets, seed, rects = _LAYOUTS[name]
    target = targets()
    obj = _pile_counts(side, np.random.default_rng(seed))
    blocked = _buildings(side, rects) if rects else None
    scene = Scene.from_arrays(np.zeros_like(obj), target, name=name, blocked=blocked)
    # material on a target cell is already delivered: the site starts with none there
    empty = np.asarray(scene.target_mask) | np.asarray(scene.blocked)
    return scene.with_obj(np.where(empty, 0.0, obj))


@functools.cache
def _cached(name: str) -> Scene:
    return build_site(name)   # Scenes are immutable, so sharing one instance is safe


def site(name: str) -> Scene:
    """The built-in fleet site ``name`` (one of :data:`SITES`); cell size 1, origin (0, 0).

    Deterministic: the same counts and geometry on every call and machine (built once per process
    and shared; Scenes are immutable). Raises ValueError naming the choices for an unknown name.
    """
    _check_name(name)
    return _cached(name)
