"""Chunks of settings evaluated in one jitted, vmapped kernel, and the memory budget that sizes them."""
from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.transport import FabricParams, Scene, count_table_hops, fabric_of, highways, select_routes
from jaxplan.transport.spillage import SpillParams

# Per-setting bytes = this factor x (the fabric's output bytes + the scene's bytes): the DP's working
# set (tables of several candidates per direction) is a few times its output.
WORKSPACE_FACTOR = 4

__all__ = ["Chunk", "bytes_per_table", "chunk_size_for", "evaluate_chunk", "metrics_of", "with_highways"]


def metrics_of(scene, fp: FabricParams, sp: SpillParams, top: int, max_steps: int, fab=None) -> dict:
    """The per-setting metrics (``METRICS``) of one scene and parameter setting; vmappable.

    fab: the fabric of ``scene`` under ``fp`` (built here when None).
    """
    fab = fabric_of(scene, fp) if fab is None else fab
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
    sel = select_routes(scene, fab, sources, fp.slack_tau, sp, max_steps=max_steps)
    entry = sel.entry[:, None]
    raw = jnp.take_along_axis(fab.table.raw[sources[:, 0], sources[:, 1]], entry, -1)[:, 0]
    delivered = jnp.take_along_axis(sel.delivered, entry, -1)[:, 0]
    hops = jnp.take_along_axis(count_table_hops(fab.table, scene.detour)[sources[:, 0], sources[:, 1]], entry, -1)[:, 0]
    # +1: a route ending in a boundary fallback takes one more walk step (conservative for the others)
    truncated = valid & (hops + 1 > max_steps)
    return dict(out, top_collected=jnp.sum(jnp.where(valid, raw, 0.0)),
                top_delivered=jnp.sum(jnp.where(valid, delivered, 0.0)), routes_truncated=jnp.any(truncated))


def with_highways(fab, scene, fp: FabricParams):
    """``fab`` with its highways (Eq. 11) recomputed for ``fp.tau_h``: the only part of the fabric that
    depends on a field in ``AFTER_TABLE``."""
    mask = highways(fab.heat, jnp.asarray(scene.target_mask, bool), fp.tau_h,
                    relative=fp.highway_relative, smoothing=fp.highway_smoothing, nms=fp.highway_nms)
    return fab._replace(highways=mask)


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
        fab = fabric_of(scene, FabricParams(**fstat, **table_fields))

        def one_setting(o, s):
            fp = FabricParams(**fstat, **table_fields, **{k: o[j] for j, k in enumerate(other_keys)})
            sp = SpillParams(**sstat, **{k: s[j] for j, k in enumerate(spill_keys)})
            return metrics_of(scene, fp, sp, top, max_steps, fab=with_highways(fab, scene, fp))

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

    ``WORKSPACE_FACTOR`` x (the fabric's output arrays, from ``jax.eval_shape``, plus the scene's
    arrays), plus per setting ``WORKSPACE_FACTOR`` f32 grids (highways and route metrics).
    """
    fp = FabricParams(**(fabric_static or {}))
    out = jax.eval_shape(fabric_of, scene, fp)
    h, w = scene.shape
    return WORKSPACE_FACTOR * (_bytes(out) + _bytes(scene) + per_table * 4 * h * w)


def chunk_size_for(scene: Scene, memory_budget_mb: float, fabric_static: dict | None = None,
                   per_table: int = 1, n_tables: int | None = None) -> int:
    """Tables per chunk for ``scene``'s grid shape: ``budget // bytes_per_table``, at least 1 and at most
    ``n_tables``. A chunk evaluates ``tables x per_table`` settings."""
    size = max(1, int(memory_budget_mb * 2**20) // bytes_per_table(scene, fabric_static, per_table))
    return size if n_tables is None else max(1, min(size, n_tables))


