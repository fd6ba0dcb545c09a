"""Highway anchors (Eq. 12) and connectors to them (Section 3.4, Algorithm 4), for all roots at once."""
from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.core import grid_jit, lattice
from jaxplan.transport import connector_closure
from jaxplan.transport.connector_closure import CLOSURE_CAPACITY
from jaxplan.transport.fabric import Fabric, Paths, Table, continuation_dp, walk_table
from jaxplan.transport.params import FabricParams, validate_params

_ANCHOR_BATCH = 8   # connector DPs evaluated together by vmap
CONNECTOR_WINDOW = 64
"""Side, cells, of the smallest window around an anchor that a connector's DP runs on
(``connector_walks``); the next ones double it."""
ANCHOR_LIST = 8192
"""Anchor candidates ``anchors_for`` scores as a list (more: cell by cell over the grid)."""
ANCHOR_SHORT_LIST = 1024
"""The shorter list ``anchors_for`` scores when the candidates fit in it."""


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


def anchors_for(heat, highways, occupied, centers, anchor_lambda, roots, max_candidates: int = ANCHOR_LIST,
                short_candidates: int = ANCHOR_SHORT_LIST):
    """``i32[M]``: ``anchor_for`` of each of the roots ``roots: i32[M, 2]``, the same anchors. When the
    candidates (occupied highway cells) fit in a list of ``short_candidates`` or of ``max_candidates``
    (static; in row-major order, so ties still go to the lowest index) every root is scored against
    the shorter list that holds them, O(M x list); otherwise one root at a time over the grid."""
    h, w = heat.shape
    candidate = (highways & occupied).reshape(-1)
    size = min(h * w, int(max_candidates))

    def listed(size: int):
        index = lattice.true_indices(candidate, size)
        valid = index < h * w
        safe = jnp.minimum(index, h * w - 1)
        cand_heat = jnp.where(valid, heat.reshape(-1)[safe], -jnp.inf)
        cand_centers = centers.reshape(-1, 2)[safe]

        def one(root):
            d = jnp.linalg.norm(cand_centers - centers[root[0], root[1]], axis=-1)
            best = safe[jnp.argmax(jnp.where(valid, cand_heat - anchor_lambda * d, -jnp.inf))]
            is_root = occupied[root[0], root[1]] & ~highways[root[0], root[1]]
            return jnp.where(is_root & jnp.any(valid), best, -1).astype(jnp.int32)

        return jax.vmap(one)(roots)

    def each():
        return jax.lax.map(lambda r: anchor_for(heat, highways, occupied, centers, anchor_lambda, r), roots)

    # the shortest list that holds the candidates: a root's score costs the list's length
    sizes = sorted({min(size, int(short_candidates)), size})
    count = jnp.sum(candidate)
    branches = [functools.partial(listed, s) for s in sizes] + ([] if size == h * w else [each])
    return jax.lax.switch(jnp.sum(count > jnp.asarray(sizes)), branches)


def window_levels(shape, smallest: int = CONNECTOR_WINDOW) -> tuple[int, ...]:
    """The window sides ``connector_walks`` may run a DP on for a grid of ``shape``: ``smallest``,
    twice that, ... while smaller than the grid's shorter side (none on a small grid)."""
    sizes, size = [], int(smallest)
    while size < min(shape):
        sizes.append(size)
        size *= 2
    return tuple(sizes)


