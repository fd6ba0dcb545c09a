"""Rover motion: approach distance fields and the prioritised one-step move (docs/fleet.md, "Motion").

- **Distance field** of one rover: the number of 8-connected steps from every cell to its task's
  start c_0 through the cells it may drive on (``passable``: not in another rover's footprint, not
  an idle rover's cell), by breadth-first relaxation in a ``lax.while_loop`` (one round lowers every
  cell to 1 + its smallest neighbour; it stops when a round changes nothing, after at most the
  longest shortest path + 1 rounds). ``FAR`` marks cells that cannot reach c_0. ``distance_fields``
  vmaps it over rovers.
- **One step** (``move_rovers``): rovers move one after another, lowest index first (priority). A
  rover that is not pushing (approaching its task's start, or idle and driving back to its home
  cell) moves to the neighbour with the smallest distance in its field that is strictly smaller than
  its own cell's (ties: the first in ``lattice.DIRS`` order) among the *free* neighbours: in the
  grid, not in another rover's footprint, and not held by any rover now (a rover that moved earlier
  this step holds its new cell and has freed its old one). If none is free and closer, it waits. A
  pushing rover moves to the next cell of its push path if that cell is free, else waits.

No two rovers share a cell after a step (each move goes to a cell no rover holds), and no two swap:
a rover moves into a cell another rover held at the start of the step only after that rover left
it, and that rover could not have entered the mover's cell, which the mover still held.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan.core import lattice

__all__ = ["APPROACH", "FAR", "IDLE", "PUSH", "distance_field", "distance_fields", "move_rovers"]

FAR = 2 ** 30
"""Distance of a cell that cannot reach the goal (an int32 that one more step does not overflow)."""

IDLE, APPROACH, PUSH = 0, 1, 2
"""Rover phases: no task, driving to the task's start, pushing along its route."""


def distance_field(goal, passable):
    """i32[H, W]: 8-connected steps from every cell to ``goal: i32[2]`` through ``passable: bool[H, W]``
    cells; ``FAR`` for impassable cells, cells that cannot reach the goal, and everywhere when the
    goal itself is not passable."""
    h, w = passable.shape
    rows, cols = jnp.meshgrid(jnp.arange(h), jnp.arange(w), indexing="ij")
    start = jnp.where((rows == goal[0]) & (cols == goal[1]) & passable, 0, FAR).astype(jnp.int32)

    def relax(carry):
        d, _ = carry
        nearest = jnp.min(lattice.neighbours(d, FAR), 0)
        new = jnp.where(passable, jnp.minimum(d, jnp.minimum(nearest, FAR - 1) + 1), FAR)
        return new, jnp.any(new != d)

    d, _ = jax.lax.while_loop(lambda carry: carry[1], relax, (start, jnp.bool_(True)))
    return d


distance_fields = jax.vmap(distance_field)
"""i32[N, H, W]: ``distance_field`` for ``goals: i32[N, 2]`` and ``passable: bool[N, H, W]``."""


def move_rovers(pos, phase, dist, owner, push_next):
    """One step of every rover, in index order (module docstring): ``(pos i32[N, 2], moved bool[N])``.

    pos: i32[N, 2] (row, col), distinct cells; phase: i32[N] (``IDLE``, ``APPROACH``, ``PUSH``);
    dist: i32[N, H, W] each rover's distance field (read for rovers not pushing); owner: i32[H, W]
    footprint owner (-1 none); push_next: i32[N, 2] the next push-path cell of pushing rovers (their
    own cell when the path is done).
    """
    n = pos.shape[0]
    h, w = owner.shape
    dirs = jnp.asarray(lattice.DIRS_ARRAY)
    flat = pos[:, 0] * w + pos[:, 1]
    held = jnp.full(h * w, -1, jnp.int32).at[flat].set(jnp.arange(n, dtype=jnp.int32))

    def one(r, carry):
        pos, held, moved = carry
        here = pos[r]
        q = here[None] + dirs
        inside = (q[:, 0] >= 0) & (q[:, 0] < h) & (q[:, 1] >= 0) & (q[:, 1] < w)
        qf = jnp.where(inside, q[:, 0] * w + q[:, 1], 0)
        mine = (owner.reshape(-1)[qf] < 0) | (owner.reshape(-1)[qf] == r)
        free = inside & mine & (held[qf] < 0)
        d_nb = jnp.where(free, dist[r].reshape(-1)[qf], FAR + 1)
        k = jnp.argmin(d_nb)
        closer = d_nb[k] < dist[r, here[0], here[1]]
        approach_to = jnp.where(closer, q[k], here)
        nxt = push_next[r]
        nxt_flat = nxt[0] * w + nxt[1]
        push_free = (held[nxt_flat] < 0) & ((owner.reshape(-1)[nxt_flat] < 0) | (owner.reshape(-1)[nxt_flat] == r))
        push_to = jnp.where(push_free, nxt, here)
        to = jnp.where(phase[r] == PUSH, push_to, approach_to)
        go = jnp.any(to != here)
        held = held.at[here[0] * w + here[1]].set(jnp.where(go, -1, r))
        held = held.at[to[0] * w + to[1]].set(r)
        return pos.at[r].set(to), held, moved.at[r].set(go)

    pos, _, moved = jax.lax.fori_loop(0, n, one, (pos, held, jnp.zeros(n, bool)))
    return pos, moved
