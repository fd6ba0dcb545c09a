"""Serial reference of the fleet's kernels (``jaxplan.fleet``): plain Python, one cell and one rover
at a time, written from docs/fleet.md.

- ``distance_field``: breadth-first search from the goal (a queue), 8-connected.
- ``distance_field_to``: the same search, left once the stop cell's layer is labelled.
- ``move_rovers``: the prioritised one-step move rule.
- ``greedy_assign``: the coordinated strategy's greedy choice over (idle rover, candidate) pairs.
- ``rate_sources``: the idle rovers' best sources by rate (``FleetConfig.candidates_by="rate"``).
- ``make_way``: parked rovers that hold up the best free candidate sent to new homes.
- ``first_blocker``, ``path_blocker``: the rover a footprint, or a source's fabric path, meets first.
"""
from __future__ import annotations

from collections import deque

import numpy as np

from jaxplan.reference.heatmap import table_path
from jaxplan.reference.visibility import DIRS

FAR = 2 ** 30          # as jaxplan.fleet.motion.FAR
IDLE, APPROACH, PUSH = 0, 1, 2


def _cuts_corner(blocked, r, c, dr, dc) -> bool:
    """Whether the step (dr, dc) from (r, c) passes between a blocked cell and another (docs/fleet.md)."""
    return blocked is not None and bool(dr and dc and (blocked[r + dr, c] or blocked[r, c + dc]))


def distance_field(goal, passable, stop_at=None, blocked=None) -> np.ndarray:
    """i64[H, W]: 8-connected steps to ``goal`` (row, col) through ``passable`` cells; FAR elsewhere.
    blocked: optional bool[H, W]; no step cuts a blocked cell's corner.

    With ``stop_at``: every cell farther from ``goal`` than ``stop_at`` is left FAR (nothing changes
    where ``stop_at`` cannot reach the goal). The queue holds cells in order of distance, so the
    first cell popped at the stop cell's distance d* means every cell at d* is labelled: the search
    ends there, before labelling d* + 1.
    """
    passable = np.asarray(passable, bool)
    h, w = passable.shape
    d = np.full((h, w), FAR, np.int64)
    g = (int(goal[0]), int(goal[1]))
    stop = None if stop_at is None else (int(stop_at[0]), int(stop_at[1]))
    if not passable[g]:
        return d
    d[g] = 0
    queue = deque([g])
    while queue:
        r, c = queue.popleft()
        if stop is not None and d[r, c] >= d[stop]:
            break
        for dr, dc in DIRS:
            q = (r + dr, c + dc)
            if 0 <= q[0] < h and 0 <= q[1] < w and passable[q] and d[q] == FAR and \
                    not _cuts_corner(blocked, r, c, dr, dc):
                d[q] = d[r, c] + 1
                queue.append(q)
    return d


def distance_field_to(goal, passable, stop_at, blocked=None) -> np.ndarray:
    """``distance_field`` stopped at ``stop_at`` (the serial twin of ``motion.distance_field_to``)."""
    return distance_field(goal, passable, stop_at, blocked)


def move_rovers(pos, phase, dist, owner, push_next, blocked=None):
    """``(pos i64[N, 2], moved bool[N])`` after one step of the move rule (``jaxplan.fleet.motion``):
    dist[r] is rover r's distance grid (its pool field, or the Chebyshev distance to its goal);
    blocked: optional bool[H, W], cells no rover enters and whose corners no approach step cuts."""
    pos = [tuple(int(v) for v in p) for p in np.asarray(pos)]
    owner = np.asarray(owner)
    h, w = owner.shape
    held = {p: r for r, p in enumerate(pos)}
    moved = [False] * len(pos)
    for r, here in enumerate(pos):
        def free(q, r=r):
            inside = 0 <= q[0] < h and 0 <= q[1] < w
            return inside and owner[q] in (-1, r) and q not in held and (blocked is None or not blocked[q])
        to = here
        if phase[r] != PUSH:
            best = dist[r][here]
            for dr, dc in DIRS:
                q = (here[0] + dr, here[1] + dc)
                if free(q) and dist[r][q] < best and not _cuts_corner(blocked, here[0], here[1], dr, dc):
                    to, best = q, dist[r][q]
        elif phase[r] == PUSH:
            q = tuple(int(v) for v in push_next[r])
            if q != here and free(q):
                to = q
        if to != here:
            del held[here]
            held[to] = r
            pos[r] = to
            moved[r] = True
    return np.asarray(pos, np.int64).reshape(-1, 2), np.asarray(moved)


def greedy_assign(idle, pos, starts, steps, predicted, usable, footprints, reserved=()):
    """The coordinated strategy's greedy assignment: a list of (rover, candidate) in the order chosen.

    idle: bool[N]; pos: [N, 2] rover cells; starts: [M, 2] each candidate's first cell; steps: [M]
    push steps; predicted: [M] delivered objects; usable: bool[M] (a pushable plan); footprints: M
    sets of (row, col); reserved: cells of the footprints of tasks already running.
    Each round takes the best score ``predicted / (Chebyshev(rover, start) + steps)`` (float32, as the
    kernel) over idle rovers x unused usable candidates whose footprint meets neither ``reserved`` nor
    a footprint chosen before and holds no other rover's cell; ties go to the lowest (rover,
    candidate) in row-major order. It stops when no pair is left.
    """
    idle = [bool(v) for v in idle]
    pos = [tuple(int(v) for v in p) for p in np.asarray(pos)]
    used = [False] * len(footprints)
    taken = set(reserved)
    chosen = []
    while True:
        best, pick = -np.inf, None
        for r in range(len(pos)):
            if not idle[r]:
                continue
            for c, cells in enumerate(footprints):
                if used[c] or not usable[c] or cells & taken:
                    continue
                if any(p in cells for q, p in enumerate(pos) if q != r):
                    continue
                approach = max(abs(pos[r][0] - int(starts[c][0])), abs(pos[r][1] - int(starts[c][1])))
                score = np.float32(predicted[c]) / np.float32(approach + int(steps[c]))
                if score > best:
                    best, pick = score, (r, c)
        if pick is None:
            return chosen
        r, c = pick
        chosen.append(pick)
        idle[r], used[c] = False, True
        taken |= footprints[c]


