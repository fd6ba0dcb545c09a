"""Route selection with spillage on (Section 3.2, Eq. 6), batched over sources.

A source's candidate set is every entry of its continuation table whose raw count is within the slack
``tau`` of the best (``raw >= J(C) - tau``). With spillage on, each candidate is pushed through the spill
evaluator and the selected route maximises ``(delivered, -length)``; delivered masses within
``DELIVERED_TIE`` objects count as equal, so near-ties go to the shorter route and then to the lower
table entry. With spillage off the selection is entry 0 (Eq. 5).

``reselect`` applies the selection to every source at once and re-derives what follows the selected
paths (first hops, headings, psi, heatmap, highways), as the paper does once one route has been
selected for each source (Section 3.3); ``build_fabric`` alone uses entry 0.

Only sources with two or more candidates need the spill evaluator (a single candidate is entry 0).
Called with concrete arrays, ``select_all`` reads how many (source, entry) pairs that leaves and
how long their longest walk is, and evaluates just those pairs in a buffer of the next power-of-two
size, walked for the next power-of-two length (each size compiles once); under a caller's ``jit``
it evaluates every cell's every entry in one program. Both give the same entries.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.core import grid_jit, traced
from jaxplan.transport import execute, rebuild, spillage
from jaxplan.transport import fabric as _fabric
from jaxplan.transport.fabric import Fabric, walk_table

DELIVERED_TIE = 1e-4   # objects


class Selection(NamedTuple):
    """Per-source route choice. B sources, K table entries.

    entry: i32[B], the selected table entry.  delivered: f32[B, K] objects per candidate (-inf
    outside the candidate set).  candidate: bool[B, K], inside the slack-tau candidate set.
    """

    entry: jax.Array
    delivered: jax.Array
    candidate: jax.Array


def candidate_mask(raw, slack_tau):
    """``bool[..., K]``: table entries with ``raw >= raw[..., 0] - slack_tau`` (used entries only)."""
    return (raw > -jnp.inf) & (raw >= raw[..., :1] - slack_tau)


def _pick(delivered, length, candidate):
    """Lexicographic argmax of (delivered, -length) over the last axis, ties to the lower index."""
    best = jnp.max(jnp.where(candidate, delivered, -jnp.inf), -1, keepdims=True)
    near = candidate & (delivered >= best - DELIVERED_TIE)
    shortest = jnp.min(jnp.where(near, length, jnp.inf), -1, keepdims=True)
    return jnp.argmax(near & (length <= shortest), -1).astype(jnp.int32)


def _delivered(scene, table, source, rank, spill: spillage.SpillParams, max_steps: int, evaluator):
    """f32[]: objects delivered by pushing table entry ``rank`` of ``source`` (i32[2])."""
    path = walk_table(table, source, rank, max_steps, scene.detour)
    route = execute.route_from_path(scene, path.cells, path.n_cells, path.fallback)
    points, n_points = execute.waypoints(scene, route)
    pickup, _ = execute.waypoint_pickup(scene, route)
    return spillage.evaluate_route(points, n_points, pickup, spill, evaluator, chunk=execute.SPLINE_CHUNK)[0]


def select_routes(scene, fabric: Fabric, sources, slack_tau, spill: spillage.SpillParams, *, max_steps: int,
                  evaluator: spillage.Evaluator = spillage.curvature_spill) -> Selection:
    """Eq. 6 for every source in ``sources: i32[B, 2]`` at once (``vmap`` over sources and entries).

    slack_tau: f32[] objects; max_steps: static walk length (``fabric.table_hops`` bounds it).
    """
    sources = jnp.asarray(sources, jnp.int32).reshape(-1, 2)
    k = fabric.table.raw.shape[-1]
    raw = fabric.table.raw[sources[:, 0], sources[:, 1]]
    length = fabric.table.length[sources[:, 0], sources[:, 1]]
    candidate = candidate_mask(raw, slack_tau)
    if not spill.enabled:
        return Selection(jnp.zeros(sources.shape[0], jnp.int32), jnp.where(candidate, raw, -jnp.inf), candidate)

    def delivered_of(source, rank):
        return _delivered(scene, fabric.table, source, rank, spill, max_steps, evaluator)

    ranks = jnp.arange(k, dtype=jnp.int32)
    delivered = jax.vmap(lambda s: jax.vmap(lambda r: delivered_of(s, r))(ranks))(sources)
    delivered = jnp.where(candidate, delivered, -jnp.inf)
    return Selection(_pick(delivered, length, candidate), delivered, candidate)


select_routes_jit = grid_jit(select_routes, static_argnames=("max_steps", "evaluator"))


def _pairs_to_evaluate(fabric: Fabric, slack_tau):
    """``bool[H, W, K]``: the candidate entries of occupied sources that have two or more candidates."""
    candidate = candidate_mask(fabric.table.raw, slack_tau) & fabric.occupied[..., None]
    return candidate & (jnp.sum(candidate, -1, keepdims=True) >= 2)


@grid_jit
def _pair_counts(fabric: Fabric, slack_tau, detour):
    """``(pairs, longest)``: how many pairs need the evaluator, and the most grid steps among them
    (detour steps included; detour: ``Scene.detour``)."""
    pairs = _pairs_to_evaluate(fabric, slack_tau)
    hops = _fabric.count_table_hops(fabric.table, detour)
    return jnp.sum(pairs, dtype=jnp.int32), jnp.max(jnp.where(pairs, hops, 0))


def _select_pairs(scene, fabric: Fabric, slack_tau, spill: spillage.SpillParams, *, capacity: int,
                  max_steps: int, evaluator):
    """``i32[H, W]`` Eq. 6 entries, the evaluator run on the first ``capacity`` pairs only."""
    h, w, k = fabric.table.raw.shape
    pairs = _pairs_to_evaluate(fabric, slack_tau)
    flat = jnp.nonzero(pairs.reshape(-1), size=capacity, fill_value=h * w * k)[0]
    safe = jnp.minimum(flat, h * w * k - 1)
    cell, rank = safe // k, (safe % k).astype(jnp.int32)
    sources = jnp.stack([cell // w, cell % w], -1).astype(jnp.int32)
    delivered = jax.vmap(lambda s, r: _delivered(scene, fabric.table, s, r, spill, max_steps, evaluator))(sources, rank)
    delivered = jnp.full(h * w * k, -jnp.inf).at[flat].set(delivered, mode="drop").reshape(h, w, k)
    entry = _pick(delivered, fabric.table.length, pairs)
    return jnp.where(jnp.any(pairs, -1), entry, 0)


_select_pairs_jit = grid_jit(_select_pairs, static_argnames=("capacity", "max_steps", "evaluator"))


def _bucket(n: int, largest: int, smallest: int) -> int:
    """The smallest of ``smallest``, 2 ``smallest``, 4 ``smallest``, ... that is >= n, capped at ``largest``."""
    return next((size for size in rebuild.capacity_buckets(largest, smallest) if size >= n), largest)


def _select_every_cell(scene, fabric: Fabric, slack_tau, spill, *, max_steps: int, evaluator):
    h, w = fabric.occupied.shape
    rows, cols = jnp.meshgrid(jnp.arange(h, dtype=jnp.int32), jnp.arange(w, dtype=jnp.int32), indexing="ij")
    sources = jnp.stack([rows.reshape(-1), cols.reshape(-1)], -1)
    entry = select_routes(scene, fabric, sources, slack_tau, spill, max_steps=max_steps, evaluator=evaluator).entry
    return jnp.where(fabric.occupied, entry.reshape(h, w), 0)


def select_all(scene, fabric: Fabric, slack_tau, spill: spillage.SpillParams, *, max_steps: int,
               evaluator: spillage.Evaluator = spillage.curvature_spill):
    """``i32[H, W]``: the Eq. 6 entry of every occupied cell (0 elsewhere, and everywhere with
    spillage off). max_steps: static walk length, as in ``select_routes``.

    With concrete arrays only the pairs that need the evaluator are walked (module docstring);
    traced, every cell's every entry is, in one program (``select_routes`` over all cells).
    """
    h, w = fabric.occupied.shape
    if not spill.enabled:
        return jnp.zeros((h, w), jnp.int32)
    if traced(scene, fabric, slack_tau, spill):
        return _select_every_cell(scene, fabric, slack_tau, spill, max_steps=max_steps, evaluator=evaluator)
    n_pairs, longest = (int(x) for x in _pair_counts(fabric, slack_tau, scene.detour))
    if n_pairs == 0:
        return jnp.zeros((h, w), jnp.int32)
    capacity = _bucket(n_pairs, fabric.table.raw.size, 64)
    # + 1: a final fallback is a walk step; never longer than the caller's walk, which it then equals
    walk = _bucket(longest + 1, int(max_steps), 8)
    return _select_pairs_jit(scene, fabric, slack_tau, spill, capacity=capacity, max_steps=walk, evaluator=evaluator)


def reselect(scene, params, fabric: Fabric, spill: spillage.SpillParams, *, max_steps: int,
             evaluator: spillage.Evaluator = spillage.curvature_spill) -> Fabric:
    """``fabric`` with every source's path chosen by Eq. 6 (``select_all``): ``selected``, first hops,
    headings, fallbacks, psi (Phi = the selected route's raw count, Eq. 7), heatmap and highways
    follow the selected entries; the table, ``value`` and ``length`` (entry 0) are unchanged.

    params: the ``FabricParams`` the fabric was built with (its ``slack_tau``, ``tau_h``, highway
    options); max_steps: static walk length (``fabric.table_hops`` bounds it). Concrete arrays take
    the compact evaluation of ``select_all`` and a jitted re-derivation; ``reselect_jit`` is the
    whole of it as one program.
    """
    entry = select_all(scene, fabric, params.slack_tau, spill, max_steps=max_steps, evaluator=evaluator)
    return _rederive_jit(scene, params, fabric, entry)   # under a caller's jit this is inlined


@grid_jit
def _rederive_jit(scene, params, fabric: Fabric, entry):
    return _fabric.derive(scene, params, fabric.table, jnp.moveaxis(fabric.feasible, -1, 0), fabric.rounds,
                          fabric.converged, entry)


reselect_jit = grid_jit(reselect, static_argnames=("max_steps", "evaluator"))
