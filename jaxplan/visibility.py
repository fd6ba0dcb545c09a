"""Visibility cones and occupied successors over the whole grid (Section 3.1, Algorithm 1).

All functions are pure array kernels: one call covers every cell and all 8 directions.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan import _grid


def cone_cos(theta_tol_deg):
    """``cos(theta_tol)`` with the conventions' slack, so exact boundary steps stay feasible."""
    return jnp.cos(jnp.deg2rad(jnp.asarray(theta_tol_deg, jnp.float32))) - _grid.CONE_EPS


def cone_alignment(tvec):
    """``f32[8, H, W]``: ``t(C) . step_unit`` for every cell and direction (Eq. 1's left side).

    tvec: f32[H, W, 2], unit (x, y) vector toward the goal per cell.
    """
    unit = jnp.asarray(_grid.STEP_UNIT)                      # [8, 2]
    return jnp.einsum("hwx,dx->dhw", tvec, unit)


def feasible_successors(occupied, goal, dist, tvec, theta_tol_deg, monotone: bool, cell_size):
    """``bool[8, H, W]``: is the neighbour of C in direction i a feasible successor (Eq. 1, 2)?

    occupied: bool[H, W], cells that can be expanded (sources).
    goal: bool[H, W], cells whose entry ends a path (target cells; for connectors the anchor).
    dist: f32[H, W], world units, distance to the goal (0 on goal cells).
    tvec: f32[H, W, 2], unit (x, y) vector to the closest goal point.
    theta_tol_deg: f32[], cone half-angle, degrees. monotone: static; the strict monotone rule.
    cell_size: f32[], world units per cell.
    """
    in_grid = jnp.asarray(_grid.in_grid(occupied.shape))
    enterable = _grid.neighbours(occupied | goal, False)
    ok = occupied[None] & in_grid & enterable & (cone_alignment(tvec) >= cone_cos(theta_tol_deg))
    if monotone:
        nb_dist = _grid.neighbours(dist, jnp.inf)
        ok = ok & (nb_dist < dist[None] - _grid.MONOTONE_EPS * cell_size)
    return ok


def fallback_direction(tvec):
    """``i32[H, W]``: the in-grid direction best aligned with ``t(C)`` (ties to the lower index).

    It is the heatmap's first hop of a boundary-fallback cell; ``-1`` when the grid has no neighbour
    (a 1x1 grid).
    """
    in_grid = _grid.in_grid(tvec.shape[:2])
    score = jnp.where(jnp.asarray(in_grid), cone_alignment(tvec), -jnp.inf)
    best = jnp.argmax(score, axis=0).astype(jnp.int32)
    # on the host: XLA constant-folds a reduction of a constant mask slowly (about 1 s at 256^2)
    return jnp.where(jnp.asarray(in_grid.any(axis=0)), best, -1)


class SuccessorGraph(NamedTuple):
    """The successor graph of a grid, fixed while the fabric's dynamic program runs.

    obj: f32[H, W] objects; feasible: bool[8, H, W] (``feasible_successors``); enters_goal:
    bool[8, H, W] feasible steps into a goal cell; fallback: bool[H, W] occupied cells without a
    feasible successor; fallback_len: f32[H, W] world units; step_len: f32[8] world units.
    """

    obj: jax.Array
    feasible: jax.Array
    enters_goal: jax.Array
    fallback: jax.Array
    fallback_len: jax.Array
    step_len: jax.Array


def successor_graph(obj, occupied, goal, dist, tvec, theta_tol_deg, cell_size, monotone: bool) -> SuccessorGraph:
    """Build the ``SuccessorGraph`` (arguments as in ``feasible_successors``; dist is also the
    fallback length)."""
    feasible = feasible_successors(occupied, goal, dist, tvec, theta_tol_deg, monotone, cell_size)
    return SuccessorGraph(
        obj=jnp.asarray(obj, jnp.float32),
        feasible=feasible,
        enters_goal=feasible & _grid.neighbours(goal, False),
        fallback=occupied & ~jnp.any(feasible, axis=0),
        fallback_len=jnp.asarray(dist, jnp.float32),
        step_len=jnp.asarray(_grid.STEP_CELLS) * cell_size,
    )
