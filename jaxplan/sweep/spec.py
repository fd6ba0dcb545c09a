"""Sweep specs: the TOML/dict a user writes, validated into a ``SweepSpec``, and its settings in order.

A spec's settings are the product of its lists, bounded by ``MAX_SETTINGS`` before anything is built
and never held as a list: ``settings_of`` computes setting i from i.
"""
from __future__ import annotations

import dataclasses
import math
import os
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import jax

from jaxplan.core import path_kind, read_text
from jaxplan.transport import (
    BUILTIN_SCENES,
    MAX_FILE_SIDE,
    FabricParams,
    Scene,
    builtin_scene,
    random_scene,
    site_from_map,
    validate_params,
)
from jaxplan.transport.spillage import SpillParams, validate_spill_params

__all__ = ["MAX_SETTINGS", "METRICS", "REFUSED", "Settings", "SweepSpec", "columns_of", "load_spec", "settings_of",
           "tables_of"]

# A sweep writes one CSV row per setting; ten million rows are a gigabyte of CSV and days of work on a
# CPU. A larger product is refused before any scene is built.
MAX_SETTINGS = 10_000_000

# Every field a spec accepts changes some metric; the others are refused with the reason (REFUSED), so
# that no swept column is silently ignored. FabricParams fields are listed explicitly: a field added
# there is refused as unknown until it is listed here (tests/sweep holds every field to one of the two).
FABRIC_TRACED = ("theta_tol_deg", "tau_h", "slack_tau")
FABRIC_STATIC = ("monotone", "k", "max_hops", "highway_relative", "highway_smoothing", "highway_nms", "solver")
REFUSED = {
    "temperature": "sweeps build the hard fabric (their metrics read its continuation table); a temperature > 0 "
                   "builds the soft fabric, a relaxation for gradients: tune it with jaxplan.tune (fit_fabric)",
    "anchor_lambda": "it only weighs connectors (Eq. 12), which a sweep does not compute, so every row would be "
                     "equal; compare it with jaxplan.plan_connectors or in episodes (jaxplan episode)",
    "soft_rounds": "it only sets the soft fabric's rounds, and sweeps build the hard fabric",
}
# the spill model's fields, all read by the route metrics (top_delivered)
SPILL_TRACED = tuple(p[0].name for p, _ in jax.tree_util.tree_flatten_with_path(SpillParams())[0])
SPILL_STATIC = tuple(f.name for f in dataclasses.fields(SpillParams) if f.name not in SPILL_TRACED)
_TOP_KEYS = ("scenes", "site_seed", "random_scenes", "fabric", "spill", "static", "metrics")

METRICS = {
    "occupied_cells": "non-target cells with obj > 0",
    "total_mass": "objects on the grid (target cells included)",
    "mean_value": "mean J(C) over occupied cells, objects",
    "mean_length": "mean L(C) over occupied cells, world units",
    "highway_cells": "highway cells (Eq. 11)",
    "max_heat": "largest heatmap value (Eq. 10), objects",
    "solver_rounds": "solver iterations of the DP",
    "converged": "the DP reached its fixed point",
    "top_collected": "raw count (Eq. 5) of the selected routes of the top_sources cells with the largest J, objects",
    "top_delivered": "delivered mass (Eq. 6, spill model) of those routes, objects; = top_collected "
                     "when spill.enabled is false",
    "routes_truncated": "a selected route of those sources is longer than max_steps (its numbers are partial)",
}
# Fabric fields that do not enter the DP table: tau_h only thresholds the heatmap into highways,
# slack_tau only widens the route candidate set. Settings differing only in these (and in spill
# parameters) share one build_fabric.
AFTER_TABLE = ("tau_h", "slack_tau")
PAD = "__pad__"


# --------------------------------------------------------------------------------------------------
# Spec
# --------------------------------------------------------------------------------------------------

class SweepSpec(NamedTuple):
    """A validated sweep spec.

    scenes: tuple of (label, Scene), the label written in the ``scene`` column.
    fabric_grid / spill_grid: tuple of (field, tuple of float values), in spec order.
    fabric_static / spill_static: dict of static fields. top_sources: int >= 0. max_steps: int or None
    (default: H + W + 1 per grid shape).
    """

    scenes: tuple
    fabric_grid: tuple
    spill_grid: tuple
    fabric_static: dict
    spill_static: dict
    top_sources: int
    max_steps: int | None