def rate_sources(value, length, occupied, owner, pos, idle, m: int, cell_size: float, per_rover: int = 2):
    """The flat cell indices (a list of at most m) of the idle rovers' ``per_rover`` best sources by
    ``value / (Chebyshev distance from the rover + length / cell_size + 1)`` among occupied cells
    with ``owner < 0``: every idle rover's best (rovers in index order), then every second best, and
    so on, each cell listed once. Ties go to the lowest flat index. Computed in float32, as the
    kernel."""
    h, w = owner.shape
    ranked = []
    for r in range(len(pos)):
        if not idle[r]:
            ranked.append([])
            continue
        scored = []
        for i in range(h):
            for j in range(w):
                if occupied[i, j] and owner[i, j] < 0:
                    far = max(abs(i - int(pos[r][0])), abs(j - int(pos[r][1])))
                    rate = np.float32(value[i, j]) / (np.float32(far) + np.float32(length[i, j]) /
                                                      np.float32(cell_size) + np.float32(1.0))
                    scored.append((-float(rate), i * w + j))
        ranked.append([cell for _, cell in sorted(scored)[:per_rover]])
    out = []
    for k in range(per_rover):
        for r in range(len(pos)):
            if k < len(ranked[r]) and ranked[r][k] not in out:
                out.append(ranked[r][k])
    return out[:m]


def make_way(footprints, exists, usable, predicted, steps, owner, pos, home, parked, wanted, blocked, target, obj):
    """``(home [N, 2], moved bool[N])`` (``jaxplan.fleet.make_way``), one candidate and one cell at a time.

    footprints: M sets of (row, col); exists, usable: bool[M]; predicted, steps: [M]; owner: [H, W]
    (-1 free); pos, home: [N, 2]; parked: bool[N]; wanted: bool; blocked, target: bool[H, W]; obj:
    [H, W] counts. The candidate: the best ``predicted / max(steps, 1)`` (float32; ties: the lowest
    index) among existing usable ones whose footprint meets no reservation and holds rovers, all of
    them parked. Its parked rovers, in rover order, take the free cell (not blocked, not a target,
    not reserved, outside its footprint, nobody's home or cell, nor one given before) of the least
    Chebyshev distance + (H + W) x (in a usable footprint) + (H + W) x (holds material); ties:
    row-major. A rover with no such cell keeps its home.
    """
    h, w = owner.shape
    pos = [tuple(int(v) for v in p) for p in np.asarray(pos)]
    home = [tuple(int(v) for v in p) for p in np.asarray(home)]
    n = len(pos)
    best, pick = -np.inf, None
    for c, cells in enumerate(footprints):
        if not (wanted and exists[c] and usable[c]) or any(owner[p] >= 0 for p in cells):
            continue
        inside = [r for r in range(n) if pos[r] in cells]
        if inside and all(parked[r] for r in inside):
            score = np.float32(predicted[c]) / np.float32(max(int(steps[c]), 1))
            if score > best:
                best, pick = score, c
    moved = [False] * n
    if pick is None:
        return np.asarray(home), np.asarray(moved)
    union = set().union(*(footprints[c] for c in range(len(footprints)) if exists[c] and usable[c]))
    taken = set(home) | set(pos)
    for r in range(n):
        if not (parked[r] and pos[r] in footprints[pick]):
            continue
        moved[r] = True
        ranked = []
        for i in range(h):
            for j in range(w):
                cell = (i, j)
                if blocked[i, j] or target[i, j] or owner[i, j] >= 0 or cell in footprints[pick] or cell in taken:
                    continue
                far = max(abs(i - pos[r][0]), abs(j - pos[r][1]))
                ranked.append((far + (h + w) * (int(cell in union) + int(obj[i, j] > 0)), i * w + j, cell))
        if ranked:
            home[r] = min(ranked)[2]
            taken.add(home[r])
    return np.asarray(home), np.asarray(moved)


def first_blocker(mask, owner) -> int:
    """The rover holding the first cell (row-major) of ``mask: bool[H, W]`` that ``owner: int[H, W]``
    reserves (-1 free); -1 when the mask meets no reservation (``set_aside.blockers``)."""
    for r, c in zip(*np.nonzero(np.asarray(mask))):
        if owner[r, c] >= 0:
            return int(owner[r, c])
    return -1


def path_blocker(next_dir, next_rank, selected, owner, source) -> int:
    """The rover holding the first reserved cell on the walk of ``source``'s selected table entry,
    the source first (``table_path``); -1 when it meets none (``set_aside.path_blockers`` on a
    scene without detours)."""
    r, c = int(source[0]), int(source[1])
    for cell in table_path(np.asarray(next_dir), np.asarray(next_rank), (r, c), int(selected[r, c])):
        if owner[cell] >= 0:
            return int(owner[cell])
    return -1
