"""Serial reference for the per-source A* search (Section 3.2, Algorithm 2), with K-best lists.

One search per source cell, a ``heapq`` priority queue, plain Python. The search is generic over an
oriented successor graph (``Graph``): the fabric orients it to the target (``fabric.py``), connectors
orient it to an anchor cell (``connectors.py``).

Scores and order (docs/transport.md, "Paths and the fabric")
----------------------------------------------------------------
A complete path has ``raw`` (objects on its non-goal cells, source included) and ``len`` (world
units: every grid step in full, plus the fallback segment when it ends with a fallback). Paths are
ranked by ``(raw, -len)``; exact ties go to the lower first direction, then the lower continuation
rank. With the monotone rule that tie rule is the same as comparing the paths' direction sequences
lexicographically (a fallback end counts as direction 8): two tied paths through the same first
neighbour are tied suffixes there, ranked in the neighbour's list by the same rule, recursively.
So one comparison (``precedes``) serves every list. Lengths are equal when within ``1e-9 * s``
(sums of ``s`` and ``s*sqrt(2)`` taken in different orders differ in the last bits); raws compare
exactly (the fabric rounds obj to float32 values, whose float64 sums are exact in practice).

The A* priority of a partial path ending at ``v`` is lexicographic, best first:
``f_raw = g_raw + h_raw(v)`` (largest first), then ``f_len = g_len + h_len(v)`` (smallest first), then
the direction sequence so far. ``h_raw(v)`` is the mass of the occupied cells reachable from ``v``
(an upper bound on what is left to collect: a path visits each at most once) and ``h_len(v)`` is the
straight-line distance from ``v`` to the goal (a lower bound on the remaining length). Both are
admissible, so complete paths leave the queue in rank order and the search stops once ``K`` of
them are out and nothing left in the queue can tie or beat the K-th.

Prefix lengths are kept as counts of straight and diagonal steps and turned into
``s * (n_straight + n_diag * sqrt(2))``, so two prefixes of equal length compare exactly equal and
the direction sequence then decides, as the tie rule asks.

Pruning and reuse (monotone rule only)
--------------------------------------
- Per-node K-dominance: the paths that can follow a node do not depend on how the search got there
  (the graph is acyclic, so no prefix can block a suffix), and prefixes at one node leave the queue
  in their own rank order (they share ``h``). A prefix ranked K+1 or worse at a node therefore only
  leads to paths that K others beat, so each node is expanded at most K times.
- Continuation reuse (value substitution, Eq. 4): when a prefix reaches a node ``s`` whose K-best list
  is already known (sources are solved near to far, so every successor of a source is solved before
  it), ``s`` is not expanded: the prefix joined with each of ``s``'s K continuations goes straight
  into the queue as a complete path with its exact score. Reuse changes the work, never the result.
- With a hop cap that can bind (``max_hops`` below the longest path), the suffixes depend on the
  hops already used: dominance is then per ``(node, hops)`` and reuse is off.

Without the monotone rule the graph may have cycles: the search runs over SIMPLE paths (no revisits)
of at most ``max_hops`` grid steps, as a plain best-first tree search with neither pruning nor reuse
(both would be wrong there). Its cost is exponential in the path length: tiny grids only.
"""
from __future__ import annotations

import dataclasses
import functools
import heapq
import math
from collections.abc import Callable, Hashable

import numpy as np

from jaxplan.reference.visibility import DIRS, FALLBACK, step_cells

__all__ = ["Candidate", "Graph", "make_candidate", "precedes", "sort_candidates", "search_kbest",
           "reachable_mass_dag", "reachable_mass_cyclic", "LEN_TOL"]

Cell = tuple[int, int]

SQRT2 = math.sqrt(2.0)
LEN_TOL = 1e-9  # two lengths are equal when within LEN_TOL * cell_size
# Whether each direction is a diagonal step (length s*sqrt(2)) rather than a straight one (length s).
DIAG_OF = tuple(dr != 0 and dc != 0 for dr, dc in DIRS)


@dataclasses.dataclass(frozen=True)
class Candidate:
    """One complete path.

    raw: objects collected (the path's non-goal cells, source included).
    length: world units (grid steps in full, plus the fallback segment if any).
    cells: ``(row, col)`` of the source, then each cell entered; a path that ends by entering a goal
      cell includes it, a fallback path ends at the last grid cell.
    dirs: direction index (0-7) of each step, then ``8`` when the path ends with a fallback.
    """

    raw: float
    length: float
    cells: tuple[Cell, ...]
    dirs: tuple[int, ...]

    @property
    def fallback(self) -> bool:
        return bool(self.dirs) and self.dirs[-1] == FALLBACK

    @property
    def hops(self) -> int:
        """Grid steps (the fallback segment is not a step)."""
        return len(self.dirs) - int(self.fallback)

    @property
    def first_hop(self) -> Cell | None:
        """Second cell of the path, ``None`` for a path that falls back at its source."""
        return self.cells[1] if len(self.cells) > 1 else None