def _fail(key: str, message: str):
    raise ValueError(f"sweep spec: {key}: {message}")


def _finite(v) -> bool:
    try:
        return math.isfinite(float(v))
    except OverflowError:   # an int beyond float range
        return False


def _short(v) -> str:
    text = repr(v)
    return text if len(text) <= 40 else f"{text[:20]}... ({len(text)} characters)"


def _values(key: str, raw) -> tuple:
    vals = raw if isinstance(raw, (list, tuple)) else [raw]
    if not vals:
        _fail(key, "an empty list; give at least one value, e.g. [45.0, 60.0].")
    out = []
    for v in vals:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not _finite(v):
            _fail(key, f"expected a finite number or a list of them; got {_short(v)}.")
        out.append(float(v))
    return tuple(out)


def _site_seed(spec: dict) -> int:
    """The seed that places targets and piles on the spec's ``.map`` sites (``site_seed``, default 0)."""
    seed = spec.get("site_seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2 ** 32:
        _fail("site_seed", f"expected an int in [0, 2^32) (the seed of the .map sites' targets and piles); "
              f"got {_short(seed)}.")
    return seed


def _scenes(spec: dict, base: Path | None) -> tuple:
    out = []
    names = spec.get("scenes", [])
    if isinstance(names, str):
        names = [names]
    if not isinstance(names, list):
        _fail("scenes", f"expected a list of built-in names or scene files; got {names!r}.")
    for name in names:
        if not isinstance(name, str):
            _fail("scenes", f"expected strings (built-in names or file paths); got {name!r}.")
        if name in BUILTIN_SCENES:
            out.append((name, builtin_scene(name)))
            continue
        path = Path(name)
        if not path.is_absolute() and base is not None:
            path = base / path
        try:
            kind = path_kind(path)
        except ValueError as exc:
            _fail("scenes", str(exc))
        if kind == "dir":
            _fail("scenes", f"{name!r} is a directory ({path}); give a .npz/.json scene file or a built-in "
                  f"scene ({', '.join(BUILTIN_SCENES)}).")
        if kind == "missing":
            _fail("scenes", f"{name!r} is neither a built-in scene ({', '.join(BUILTIN_SCENES)}) nor an existing "
                  ".npz/.json scene file or .map site.")
        try:   # both name the file and what is wrong with it
            scene = site_from_map(path, _site_seed(spec)) if path.suffix.lower() == ".map" else Scene.load(path)
        except ValueError as exc:
            _fail("scenes", str(exc))
        out.append((name, scene))
    rnd = spec.get("random_scenes")
    if rnd is not None:
        if not isinstance(rnd, dict):
            _fail("random_scenes", "expected a table with seeds, shape and density.")
        unknown = set(rnd) - {"seeds", "shape", "density"}
        if unknown:
            _fail(f"random_scenes.{sorted(unknown)[0]}", "unknown key; use seeds, shape and density.")
        seeds = rnd.get("seeds")
        if not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) and s >= 0 for s in seeds):
            _fail("random_scenes.seeds", f"expected a non-empty list of ints >= 0; got {seeds!r}.")
        shape = rnd.get("shape", [25, 25])
        if (not isinstance(shape, list) or len(shape) != 2
                or not all(isinstance(s, int) and not isinstance(s, bool) and 3 <= s <= MAX_FILE_SIDE for s in shape)):
            _fail("random_scenes.shape", f"expected [H, W] with ints in [3, {MAX_FILE_SIDE}] (the largest grid a "
                  f"scene file holds); got {shape!r}.")
        density = rnd.get("density", 0.4)
        if isinstance(density, bool) or not isinstance(density, (int, float)) or not 0 < density <= 1:
            _fail("random_scenes.density", f"expected a fraction in (0, 1]; got {density!r}.")
        out += [(f"random:{s}", random_scene(s, tuple(shape), float(density))) for s in seeds]
    if not out:
        _fail("scenes", "no scenes; give scenes = [\"default\"] and/or a [random_scenes] table.")
    return tuple(out)


def _grid(spec: dict, section: str, traced: tuple, static: tuple) -> tuple:
    table = spec.get(section, {})
    if not isinstance(table, dict):
        _fail(section, f"expected a table of field = value or [values]; got {table!r}.")
    out = []
    for key, raw in table.items():
        if key in REFUSED and section == "fabric":
            _fail(f"{section}.{key}", f"not sweepable: {REFUSED[key]}.")
        if key in static:
            _fail(f"{section}.{key}", "a static field (it changes the compiled program); put it under [static].")
        if key not in traced:
            _fail(f"{section}.{key}", f"unknown field; the sweepable fields are {', '.join(traced)}.")
        out.append((key, _values(f"{section}.{key}", raw)))
    return tuple(out)