def _window_start(anchor, side: int, size: int):
    """First row (or column) of the ``size`` cells around ``anchor`` kept inside ``[0, side)``."""
    return jnp.clip(anchor - size // 2, 0, side - size)


def _closure_of(scene, fabric: Fabric, params: FabricParams, sources, mine, anchor_flat, capacity: int):
    """``connector_closure.downstream_cells`` of the ``mine`` rows of ``sources: i32[B, 2]`` toward
    ``anchor_flat`` (a cell): the steps into the anchor end there."""
    h, w = fabric.occupied.shape
    n = h * w

    def successors(head):
        g, nb = connector_closure.connector_lanes(scene, fabric, params, head, anchor_flat)
        return jnp.where(g.feasible & ~g.enters_goal, nb, n)

    seeds = jnp.where(mine, sources[:, 0] * w + sources[:, 1], n)
    return connector_closure.downstream_cells(successors, seeds, n, capacity)


def _walks_on(scene, fabric: Fabric, params: FabricParams, sources, mine, anchor_flat, max_steps: int,
              size: tuple[int, int] | None) -> Paths:
    """``Paths[B]``: the connector walks of ``sources`` (i32[B, 2]; rows where ``mine`` is False walk
    from the anchor itself) toward one anchor, its DP on the ``size`` window around the anchor, or
    on the whole grid (``size`` None)."""
    h, w = fabric.occupied.shape
    ar, ac = anchor_flat // w, anchor_flat % w
    if size is None:
        table, offset = connector_table(scene, fabric, params, anchor_flat), jnp.zeros(2, jnp.int32)
    else:
        sh, sw = size
        r0, c0 = _window_start(ar, h, sh), _window_start(ac, w, sw)

        def cut(a):
            return jax.lax.dynamic_slice(a, (r0, c0) + (0,) * (a.ndim - 2), (sh, sw) + a.shape[2:])

        centers = cut(lattice.cell_centers((h, w), scene.cell_size, scene.origin))
        goal, dist, unit = anchor_frame(centers, (ar - r0) * sw + (ac - c0))
        table, _, _, _ = continuation_dp(
            cut(scene.obj), cut(fabric.occupied) & ~goal, goal, dist, unit, params.theta_tol_deg, scene.cell_size,
            monotone=params.monotone, k=1, max_hops=params.resolved_max_hops((h, w)), blocked=cut(scene.blocked))
        offset = jnp.stack([r0, c0]).astype(jnp.int32)
    starts = jnp.where(mine[:, None], sources, jnp.stack([ar, ac]).astype(jnp.int32)) - offset
    paths = jax.vmap(lambda s: walk_table(table, s, jnp.int32(0), max_steps))(starts)
    return paths._replace(cells=jnp.where(paths.cells >= 0, paths.cells + offset, -1))


def connector_walks(scene, fabric: Fabric, params: FabricParams, sources, anchors, max_steps: int,
                    levels: tuple[int, ...] | None = None, closure: int = CLOSURE_CAPACITY) -> Paths:
    """``Paths[B]``: each source's connector path to its anchor, ``walk_table(connector_table(scene,
    fabric, params, anchors[i]), sources[i], 0, max_steps)``, the same paths.

    sources: i32[B, 2]; anchors: i32[B] flat indices (-1: no anchor, an empty connector). Sources
    that share an anchor share its DP. With the monotone rule every successor is strictly nearer the
    anchor, so a source's walk and every cell the DP reads for it lie in the disc of radius
    d(source, h*) around h* (their corner cells one cell beyond): each distinct anchor's DP runs on
    the smallest window of ``levels`` (static; default ``window_levels``) around it that holds the
    discs of all its sources, and on the whole grid when none does (or without the monotone rule).
    Before any window, the cells its sources' connectors can visit are listed
    (``connector_closure.downstream_cells``): when at most ``closure`` (static; 0: never) they are,
    the DP runs on them alone (``connector_closure.closure_walks``), the same paths again.
    The anchors run one after another (``lax.map``), so a DP costs its own cells only.
    """
    h, w = fabric.occupied.shape
    levels = window_levels((h, w)) if levels is None else tuple(s for s in levels if s < max(h, w))
    if not params.monotone:
        levels = ()
    b = anchors.shape[0]
    sources = jnp.asarray(sources, jnp.int32)
    distinct = slot_anchors(anchors, b)
    reach = jnp.ceil(jnp.sqrt(jnp.sum(((sources - jnp.stack([anchors // w, anchors % w], -1)) * 1.0) ** 2, -1)))
    reach = reach.astype(jnp.int32) + 1
    sizes = [(min(s, h), min(s, w)) for s in levels]

    def one_anchor(anchor):
        safe = jnp.maximum(anchor, 0)
        mine = (anchors == anchor) & (anchor >= 0)
        here = jnp.stack([safe // w, safe % w])
        lo = jnp.maximum(here - reach[:, None], 0)
        hi = jnp.minimum(here + reach[:, None], jnp.asarray([h - 1, w - 1]))
        fits = [jnp.all(~mine[:, None] | ((lo >= start) & (hi < start + jnp.asarray(size))))
                for size in sizes
                for start in [jnp.stack([_window_start(here[0], h, size[0]), _window_start(here[1], w, size[1])])]]
        # the first level that holds every disc; the whole grid when none does; 0 for no anchor
        level = jnp.argmax(jnp.asarray(fits + [True]))
        branches = [functools.partial(_walks_on, scene, fabric, params, sources, mine, safe, max_steps, size)
                    for size in sizes + [None]]
        empty = lambda: jax.tree.map(jnp.zeros_like, jax.eval_shape(branches[-1]))  # noqa: E731
        if not (closure and params.monotone):
            return jax.lax.switch(jnp.where(anchor < 0, 0, 1 + level), [empty] + branches)
        cells, count = jax.lax.cond(
            anchor >= 0, lambda: _closure_of(scene, fabric, params, sources, mine, safe, closure),
            lambda: (jnp.full(closure, h * w, jnp.int32), jnp.int32(0)))
        on_closure = functools.partial(connector_closure.closure_walks, scene, fabric, params, sources, safe, cells,
                                       max_steps)
        case = jnp.where(anchor < 0, 0, jnp.where(count <= closure, 1, 2 + level))
        return jax.lax.switch(case, [empty, on_closure] + branches)

    walks = jax.lax.map(one_anchor, distinct)                                   # [B anchors, B sources]
    slot = jnp.argmax(distinct[None] == anchors[:, None], -1)
    mine = jax.tree.map(lambda a: a[slot, jnp.arange(b)], walks)
    # a source without an anchor: its cell alone, nothing collected
    none = anchors < 0
    cells = jnp.full_like(mine.cells, -1).at[:, 0].set(sources)
    return Paths(jnp.where(none[:, None, None], cells, mine.cells), jnp.where(none, 1, mine.n_cells),
                 jnp.where(none, -jnp.inf, mine.raw), jnp.where(none, jnp.inf, mine.length),
                 jnp.where(none, False, mine.fallback), jnp.where(none, True, mine.complete))


def _toward(centers, anchor_flat):
    """Distance ``f32[H, W]`` and unit vector ``f32[H, W, 2]`` from every centre to one anchor."""
    return lattice.norm_and_unit(centers.reshape(-1, 2)[jnp.maximum(anchor_flat, 0)] - centers)


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
    _, straight = lattice.norm_and_unit(centers.reshape(-1, 2)[a_flat] - centers)
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
