"""Running a sweep: the cartesian product of a spec, evaluated in ``vmap``ped chunks, one CSV row per setting.

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
``tau_h`` and ``slack_tau``), then the other ``[fabric]`` fields, then ``[spill]``, each
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

Backends: ``"local"`` evaluates chunks in this process; ``"ray"`` (``jaxplan.sweep.ray``, the optional
extra ``jaxplan[distributed]``) runs each chunk as a Ray task with retries. Both call ``evaluate_chunk``,
so they give identical rows.
"""
from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np

from jaxplan.core import check_interrupt
from jaxplan.sweep.chunks import Chunk, chunk_size_for, evaluate_chunk
from jaxplan.sweep.spec import METRICS, Settings, SweepSpec, columns_of, load_spec, settings_of, tables_of
from jaxplan.transport import FabricParams, check_build_memory


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

__all__ = ["MAX_BUDGET_MB", "plan_chunks", "run_sweep"]

MAX_BUDGET_MB = 2 ** 20   # 1 TB: a chunk's working memory; its table count must stay a finite int


def _setting_fields(spec: SweepSpec, setting) -> list[str]:
    i, fvals, svals = setting
    return [spec.scenes[i][0]] + [_fmt(float(v)) for v in (*fvals, *svals)]


def _read_done(out: Path, header: list[str], spec: SweepSpec, settings: Settings) -> set[int]:
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


def plan_chunks(spec: SweepSpec, settings: Settings, memory_budget_mb: float) -> list[_Plan]:
    """Chunks of U tables (x M settings each) from a run of consecutive scenes of one grid shape; U is
    fixed per shape and the last chunk of a run is padded by repeating its last table, so every call of
    one shape has the same array shapes (one compile per grid shape)."""
    table_keys, per_table = tables_of(spec)
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


def _rows_text(spec: SweepSpec, settings: Settings, plan: _Plan, result: dict) -> str:
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
            or not 0 < memory_budget_mb <= MAX_BUDGET_MB:
        raise ValueError(f"memory_budget_mb: must be a number in (0, {MAX_BUDGET_MB}] (MB per chunk); "
                         f"got {memory_budget_mb!r}.")
    if address is not None and backend != "ray":
        raise ValueError("address: only used with backend='ray'; drop it or add backend='ray'.")
    spec = spec if isinstance(spec, SweepSpec) else load_spec(spec)
    for shape in sorted({scene.shape for _, scene in spec.scenes}):   # before the output is touched
        check_build_memory(shape, FabricParams(**spec.fabric_static))
    out = Path(out)
    if out.parent and not out.parent.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
    settings = settings_of(spec)
    header = columns_of(spec)
    done = _read_done(out, header, spec, settings) if out.exists() else set()
    if not out.exists() or out.stat().st_size == 0:
        out.write_text(",".join(header) + "\n")
    todo = [p for p in plan_chunks(spec, settings, memory_budget_mb) if not set(p.rows) <= done]

    from tqdm.auto import tqdm

    bar = tqdm(total=len(settings), initial=len(done), unit="setting", disable=not progress, desc="sweep")
    if backend == "ray":
        from jaxplan.sweep import ray as sweep_ray

        results = sweep_ray.evaluate_chunks([p.chunk for p in todo], address=address, max_retries=max_retries,
                                             fault_marker=_fault_marker)
    else:
        results = (evaluate_chunk(p.chunk) for p in todo)
    try:
        with open(out, "a") as fh:
            for plan, result in zip(todo, results):
                check_interrupt()
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
