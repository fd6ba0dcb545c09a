"""Sources set aside: a coordinated planning's candidates whose tasks met a running task's footprint,
kept out of the next plannings while that task runs (docs/fleet.md, "Strategies").

Rovers that became idle at one target rank the same sources first (their rates are taken from where
they became idle), and near a target those sources' routes share the highway a running push holds.
Planned again at every step, such a candidate stays blocked and its rovers stay idle while piles
whose routes are free wait. Set aside until the task it met ends, it lets the next planning offer the
rovers their next sources. Setting a source aside changes which sources are planned, never a plan.

The list is a ring of T slots (``CAPACITY``): when it is full the oldest entries are overwritten, and
their sources may be planned again sooner.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.fleet.assign import pack_bits
from jaxplan.fleet.motion import IDLE
from jaxplan.transport import walk_table

__all__ = ["CAPACITY", "SetAside", "add", "blockers", "empty", "holding", "path_blockers", "withheld"]

CAPACITY = 1024
"""Slots of a coordinated fleet's set-aside list (T)."""


class SetAside(NamedTuple):
    """Sources set aside, T slots.

    cells: i32[T] flat source cells (row-major; -1: an empty slot). rover: i32[T] the rover whose
    reserved footprint the source's task met. task: i32[T] that rover's ``Rovers.task_step`` then: the
    entry holds while the rover runs that task. next: i32[] the slot the next entry goes to.
    """

    cells: jax.Array
    rover: jax.Array
    task: jax.Array
    next: jax.Array


def empty(capacity: int = CAPACITY) -> SetAside:
    """A list of ``capacity`` empty slots (0 for the strategies that plan no candidates)."""
    none = jnp.full(capacity, -1, jnp.int32)
    return SetAside(cells=none, rover=none, task=none, next=jnp.int32(0))


def holding(aside: SetAside, phase, task_step):
    """bool[T]: the entries whose rover still runs the task they met (``phase: i32[N]``, ``task_step:
    i32[N]``, the rovers' ``Rovers`` fields)."""
    r = jnp.maximum(aside.rover, 0)
    return (aside.cells >= 0) & (phase[r] != IDLE) & (task_step[r] == aside.task)


def withheld(aside: SetAside, holds, shape):
    """bool[H, W]: the cells of the entries ``holds: bool[T]`` (``holding``)."""
    flat = jnp.where(holds, aside.cells, shape[0] * shape[1])
    return jnp.zeros(shape[0] * shape[1], bool).at[flat].set(True, mode="drop").reshape(shape)


def blockers(words, owner):
    """i32[M]: for each of M packed footprint masks (u32[M, ceil(H W / 32)], ``assign.pack_bits``), the
    rover that holds the first reserved cell (row-major) it meets in ``owner: i32[H, W]`` (-1 free);
    -1 for a mask that meets none. One word per 32 cells, then the lowest set bit of the first word
    that meets a reservation."""
    flat_owner = owner.reshape(-1)
    reserved = pack_bits((owner >= 0)[None])[0]

    def first_met(row):
        hit = row & reserved
        word = jnp.argmax(hit != 0)
        bits = hit[word]
        lowest = 31 - jax.lax.clz(bits & (~bits + jnp.uint32(1)))
        cell = word * 32 + lowest.astype(jnp.int32)
        return jnp.where(bits != 0, flat_owner[jnp.minimum(cell, flat_owner.shape[0] - 1)], -1)

    return jax.vmap(first_met)(words).astype(jnp.int32)


def path_blockers(scene, fabric, owner, flat, todo, max_steps: int):
    """i32[m]: for each source ``flat: i32[m]`` (row-major) where ``todo: bool[m]``, the rover that holds
    the first reserved cell (``owner: i32[H, W]``, -1 free) on the source's fabric path (the source,
    then the walk of its selected table entry, ``Fabric.selected``, at most ``max_steps`` steps,
    static); -1 where it meets none or not ``todo``. A task's route is that path, or a connector to
    its anchor's path, so a source whose path meets a reservation is set aside without planning its
    task: a screen, since planning checks the task's own route and spill."""
    w = owner.shape[1]

    def first_met(cell, do):
        source = jnp.stack([cell // w, cell % w]).astype(jnp.int32)
        path = walk_table(fabric.table, source, fabric.selected[source[0], source[1]], max_steps, scene.detour).cells
        on = path[:, 0] >= 0
        held = jnp.where(on, owner[jnp.maximum(path[:, 0], 0), jnp.maximum(path[:, 1], 0)], -1)
        met = held >= 0
        return jnp.where(do & jnp.any(met), held[jnp.argmax(met)], -1)

    return jax.vmap(first_met)(flat, todo).astype(jnp.int32)


def add(aside: SetAside, cells, rover, new, task_step) -> SetAside:
    """The list with the sources ``cells: i32[M]`` (flat) where ``new: bool[M]``, each set aside for
    ``rover: i32[M]`` (the rover its task met, ``blockers``) and that rover's current task
    (``task_step: i32[N]``), written in order into the next slots of the ring."""
    t = aside.cells.shape[0]
    slot = jnp.where(new, (aside.next + jnp.cumsum(new) - 1) % t, t)
    r = jnp.maximum(rover, 0)
    put = lambda a, v: a.at[slot].set(v, mode="drop")   # noqa: E731
    return SetAside(cells=put(aside.cells, cells), rover=put(aside.rover, r), task=put(aside.task, task_step[r]),
                    next=(aside.next + jnp.sum(new, dtype=jnp.int32)) % t)
