"""Serial reference for anchors (Eq. 12) and highway connectors (Section 3.4, Algorithm 4).

Plain Python, float64, following docs/transport.md ("Anchors and connectors"):

- roots: occupied cells that are not highway cells; anchor candidates: occupied highway cells;
- ``h*(R) = argmax_h H(h) - lambda * |c_R - c_h|`` (world units), ties to the lowest row-major index;
- the connector ``R -> h*`` is the best single path of the same A* search oriented to ``h*``: forward
  direction ``unit(c_h - c)``, successors are occupied cells or ``h*`` itself, monotone rule
  ``|c_N - c_h| < |c_C - c_h| - 1e-5 s``, entering ``h*`` ends the path, and a cell without successors
  falls back to a straight segment to ``c_h``. Its raw counts its cells except ``h*``;
- the via-highway route is the connector followed by ``P*(h*)``: raw ``conn_raw + J(h*)``, length
  ``conn_len + L(h*)``.
"""
from __future__ import annotations

import math

import numpy as np

from jaxplan.reference.search import (
    Candidate,
    Graph,
    reachable_cells,
    reachable_mass_cyclic,
    reachable_mass_dag,
    search_kbest,
)
from jaxplan.reference.visibility import DIRS, MONOTONE_EPS, cone_ok, fallback_hop, in_grid

__all__ = ["anchors", "anchor_graph", "connector", "connectors"]


def anchors(heat, highways, occupied, cell_size, anchor_lambda) -> np.ndarray:
    """``int[H, W, 2]``: ``(row, col)`` of each root's anchor ``h*`` (Eq. 12); -1 elsewhere.

    heat: f64[H, W] (objects, the unsmoothed ``H``); highways, occupied: bool[H, W]; cell_size: world
    units; anchor_lambda: heat units per world unit. Brute force over all roots x all candidates;
    a strict ``>`` in row-major candidate order gives ties to the lowest row-major index.
    """
    h, w = occupied.shape
    s = float(cell_size)
    lam = float(anchor_lambda)
    out = np.full((h, w, 2), -1, dtype=np.int64)
    candidates = [(r, c) for r in range(h) for c in range(w) if highways[r, c] and occupied[r, c]]
    for r in range(h):
        for c in range(w):
            if not occupied[r, c] or highways[r, c]:
                continue   # not a root
            best, best_score = None, -math.inf
            for hr, hc in candidates:
                score = float(heat[hr, hc]) - lam * s * math.hypot(hr - r, hc - c)
                if score > best_score:
                    best, best_score = (hr, hc), score
            if best is not None:
                out[r, c] = best
    return out


def anchor_graph(root, anchor, obj, occupied, cell_size, cos_theta, monotone, blocked=None):
    """The successor graph oriented to ``anchor`` and the nodes reachable from ``root``.

    Returns ``(graph, forward, nodes, longest)``: the search ``Graph`` (with its ``h_raw`` filled in
    for the reachable nodes), ``forward(cell)`` (unit ``(x, y)`` vector to the anchor), the reachable
    non-anchor nodes sorted by distance to the anchor (nearest first), and with the monotone rule
    ``{node: most grid steps of any path from it}`` (``None`` without it).
    """
    shape = occupied.shape
    s = float(cell_size)
    ar, ac = anchor

    def dist_to_anchor(cell):
        return s * math.hypot(cell[0] - ar, cell[1] - ac)

    def forward(cell):
        dx, dy = ac - cell[1], ar - cell[0]          # world (x, y): x is the column
        n = math.hypot(dx, dy)
        return (dx / n, dy / n)

    succ_cache: dict = {}

    def successors(cell):
        if cell in succ_cache:
            return succ_cache[cell]
        out = []
        r, c = cell
        fwd = forward(cell)
        for k, (dr, dc) in enumerate(DIRS):
            nxt = (r + dr, c + dc)
            if not in_grid(nxt[0], nxt[1], shape):
                continue
            is_goal = nxt == (ar, ac)
            if not (is_goal or occupied[nxt]):
                continue
            if not cone_ok(fwd, k, cos_theta):
                continue
            if blocked is not None and dr and dc and (blocked[r + dr, c] or blocked[r, c + dc]):
                continue
            if monotone and not (dist_to_anchor(nxt) < dist_to_anchor(cell) - MONOTONE_EPS * s):
                continue
            out.append((k, nxt, is_goal))
        succ_cache[cell] = out
        return out

    # Nodes reachable from the root (the only ones the search can touch).
    nodes = {root} | reachable_cells(root, successors)
    order = sorted(nodes, key=lambda cell: (dist_to_anchor(cell), cell))

    longest = None
    if monotone:
        # Successors are strictly closer to the anchor, so nearest-first is a topological order.
        h_raw, longest = reachable_mass_dag(order, successors, obj)
    else:
        h_raw = reachable_mass_cyclic(order, successors, obj)
    graph = Graph(obj=obj, cell_size=s, successors=successors, fallback_length=dist_to_anchor,
                  h_raw=h_raw.__getitem__, h_len=dist_to_anchor)
    return graph, forward, order, longest


