"""Highway anchors (Eq. 12) and connectors to them (Section 3.4, Algorithm 4), for all roots at once."""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.core import grid_jit, lattice
from jaxplan.transport.fabric import Fabric, Table, continuation_dp
from jaxplan.transport.params import FabricParams, validate_params

_ANCHOR_BATCH = 8   # connector DPs evaluated together by vmap


class Connectors(NamedTuple):
    """Anchors and connectors for every root (occupied, non-highway cell). H x W grid, A slots.

    anchor: i32[H, W, 2], (row, col) of h*(R); -1 where R is no root or has no candidate.
    raw: f32[H, W], objects the connector collects (R included, h* excluded); 0 without a connector.
    length: f32[H, W], connector length, world units.
    first_hop: i32[H, W, 2], (row, col) of the connector's first cell; -1 for none or a straight
      fallback segment. heading: f32[H, W, 2], unit (x, y) direction of the connector's start.
    via_raw, via_len: f32[H, W], the via-highway route: connector then P*(h*).
    has_connector: bool[H, W], root with an anchor among the planned slots.
    truncated: bool[], some roots' anchors did not fit in ``max_anchors`` slots.
    anchors: i32[A], flat index of each planned anchor (-1 unused slot); slot: i32[H, W] slot of each
      root's anchor (-1 none). tables: Table with a leading A axis, each anchor's K=1 connector table.
    """

    anchor: jax.Array
    raw: jax.Array
    length: jax.Array
    first_hop: jax.Array
    heading: jax.Array
    via_raw: jax.Array
    via_len: jax.Array
    has_connector: jax.Array
    truncated: jax.Array
    anchors: jax.Array
    slot: jax.Array
    tables: Table


def choose_anchors(heat, highways, occupied, centers, anchor_lambda, *, block_rows: int = 8,
                   max_candidates: int | None = None):
    """``i32[H, W]`` flat index of ``h*(R)`` for every cell (-1 for non-roots or no candidate).

    heat: f32[H, W] objects; highways, occupied: bool[H, W]; centers: f32[H, W, 2] world units;
    anchor_lambda: f32[] heat per world unit. Every root is scored against every candidate (Eq. 12),
    ``block_rows`` grid rows of roots at a time. max_candidates (static): the candidates are first
    gathered into a list of this size (in row-major order, so ties still go to the lowest index);
    it must be at least their number (``candidate_count``). None = H * W, always enough.
    """
    h, w = heat.shape
    candidate = (highways & occupied).reshape(-1)
    size = h * w if max_candidates is None else int(max_candidates)
    index = jnp.nonzero(candidate, size=size, fill_value=h * w)[0]
    valid = index < h * w
    safe = jnp.minimum(index, h * w - 1)
    cand_heat = jnp.where(valid, heat.reshape(-1)[safe], -jnp.inf)
    cand_centers = centers.reshape(-1, 2)[safe]
    pad = (-h) % block_rows
    blocks = jnp.pad(centers, ((0, pad), (0, 0), (0, 0))).reshape(-1, block_rows * w, 2)

    def best(block):
        d = jnp.linalg.norm(block[:, None, :] - cand_centers[None], axis=-1)
        score = jnp.where(valid[None], cand_heat[None] - anchor_lambda * d, -jnp.inf)
        return safe[jnp.argmax(score, axis=1)].astype(jnp.int32)   # first max: lowest row-major index

    anchor = jax.lax.map(best, blocks).reshape(-1)[: h * w].reshape(h, w)
    roots = occupied & ~highways
    return jnp.where(roots & jnp.any(candidate), anchor, -1)


def candidate_count(fabric: Fabric) -> int:
    """Number of anchor candidates (occupied highway cells), read on the host."""
    return int(jnp.sum(fabric.highways & fabric.occupied))


def candidate_buffer(fabric: Fabric) -> int | None:
    """A static ``max_candidates`` for ``choose_anchors``: the next power of two (>= 64) above the
    candidate count, so that a few sizes cover every call; None (all cells) under tracing."""
    if isinstance(fabric.highways, jax.core.Tracer):
        return None
    h, w = fabric.highways.shape
    return min(h * w, max(64, 1 << max(0, candidate_count(fabric) - 1).bit_length()))


def anchor_for(heat, highways, occupied, centers, anchor_lambda, root):
    """``i32[]`` flat index of ``h*(R)`` for one root ``R = root: i32[2]`` (-1: not a root, or no
    candidate). The same rule as ``choose_anchors``, in O(H W) for one cell."""
    h, w = heat.shape
    candidate = (highways & occupied).reshape(-1)
    d = jnp.linalg.norm(centers.reshape(-1, 2) - centers[root[0], root[1]], axis=-1)
    score = jnp.where(candidate, heat.reshape(-1) - anchor_lambda * d, -jnp.inf)
    is_root = occupied[root[0], root[1]] & ~highways[root[0], root[1]]
    return jnp.where(is_root & jnp.any(candidate), jnp.argmax(score), -1).astype(jnp.int32)


def connector_table(scene, fabric: Fabric, params: FabricParams, anchor_flat):
    """The K=1 connector ``Table`` of every cell toward one anchor (flat index; Section 3.4)."""
    centers = lattice.cell_centers(fabric.occupied.shape, scene.cell_size, scene.origin)
    return _connector_table(scene, fabric, params, anchor_flat, centers)


def _norm_and_unit(delta):
    """Length ``[...]`` and unit vector ``[..., 2]`` of ``delta: [..., 2]`` (zero vector for zero length)."""
    norm = jnp.linalg.norm(delta, axis=-1)
    return norm, jnp.where(norm[..., None] > 0, delta / jnp.maximum(norm, 1e-30)[..., None], 0.0)


