"""Visibility cones and occupied successors over the whole grid (Section 3.1, Algorithm 1).

All functions are pure array kernels: one call covers every cell and all 8 directions.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.core import lattice
from jaxplan.transport import obstacles


def cone_cos(theta_tol_deg):
    """``cos(theta_tol)`` with the conventions' slack, so exact boundary steps stay feasible."""
    return jnp.cos(jnp.deg2rad(jnp.asarray(theta_tol_deg, jnp.float32))) - lattice.CONE_EPS


def cone_alignment(tvec):
    """``f32[8, H, W]``: ``t(C) . step_unit`` for every cell and direction (Eq. 1's left side).

    tvec: f32[H, W, 2], unit (x, y) vector toward the goal per cell (any leading shape: ``[C, 2]``
    for a list of cells gives ``f32[8, C]``).
    """
    return jnp.stack([step_alignment(tvec, d) for d in range(lattice.N_DIRS)])


def step_alignment(tvec, d: int):
    """``t . step_unit[d]`` for ``tvec: f32[..., 2]``: one elementwise expression, so that the grid
    kernel and the selective rebuild's per-cell lanes round alike."""
    ux, uy = (float(u) for u in lattice.STEP_UNIT[d])
    return tvec[..., 0] * ux + tvec[..., 1] * uy


def step_feasible(occupied, enterable, alignment, dist, nb_dist, cos_t, monotone: bool, cell_size, corner_ok=True):
    """Eq. 1 and the monotone rule for single steps, elementwise (broadcasting): the step from a cell
    (``occupied``, ``dist``) to a neighbour (``enterable``: occupied or goal, at ``nb_dist``) whose
    direction has ``alignment`` t . step_unit. cos_t: ``cone_cos(theta_tol)``. corner_ok: the step
    cuts no blocked cell's corner (``obstacles.corner_free``). The caller masks steps off the grid."""
    ok = occupied & enterable & (alignment >= cos_t) & corner_ok
    if monotone:
        ok = ok & (nb_dist < dist - lattice.MONOTONE_EPS * cell_size)
    return ok


def feasible_successors(occupied, goal, dist, tvec, theta_tol_deg, monotone: bool, cell_size, blocked=None):
    """``bool[8, H, W]``: is the neighbour of C in direction i a feasible successor (Eq. 1, 2)?

    occupied: bool[H, W], cells that can be expanded (sources).
    goal: bool[H, W], cells whose entry ends a path (target cells; for connectors the anchor).
    dist: f32[H, W], world units, distance to the goal (0 on goal cells).
    tvec: f32[H, W, 2], unit (x, y) vector to the closest goal point.
    theta_tol_deg: f32[], cone half-angle, degrees. monotone: static; the strict monotone rule.
    cell_size: f32[], world units per cell. blocked: optional bool[H, W], blocked cells (a diagonal
    step may not cut their corners; they are neither occupied nor goal cells, so never entered).
    """
    shape = occupied.shape
    # off the grid a neighbour is neither enterable nor nearer: the border of ``lattice.pad_flat``'s
    # layout, where the 8 neighbour reads are constant offsets (vectorised, no bounds test)
    own = lambda a, fill: lattice.padded_rows(lattice.pad_flat(a, fill), 0, 0, shape)  # noqa: E731
    source, source_dist = own(occupied, False), own(dist, jnp.inf)
    tvec_rows = jnp.stack([own(tvec[..., 0], 0.0), own(tvec[..., 1], 0.0)], -1)
    enterable, nb_dist = lattice.pad_flat(occupied | goal, False), lattice.pad_flat(dist, jnp.inf)
    cos_t = cone_cos(theta_tol_deg)
    steps = []
    for d, (dr, dc) in enumerate(lattice.DIRS):
        ok = step_feasible(source, lattice.padded_rows(enterable, dr, dc, shape), step_alignment(tvec_rows, d),
                           source_dist, lattice.padded_rows(nb_dist, dr, dc, shape) if monotone else None, cos_t,
                           monotone, cell_size)
        steps.append(lattice.rows_to_grid(ok, shape))
    steps = jnp.stack(steps)
    return steps if blocked is None else steps & obstacles.corner_free(blocked)


def fallback_direction(tvec):
    """``i32[H, W]``: the in-grid direction best aligned with ``t(C)`` (ties within
    ``lattice.ALIGN_TIE_EPS`` to the lower index).

    It is the heatmap's first hop of a boundary-fallback cell; ``-1`` when the grid has no neighbour
    (a 1x1 grid).
    """
    in_grid = lattice.in_grid(tvec.shape[:2])
    # on the host: XLA constant-folds a reduction of a constant mask slowly (about 1 s at 256^2)
    return _best_aligned(cone_alignment(tvec), jnp.asarray(in_grid), jnp.asarray(in_grid.any(axis=0)))