@dataclasses.dataclass
class Graph:
    """An oriented successor graph for the search.

    obj: f64[H, W] objects per cell. cell_size: world units.
    successors: cell -> list of ``(direction, next_cell, is_goal)`` in direction order; an empty list
      means the cell ends with a fallback. Entering a goal cell ends a path.
    fallback_length: cell -> world length of the fallback segment from that cell.
    h_raw: cell -> admissible upper bound on the objects still collectable after the cell.
    h_len: cell -> admissible lower bound on the length still to go (world units).
    """

    obj: np.ndarray
    cell_size: float
    successors: Callable[[Cell], list]
    fallback_length: Callable[[Cell], float]
    h_raw: Callable[[Cell], float]
    h_len: Callable[[Cell], float]


def make_candidate(graph: Graph, cells, dirs) -> Candidate:
    """Build a complete path with its canonical score.

    The sums run from the end of the path back to the source (``raw(C) = obj(C) + raw(rest)``), the
    order in which the continuation table accumulates them, so a path gets the same numbers whatever
    search (with or without reuse) found it.
    """
    cells, dirs = tuple(cells), tuple(dirs)
    fallback = bool(dirs) and dirs[-1] == FALLBACK
    steps = dirs[:-1] if fallback else dirs
    counted = cells if fallback else cells[:-1]   # the goal cell a path enters is not collected
    raw = 0.0
    for cell in reversed(counted):
        raw = float(graph.obj[cell]) + raw
    length = graph.fallback_length(cells[-1]) if fallback else 0.0
    for k in reversed(steps):
        length = step_cells(k) * graph.cell_size + length
    return Candidate(raw, length, cells, dirs)


def precedes(a: Candidate, b: Candidate, cell_size: float) -> bool:
    """Whether ``a`` ranks strictly before ``b``: more raw, then shorter, then lower directions."""
    if a.raw != b.raw:
        return a.raw > b.raw
    if abs(a.length - b.length) > LEN_TOL * cell_size:
        return a.length < b.length
    return a.dirs < b.dirs


def sort_candidates(cands, cell_size: float) -> list[Candidate]:
    """Candidates sorted best first by ``precedes``."""
    def cmp(a, b):
        return -1 if precedes(a, b, cell_size) else (1 if precedes(b, a, cell_size) else 0)
    return sorted(cands, key=functools.cmp_to_key(cmp))


def _strictly_worse(f_raw, f_len, c: Candidate, cell_size) -> bool:
    """Whether a queue entry with bounds ``(f_raw, f_len)`` cannot tie or beat candidate ``c``."""
    if f_raw != c.raw:
        return f_raw < c.raw
    return f_len > c.length + LEN_TOL * cell_size