def _toward(centers, anchor_flat):
    """Distance ``f32[H, W]`` and unit vector ``f32[H, W, 2]`` from every centre to one anchor."""
    return _norm_and_unit(centers.reshape(-1, 2)[jnp.maximum(anchor_flat, 0)] - centers)


def anchor_frame(centers, anchor_flat):
    """The goal mask ``bool[H, W]``, distance ``f32[H, W]`` and unit direction ``f32[H, W, 2]`` of the
    connector problem toward one anchor (flat index)."""
    h, w = centers.shape[:2]
    goal = (jnp.arange(h * w) == anchor_flat).reshape(h, w)
    dist, unit = _toward(centers, anchor_flat)
    return goal, dist, unit


def _connector_table(scene, fabric: Fabric, params: FabricParams, anchor_flat, centers):
    h, w = fabric.occupied.shape
    goal, dist, unit = anchor_frame(centers, anchor_flat)
    table, _, _, _ = continuation_dp(
        scene.obj, fabric.occupied & ~goal, goal, dist, unit, params.theta_tol_deg, scene.cell_size,
        monotone=params.monotone, k=1, max_hops=params.resolved_max_hops((h, w)), blocked=scene.blocked)
    return table


def slot_anchors(anchor_flat, max_anchors: int):
    """``i32[A]``: the distinct anchors of ``anchor_flat`` (sorted), -1 in unused slots."""
    anchors = jnp.unique(anchor_flat, size=max_anchors + 1, fill_value=-1)
    # unique() sorts, so a -1 (cells without anchor) comes first: drop it and keep max_anchors slots.
    anchors = jnp.where(anchors[0] < 0, anchors[1:], anchors[:-1])
    return jnp.where((anchors >= 0) & (jnp.arange(max_anchors) < jnp.sum(anchors >= 0)), anchors, -1)


def _plan(scene, params: FabricParams, fabric: Fabric, max_anchors: int,
          max_candidates: int | None = None) -> Connectors:
    h, w = fabric.occupied.shape
    centers = lattice.cell_centers((h, w), scene.cell_size, scene.origin)
    anchor_flat = choose_anchors(fabric.heat, fabric.highways, fabric.occupied, centers, params.anchor_lambda,
                                 max_candidates=max_candidates)
    anchors = slot_anchors(anchor_flat, max_anchors)
    # vmapped over distinct anchors, a few at a time so memory stays bounded on large grids
    tables = jax.lax.map(lambda a: _connector_table(scene, fabric, params, a, centers), anchors,
                         batch_size=min(_ANCHOR_BATCH, max_anchors))
    return assemble(scene, fabric, anchor_flat, anchors, tables)


def assemble(scene, fabric: Fabric, anchor_flat, anchors, tables: Table) -> Connectors:
    """``Connectors`` from every root's anchor (flat, -1 none), the slot anchors and their tables."""
    h, w = fabric.occupied.shape
    centers = lattice.cell_centers((h, w), scene.cell_size, scene.origin)
    match = (anchor_flat[None] == anchors[:, None, None]) & (anchors[:, None, None] >= 0)
    slot = jnp.where(jnp.any(match, 0), jnp.argmax(match, 0), -1).astype(jnp.int32)
    has = slot >= 0
    safe_slot = jnp.maximum(slot, 0)
    rows, cols = jnp.meshgrid(jnp.arange(h), jnp.arange(w), indexing="ij")
    pick = lambda a: a[safe_slot, rows, cols, 0]  # noqa: E731
    raw = jnp.where(has, pick(tables.raw), 0.0)
    length = jnp.where(has, pick(tables.length), 0.0)
    d0 = jnp.where(has, pick(tables.next_dir), -1)
    steps = (d0 >= 0) & (d0 < lattice.FALLBACK)
    safe_dir = jnp.clip(d0, 0, 7)
    first_hop = jnp.where(steps[..., None], lattice.neighbour_index(safe_dir), -1)
    a_flat = jnp.maximum(anchor_flat, 0)
    # a straight fallback connector points from the root straight at its anchor
    _, straight = _norm_and_unit(centers.reshape(-1, 2)[a_flat] - centers)
    heading = jnp.where(steps[..., None], jnp.asarray(lattice.STEP_UNIT)[safe_dir],
                        jnp.where(has[..., None], straight, 0.0))
    anchor_rc = jnp.where((anchor_flat >= 0)[..., None], jnp.stack([a_flat // w, a_flat % w], -1), -1)
    via_raw = jnp.where(has, raw + fabric.value.reshape(-1)[a_flat], 0.0)
    via_len = jnp.where(has, length + fabric.length.reshape(-1)[a_flat], 0.0)
    truncated = jnp.any((anchor_flat >= 0) & ~has)
    return Connectors(anchor_rc.astype(jnp.int32), raw, length, first_hop.astype(jnp.int32), heading,
                      via_raw, via_len, has, truncated, anchors, slot, tables)


_plan_jit = grid_jit(_plan, static_argnums=(3, 4))


def plan_connectors(scene, params: FabricParams | None, fabric: Fabric, *, max_anchors: int = 32) -> Connectors:
    """Anchors (Eq. 12) for all roots and connectors to them, one DP per distinct anchor (batched).

    ``max_anchors`` (static) bounds the number of distinct anchors planned; roots whose anchor does
    not fit are flagged by ``Connectors.truncated`` and get no connector.
    """
    params = FabricParams() if params is None else params
    if not any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(params)):
        validate_params(params)
    if not isinstance(max_anchors, int) or max_anchors < 1:
        raise ValueError(f"max_anchors: must be an int >= 1; got {max_anchors!r}.")
    return _plan_jit(scene, params, fabric, max_anchors, candidate_buffer(fabric))
