"""Parameter sweeps: the cartesian product of a spec, evaluated in ``vmap``ped chunks, one CSV row per setting.

A **spec** (a TOML file or the equivalent dict) names the scenes and, per traced parameter, a value or a
list of values; static configuration is fixed for the whole sweep::

    scenes = ["default", "site.npz"]            # built-in names or scene files (.npz / .json)
    [random_scenes]                             # optional: random scenes of one shape, one per seed
    seeds = [0, 1, 2]
    shape = [25, 25]
    density = 0.4                               # fraction of cells holding 1..6 objects
    [fabric]                                    # traced FabricParams fields
    theta_tol_deg = [30.0, 45.0, 60.0]
    tau_h = [0.3, 0.5]
    [spill]                                     # traced SpillParams fields
    lam = [0.0, 0.05]
    [static]                                    # static FabricParams / SpillParams fields
    k = 4
    [metrics]
    top_sources = 4                             # Eq. 6 delivered mass of the best N sources (0 = off)

Settings are ordered scene-major, then by the ``[fabric]`` fields that change the DP table (all but
``tau_h``, ``slack_tau``, ``anchor_lambda``), then the other ``[fabric]`` fields, then ``[spill]``, each
group in the order given, the last varying fastest; ``setting`` (0-based) is the row's position in that
order. So the settings sharing one DP table (same scene and table fields) are contiguous: a chunk holds
U such tables, runs ``build_fabric`` once per table and evaluates the M settings of each table with a
``vmap`` (highways for their tau_h, Eq. 6 routes for their slack and spill parameters), all in one
``jit``; over the U tables a ``vmap`` on accelerators, a ``lax.map`` on CPU (see ``_chunk_kernel`` and
docs/sweeps.md). Chunks hold one grid shape and are padded to a fixed size per shape (one compile per
shape), and their boundaries are fixed, so a resumed run computes every setting exactly as an
uninterrupted one. U comes from a memory budget
(``chunk_size_for``). Rows are appended and flushed chunk by chunk, so an interrupted sweep resumes:
rows already in the output file are kept (a torn last line is dropped) and only the missing chunks are
evaluated. The resumed file is byte-identical to an uninterrupted run.

Backends: ``"local"`` evaluates chunks in this process; ``"ray"`` (``jaxplan._sweep_ray``, the optional
extra ``jaxplan[distributed]``) runs each chunk as a Ray task with retries. Both call ``evaluate_chunk``,
so they give identical rows.
"""
from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import os
import tomllib
from pathlib import Path
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan import fabric as _fabric
from jaxplan import heatmap as _heatmap
from jaxplan import params as _params
from jaxplan import selection as _selection
from jaxplan.params import FabricParams, validate_params
from jaxplan.scene import BUILTIN_SCENES, Scene, builtin_scene, circle
from jaxplan.spillage import SpillParams, validate_spill_params

__all__ = ["METRICS", "SweepSpec", "bytes_per_table", "chunk_size_for", "columns_of", "evaluate_chunk", "load_spec",
           "random_scene", "run_sweep", "settings_of"]

# Traced fields read from the parameter classes, so a field added there is sweepable at once.
FABRIC_TRACED = tuple(_params._TRACED)
FABRIC_STATIC = tuple(_params._STATIC)
SPILL_TRACED = tuple(p[0].name for p, _ in jax.tree_util.tree_flatten_with_path(SpillParams())[0])
SPILL_STATIC = tuple(f.name for f in dataclasses.fields(SpillParams) if f.name not in SPILL_TRACED)
_TOP_KEYS = ("scenes", "random_scenes", "fabric", "spill", "static", "metrics")

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
# slack_tau only widens the route candidate set, anchor_lambda only weighs connectors (not computed
# here). Settings differing only in these (and in spill parameters) share one build_fabric.
_AFTER_TABLE = ("tau_h", "slack_tau", "anchor_lambda")
# Per-setting bytes = this factor x (the fabric's output bytes + the scene's bytes): the DP's working
# set (tables of several candidates per direction) is a few times its output.
_WORKSPACE_FACTOR = 4
_PAD = "__pad__"


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


def _values(key: str, raw) -> tuple:
    vals = raw if isinstance(raw, (list, tuple)) else [raw]
    if not vals:
        _fail(key, "an empty list; give at least one value, e.g. [45.0, 60.0].")
    out = []
    for v in vals:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
            _fail(key, f"expected a finite number or a list of them; got {v!r}.")
        out.append(float(v))
    return tuple(out)