def connector(root, anchor, obj, occupied, cell_size, cos_theta, *, monotone, max_hops, stats, blocked=None):
    """The best connector ``root -> anchor`` as a ``Candidate`` (``None`` if no path exists).

    obj: f64[H, W]; occupied: bool[H, W]; cell_size: world units; cos_theta: ``cos(theta_tol)``.
    Also returns the first hop: ``(candidate, first_hop)`` where ``first_hop`` is the second cell of
    the path, or, for a connector that falls back at the root, the in-grid neighbour best aligned with
    the direction to the anchor (as for target fallbacks); ``None`` if undefined.
    """
    graph, forward, _, longest = anchor_graph(root, anchor, obj, occupied, cell_size, cos_theta, monotone, blocked)
    if monotone:
        # Per-node pruning is exact unless the hop cap can cut a path short (then per (node, hops)).
        dominance = "node" if longest[root] <= max_hops else "node_hops"
    else:
        dominance = None
    found = search_kbest(graph, root, 1, max_hops=max_hops, simple_paths=not monotone,
                         dominance=dominance, cache=None, stats=stats)
    if not found:
        return None, None
    best: Candidate = found[0]
    hop = best.first_hop
    if hop is None:
        fb = fallback_hop(root[0], root[1], forward(root), occupied.shape)
        hop = None if fb is None else fb[1]
    return best, hop


def connectors(anchor, obj, occupied, value, length, cell_size, cos_theta, *, monotone, max_hops, stats,
               blocked=None):
    """Connectors and via-highway routes for every root with an anchor.

    anchor: int[H, W, 2] from ``anchors``; obj: f64[H, W]; value, length: f64[H, W] ``J`` and ``L``.
    Returns ``(conn_raw, conn_len, conn_first_hop, via_raw, via_len, conn_paths)``:
    conn_raw f64[H, W] objects (the connector's cells except ``h*``), conn_len f64[H, W] world units,
    conn_first_hop int[H, W, 2], via_raw = conn_raw + J(h*), via_len = conn_len + L(h*), and
    ``conn_paths {root: [cells]}`` (ending at ``h*``, or at the last cell for a fallback connector).
    Cells without an anchor hold 0 / -1; a root whose anchor cannot be reached (possible only without
    the monotone rule or under a binding hop cap) holds -inf raw / +inf length.
    """
    h, w = occupied.shape
    conn_raw = np.zeros((h, w))
    conn_len = np.zeros((h, w))
    via_raw = np.zeros((h, w))
    via_len = np.zeros((h, w))
    conn_hop = np.full((h, w, 2), -1, dtype=np.int64)
    conn_paths = {}
    for r in range(h):
        for c in range(w):
            if anchor[r, c, 0] < 0:
                continue
            hstar = (int(anchor[r, c, 0]), int(anchor[r, c, 1]))
            best, hop = connector((r, c), hstar, obj, occupied, cell_size, cos_theta,
                                  monotone=monotone, max_hops=max_hops, stats=stats, blocked=blocked)
            if best is None:
                conn_raw[r, c], conn_len[r, c] = -math.inf, math.inf
                via_raw[r, c], via_len[r, c] = -math.inf, math.inf
                continue
            conn_raw[r, c], conn_len[r, c] = best.raw, best.length
            via_raw[r, c] = best.raw + value[hstar]
            via_len[r, c] = best.length + length[hstar]
            if hop is not None:
                conn_hop[r, c] = hop
            conn_paths[(r, c)] = list(best.cells)
    return conn_raw, conn_len, conn_hop, via_raw, via_len, conn_paths
