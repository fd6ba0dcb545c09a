"""Serial reference fabric: every source's A* search, then psi, heatmap, highways and connectors.

``reference_fabric`` is the oracle the JAX kernels are tested against and the peer benchmarks compare
with. It follows docs/transport.md literally and favours readability over speed (plain Python,
float64, one priority-queue search per source cell).
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from jaxplan.reference.connectors import anchors as find_anchors
from jaxplan.reference.connectors import connectors as find_connectors
from jaxplan.reference.heatmap import heat_map, highway_mask, psi_map
from jaxplan.reference.search import Graph, reachable_mass_cyclic, reachable_mass_dag, search_kbest
from jaxplan.reference.visibility import DIRS, cos_tol, fallback_alignments, fallback_hop, step_unit, successors

__all__ = ["ReferenceFabric", "reference_fabric"]

# unique_first_hop: candidates this close to the best count as ties of it (objects, cell sizes).
_NEAR_RAW = 0.5
_NEAR_LEN = 1e-6
# A fallback hop whose two best alignments differ by less than this is a tie (float32 rounding decides it).
_NEAR_DOT = 1e-6


def _fallback_tied(r: int, c: int, forward_xy, shape) -> bool:
    """Whether the fallback hop of cell (r, c) (:func:`fallback_hop`) is a near-tie between two
    in-grid neighbours: e.g. ``t(C)`` at 157.5 degrees aligns equally with the 135 and 180 degree steps."""
    dots = sorted(dot for dot, _, _ in fallback_alignments(r, c, forward_xy, shape))
    return len(dots) > 1 and dots[-1] - dots[-2] < _NEAR_DOT


@dataclasses.dataclass
class ReferenceFabric:
    """Everything ``reference_fabric`` computes for an H x W grid (numpy arrays, float64).

    Same names as the JAX ``Fabric`` where both have the field.

    value: f64[H, W], J(C) = raw(P*(C)), objects; 0 where not occupied (-inf for an occupied cell with
      no complete path, possible only without the monotone rule or under a binding hop cap).
    length: f64[H, W], L(C) = len(P*(C)), world units; 0 where not occupied (+inf with no path).
    first_hop: int[H, W, 2], (row, col) of u(C); -1 where undefined.
    heading: f64[H, W, 2], unit (x, y) vector c -> u(C); 0 where undefined.
    fallback: bool[H, W], occupied cells with no feasible successor (boundary fallback).
    occupied: bool[H, W], non-target cells with obj > 0.
    feasible: bool[H, W, 8], direction k of the cell is in Vis (Eq. 1, monotone rule); False on
      non-occupied cells.
    table_raw: f64[H, W, K], objects, the K best paths' raw, best first; -inf for unused entries.
    table_len: f64[H, W, K], world units, their lengths; +inf for unused entries.
    psi: f64[H, W], propagated mass (Eqs. 7-8), objects.
    heat: f64[H, W], look-back heatmap (Eq. 10), objects; 0 on target cells.
    highways: bool[H, W], highway cells (Eq. 11).
    paths: {(r, c): [cells of P*(C)]}, source first, the target cell it ends in included.
    candidates: {(r, c): [(raw, len, [cells]), ...]} best first: the K-best list, or with
      ``slack_tau`` the entries with raw >= J(C) - slack_tau.
    unique_first_hop: bool[H, W], occupied cells whose optimum's first hop is unambiguous: every
      candidate within 0.5 objects and 1e-6 s of the best has the same first hop, and the list
      holds a candidate outside that band or has fewer than K entries (so no tie was cut off), and a
      fallback hop among them is not a near-tie of two neighbours (``_fallback_tied``).
    anchor: int[H, W, 2], (row, col) of h*(R) for roots (Eq. 12); -1 where none.
    conn_raw: f64[H, W], objects on the connector except h*; 0 where no anchor.
    conn_len: f64[H, W], connector length, world units; 0 where no anchor.
    conn_first_hop: int[H, W, 2], second cell of the connector (or its fallback hop); -1 if none.
    via_raw: f64[H, W], conn_raw + J(h*); via_len: f64[H, W], conn_len + L(h*); 0 where no anchor.
    conn_paths: {(r, c): [cells of the connector]} (ends at h*, or at the last cell of a fallback).
    stats: dict with ``expansions``, ``substitutions``, ``pruned``, ``peak_open`` (target searches),
      ``conn_expansions``, ``conn_peak_open`` (connector searches), ``seconds`` (whole call, wall
      clock), ``search_seconds`` (target searches only).
    """

    value: np.ndarray
    length: np.ndarray
    first_hop: np.ndarray
    heading: np.ndarray
    fallback: np.ndarray
    occupied: np.ndarray
    feasible: np.ndarray
    table_raw: np.ndarray
    table_len: np.ndarray
    psi: np.ndarray
    heat: np.ndarray
    highways: np.ndarray
    paths: dict
    candidates: dict
    unique_first_hop: np.ndarray
    anchor: np.ndarray
    conn_raw: np.ndarray
    conn_len: np.ndarray
    conn_first_hop: np.ndarray
    via_raw: np.ndarray
    via_len: np.ndarray
    conn_paths: dict
    stats: dict


def _new_stats() -> dict:
    return {"expansions": 0, "substitutions": 0, "pruned": 0, "peak_open": 0}


def reference_fabric(obj, target_mask, dist, tvec, cell_size, theta_tol_deg, *, monotone=True, k=4,
                     slack_tau=None, reuse=True, max_hops=None, tau_h=0.5, highway_relative=True,
                     highway_smoothing=False, highway_nms=False, anchor_lambda=1.0,
                     with_connectors=True, blocked=None) -> ReferenceFabric:
    """Build the fabric serially (Sections 3.1-3.4, Algorithms 1-4).

    obj: f[H, W], objects per cell (rounded to float32 values, the kernels' dtype, then float64: sums
      of such values are exact, so path scores do not depend on summation order).
    target_mask: bool[H, W]. dist: f[H, W], world units, d(C, T) (0 on target cells).
    tvec: f[H, W, 2], unit (x, y) vector to the closest boundary point ((0, 0) on target cells).
    cell_size: world units. theta_tol_deg: cone half-angle, degrees.
    monotone: strict monotone rule (default). Without it the search enumerates simple paths of at
      most ``max_hops`` steps: exponential, tiny grids only.
    k: K, the depth of each cell's K-best list. slack_tau: if given, ``candidates`` keeps the K-best
      entries with raw >= J - slack_tau (objects). reuse: continuation reuse (Eq. 4), monotone only;
      it changes the work, never the result. max_hops: grid-step cap; default H*W with the monotone
      rule, 2*(H+W) without. tau_h, highway_relative, highway_smoothing, highway_nms: Eq. 11.
    anchor_lambda: Eq. 12, heat units per world unit. with_connectors: compute anchors/connectors.
    blocked: optional bool[H, W], blocked cells (``dist`` is then the obstacle-aware distance, inf on
      cells cut off from every target, which are not occupied).
    """
    t_start = time.perf_counter()
    obj = np.asarray(obj, dtype=np.float32).astype(np.float64)
    target = np.asarray(target_mask, dtype=bool)
    dist = np.asarray(dist, dtype=np.float64)
    tvec = np.asarray(tvec, dtype=np.float64)
    s = float(cell_size)
    cos_theta = cos_tol(theta_tol_deg)
    h, w = obj.shape if obj.ndim == 2 else (-1, -1)
    k = int(k)
    if max_hops is None:
        max_hops = h * w if monotone else 2 * (h + w)
    if obj.ndim != 2 or target.shape != obj.shape or dist.shape != obj.shape or tvec.shape != (h, w, 2):
        raise ValueError(f"reference_fabric: expected obj, target_mask, dist of shape (H, W) and tvec of "
                         f"shape (H, W, 2); got {obj.shape}, {target.shape}, {dist.shape}, {tvec.shape}.")
    if k < 1 or int(max_hops) < 1 or not s > 0:
        raise ValueError(f"reference_fabric: need k >= 1, max_hops >= 1 and cell_size > 0; "
                         f"got k={k}, max_hops={max_hops}, cell_size={s}.")
    max_hops = int(max_hops)
    occupied = ~target & (obj > 0) & np.isfinite(dist)

    # --- Visibility (Algorithm 1) for every occupied cell, once.
    succ = {}
    feasible = np.zeros((h, w, 8), dtype=bool)
    for r in range(h):
        for c in range(w):
            if occupied[r, c]:
                vis = successors(r, c, occupied, target, dist, tvec, s, cos_theta, monotone, blocked)
                succ[(r, c)] = [(d, nxt, bool(target[nxt])) for d, nxt in vis]
                for d, _ in vis:
                    feasible[r, c, d] = True

    # Sources near to far (Section 3.2), ties by row-major index. Under the monotone rule every
    # successor is strictly nearer, so this is also a topological order of the successor graph.
    sources = sorted(succ, key=lambda cell: (dist[cell], cell))

    # --- The cone-visible heuristic h_raw (and, with the monotone rule, the longest path in hops).
    if monotone:
        h_raw, longest = reachable_mass_dag(sources, succ.__getitem__, obj)
        # A cap below the longest path makes the suffixes depend on the hops used so far.
        capped = max(longest.values(), default=0) > max_hops
        dominance = "node_hops" if capped else "node"
        cache = {} if (reuse and not capped) else None
    else:
        h_raw = reachable_mass_cyclic(sources, succ.__getitem__, obj)
        dominance, cache = None, None   # both are invalid when the graph has cycles

    graph = Graph(obj=obj, cell_size=s, successors=succ.__getitem__,
                  fallback_length=lambda cell: float(dist[cell]),
                  h_raw=h_raw.__getitem__, h_len=lambda cell: float(dist[cell]))

    # --- Per-source A* (Algorithm 2), K-best lists.
    stats = _new_stats()
    t_search = time.perf_counter()
    kbest = {}
    for src in sources:
        kbest[src] = search_kbest(graph, src, k, max_hops=max_hops, simple_paths=not monotone,
                                  dominance=dominance, cache=cache, stats=stats)
        if cache is not None:
            cache[src] = kbest[src]
    search_seconds = time.perf_counter() - t_search

    # --- Per-cell fields from the lists.
    value = np.zeros((h, w))
    length = np.zeros((h, w))
    first_hop = np.full((h, w, 2), -1, dtype=np.int64)
    heading = np.zeros((h, w, 2))
    fallback = np.zeros((h, w), dtype=bool)
    table_raw = np.full((h, w, k), -math.inf)
    table_len = np.full((h, w, k), math.inf)
    unique = np.zeros((h, w), dtype=bool)
    paths, candidates = {}, {}

    def hop_of(cand):
        """u(C) for one candidate: its second cell, or the fallback hop when it falls back at C."""
        if cand.first_hop is not None:
            return cand.first_hop
        fb = fallback_hop(cand.cells[0][0], cand.cells[0][1], tuple(tvec[cand.cells[0]]), (h, w))
        return None if fb is None else fb[1]

    for src in sources:
        r, c = src
        lst = kbest[src]
        fallback[r, c] = not succ[src]
        for i, cand in enumerate(lst):
            table_raw[r, c, i] = cand.raw
            table_len[r, c, i] = cand.length
        if not lst:
            value[r, c], length[r, c] = -math.inf, math.inf
            candidates[src] = []
            continue
        best = lst[0]
        value[r, c], length[r, c] = best.raw, best.length
        paths[src] = list(best.cells)
        hop = hop_of(best)
        if hop is not None:
            first_hop[r, c] = hop
            # v(C) = unit(c1 - c) in world (x, y): the unit vector of the step's direction.
            heading[r, c] = step_unit(DIRS.index((hop[0] - r, hop[1] - c)))
        kept = lst if slack_tau is None else [x for x in lst if x.raw >= best.raw - float(slack_tau)]
        candidates[src] = [(x.raw, x.length, list(x.cells)) for x in kept]
        near = [x for x in lst
                if abs(x.raw - best.raw) <= _NEAR_RAW and abs(x.length - best.length) <= _NEAR_LEN * s]
        unique[r, c] = (len({hop_of(x) for x in near}) == 1) and (len(near) < len(lst) or len(lst) < k)
        if any(x.first_hop is None for x in near) and _fallback_tied(r, c, tuple(tvec[r, c]), (h, w)):
            unique[r, c] = False

    # --- psi (Eqs. 7-8), heatmap (Algorithm 3), highways (Eq. 11).
    psi = psi_map(paths, value)
    heat = heat_map(occupied, first_hop, heading, psi, target, s)
    highways = highway_mask(heat, target, tau_h, relative=highway_relative,
                            smoothing=highway_smoothing, nms=highway_nms)

    # --- Anchors (Eq. 12) and connectors (Algorithm 4).
    conn_stats = _new_stats()
    if with_connectors:
        anchor = find_anchors(heat, highways, occupied, s, anchor_lambda)
        conn_raw, conn_len, conn_hop, via_raw, via_len, conn_paths = find_connectors(
            anchor, obj, occupied, value, length, s, cos_theta, monotone=monotone, max_hops=max_hops,
            stats=conn_stats, blocked=blocked)
    else:
        anchor = np.full((h, w, 2), -1, dtype=np.int64)
        conn_hop = np.full((h, w, 2), -1, dtype=np.int64)
        conn_raw, conn_len, via_raw, via_len = (np.zeros((h, w)) for _ in range(4))
        conn_paths = {}

    stats.update(conn_expansions=conn_stats["expansions"], conn_peak_open=conn_stats["peak_open"],
                 search_seconds=search_seconds, seconds=time.perf_counter() - t_start)
    return ReferenceFabric(
        value=value, length=length, first_hop=first_hop, heading=heading, fallback=fallback,
        occupied=occupied, feasible=feasible, table_raw=table_raw, table_len=table_len, psi=psi,
        heat=heat, highways=highways, paths=paths, candidates=candidates, unique_first_hop=unique,
        anchor=anchor, conn_raw=conn_raw, conn_len=conn_len, conn_first_hop=conn_hop,
        via_raw=via_raw, via_len=via_len, conn_paths=conn_paths, stats=stats)