def _read_toml(path: Path) -> dict:
    """The TOML table of the spec file ``path``; a one-line ValueError ``sweep spec: <path>: ...``
    for a missing, unreadable, empty, binary or malformed file."""
    try:
        text = read_text(path, 'a TOML spec file, e.g. scenes = ["default"] (docs/sweeps.md)')
    except ValueError as exc:
        raise ValueError(f"sweep spec: {path}: {exc}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"sweep spec: {path}: not valid TOML ({exc}).") from None
    except RecursionError:   # tomllib parses nested arrays and inline tables recursively
        raise ValueError(f"sweep spec: {path}: nested too deeply to read (arrays or inline tables inside "
                         "one another hundreds of levels deep); a spec needs two levels.") from None


def load_spec(spec: dict | str | os.PathLike) -> SweepSpec:
    """Validate a spec dict or read a TOML file; scene files are relative to the TOML file's folder.

    Raises ``ValueError`` naming the bad key and the fix.
    """
    base = None
    if not isinstance(spec, dict):
        path = Path(spec)
        spec = _read_toml(path)
        base = path.parent
    unknown = [k for k in spec if k not in _TOP_KEYS]
    if unknown:
        _fail(unknown[0], f"unknown key; the spec's keys are {', '.join(_TOP_KEYS)}.")
    fabric_grid = _grid(spec, "fabric", FABRIC_TRACED, FABRIC_STATIC)
    # the fields that change the DP table first: settings sharing a table are then contiguous
    fabric_grid = tuple(sorted(fabric_grid, key=lambda kv: kv[0] in AFTER_TABLE))
    spill_grid = _grid(spec, "spill", SPILL_TRACED, SPILL_STATIC)
    _check_size(_scene_count(spec), fabric_grid + spill_grid)
    static = spec.get("static", {})
    if not isinstance(static, dict):
        _fail("static", "expected a table of static fields, e.g. k = 4.")
    for key in static:
        if key in REFUSED:
            _fail(f"static.{key}", f"not sweepable: {REFUSED[key]}.")
        if key in FABRIC_TRACED or key in SPILL_TRACED:
            _fail(f"static.{key}", "a traced field; put it under [fabric] or [spill] (a value or a list).")
        if key not in FABRIC_STATIC and key not in SPILL_STATIC:
            _fail(f"static.{key}", f"unknown field; the static fields are {', '.join(FABRIC_STATIC + SPILL_STATIC)}.")
    fabric_static = {k: v for k, v in static.items() if k in FABRIC_STATIC}
    spill_static = {k: v for k, v in static.items() if k in SPILL_STATIC}
    # every value through the parameter classes' own validation (their errors name the field)
    for key, vals in fabric_grid:
        for v in vals:
            validate_params(FabricParams(**fabric_static, **{key: v}))
    validate_params(FabricParams(**fabric_static))
    for key, vals in spill_grid:
        for v in vals:
            validate_spill_params(SpillParams(**spill_static, **{key: v}))
    validate_spill_params(SpillParams(**spill_static))
    metrics = spec.get("metrics", {})
    if not isinstance(metrics, dict) or set(metrics) - {"top_sources", "max_steps"}:
        _fail("metrics", "expected a table with top_sources (int >= 0) and optionally max_steps (int >= 1).")
    top = metrics.get("top_sources", 4)
    if isinstance(top, bool) or not isinstance(top, int) or top < 0:
        _fail("metrics.top_sources", f"expected an int >= 0 (0 turns the route metrics off); got {top!r}.")
    max_steps = metrics.get("max_steps")
    if max_steps is not None and (isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1):
        _fail("metrics.max_steps", f"expected an int >= 1 (route walk length); got {max_steps!r}.")
    _check_routes_read(fabric_grid, spill_grid, spill_static, top)
    return SweepSpec(_scenes(spec, base), fabric_grid, spill_grid, fabric_static, spill_static, top, max_steps)


def _scene_count(spec: dict) -> int:
    """How many scenes the spec names (its lists' lengths; the scenes are checked when built)."""
    names = spec.get("scenes", [])
    rnd = spec.get("random_scenes")
    seeds = rnd.get("seeds") if isinstance(rnd, dict) else None
    return max(1, (1 if isinstance(names, str) else len(names) if isinstance(names, list) else 0)
               + (len(seeds) if isinstance(seeds, list) else 0))


def _check_size(n_scenes: int, grid: tuple) -> None:
    """Refuse a product of more than ``MAX_SETTINGS`` settings, from the lists' lengths alone."""
    total = n_scenes * math.prod(len(vals) for _, vals in grid)
    if total > MAX_SETTINGS:
        sizes = " x ".join([f"{n_scenes} scene(s)"] + [f"{len(vals)} {key}" for key, vals in grid])
        _fail("spec", f"{total:,} settings ({sizes}); a sweep holds at most {MAX_SETTINGS:,} (one CSV row "
              "each). Shorten the lists or split the sweep into several specs.")


def _check_routes_read(fabric_grid, spill_grid, spill_static: dict, top: int) -> None:
    """Refuse route-selection fields that the route metrics would not read: every spill field and
    slack_tau with ``metrics.top_sources = 0`` (no route metric), and the spill model's fields and
    slack_tau with ``static.enabled = false`` (routes by raw count, Eq. 5: no spill, entry 0)."""
    named = [f"spill.{k}" for k, _ in spill_grid] + [f"static.{k}" for k in spill_static]
    named += [f"fabric.{k}" for k, _ in fabric_grid if k == "slack_tau"]
    if top == 0 and named:
        _fail(named[0], "metrics.top_sources = 0 turns the route metrics off, and only they read the route "
              "selection (slack_tau) and the spill model, so every row would be equal; set "
              "metrics.top_sources >= 1 or drop the field.")
    if spill_static.get("enabled", True) is False:
        ignored = [n for n in named if n != "static.enabled"]
        if ignored:
            _fail(ignored[0], "static.enabled = false selects routes by raw count (Eq. 5, entry 0) without a "
                  "spill model, so every row would be equal; drop the field or enabled = false.")


class Settings(Sequence):
    """The settings of a spec in sweep order, computed from their index (nothing is held but the
    lists): setting i is ``(scene_index, fabric_values, spill_values)``. Scene-major, then the lists in
    order, the last one fastest, as ``itertools.product`` would list them."""

    def __init__(self, n_scenes: int, fabric_lists: list, spill_lists: list):
        self._lists = [tuple(v) for v in (*fabric_lists, *spill_lists)]
        self._n_fabric = len(fabric_lists)
        self._per_scene = math.prod(len(v) for v in self._lists)
        self._n = n_scenes * self._per_scene

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(self._n))]
        if i < 0:
            i += self._n
        if not 0 <= i < self._n:
            raise IndexError(f"setting {i} of {self._n}")
        scene, rest = divmod(i, self._per_scene)
        combo = []
        for values in reversed(self._lists):
            rest, k = divmod(rest, len(values))
            combo.append(values[k])
        combo.reverse()
        return scene, tuple(combo[:self._n_fabric]), tuple(combo[self._n_fabric:])


def settings_of(spec: SweepSpec) -> Settings:
    """Every setting as ``(scene_index, fabric_values, spill_values)`` in sweep order (scene-major, then
    ``spec.fabric_grid`` -- the fields that change the DP table first -- then ``spec.spill_grid``), as a
    lazy sequence."""
    return Settings(len(spec.scenes), [vals for _, vals in spec.fabric_grid], [vals for _, vals in spec.spill_grid])


def columns_of(spec: SweepSpec) -> list[str]:
    """The CSV header: setting, scene, the swept fields, then ``METRICS``."""
    return (["setting", "scene"] + [k for k, _ in spec.fabric_grid] + [f"spill_{k}" for k, _ in spec.spill_grid]
            + list(METRICS))


def tables_of(spec: SweepSpec):
    """``(table_keys, per_table)``: the swept fabric fields that change the DP table (in grid order), and
    the number of settings sharing one table (the product of every other swept field's list length)."""
    table_keys = tuple(k for k, _ in spec.fabric_grid if k not in AFTER_TABLE)
    per_table = math.prod(len(v) for k, v in spec.fabric_grid if k in AFTER_TABLE) * \
        math.prod(len(v) for _, v in spec.spill_grid)
    return table_keys, per_table


