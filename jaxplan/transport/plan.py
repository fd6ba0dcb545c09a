"""The one-tick planner: query the fabric, choose Rearrange or Deliver, and the route (Section 3).

One tick (``docs/transport.md``, "Episodes"):

1. **Source**: the occupied cell whose selected route collects the most (``argmax J``; rule
   ``"max_value"``), or the occupied cell nearest to the target (``"nearest"``). Ties: lowest
   row-major index.
2. **Deliver route**: among the source's slack-tau candidates, the one with the largest delivered mass
   under the spill model, then the shortest (Eq. 6; entry 0 with spillage off).
3. **Rearrange route**: if the source is a root with a highway anchor h* (Eq. 12), the connector to h*
   (one whose straight jump to h* crosses a blocked cell is not driven: ``obstacles.jump_clear``)
   followed by h*'s selected path (Section 3.4; ``Fabric.selected``).
4. **Choice**: Rearrange when ``via_raw > (1 + rearrange_margin) * raw(Deliver route)``, i.e. when
   going through the highway collects clearly more; otherwise Deliver. ``rearrange_margin`` is a
   traced parameter (``inf`` never rearranges).

With ``reselect`` (and spillage on) every tick first applies Eq. 6 to every source
(``selection.reselect``), so that headings, psi, the heatmap, highways and anchors follow the routes
selected by delivered mass, as the paper does; its cost is part of the tick's planning time.

The episode (``episode.act``, ``run.run_episode``) and the fleet (``jaxplan.fleet``) push the plans
made here; this module pushes nothing.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.core import grid_jit, lattice
from jaxplan.transport import connectors, execute, obstacles, selection, spillage
from jaxplan.transport.fabric import Fabric, Paths, Table, walk_table
from jaxplan.transport.params import FabricParams

if TYPE_CHECKING:   # the parameters live with the episode, which imports this module
    from jaxplan.transport.episode import EpisodeParams


class Plan(NamedTuple):
    """One tick's decision. S = 2 * (max_steps + 1) route slots.

    source: i32[2]; has_source: bool[]; mode: i32[] (0 deliver, 1 rearrange); route: execute.Route;
    raw: f32[] objects the route collects (pre-spill); complete: bool[] every walk ended in time;
    anchor: i32[2] (-1 none); entry: i32[] the Deliver route's table entry; connector: i32[S, 2]
    cells of the connector part (-1 padded) for plots.
    """

    source: jax.Array
    has_source: jax.Array
    mode: jax.Array
    route: execute.Route
    raw: jax.Array
    complete: jax.Array
    anchor: jax.Array
    entry: jax.Array
    connector: jax.Array


def _pad_rows(cells, rows: int):
    return jnp.concatenate([cells, jnp.full((rows - cells.shape[0], 2), -1, jnp.int32)])


def _concat_paths(first, first_n, second, second_n):
    """Rows ``first[:first_n]`` then ``second[:second_n]`` in one padded ``[2S, 2]`` array."""
    rows = first.shape[0] + second.shape[0]
    i = jnp.arange(rows)
    from_second = jnp.clip(i - first_n, 0, second.shape[0] - 1)
    out = jnp.where((i < first_n)[:, None], first[jnp.minimum(i, first.shape[0] - 1)], second[from_second])
    return jnp.where((i < first_n + second_n)[:, None], out, -1), first_n + second_n


def choose_source(scene, fabric: Fabric, rule: str, allowed=None):
    """``(source i32[2], has_source bool[])``: the occupied cell the rule picks (``argmax J`` for
    "max_value", the one nearest to the target for "nearest"; ties to the lowest row-major index).

    allowed: optional bool[H, W]; only occupied cells where it is True are candidates (a fleet skips
    the cells other rovers have reserved). has_source is False when no candidate is left; the
    source is then (0, 0).
    """
    h, w = scene.shape
    score = fabric.value if rule == "max_value" else -scene.dist
    candidates = fabric.occupied if allowed is None else fabric.occupied & allowed
    flat = jnp.argmax(jnp.where(candidates, score, -jnp.inf).reshape(-1))
    return jnp.stack([flat // w, flat % w]).astype(jnp.int32), jnp.any(candidates)


def plan_tick(scene, params: FabricParams, ep: EpisodeParams, spill: spillage.SpillParams, fabric: Fabric,
              max_steps: int, evaluator: spillage.Evaluator = spillage.curvature_spill) -> Plan:
    """Choose the source, the mode and the route for one push (the module docstring's rule):
    ``choose_source`` then ``plan_for_source``."""
    source, has_source = choose_source(scene, fabric, ep.source_rule)
    plan = plan_for_source(scene, params, ep, spill, fabric, source, max_steps, evaluator)
    return plan._replace(has_source=has_source)


def plan_for_source(scene, params: FabricParams, ep: EpisodeParams, spill: spillage.SpillParams, fabric: Fabric,
                    source, max_steps: int, evaluator: spillage.Evaluator = spillage.curvature_spill) -> Plan:
    """The mode and the route of one push from a given ``source: i32[2]`` (steps 2-4 of the module
    docstring). ``Plan.has_source`` says whether the source is an occupied cell. max_steps,
    evaluator: static, as in ``plan_tick``. Pure and jittable. To plan many sources, compute their
    anchors and connectors together (``source_anchors``, ``connector_walk``: sources sharing an
    anchor share its DP) and ``vmap`` ``plan_with_connector``; a ``vmap`` of this function runs every
    connector DP on the whole grid."""
    source = jnp.asarray(source, jnp.int32)
    anchor = source_anchor(scene, params, fabric, source)
    conn = jax.tree.map(lambda a: a[0], connector_walk(scene, params, fabric, source[None], anchor[None], max_steps))
    return plan_with_connector(scene, params, ep, spill, fabric, source, anchor, conn, max_steps, evaluator)


def source_anchor(scene, params: FabricParams, fabric: Fabric, source):
    """i32[]: flat index of the highway anchor h* of ``source: i32[2]`` (Eq. 12; -1 none)."""
    centers = lattice.cell_centers(scene.shape, scene.cell_size, scene.origin)
    return connectors.anchor_for(fabric.heat, fabric.highways, fabric.occupied, centers, params.anchor_lambda,
                                 jnp.asarray(source, jnp.int32))


def source_anchors(scene, params: FabricParams, fabric: Fabric, sources):
    """i32[B]: ``source_anchor`` of each of ``sources: i32[B, 2]`` (``connectors.anchors_for``)."""
    centers = lattice.cell_centers(scene.shape, scene.cell_size, scene.origin)
    return connectors.anchors_for(fabric.heat, fabric.highways, fabric.occupied, centers, params.anchor_lambda,
                                  jnp.asarray(sources, jnp.int32))


def connector_walk(scene, params: FabricParams, fabric: Fabric, sources, anchors, max_steps: int) -> Paths:
    """``Paths[B]``: the connector paths from ``sources: i32[B, 2]`` to their anchors (flat, -1 none):
    the walks of ``anchor_connector``'s tables, each distinct anchor's DP run once, on a window
    around it when that holds its sources' reach (``connectors.connector_walks``). Not for ``vmap``
    (the window is chosen by a switch, which ``vmap`` would run whole): pass the batch."""
    return connectors.connector_walks(scene, fabric, params, sources, anchors, max_steps)


def anchor_connector(scene, params: FabricParams, fabric: Fabric, anchor) -> Table:
    """The K=1 connector table toward ``anchor`` (flat index); a one-entry empty table when it is -1,
    without running the DP (under ``vmap`` both run: batch by distinct anchor instead)."""
    h, w = scene.shape

    def no_connector(_):
        shape = (h, w, 1)
        return Table(jnp.full(shape, -jnp.inf), jnp.full(shape, jnp.inf), jnp.full(shape, -1, jnp.int32),
                     jnp.full(shape, -1, jnp.int32))

    return jax.lax.cond(anchor >= 0, lambda _: connectors.connector_table(scene, fabric, params,
                                                                          jnp.maximum(anchor, 0)),
                        no_connector, None)


def plan_with_connector(scene, params: FabricParams, ep: EpisodeParams, spill: spillage.SpillParams,
                        fabric: Fabric, source, anchor, conn: Paths, max_steps: int,
                        evaluator: spillage.Evaluator = spillage.curvature_spill) -> Plan:
    """``plan_for_source`` with the source's anchor (``source_anchor``) and its connector path
    (``connector_walk``) given, so that a batch of sources computes their connectors one by one
    (each on its own window) and plans the rest vmapped."""
    h, w = scene.shape
    source = jnp.asarray(source, jnp.int32)
    has_source = fabric.occupied[source[0], source[1]]
    sel = selection.select_routes(scene, fabric, source[None], params.slack_tau, spill,
                                  max_steps=max_steps, evaluator=evaluator)
    entry = sel.entry[0]
    direct = walk_table(fabric.table, source, entry, max_steps, scene.detour)
    safe_anchor = jnp.maximum(anchor, 0)
    anchor_rc = jnp.stack([safe_anchor // w, safe_anchor % w]).astype(jnp.int32)
    anchor_entry = fabric.selected[anchor_rc[0], anchor_rc[1]]
    tail = walk_table(fabric.table, anchor_rc, anchor_entry, max_steps, scene.detour)
    # a connector that enters h* lists it last; the tail starts at h*, so drop the duplicate
    conn_cells = jnp.where(conn.fallback, conn.n_cells, conn.n_cells - 1)
    via_cells, via_n = _concat_paths(conn.cells, conn_cells, tail.cells, tail.n_cells)
    via_raw = conn.raw + fabric.table.raw[anchor_rc[0], anchor_rc[1], anchor_entry]
    jump_from = conn.cells[jnp.maximum(conn.n_cells - 1, 0)]
    drivable = ~conn.fallback | obstacles.jump_clear(scene.blocked, jump_from, anchor_rc)
    can_rearrange = (anchor >= 0) & jnp.isfinite(conn.raw) & conn.complete & tail.complete & drivable
    rearrange = can_rearrange & (via_raw > (1.0 + ep.rearrange_margin) * direct.raw)

    rows = via_cells.shape[0]
    cells = jnp.where(rearrange, via_cells, _pad_rows(direct.cells, rows))
    n_cells = jnp.where(rearrange, via_n, direct.n_cells)
    fallback = jnp.where(rearrange, tail.fallback, direct.fallback)
    route = execute.route_from_path(scene, cells, n_cells, fallback)
    connector = jnp.where(rearrange & (jnp.arange(rows) < conn.n_cells)[:, None], _pad_rows(conn.cells, rows), -1)
    return Plan(source, has_source, rearrange.astype(jnp.int32), route,
                jnp.where(rearrange, via_raw, direct.raw),
                jnp.where(rearrange, conn.complete & tail.complete, direct.complete),
                jnp.where(anchor >= 0, anchor_rc, -1), entry, connector)


plan_tick_jit = grid_jit(plan_tick, static_argnames=("max_steps", "evaluator"))


def plan_episode_tick(scene, params: FabricParams, ep: EpisodeParams, spill: spillage.SpillParams, fabric: Fabric,
                      cap: int, evaluator: spillage.Evaluator):
    """``(Plan, Fabric)``: one tick's plan as an episode makes it, and the fabric it was planned on
    (Eq. 6 applied to every source first with ``ep.reselect`` and spillage on). cap: static walk
    length. Host-level: ``plan_tick`` runs jitted inside."""
    if ep.reselect and spill.enabled:
        fabric = selection.reselect(scene, params, fabric, spill, max_steps=cap, evaluator=evaluator)
    # plan_tick reads only source_rule among the static fields: fixing the others (the budget, the
    # rebuild mode, reselect, applied above) lets episodes that differ in them share one program
    planning = ep.replace(max_pushes=0, rebuild="auto", reselect=False)
    return plan_tick_jit(scene, params, planning, spill, fabric, max_steps=cap, evaluator=evaluator), fabric


class PlanReads(NamedTuple):
    """The cells and entries of the fabric and the counts that ``plan_for_source`` read for one source,
    so that a refresh of the fabric can tell whether it changed the plan (``plans_unchanged``).
    K table entries; S = max_steps + 1.

    source: i32[2]; anchor: i32[] its highway anchor (flat, -1 none); walks: i32[K + 1, S] the flat
    (row-major) indices of the cells of the walks it read (its Eq. 6 candidate entries', then the
    anchor's selected path; -1 padded); window: i32[4] first row, last row, first column, last
    column of the cells its connector DP read (an empty box, first > last, without an anchor).
    """

    source: jax.Array
    anchor: jax.Array
    walks: jax.Array
    window: jax.Array


def plan_reads(scene, params: FabricParams, fabric: Fabric, source, anchor, max_steps: int) -> PlanReads:
    """``PlanReads`` of ``plan_with_connector`` from ``source: i32[2]`` with its ``anchor`` (i32[], flat;
    ``source_anchor``). Every walk reads the table's ``next_dir`` and ``next_rank`` and, for the spill
    model's pickup, the counts at the cells it visits; with the monotone rule the connector DP reads
    only the disc of radius d(source, anchor) around the anchor, its corner cells one beyond
    (``connectors.connector_walks``), without it the whole grid. max_steps: static, as in
    ``plan_for_source``."""
    h, w = scene.shape
    source = jnp.asarray(source, jnp.int32)
    k = fabric.table.raw.shape[-1]
    candidate = selection.candidate_mask(fabric.table.raw[source[0], source[1]], params.slack_tau)
    walks = jax.vmap(lambda r: walk_table(fabric.table, source, r, max_steps, scene.detour).cells)(
        jnp.arange(k, dtype=jnp.int32))
    safe = jnp.maximum(anchor, 0)
    anchor_rc = jnp.stack([safe // w, safe % w]).astype(jnp.int32)
    tail = walk_table(fabric.table, anchor_rc, fabric.selected[anchor_rc[0], anchor_rc[1]], max_steps, scene.detour)
    read = jnp.concatenate([candidate, (anchor >= 0)[None]])
    walks = jnp.concatenate([walks, tail.cells[None]])
    # flat indices: half the bytes of (row, col) pairs for every cached task
    walks = jnp.where(read[:, None] & (walks[..., 0] >= 0), walks[..., 0] * w + walks[..., 1], -1)
    if params.monotone:
        reach = jnp.ceil(jnp.sqrt(jnp.sum((source - anchor_rc) ** 2.0))).astype(jnp.int32) + 2
        lo, hi = jnp.maximum(anchor_rc - reach, 0), jnp.minimum(anchor_rc + reach, jnp.asarray([h - 1, w - 1]))
    else:
        lo, hi = jnp.zeros(2, jnp.int32), jnp.asarray([h - 1, w - 1], jnp.int32)
    window = jnp.where(anchor >= 0, jnp.stack([lo[0], hi[0], lo[1], hi[1]]), jnp.asarray([1, 0, 1, 0]))
    return PlanReads(source, jnp.asarray(anchor, jnp.int32), walks, window.astype(jnp.int32))


class FabricChanges(NamedTuple):
    """Where a refresh changed what plans read (``fabric_changes``). H x W grid.

    walked: bool[H, W] cells whose table continuations (``next_dir``, ``next_rank``, any entry) or counts
    changed; counts: i32[H + 1, W + 1] the summed-area table of the cells whose counts changed (entry
    [r, c]: how many in rows < r and columns < c).
    """

    walked: jax.Array
    counts: jax.Array


def fabric_changes(before_obj, obj, old: Fabric, new: Fabric) -> FabricChanges:
    """``FabricChanges`` from the counts ``before_obj`` and fabric ``old`` to ``obj`` and ``new``
    (f32[H, W] each)."""
    moved = before_obj != obj
    table = jnp.any((old.table.next_dir != new.table.next_dir) | (old.table.next_rank != new.table.next_rank), -1)
    counts = jnp.pad(jnp.cumsum(jnp.cumsum(moved.astype(jnp.int32), 0), 1), ((1, 0), (1, 0)))
    return FabricChanges(table | moved, counts)


def plans_unchanged(scene, params: FabricParams, reads: PlanReads, old: Fabric, new: Fabric,
                    changes: FabricChanges):
    """bool[B]: which of B plans (``reads``: ``PlanReads[B]``, read on ``old``) ``plan_for_source``
    would make again, the same, on ``new`` (``changes``: ``fabric_changes(..., old, new)``): the
    source's anchor is the same, the table entries and occupancy read at the source and the anchor
    are the same, no walked cell changed and no count in the connector's window did."""
    src, anchor = reads.source, reads.anchor
    h, w = scene.shape
    same_anchor = source_anchors(scene, params, new, src) == anchor
    at_src = lambda a: a[src[:, 0], src[:, 1]]  # noqa: E731
    same_source = (jnp.all(at_src(old.table.raw) == at_src(new.table.raw), -1)
                   & jnp.all(at_src(old.table.length) == at_src(new.table.length), -1)
                   & (at_src(old.occupied) == at_src(new.occupied)))
    safe = jnp.maximum(anchor, 0)
    ar, ac = safe // w, safe % w
    entry = old.selected[ar, ac]
    same_tail = (anchor < 0) | ((entry == new.selected[ar, ac])
                                & (old.table.raw[ar, ac, entry] == new.table.raw[ar, ac, entry]))
    walked = jnp.any(changes.walked.reshape(-1)[jnp.maximum(reads.walks, 0)] & (reads.walks >= 0), (1, 2))
    r0, r1, c0, c1 = (reads.window[:, i] for i in range(4))
    box = lambda r, c: changes.counts[jnp.clip(r, 0, h), jnp.clip(c, 0, w)]  # noqa: E731
    in_window = box(r1 + 1, c1 + 1) - box(r0, c1 + 1) - box(r1 + 1, c0) + box(r0, c0)
    in_window = jnp.where((r0 <= r1) & (c0 <= c1), in_window, 0)
    return same_anchor & same_source & same_tail & ~walked & (in_window == 0)
