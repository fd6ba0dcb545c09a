"""The fleet's invariants, checked after a run on what it recorded: no two rovers in one cell, no
swap, no jump, no rover inside another rover's reserved footprint, no cell reserved twice.

A plain serial pass over the recorded positions and reservations, independent of the kernels that
produced them: ``run_fleet`` reports its count (``FleetRun.conflicts``, which must be 0).
"""
from __future__ import annotations

import numpy as np

__all__ = ["conflicts"]


def conflicts(positions, reservations) -> list:
    """Invariant violations in a recorded fleet run: a list of ``(step, kind, rovers)`` (empty = none).

    positions: [T + 1, N, 2], every rover's cell after each step (row 0: the start).
    reservations: iterable of ``(rover, first, last, cells)``: the rover held the footprint ``cells``
    (iterable of (row, col)) for the positions of steps ``first`` .. ``last`` (inclusive).
    Kinds: "same cell" (two rovers in one cell), "swap" (two rovers exchanged cells in one step),
    "footprint" (a rover in a cell another rover holds reserved), "overlap" (two rovers hold one cell
    reserved at once), "jump" (a rover moved more than one cell in one step).
    The reserved cells are kept in one map, updated as reservations start and end, so the check costs
    the reservations' cells plus N^2 per step.
    """
    positions = np.asarray(positions)
    t_end = positions.shape[0]
    starting: dict[int, list] = {}
    for rover, first, last, cells in reservations:
        if int(first) <= int(last):
            starting.setdefault(max(int(first), 0), []).append(
                (int(rover), int(last), [(int(c[0]), int(c[1])) for c in cells]))
    ending: dict[int, list] = {}
    held: dict[tuple, set] = {}
    found = []
    for t in range(t_end):
        for rover, last, cells in starting.get(t, []):
            for cell in cells:
                owners = held.setdefault(cell, set())
                if owners - {rover}:
                    found.append((t, "overlap", tuple(sorted(owners | {rover}))))
                owners.add(rover)
            ending.setdefault(last, []).append((rover, cells))
        now = [tuple(int(v) for v in p) for p in positions[t]]
        for i in range(len(now)):
            for j in range(i + 1, len(now)):
                if now[i] == now[j]:
                    found.append((t, "same cell", (i, j)))
            others = held.get(now[i], set()) - {i}
            if others:
                found.append((t, "footprint", (i, min(others))))
        if t > 0:
            before = [tuple(int(v) for v in p) for p in positions[t - 1]]
            for i in range(len(now)):
                if max(abs(now[i][0] - before[i][0]), abs(now[i][1] - before[i][1])) > 1:
                    found.append((t, "jump", (i,)))
                for j in range(i + 1, len(now)):
                    if now[i] != before[i] and now[i] == before[j] and now[j] == before[i]:
                        found.append((t, "swap", (i, j)))
        for rover, cells in ending.pop(t, []):
            for cell in cells:
                held[cell].discard(rover)
                if not held[cell]:
                    del held[cell]
    return found