def search_kbest(graph: Graph, source: Cell, k: int, *, max_hops: int, simple_paths: bool,
                 dominance: str | None, cache: dict | None, stats: dict) -> list[Candidate]:
    """The ``k`` best complete paths from ``source``, best first (fewer if fewer exist).

    max_hops: most grid steps a path may take. simple_paths: forbid revisiting a cell (needed without
    the monotone rule; with it every path is simple anyway). dominance: ``"node"`` (expand each node
    at most k times), ``"node_hops"`` (at most k times per (node, hops used)), or ``None`` (no
    pruning). cache: ``{cell: [Candidate, ...]}`` of solved cells for continuation reuse, or ``None``.
    stats: counters updated in place: ``expansions`` (nodes whose successors were generated),
    ``substitutions`` (prefixes completed from the cache), ``pruned``, ``peak_open``.
    """
    s = graph.cell_size
    heap: list = []
    tick = 0  # unique last key component: the payloads are never compared

    def push_partial(cells, dirs, g_raw, n_straight, n_diag):
        nonlocal tick
        v = cells[-1]
        g_len = s * (n_straight + n_diag * SQRT2)
        key = (-(g_raw + graph.h_raw(v)), g_len + graph.h_len(v), dirs, tick)
        heapq.heappush(heap, (key, ("partial", cells, dirs, g_raw, n_straight, n_diag)))
        tick += 1
        stats["peak_open"] = max(stats["peak_open"], len(heap))

    def push_complete(cells, dirs):
        nonlocal tick
        cand = make_candidate(graph, cells, dirs)
        heapq.heappush(heap, ((-cand.raw, cand.length, cand.dirs, tick), ("complete", cand)))
        tick += 1
        stats["peak_open"] = max(stats["peak_open"], len(heap))

    push_partial((source,), (), float(graph.obj[source]), 0, 0)
    done: list[Candidate] = []
    expanded_at: dict[Hashable, int] = {}

    while heap:
        if len(done) >= k:
            top_key = heap[0][0]
            if _strictly_worse(-top_key[0], top_key[1], done[k - 1], s):
                break
        _, item = heapq.heappop(heap)
        if item[0] == "complete":
            done.append(item[1])
            continue
        _, cells, dirs, g_raw, n_straight, n_diag = item
        v = cells[-1]
        hops = len(dirs)

        if dominance is not None:
            dom_key = v if dominance == "node" else (v, hops)
            if expanded_at.get(dom_key, 0) >= k:
                stats["pruned"] += 1
                continue
            expanded_at[dom_key] = expanded_at.get(dom_key, 0) + 1

        if cache is not None and v != source and v in cache:
            # Value substitution (Eq. 4): join the prefix with every cached continuation of v.
            stats["substitutions"] += 1
            for cont in cache[v]:
                push_complete(cells + cont.cells[1:], dirs + cont.dirs)
            continue

        stats["expansions"] += 1
        succ = graph.successors(v)
        if not succ:
            # Boundary fallback: a straight segment from v; it collects nothing more.
            push_complete(cells, dirs + (FALLBACK,))
            continue
        if hops + 1 > max_hops:
            continue  # the hop cap: no further step allowed (and v has successors, so no fallback)
        for d, nxt, is_goal in succ:
            if simple_paths and nxt in cells:
                continue
            if is_goal:
                push_complete(cells + (nxt,), dirs + (d,))
            else:
                diag = DIAG_OF[d]
                push_partial(cells + (nxt,), dirs + (d,), g_raw + float(graph.obj[nxt]),
                             n_straight + int(not diag), n_diag + int(diag))

    return sort_candidates(done, s)[:k]




# ----------------------------------------------------------------------------------------------
# The cone-visible heuristic: mass of the occupied cells reachable from a node


def _bits_mass(bits: int, obj_flat: np.ndarray) -> float:
    """Total of ``obj_flat`` over the set bits of ``bits`` (bit i = flat cell index i)."""
    if bits == 0:
        return 0.0
    n = obj_flat.size
    raw = np.frombuffer(bits.to_bytes((n + 7) // 8, "little"), dtype=np.uint8)
    mask = np.unpackbits(raw, bitorder="little")[:n].astype(bool)
    return float(obj_flat[mask].sum())


def reachable_mass_dag(order, successors, obj: np.ndarray):
    """``h_raw`` and the longest hop count for every node of an acyclic successor graph.

    order: nodes such that every successor comes before its predecessors (e.g. increasing distance to
    the goal under the strict monotone rule). successors: node -> list of (dir, next, is_goal).
    obj: f64[H, W].

    Reachable sets are Python-int bitsets (bit ``r * W + c``): reach(v) = union over non-goal
    successors n of {n} | reach(n). Returns ``(h_raw: {node: float}, longest: {node: int})``, where
    ``longest`` counts grid steps (a step into a goal counts, a fallback does not).
    """
    w = obj.shape[1]
    obj_flat = obj.reshape(-1)
    reach: dict = {}
    h_raw: dict = {}
    longest: dict = {}
    for v in order:
        bits = 0
        hops = 0
        for _, nxt, is_goal in successors(v):
            if is_goal:
                hops = max(hops, 1)
            else:
                bits |= reach[nxt] | (1 << (nxt[0] * w + nxt[1]))
                hops = max(hops, 1 + longest[nxt])
        reach[v] = bits
        longest[v] = hops
        h_raw[v] = _bits_mass(bits, obj_flat)
    return h_raw, longest


def reachable_cells(start, successors) -> set:
    """Non-goal cells reachable from ``start`` by one or more successor steps (depth-first)."""
    seen = set()
    stack = [start]
    while stack:
        u = stack.pop()
        for _, nxt, is_goal in successors(u):
            if not is_goal and nxt not in seen:
                seen.add(nxt)
                stack.append(nxt)
    return seen


def reachable_mass_cyclic(nodes, successors, obj: np.ndarray) -> dict:
    """``h_raw`` for a successor graph that may have cycles: a graph search from every node.

    The node itself is excluded even when a cycle leads back to it (a simple path cannot collect it
    twice). Returns ``{node: float}``.
    """
    return {v: float(sum(obj[c] for c in reachable_cells(v, successors) - {v})) for v in nodes}