def random_scene(seed: int, shape, density: float) -> Scene:
    """A random scene: counts 1..6 on a fraction ``density`` of the cells, a circular target of radius
    max(1, 0.1 min(H, W)) cells at the grid centre (the benchmarks' instances). Named ``random:SEED``."""
    h, w = shape
    rng = np.random.default_rng(seed)
    counts = rng.integers(1, 7, (h, w)).astype(np.float32)
    obj = np.where(rng.random((h, w)) < density, counts, 0.0).astype(np.float32)
    target = circle((w / 2, h / 2), max(1.0, 0.1 * min(h, w)), resolution=64)
    scene = Scene.from_arrays(np.zeros_like(obj), target, name=f"random:{seed}")
    return scene.with_obj(np.where(np.asarray(scene.target_mask), 0.0, obj))


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
        if not path.is_file():
            _fail("scenes", f"{name!r} is neither a built-in scene ({', '.join(BUILTIN_SCENES)}) nor an existing "
                  ".npz/.json scene file.")
        out.append((name, Scene.load(path)))
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
                or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 3 for s in shape)):
            _fail("random_scenes.shape", f"expected [H, W] with ints >= 3; got {shape!r}.")
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
        if key in static:
            _fail(f"{section}.{key}", "a static field (it changes the compiled program); put it under [static].")
        if key not in traced:
            _fail(f"{section}.{key}", f"unknown field; the traced fields are {', '.join(traced)}.")
        out.append((key, _values(f"{section}.{key}", raw)))
    return tuple(out)


def load_spec(spec: dict | str | os.PathLike) -> SweepSpec:
    """Validate a spec dict or read a TOML file; scene files are relative to the TOML file's folder.

    Raises ``ValueError`` naming the bad key and the fix.
    """
    base = None
    if not isinstance(spec, dict):
        path = Path(spec)
        if not path.is_file():
            raise ValueError(f"sweep spec: no such file {str(path)!r}; give a TOML file or a dict.")
        try:
            spec = tomllib.loads(path.read_text())
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"sweep spec: {path}: not valid TOML ({exc}).") from None
        base = path.parent
    unknown = [k for k in spec if k not in _TOP_KEYS]
    if unknown:
        _fail(unknown[0], f"unknown key; the spec's keys are {', '.join(_TOP_KEYS)}.")
    fabric_grid = _grid(spec, "fabric", FABRIC_TRACED, FABRIC_STATIC)
    # the fields that change the DP table first: settings sharing a table are then contiguous
    fabric_grid = tuple(sorted(fabric_grid, key=lambda kv: kv[0] in _AFTER_TABLE))
    spill_grid = _grid(spec, "spill", SPILL_TRACED, SPILL_STATIC)
    static = spec.get("static", {})
    if not isinstance(static, dict):
        _fail("static", "expected a table of static fields, e.g. k = 4.")
    for key in static:
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
    return SweepSpec(_scenes(spec, base), fabric_grid, spill_grid, fabric_static, spill_static, top, max_steps)


def settings_of(spec: SweepSpec) -> list[tuple]:
    """Every setting as ``(scene_index, fabric_values, spill_values)`` in sweep order (scene-major, then
    ``spec.fabric_grid`` -- the fields that change the DP table first -- then ``spec.spill_grid``)."""
    fabric_lists = [vals for _, vals in spec.fabric_grid]
    spill_lists = [vals for _, vals in spec.spill_grid]
    return [(i, combo[:len(fabric_lists)], combo[len(fabric_lists):])
            for i in range(len(spec.scenes))
            for combo in itertools.product(*fabric_lists, *spill_lists)]


def columns_of(spec: SweepSpec) -> list[str]:
    """The CSV header: setting, scene, the swept fields, then ``METRICS``."""
    return (["setting", "scene"] + [k for k, _ in spec.fabric_grid] + [f"spill_{k}" for k, _ in spec.spill_grid]
            + list(METRICS))


def _split(spec: SweepSpec):
    """``(table_keys, per_table)``: the swept fabric fields that change the DP table (in grid order), and
    the number of settings sharing one table (the product of every other swept field's list length)."""
    table_keys = tuple(k for k, _ in spec.fabric_grid if k not in _AFTER_TABLE)
    per_table = math.prod(len(v) for k, v in spec.fabric_grid if k in _AFTER_TABLE) * \
        math.prod(len(v) for _, v in spec.spill_grid)
    return table_keys, per_table


