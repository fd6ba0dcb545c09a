"""Making way: parked rovers leave the footprint of a task they hold up (docs/fleet.md, "Making way").

An idle rover parks on its home cell, and a task may start only if no rover but the one it is given
to stands in its footprint (``assign``). Parked rovers can thus hold up every task around them: on
a small site most tasks of a large fleet wait for the footprint to empty while the rovers in it
wait for a task. After each coordinated assignment, while some idle rover is left without a task and
the budget allows another, the candidate (``assign.Candidates``) of the best score ``predicted /
push steps`` that is pushable, free of every reservation and held up by parked rovers only is
chosen, and those rovers get a new home (``new_homes``). They drive there as idle rovers drive home,
and the next assignment can give the task to a rover. One candidate a step: the whole-grid work is
the few moved rovers' nearest-cell searches, and only in a step that moves any.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan.fleet.assign import Candidates, clear_of, rovers_in, unpack_bits

__all__ = ["blocking_candidate", "make_way", "new_homes"]


def blocking_candidate(planned: Candidates, owner, pos, parked, wanted):
    """``(slot i32[], found bool[])``: the candidate a step makes way for (module docstring).

    planned: M candidates (footprints packed, ``assign.pack_bits``); owner: i32[H, W] the
    reservations after the assignment (-1 free); pos: i32[N, 2] rover cells; parked: bool[N] idle
    rovers on their home cell; wanted: bool[] an idle rover is left without a task and the budget
    allows another. A candidate qualifies when it exists and is pushable, meets no reservation, and
    the rovers standing in its footprint are all parked (one at least). Ties: the lowest slot.
    """
    words = planned.tasks.footprint
    w = owner.shape[1]
    inside = rovers_in(words, pos, w)                                                     # [M, N]
    clear = clear_of(words, owner)
    held = jnp.any(inside & parked[None], 1) & ~jnp.any(inside & ~parked[None], 1)
    ok = planned.exists & planned.usable & clear & held & wanted
    score = planned.tasks.predicted / jnp.maximum(planned.tasks.steps, 1).astype(jnp.float32)
    return jnp.argmax(jnp.where(ok, score, -jnp.inf)).astype(jnp.int32), jnp.any(ok)


def new_homes(home, pos, leave, footprint, avoid, material, free):
    """i32[N, 2]: ``home`` with each rover of ``leave: bool[N]`` given, in rover order, the free cell
    nearest to it (Chebyshev distance from ``pos: i32[N, 2]``; ties row-major) outside ``footprint``
    (bool[H, W]), preferring cells outside ``avoid`` (other tasks' footprints) and without
    ``material`` (each costs one grid perimeter H + W in the ranking); ``free``: bool[H, W] cells a
    rover may park on (drivable, outside targets and reservations). No two rovers get one cell: a
    rover's home or cell is never given. A rover with no such cell keeps its home."""
    h, w = free.shape
    rows, cols = jnp.meshgrid(jnp.arange(h), jnp.arange(w), indexing="ij")
    taken = jnp.zeros((h, w), bool).at[home[:, 0], home[:, 1]].set(True).at[pos[:, 0], pos[:, 1]].set(True)
    penalty = (h + w) * (avoid.astype(jnp.int32) + material.astype(jnp.int32))

    def one(r, carry):
        home, taken = carry

        def move(carry):
            home, taken = carry
            far = jnp.maximum(jnp.abs(rows - pos[r, 0]), jnp.abs(cols - pos[r, 1]))
            allowed = free & ~footprint & ~taken
            cost = jnp.where(allowed, far + penalty, jnp.iinfo(jnp.int32).max)
            flat = jnp.argmin(cost.reshape(-1))
            cell = jnp.stack([flat // w, flat % w]).astype(jnp.int32)
            found = jnp.any(allowed)
            home = home.at[r].set(jnp.where(found, cell, home[r]))
            return home, taken.at[cell[0], cell[1]].set(taken[cell[0], cell[1]] | found)

        return jax.lax.cond(leave[r], move, lambda c: c, carry)

    return jax.lax.fori_loop(0, home.shape[0], one, (home, taken))[0]


def make_way(planned: Candidates, owner, pos, home, parked, wanted, scene):
    """``(home i32[N, 2], moved bool[N])``: after an assignment, the parked rovers that hold up the
    ``blocking_candidate`` sent to ``new_homes`` (``moved``), away from its footprint and, where
    they can, from every usable candidate's footprint and from material. owner, pos, parked,
    wanted: as in ``blocking_candidate``; home: i32[N, 2]; scene: the current scene (its blocked
    cells, targets and counts)."""
    slot, found = blocking_candidate(planned, owner, pos, parked, wanted)
    h, w = owner.shape

    def send(_):
        words = planned.tasks.footprint
        mask = unpack_bits(words[slot], (h, w))
        leave = parked & mask[pos[:, 0], pos[:, 1]]
        usable = jnp.where((planned.exists & planned.usable)[:, None], words, 0)
        union = unpack_bits(jax.lax.reduce(usable, jnp.uint32(0), jax.lax.bitwise_or, (0,)), (h, w))
        free = ~scene.blocked & ~scene.target_mask & (owner < 0)
        return new_homes(home, pos, leave, mask, union, scene.obj > 0, free), leave

    return jax.lax.cond(found, send, lambda _: (home, jnp.zeros(pos.shape[0], bool)), None)
