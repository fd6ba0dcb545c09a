"""Route selection with spillage on (Section 3.2, Eq. 6), batched over sources.

A source's candidate set is every entry of its continuation table whose raw count is within the slack
``tau`` of the best (``raw >= J(C) - tau``). With spillage on, each candidate is pushed through the spill
evaluator and the selected route maximises ``(delivered, -length)``; delivered masses within
``DELIVERED_TIE`` objects count as equal, so near-ties go to the shorter route and then to the lower
table entry. With spillage off the selection is entry 0 (Eq. 5).

``reselect`` applies the selection to every source at once and re-derives what follows the selected
paths (first hops, headings, psi, heatmap, highways), as the paper does once one route has been
selected for each source (Section 3.3); ``build_fabric`` alone uses entry 0.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan import execute, fabric as _fabric, spillage
from jaxplan.fabric import Fabric, _walk

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
        path = _walk(fabric.table, source, rank, max_steps)
        route = execute.route_from_path(scene, path.cells, path.n_cells, path.fallback)
        points, n_points = execute.waypoints(scene, route)
        pickup, _ = execute.waypoint_pickup(scene, route)
        return spillage.evaluate_route(points, n_points, pickup, spill, evaluator)[0]

    ranks = jnp.arange(k, dtype=jnp.int32)
    delivered = jax.vmap(lambda s: jax.vmap(lambda r: delivered_of(s, r))(ranks))(sources)
    delivered = jnp.where(candidate, delivered, -jnp.inf)
    return Selection(_pick(delivered, length, candidate), delivered, candidate)


select_routes_jit = jax.jit(select_routes, static_argnames=("max_steps", "evaluator"))


def select_all(scene, fabric: Fabric, slack_tau, spill: spillage.SpillParams, *, max_steps: int,
               evaluator: spillage.Evaluator = spillage.curvature_spill):
    """``i32[H, W]``: the Eq. 6 entry of every occupied cell (0 elsewhere, and everywhere with
    spillage off), ``select_routes`` over all cells in one batched call."""
    h, w = fabric.occupied.shape
    if not spill.enabled:
        return jnp.zeros((h, w), jnp.int32)
    rows, cols = jnp.meshgrid(jnp.arange(h, dtype=jnp.int32), jnp.arange(w, dtype=jnp.int32), indexing="ij")
    sources = jnp.stack([rows.reshape(-1), cols.reshape(-1)], -1)
    entry = select_routes(scene, fabric, sources, slack_tau, spill, max_steps=max_steps, evaluator=evaluator).entry
    return jnp.where(fabric.occupied, entry.reshape(h, w), 0)


def reselect(scene, params, fabric: Fabric, spill: spillage.SpillParams, *, max_steps: int,
             evaluator: spillage.Evaluator = spillage.curvature_spill) -> Fabric:
    """``fabric`` with every source's path chosen by Eq. 6 (``select_all``): ``selected``, first hops,
    headings, fallbacks, psi (Phi = the selected route's raw count, Eq. 7), heatmap and highways
    follow the selected entries; the table, ``value`` and ``length`` (entry 0) are unchanged.

    params: the ``FabricParams`` the fabric was built with (its ``slack_tau``, ``tau_h``, highway
    options); max_steps: static walk length (``fabric.table_hops`` bounds it).
    """
    entry = select_all(scene, fabric, params.slack_tau, spill, max_steps=max_steps, evaluator=evaluator)
    return _fabric.derive(scene, params, fabric.table, jnp.moveaxis(fabric.feasible, -1, 0), fabric.rounds,
                          fabric.converged, entry)


reselect_jit = jax.jit(reselect, static_argnames=("max_steps", "evaluator"))