# --------------------------------------------------------------------------------------------------
# The vmapped kernel
# --------------------------------------------------------------------------------------------------

def _metrics(scene, fp: FabricParams, sp: SpillParams, top: int, max_steps: int, fab=None) -> dict:
    """The per-setting metrics (``METRICS``) of one scene and parameter setting; vmappable.

    fab: the fabric of ``scene`` under ``fp`` (built here when None).
    """
    fab = _fabric._build(scene, fp) if fab is None else fab
    occ = fab.occupied
    n = jnp.sum(occ)
    denom = jnp.maximum(n, 1).astype(jnp.float32)
    out = dict(occupied_cells=n.astype(jnp.int32), total_mass=jnp.sum(scene.obj),
               mean_value=jnp.sum(fab.value) / denom, mean_length=jnp.sum(fab.length) / denom,
               highway_cells=jnp.sum(fab.highways).astype(jnp.int32), max_heat=jnp.max(fab.heat),
               solver_rounds=fab.rounds.astype(jnp.int32), converged=fab.converged)
    if top == 0:
        zero = jnp.float32(0.0)
        return dict(out, top_collected=zero, top_delivered=zero, routes_truncated=jnp.bool_(False))
    h, w = scene.obj.shape
    scores = jnp.where(occ, fab.value, -jnp.inf).reshape(-1)
    best, idx = jax.lax.top_k(scores, top)
    valid = best > -jnp.inf
    sources = jnp.stack([idx // w, idx % w], -1).astype(jnp.int32)
    sel = _selection.select_routes(scene, fab, sources, fp.slack_tau, sp, max_steps=max_steps)
    entry = sel.entry[:, None]
    raw = jnp.take_along_axis(fab.table.raw[sources[:, 0], sources[:, 1]], entry, -1)[:, 0]
    delivered = jnp.take_along_axis(sel.delivered, entry, -1)[:, 0]
    hops = jnp.take_along_axis(_fabric._table_hops(fab.table)[sources[:, 0], sources[:, 1]], entry, -1)[:, 0]
    # +1: a route ending in a boundary fallback takes one more walk step (conservative for the others)
    truncated = valid & (hops + 1 > max_steps)
    return dict(out, top_collected=jnp.sum(jnp.where(valid, raw, 0.0)),
                top_delivered=jnp.sum(jnp.where(valid, delivered, 0.0)), routes_truncated=jnp.any(truncated))


def _with_highways(fab, scene, fp: FabricParams):
    """``fab`` with its highways (Eq. 11) recomputed for ``fp.tau_h``: the only part of the fabric that
    depends on a field in ``_AFTER_TABLE``."""
    highways = _heatmap.highways(fab.heat, jnp.asarray(scene.target_mask, bool), fp.tau_h,
                                 relative=fp.highway_relative, smoothing=fp.highway_smoothing, nms=fp.highway_nms)
    return fab._replace(highways=highways)


def _outer_mode(tables: str) -> str:
    """``"vmap"`` or ``"map"`` for ``tables="auto"``: ``vmap`` on accelerators, ``lax.map`` on CPU, where a
    batched DP (batched gathers, while loops that select over their whole state) measured slower than
    one table at a time (experiments/results/sweep.md)."""
    if tables != "auto":
        return tables
    return "map" if jax.default_backend() == "cpu" else "vmap"


@functools.lru_cache(maxsize=32)
def _chunk_kernel(fabric_static: tuple, spill_static: tuple, table_keys: tuple, other_keys: tuple,
                  spill_keys: tuple, top: int, max_steps: int, tables: str = "auto"):
    """The chunk program, one ``jit``: over the chunk's U tables (scene + the fields that change the DP:
    one ``build_fabric`` each) a ``vmap`` or, on CPU, a ``lax.map`` (``tables``: "vmap", "map" or
    "auto"); inside, a ``vmap`` over the M settings sharing a table (highways for their tau_h, route
    metrics for their slack and spill parameters). The inner ``vmap`` batches only what depends on
    those parameters: the route walks and splines of one table are computed once for all M.

    (scenes stacked [S, ...], scene_index i32[U], table_values f32[U, Ft], other_values f32[M, Fo],
    spill_values f32[M, P]) -> dict of [U, M] metrics.
    """
    fstat, sstat = dict(fabric_static), dict(spill_static)

    def one_table(scenes, i, tvals, ovals, svals):
        scene = jax.tree_util.tree_map(lambda a: a[i], scenes)
        table_fields = {k: tvals[j] for j, k in enumerate(table_keys)}
        fab = _fabric._build(scene, FabricParams(**fstat, **table_fields))

        def one_setting(o, s):
            fp = FabricParams(**fstat, **table_fields, **{k: o[j] for j, k in enumerate(other_keys)})
            sp = SpillParams(**sstat, **{k: s[j] for j, k in enumerate(spill_keys)})
            return _metrics(scene, fp, sp, top, max_steps, fab=_with_highways(fab, scene, fp))

        return jax.vmap(one_setting)(ovals, svals)

    if _outer_mode(tables) == "vmap":
        return jax.jit(jax.vmap(one_table, in_axes=(None, 0, 0, None, None)))

    def mapped(scenes, index, tvals, ovals, svals):
        return jax.lax.map(lambda x: one_table(scenes, x[0], x[1], ovals, svals), (index, tvals))

    return jax.jit(mapped)


class Chunk(NamedTuple):
    """One chunk's inputs, plain numpy (picklable for Ray): U tables x M settings each.

    scenes: tuple of the stacked scene leaves [S, ...] of one grid shape; scene_index: i32[U];
    table_values: f32[U, Ft] (fields that change the DP); other_values: f32[M, Fo] (the other fabric
    fields); spill_values: f32[M, P]; static: hashable kernel config.
    """

    scenes: tuple
    scene_index: np.ndarray
    table_values: np.ndarray
    other_values: np.ndarray
    spill_values: np.ndarray
    static: tuple


def evaluate_chunk(chunk: Chunk, tables: str = "auto") -> dict:
    """Run the chunk kernel on one chunk: a dict of numpy metric arrays, [U * M] each (table-major).

    tables: how the chunk's U tables are batched, "vmap", "map" (``lax.map``) or "auto" (see ``_chunk_kernel``).
    """
    if tables not in ("auto", "vmap", "map"):
        raise ValueError(f"tables: must be 'auto', 'vmap' or 'map'; got {tables!r}.")
    scenes = Scene(*(jnp.asarray(a) for a in chunk.scenes))
    kernel = _chunk_kernel(*chunk.static, tables=tables)
    out = kernel(scenes, jnp.asarray(chunk.scene_index), jnp.asarray(chunk.table_values, jnp.float32),
                 jnp.asarray(chunk.other_values, jnp.float32), jnp.asarray(chunk.spill_values, jnp.float32))
    return {k: np.asarray(v).reshape(-1) for k, v in jax.device_get(out).items()}


def _bytes(tree) -> int:
    return sum(int(np.prod(x.shape)) * np.dtype(x.dtype).itemsize for x in jax.tree_util.tree_leaves(tree))


def bytes_per_table(scene: Scene, fabric_static: dict | None = None, per_table: int = 1) -> int:
    """Estimated working memory of one table and its ``per_table`` settings, bytes.

    ``_WORKSPACE_FACTOR`` x (the fabric's output arrays, from ``jax.eval_shape``, plus the scene's
    arrays), plus per setting ``_WORKSPACE_FACTOR`` f32 grids (highways and route metrics).
    """
    fp = FabricParams(**(fabric_static or {}))
    out = jax.eval_shape(_fabric._build, scene, fp)
    h, w = scene.shape
    return _WORKSPACE_FACTOR * (_bytes(out) + _bytes(scene) + per_table * 4 * h * w)


def chunk_size_for(scene: Scene, memory_budget_mb: float, fabric_static: dict | None = None,
                   per_table: int = 1, n_tables: int | None = None) -> int:
    """Tables per chunk for ``scene``'s grid shape: ``budget // bytes_per_table``, at least 1 and at most
    ``n_tables``. A chunk evaluates ``tables x per_table`` settings."""
    size = max(1, int(memory_budget_mb * 2**20) // bytes_per_table(scene, fabric_static, per_table))
    return size if n_tables is None else max(1, min(size, n_tables))


# --------------------------------------------------------------------------------------------------
# Output file and resumption
# --------------------------------------------------------------------------------------------------

def _fmt(v) -> str:
    if isinstance(v, str):
        return v
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (np.floating, np.ndarray)):
        return str(np.float32(v))   # shortest text that reads back as the same float32
    return repr(float(v))


def _setting_fields(spec: SweepSpec, setting) -> list[str]:
    i, fvals, svals = setting
    return [spec.scenes[i][0]] + [_fmt(float(v)) for v in (*fvals, *svals)]


def _read_done(out: Path, header: list[str], spec: SweepSpec, settings: list) -> set[int]:
    """Setting indices already written to ``out``; drops a torn last line; checks the rows belong to
    this sweep (same header, same scene and values at each setting index)."""
    data = out.read_bytes()
    if not data:
        return set()
    keep = data if data.endswith(b"\n") else data[:data.rfind(b"\n") + 1]   # a torn last line is dropped
    lines = keep.decode().splitlines()
    if not lines:                 # not even the header made it: start over
        out.write_bytes(b"")
        return set()
    if lines[0].split(",") != header:
        raise ValueError(f"out: {out} holds rows of another sweep (its header is not {','.join(header)}); "
                         "give a new --out file or delete this one to start over.")
    done = set()
    good = len(lines[0].encode()) + 1
    for line in lines[1:]:
        fields = line.split(",")
        if len(fields) != len(header):
            break                                                          # torn row: drop it and the rest
        idx = int(fields[0])
        if not 0 <= idx < len(settings) or fields[1:2 + len(spec.fabric_grid) + len(spec.spill_grid)] != \
                _setting_fields(spec, settings[idx]):
            raise ValueError(f"out: {out} row for setting {fields[0]} does not match this spec; give a new "
                             "--out file or delete this one to start over.")
        done.add(idx)
        good += len(line.encode()) + 1
    if good != len(data):
        with open(out, "r+b") as fh:
            fh.truncate(good)
    return done


class _Plan(NamedTuple):
    rows: list          # setting indices of the chunk (real ones, in order)
    chunk: Chunk


def _plan_chunks(spec: SweepSpec, settings: list, memory_budget_mb: float) -> list[_Plan]:
    """Chunks of U tables (x M settings each) from a run of consecutive scenes of one grid shape; U is
    fixed per shape and the last chunk of a run is padded by repeating its last table, so every call of
    one shape has the same array shapes (one compile per grid shape)."""
    table_keys, per_table = _split(spec)
    names = [k for k, _ in spec.fabric_grid]
    t_idx = [names.index(k) for k in table_keys]
    o_idx = [j for j, k in enumerate(names) if k not in table_keys]
    other_keys = tuple(names[j] for j in o_idx)
    spill_keys = tuple(k for k, _ in spec.spill_grid)
    n_tables = len(settings) // per_table
    # settings are table-major: table t owns settings [t * M, (t + 1) * M), all with the same other values
    first = settings[:per_table]
    other = np.array([[f[j] for j in o_idx] for _, f, _ in first], np.float32).reshape(per_table, len(o_idx))
    spill = np.array([s for _, _, s in first], np.float32).reshape(per_table, len(spill_keys))
    runs: list[list[int]] = []
    for t in range(n_tables):
        i = settings[t * per_table][0]
        if runs and spec.scenes[settings[runs[-1][-1] * per_table][0]][1].shape == spec.scenes[i][1].shape:
            runs[-1].append(t)
        else:
            runs.append([t])
    tables_of_shape: dict[tuple, int] = {}
    for run in runs:
        shape = spec.scenes[settings[run[0] * per_table][0]][1].shape
        tables_of_shape[shape] = tables_of_shape.get(shape, 0) + len(run)
    plans = []
    for run in runs:
        scene_ids = sorted({settings[t * per_table][0] for t in run})
        scene0 = spec.scenes[scene_ids[0]][1]
        shape = scene0.shape
        local = {s: j for j, s in enumerate(scene_ids)}
        stacked = tuple(np.stack([np.asarray(leaf) for leaf in leaves]) for leaves in
                        zip(*(jax.tree_util.tree_leaves(spec.scenes[s][1]) for s in scene_ids)))
        size = chunk_size_for(scene0, memory_budget_mb, spec.fabric_static, per_table, tables_of_shape[shape])
        max_steps = spec.max_steps if spec.max_steps is not None else shape[0] + shape[1] + 1
        static = (tuple(sorted(spec.fabric_static.items())), tuple(sorted(spec.spill_static.items())),
                  table_keys, other_keys, spill_keys, min(spec.top_sources, shape[0] * shape[1]), max_steps)
        for start in range(0, len(run), size):
            tables = run[start:start + size]
            padded = tables + [tables[-1]] * (size - len(tables))
            rows = [t * per_table + j for t in tables for j in range(per_table)]
            plans.append(_Plan(rows, Chunk(
                stacked, np.array([local[settings[t * per_table][0]] for t in padded], np.int32),
                np.array([[settings[t * per_table][1][j] for j in t_idx] for t in padded],
                         np.float32).reshape(size, len(t_idx)),
                other, spill, static)))
    return plans


def _rows_text(spec: SweepSpec, settings: list, plan: _Plan, result: dict) -> str:
    lines = []
    for j, n in enumerate(plan.rows):
        fields = [str(n)] + _setting_fields(spec, settings[n]) + [_fmt(result[m][j][()]) for m in METRICS]
        lines.append(",".join(fields))
    return "\n".join(lines) + "\n"


def run_sweep(spec, out, *, backend: str = "local", address: str | None = None, memory_budget_mb: float = 256.0,
              progress: bool = True, on_chunk: Callable[[int, int], Any] | None = None, max_retries: int = 3,
              _fault_marker: str | None = None) -> Path:
    """Evaluate every setting of ``spec`` and write one CSV row per setting to ``out``; returns ``out``.

    spec: a dict, a ``SweepSpec`` or a TOML file (see the module docstring). backend: ``"local"`` or
    ``"ray"`` (Ray tasks, one per chunk; ``address`` of a running cluster, else the already initialised
    Ray or a new local instance). memory_budget_mb: working memory for one chunk, MB (sets the chunk
    size). progress: a tqdm bar. on_chunk(done_settings, total): called after each chunk is written.
    max_retries: Ray task retries (failed workers and raised exceptions).

    Resumes: rows already in ``out`` are kept and only missing chunks are evaluated.
    """
    if backend not in ("local", "ray"):
        raise ValueError(f"backend: must be 'local' or 'ray'; got {backend!r}.")
    if isinstance(memory_budget_mb, bool) or not isinstance(memory_budget_mb, (int, float)) \
            or not memory_budget_mb > 0:
        raise ValueError(f"memory_budget_mb: must be a number > 0 (MB per chunk); got {memory_budget_mb!r}.")
    if address is not None and backend != "ray":
        raise ValueError("address: only used with backend='ray'; drop it or add backend='ray'.")
    spec = spec if isinstance(spec, SweepSpec) else load_spec(spec)
    out = Path(out)
    if out.parent and not out.parent.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
    settings = settings_of(spec)
    header = columns_of(spec)
    done = _read_done(out, header, spec, settings) if out.exists() else set()
    if not out.exists() or out.stat().st_size == 0:
        out.write_text(",".join(header) + "\n")
    todo = [p for p in _plan_chunks(spec, settings, memory_budget_mb) if not set(p.rows) <= done]

    from tqdm.auto import tqdm

    bar = tqdm(total=len(settings), initial=len(done), unit="setting", disable=not progress, desc="sweep")
    if backend == "ray":
        from jaxplan import _sweep_ray

        results = _sweep_ray.evaluate_chunks([p.chunk for p in todo], address=address, max_retries=max_retries,
                                             fault_marker=_fault_marker)
    else:
        results = (evaluate_chunk(p.chunk) for p in todo)
    try:
        with open(out, "a") as fh:
            for plan, result in zip(todo, results):
                missing = [n for n in plan.rows if n not in done]
                if not missing:
                    continue
                text = _rows_text(spec, settings, plan, result)
                if len(missing) != len(plan.rows):   # a chunk cut by a torn line: only its missing rows
                    keep = set(missing)
                    text = "".join(line + "\n" for line in text.splitlines() if int(line.split(",")[0]) in keep)
                fh.write(text)
                fh.flush()
                os.fsync(fh.fileno())   # a chunk's rows reach the disk before the next chunk starts
                done.update(missing)
                bar.update(len(missing))
                if on_chunk is not None:
                    on_chunk(len(done), len(settings))
    finally:
        bar.close()
        close = getattr(results, "close", None)
        if close is not None:
            close()
    _sort_rows(out)
    return out


def _sort_rows(out: Path) -> None:
    """Rows in setting order (they are written in order; this mends a file resumed after a reorder)."""
    lines = out.read_text().splitlines()
    body = lines[1:]
    keys = [int(line.split(",", 1)[0]) for line in body]
    if keys != sorted(keys):
        order = sorted(range(len(body)), key=keys.__getitem__)
        tmp = out.with_name(f".{out.name}.sorting")
        tmp.write_text("\n".join([lines[0]] + [body[i] for i in order]) + "\n")
        os.replace(tmp, out)