def fallback_direction_at(tvec, cells):
    """``fallback_direction`` at a list of cells (``cells: i32[C]``, ``H*W`` for padding): ``i32[C]``."""
    inside = lattice.lane_neighbours(cells, tvec.shape[:2]) < tvec.shape[0] * tvec.shape[1]
    alignment = cone_alignment(lattice.take_cells(tvec, cells, 0.0))
    return _best_aligned(alignment, inside, jnp.any(inside, axis=0))


def _best_aligned(alignment, inside, has_neighbour):
    # t(C) halfway between two steps (22.5 degrees off both) is an exact tie that float rounding
    # would decide either way: near-ties go to the lower index, as in the serial reference
    masked = jnp.where(inside, alignment, -jnp.inf)
    top = jnp.max(masked, axis=0, keepdims=True)
    best = jnp.argmax(masked >= top - lattice.ALIGN_TIE_EPS, axis=0).astype(jnp.int32)
    return jnp.where(has_neighbour, best, -1)


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


def successor_graph(obj, occupied, goal, dist, tvec, theta_tol_deg, cell_size, monotone: bool,
                    blocked=None) -> SuccessorGraph:
    """Build the ``SuccessorGraph`` (arguments as in ``feasible_successors``; dist is also the
    fallback length)."""
    feasible = feasible_successors(occupied, goal, dist, tvec, theta_tol_deg, monotone, cell_size, blocked)
    return SuccessorGraph(
        obj=jnp.asarray(obj, jnp.float32),
        feasible=feasible,
        enters_goal=feasible & lattice.neighbours(goal, False),
        fallback=occupied & ~jnp.any(feasible, axis=0),
        fallback_len=jnp.asarray(dist, jnp.float32),
        step_len=jnp.asarray(lattice.STEP_CELLS) * cell_size,
    )


def successor_lanes(cells, obj, occupied, goal, dist, tvec, theta_tol_deg, cell_size, monotone: bool,
                    blocked=None) -> SuccessorGraph:
    """``successor_graph`` of a list of cells only: fields ``[C]`` and ``[8, C]`` instead of ``[H, W]``
    and ``[8, H, W]`` (the same values). cells: i32[C] flat indices, ``H*W`` for padding (no
    successors); the grids as in ``successor_graph``. Costs O(C), not O(H W)."""
    nb = lattice.lane_neighbours(cells, obj.shape)
    at = lambda a, where, fill: lattice.take_cells(a, where, fill)  # noqa: E731
    return lane_graph(at(jnp.asarray(obj, jnp.float32), cells, 0.0), at(occupied, cells, False),
                      at(occupied, nb, False) | at(goal, nb, False), at(goal, nb, False), at(tvec, cells, 0.0),
                      at(dist, cells, 0.0), at(dist, nb, jnp.inf), theta_tol_deg, cell_size, monotone,
                      None if blocked is None else at(blocked, nb, False))


def lane_graph(obj, occupied, enterable, goal_nb, tvec, dist, nb_dist, theta_tol_deg, cell_size, monotone: bool,
               blocked_nb=None) -> SuccessorGraph:
    """The ``SuccessorGraph`` rows of C listed cells from their own and their neighbours' values:
    obj: f32[C]; occupied: bool[C]; enterable, goal_nb: bool[8, C] the neighbour is occupied or a goal
    cell (False off the grid, so that no step leaves it), a goal cell; tvec: f32[C, 2]; dist: f32[C];
    nb_dist: f32[8, C] (inf off the grid); blocked_nb: optional bool[8, C] the neighbour is blocked.
    For callers that compute these per cell (``connector_closure``) rather than read them from grids
    (``successor_lanes``)."""
    corner = True if blocked_nb is None else obstacles.corner_free_of(blocked_nb)
    feasible = step_feasible(
        occupied[None], enterable, cone_alignment(tvec), dist[None], nb_dist if monotone else None,
        cone_cos(theta_tol_deg), monotone, cell_size, corner)
    return SuccessorGraph(obj=obj, feasible=feasible, enters_goal=feasible & goal_nb,
                          fallback=occupied & ~jnp.any(feasible, axis=0), fallback_len=dist,
                          step_len=jnp.asarray(lattice.STEP_CELLS) * cell_size)


def graph_at(graph: SuccessorGraph, cells) -> SuccessorGraph:
    """A grid's ``SuccessorGraph`` read at a list of cells (``cells: i32[C]``, ``H*W`` for padding):
    fields ``[C]`` and ``[8, C]``, as ``successor_lanes`` computes them."""
    per_dir = lambda a: jnp.take(a.reshape(a.shape[0], -1), cells, axis=1, mode="fill", fill_value=False)  # noqa: E731
    return SuccessorGraph(obj=lattice.take_cells(graph.obj, cells, 0.0), feasible=per_dir(graph.feasible),
                          enters_goal=per_dir(graph.enters_goal),
                          fallback=lattice.take_cells(graph.fallback, cells, False),
                          fallback_len=lattice.take_cells(graph.fallback_len, cells, 0.0), step_len=graph.step_len)
