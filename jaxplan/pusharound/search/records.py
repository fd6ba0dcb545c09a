"""The gap recorder (``plan_pushes(..., record=True)``): what the search learns about gaps.

One :class:`ExpansionRecord` per expansion (one simulated batch): the node's ranked targets with the
Eq. 8-9 terms ``gap_costs`` consumes, what the batch did on each of them, and, once the search has
ended, which target led to the solution and the realised cost from the node to the end. The records
are plain data (NamedTuples of numpy arrays); ``jaxplan.tune.fit_ranking`` fits the weights on them.

Off by default; when off the search builds none of this (and its result does not depend on it).
"""
from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from jaxplan.pusharound.ranking import PresearchFeatures, RankingParams

__all__ = ["ExpansionRecord", "TargetTerms", "expansion_record", "label_records", "terms_cost"]


class TargetTerms(NamedTuple):
    """The Eq. 8-9 terms of one target's cost. first: f64[2] = (C_t, C_p) of the target itself (an
    endpoint disk: (0, its widening term)); tail: f64[P, 3] = (sum C_t, sum C_p, sum h / eta) per
    presearch leaf (the "graph" presearch: its least gap sequence, P = 1; without presearch: zeros);
    mask: bool[P] the leaves Eq. 9's minimum runs over."""

    first: np.ndarray
    tail: np.ndarray
    mask: np.ndarray


def terms_cost(params: RankingParams, terms: TargetTerms) -> float:
    """``C(g) + min over leaves of the tail`` of ``terms`` under ``params`` (numpy; :func:`gap_costs`
    without the penalty)."""
    lt, lp, eta = (float(np.asarray(v)) for v in (params.lambda_t, params.lambda_p, params.eta))
    tail = terms.tail @ np.array([lt, lp, eta])
    return lt * terms.first[0] + lp * terms.first[1] + float(np.min(tail[terms.mask]))


class ExpansionRecord(NamedTuple):
    """One expansion of :func:`plan_pushes` with its node's K targets (in the node's order, cheapest
    first at its evaluation).

    node, depth, visit: i64[] the node's id, its schedule length, its earlier batches; chi: f64[] its
    realised cost (Eq. 11 summed over its schedule).
    endpoint: bool[K] the target is an endpoint disk (Remark 5), not a gap; bodies: i64[K, 2] the
    gap's WCCG body pair (an endpoint disk: (body, -1)).
    features: :class:`PresearchFeatures` (first f64[K, 2], tail f64[K, P, 3], mask bool[K, P], penalty
    f64[K]) with ``gap_costs(params, features) == cost`` for the weights the search ran with: penalty
    holds what the weights do not scale (stuck penalties, the dead-end penalty).
    cost: f64[K] the ``Cost(g)`` the search used.
    tried, children, opened: i64[K] per target, the batch's simulated pushes on it, the children they
    made, and how many of those opened it. child_node, child_target: i64[C] the children's node ids
    and their target indices.
    After the search (:func:`label_records`): solution: bool[K] the target whose child lies on the
    solution's path (all False off the path or when the search failed); to_go_cost: f64[] the
    realised Eq. 11 cost from the node to the solution (NaN off the path); to_go_pushes: i64[] the
    pushes from the node to the solution (-1 off the path).
    """

    node: Any
    depth: Any
    visit: Any
    chi: Any
    endpoint: Any
    bodies: Any
    features: PresearchFeatures
    cost: Any
    tried: Any
    children: Any
    opened: Any
    child_node: Any
    child_target: Any
    solution: Any
    to_go_cost: Any
    to_go_pushes: Any


def expansion_record(params: RankingParams, node, batch: list, children: list) -> ExpansionRecord:
    """The record of one batch of ``node`` (a ``SearchNode`` whose targets carry their
    :class:`TargetTerms`): ``batch`` its simulated candidates, ``children`` the (opened, final, child)
    triples the batch made."""
    targets = node.targets
    k = len(targets)
    p = max(len(tg.terms.mask) for tg in targets)
    first = np.zeros((k, 2))
    tail = np.zeros((k, p, 3))
    mask = np.zeros((k, p), bool)
    penalty = np.zeros(k)
    for i, tg in enumerate(targets):
        n = len(tg.terms.mask)
        first[i], tail[i, :n], mask[i, :n] = tg.terms.first, tg.terms.tail, tg.terms.mask
        # What the weights do not scale: the cost the search used less the weighted terms (round-off,
        # float32 presearch features in "beam" mode, set to 0).
        rest = tg.cost - terms_cost(params, tg.terms)
        penalty[i] = rest if abs(rest) > 1e-5 * max(1.0, abs(tg.cost)) else 0.0
    tried, made, opened = np.zeros(k, np.int64), np.zeros(k, np.int64), np.zeros(k, np.int64)
    np.add.at(tried, [c.target for c in batch], 1)
    child_target = np.array([ch.origin[1] for _, _, ch in children], np.int64)
    np.add.at(made, child_target, 1)
    np.add.at(opened, np.array([ch.origin[1] for o, _, ch in children if o], np.int64), 1)
    bodies = np.array([tuple(tg.bodies) + (-1,) * (2 - len(tg.bodies)) for tg in targets], np.int64).reshape(k, 2)
    return ExpansionRecord(
        node=np.int64(node.nid), depth=np.int64(node.depth), visit=np.int64(node.expansions),
        chi=np.float64(node.chi), endpoint=np.array([tg.kind == "endpoint" for tg in targets]), bodies=bodies,
        features=PresearchFeatures(first, tail, mask, penalty), cost=np.array([tg.cost for tg in targets]),
        tried=tried, children=made, opened=opened,
        child_node=np.array([ch.nid for _, _, ch in children], np.int64), child_target=child_target,
        solution=np.zeros(k, bool), to_go_cost=np.float64(math.nan), to_go_pushes=np.int64(-1))


def label_records(records: list, success: bool, final_node: int, final_chi: float, final_depth: int) -> tuple:
    """``records`` with their outcome filled in: on success, the expansions of the nodes on the path
    from the root to ``final_node`` (the node that passed Eq. 7, with realised cost ``final_chi`` and
    ``final_depth`` pushes) get the target that led there and the cost and pushes still to go."""
    if not success:
        return tuple(records)
    parent = {}
    for rec in records:
        for nid, t in zip(rec.child_node.tolist(), rec.child_target.tolist()):
            parent[nid] = (int(rec.node), t)
    chosen, nid = {}, int(final_node)
    while nid in parent:
        nid, t = parent[nid]
        chosen[nid] = t
    out = []
    for rec in records:
        t = chosen.get(int(rec.node))
        if t is not None:
            sol = np.zeros(len(rec.cost), bool)
            sol[t] = True
            rec = rec._replace(solution=sol, to_go_cost=np.float64(final_chi - float(rec.chi)),
                               to_go_pushes=np.int64(final_depth - int(rec.depth)))
        out.append(rec)
    return tuple(out)
