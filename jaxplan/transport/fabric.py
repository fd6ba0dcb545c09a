"""The trajectory fabric: a dynamic program over the successor graph of the whole grid (Section 3.2).

For every occupied cell at once, the kernel keeps a *continuation table* of the K best paths to the
goal, ranked lexicographically by ``(raw, -len)`` (Eq. 5). Two solvers compute the same table:

- the **wavefront**: one round recomputes every cell's table from its neighbours' tables (max-plus
  over 8 directions x K continuations, plus the boundary fallback) until nothing changes. After
  ``k`` rounds every table is exact for paths of at most ``k`` hops. Works without the monotone rule.
- **policy iteration + sidetracks** (``jaxplan.transport.kbest``, the default with the monotone rule): far
  fewer grid passes on a DAG.

No per-source search, no Python loop over cells. Then first hops, psi, heatmap and highways.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.core import SMALL_GRID_CELLS, available_memory_bytes, grid_jit, lattice, traced
from jaxplan.transport import heatmap, kbest, obstacles, visibility
from jaxplan.transport.params import FabricParams, resolve_solver, validate_params
from jaxplan.transport.scene import Scene, occupied_cells


class Table(NamedTuple):
    """Continuation table, K entries per cell sorted best first.

    raw: f32[H, W, K], objects collected (source included); -inf for unused entries.
    length: f32[H, W, K], world units; +inf for unused entries.
    next_dir: i32[H, W, K], direction index of the first step (0-7), 8 = boundary fallback, -1 unused.
    next_rank: i32[H, W, K], entry of the neighbour's table the path continues with; -1 when the first
      step enters a goal cell (the path ends there) and for fallback or unused entries.
    """

    raw: jax.Array
    length: jax.Array
    next_dir: jax.Array
    next_rank: jax.Array


class Fabric(NamedTuple):
    """Everything ``build_fabric`` computes for one grid. Shapes for an H x W grid.

    value: f32[H, W], J(C) = raw(P*(C)), objects; 0 where not occupied.
    length: f32[H, W], L(C) = len(P*(C)), world units; 0 where not occupied.
    first_hop: i32[H, W, 2], (row, col) of u(C); -1 where undefined.
    heading: f32[H, W, 2], unit (x, y) vector c -> u(C); 0 where undefined.
    fallback: bool[H, W], occupied cells with no feasible successor (boundary fallback).
    occupied: bool[H, W], non-target cells with obj > 0.
    feasible: bool[H, W, 8], feasible successor in each direction (Eq. 1 and the monotone rule).
    table: Table, the K-best continuation table.
    psi: f32[H, W], propagated raw mass (Eqs. 7-8), objects.
    heat: f32[H, W], look-back heatmap (Eq. 10), objects; 0 on target cells.
    highways: bool[H, W], highway cells (Eq. 11).
    rounds: i32[], solver iterations (wavefront rounds or policy-iteration steps).
    converged: bool[], whether the solver reached its fixed point.
    selected: i32[H, W], the table entry each source's selected path is (0: Eq. 5; after
      ``selection.reselect``, the Eq. 6 choice), which first_hop, heading, fallback and psi follow.
      ``value`` and ``length`` stay those of entry 0, J(C) and L(C).
    """

    value: jax.Array
    length: jax.Array
    first_hop: jax.Array
    heading: jax.Array
    fallback: jax.Array
    occupied: jax.Array
    feasible: jax.Array
    table: Table
    psi: jax.Array
    heat: jax.Array
    highways: jax.Array
    rounds: jax.Array
    converged: jax.Array
    selected: jax.Array


# ----------------------------------------------------------------------------------------------
# The dynamic program


def _wavefront_dp(graph: visibility.SuccessorGraph, cell_size, k: int, max_hops: int):
    """Synchronous rounds of the K-best recursion until nothing changes (or ``max_hops`` rounds).

    Returns ``(raw, length, direction, rank)`` as ``[K, H, W]``, rounds and whether it converged.
    """
    plane = graph.obj.shape

    def cond(carry):
        return carry[-1] & (carry[-2] < max_hops)

    def body(carry):
        raw, length, idx, rounds, _ = carry
        cand_raw, cand_len = kbest.step_candidates(raw, length, graph)
        tol = kbest.length_tolerance(lattice.lead_min(cand_len), cell_size)
        # candidates come in (direction, rank) order, which is the tie-break
        new_raw, new_len, _, new_idx = kbest.select_top_k(cand_raw, cand_len, None, k, tol)
        changed = ~lattice.all_equal((new_raw, new_len, new_idx), (raw, length, idx))
        return tuple(new_raw), tuple(new_len), tuple(new_idx), rounds + 1, changed

    start = ((jnp.full(plane, -jnp.inf),) * k, (jnp.full(plane, jnp.inf),) * k, (jnp.zeros(plane, jnp.int32),) * k,
             jnp.int32(0), jnp.bool_(True))
    raw, length, idx, rounds, changed = jax.lax.while_loop(cond, body, start)
    raw, length, idx = jnp.stack(raw), jnp.stack(length), jnp.stack(idx)
    direction = jnp.where(idx == lattice.N_DIRS * k, lattice.FALLBACK, idx // k)
    return raw, length, direction, idx % k, rounds, ~changed


def ranks_from_directions(direction):
    """``i32[K, H, W]``: entry j continues with the neighbour's entry equal to the number of better
    entries that start with the same step (C's paths through N are N's paths, in N's order)."""
    k = direction.shape[0]
    same = direction[:, None] == direction[None, :]                     # [i, j, H, W]
    earlier = jnp.triu(jnp.ones((k, k), bool), 1)[..., None, None]      # i < j
    return jnp.sum(same & earlier, axis=0).astype(jnp.int32)


def continuation_dp(obj, occupied, goal, dist, tvec, theta_tol_deg, cell_size, *,
                    monotone: bool, k: int, max_hops: int, solver: str = "auto", blocked=None):
    """The K-best continuation table toward ``goal``: ``(table, feasible[8,H,W], rounds, converged)``.

    obj: f32[H, W] objects; occupied: bool[H, W] expandable cells; goal: bool[H, W] cells whose entry
    ends a path; dist: f32[H, W] world units to the goal (also the fallback length); tvec: f32[H, W, 2]
    unit (x, y) direction of the closest goal point. ``k``, ``max_hops`` and ``solver`` are static.
    solver: "wavefront" (synchronous rounds; works without the monotone rule), "policy" (policy
    iteration + sidetracks, ``jaxplan.transport.kbest``; needs the monotone rule) or "auto" (policy when
    monotone). Both give the same table; ``rounds`` counts wavefront rounds or policy iterations.
    blocked: optional bool[H, W], blocked cells (``visibility.feasible_successors``).
    """
    graph = visibility.successor_graph(obj, occupied, goal, dist, tvec, theta_tol_deg, cell_size, monotone, blocked)
    use_policy = resolve_solver(solver, monotone) == "policy"
    if use_policy and not monotone:
        raise ValueError("solver='policy' needs the monotone rule (an acyclic successor graph); "
                         "use solver='wavefront' or 'auto' with monotone=False.")
    if use_policy:
        best_raw, best_len, policy, rounds = kbest.best_paths(graph, occupied, cell_size, max_hops)
        raw, length, direction = kbest.kbest_tables(best_raw, best_len, policy, graph, occupied, k, cell_size)
        rank = ranks_from_directions(direction)
        converged = rounds < max_hops
    else:
        raw, length, direction, rank, rounds, converged = _wavefront_dp(graph, cell_size, k, max_hops)
    return make_table(raw, length, direction, rank, graph.enters_goal), graph.feasible, rounds, converged


def make_table(raw, length, direction, rank, enters_goal) -> Table:
    """Mask unused entries, mark steps into a goal cell (rank -1) and move K last: ``[H, W, K]``."""
    used = raw > -jnp.inf
    into_goal = jnp.take_along_axis(enters_goal, jnp.clip(direction, 0, 7), axis=0)
    step = used & (direction >= 0) & (direction < lattice.FALLBACK)
    next_dir = jnp.where(used, direction, -1)
    next_rank = jnp.where(step & ~into_goal, rank, -1)
    last = lambda a: jnp.moveaxis(a, 0, -1)  # noqa: E731
    return Table(last(raw), last(jnp.where(used, length, jnp.inf)), last(next_dir), last(next_rank))


# ----------------------------------------------------------------------------------------------
# First hops, headings and the fabric


def first_hops(table: Table, tvec, cell_size, entry=None):
    """From entry 0 (or ``entry: i32[H, W]`` per cell): ``(first_hop i32[H,W,2], heading f32[H,W,2],
    hop_len f32[H,W])``. A fallback cell's hop is the in-grid neighbour best aligned with t(C)
    (conventions).
    """
    h, w = tvec.shape[:2]
    rows, cols = jnp.meshgrid(jnp.arange(h, dtype=jnp.int32), jnp.arange(w, dtype=jnp.int32), indexing="ij")
    return hops_from_steps(_entry_of(table.next_dir, entry), visibility.fallback_direction(tvec), rows, cols,
                           cell_size)


def hops_from_steps(step, fallback_dir, rows, cols, cell_size):
    """``(first_hop i32[..., 2], heading f32[..., 2], hop_len f32[...])`` of cells at ``rows, cols``
    whose selected path starts with ``step`` (0-7, ``FALLBACK``, -1 none); ``fallback_dir``: their
    ``visibility.fallback_direction``. Elementwise, for the grid or a list of cells."""
    hop_dir = jnp.where(step == lattice.FALLBACK, fallback_dir, step)
    defined = hop_dir >= 0
    safe = jnp.where(defined, hop_dir, 0)
    offset = jnp.asarray(lattice.DIRS_ARRAY)[safe]
    hop = jnp.where(defined[..., None], jnp.stack([rows + offset[..., 0], cols + offset[..., 1]], -1), -1)
    heading = jnp.where(defined[..., None], jnp.asarray(lattice.STEP_UNIT)[safe], 0.0)
    hop_len = jnp.where(defined, jnp.asarray(lattice.STEP_CELLS)[safe] * cell_size, 0.0)
    return hop.astype(jnp.int32), heading, hop_len


def hop_lengths(first_hop, cell_size):
    """``f32[H, W]`` world length of each cell's first hop (0 where undefined), from ``first_hop``."""
    h, w = first_hop.shape[:2]
    rows, cols = jnp.meshgrid(jnp.arange(h, dtype=jnp.int32), jnp.arange(w, dtype=jnp.int32), indexing="ij")
    diagonal = (first_hop[..., 0] != rows) & (first_hop[..., 1] != cols)
    cells = jnp.where(diagonal, lattice.STEP_CELLS[0], lattice.STEP_CELLS[1])
    return jnp.where(first_hop[..., 0] >= 0, cells * cell_size, 0.0)


def _entry_of(a, entry):
    """``a[..., entry]`` per cell for a table field ``a: [H, W, K]`` (entry 0 when None)."""
    if entry is None:
        return a[..., 0]
    return jnp.take_along_axis(a, entry[..., None], axis=-1)[..., 0]


def derive(scene, params: FabricParams, table: Table, feasible, rounds, converged, entry=None) -> Fabric:
    """Everything downstream of the continuation table: first hops, psi, heatmap, highways.

    table: the K-best ``Table``; feasible: bool[8, H, W] successor mask it was computed on. Shared
    by the full build and the selective rebuild (``jaxplan.transport.rebuild``), which both end here. entry:
    i32[H, W] the selected entry of each source (default 0, Eq. 5; ``selection.reselect`` passes
    the Eq. 6 choice): first hops, headings, fallbacks and psi follow it.
    """
    return with_flow(scene, params, *own_fields(scene, table, feasible, rounds, converged, entry), entry is not None)


def own_fields(scene, table: Table, feasible, rounds, converged, entry=None):
    """``(fabric, hop_len)``: the fields of each cell that follow from its own table row alone
    (value, length, first hop, heading, fallback, occupied, feasible, selected); psi, heat and
    highways are None (``with_flow`` adds them). hop_len: f32[H, W] world units. Arguments as in
    ``derive``."""
    obj = jnp.asarray(scene.obj, jnp.float32)
    occupied = occupied_cells(obj, scene.target_mask, scene.dist)
    hop, heading, hop_len = first_hops(table, scene.tvec, scene.cell_size, entry)
    value = jnp.where(occupied, table.raw[..., 0], 0.0)
    length = jnp.where(occupied, table.length[..., 0], 0.0)
    selected = jnp.zeros(obj.shape, jnp.int32) if entry is None else jnp.where(occupied, entry, 0).astype(jnp.int32)
    return Fabric(value, length, hop, heading, _entry_of(table.next_dir, entry) == lattice.FALLBACK, occupied,
                  jnp.moveaxis(feasible, 0, -1), table, None, None, None, rounds, converged, selected), hop_len


def with_flow(scene, params: FabricParams, fabric: Fabric, hop_len, reselected: bool = False) -> Fabric:
    """``fabric`` with psi, heat and highways computed from its per-cell fields (the quantities that
    depend on other cells' paths). hop_len: f32[H, W] world length of each first hop; reselected
    (static): psi follows ``fabric.selected`` (Eq. 6) rather than entry 0."""
    target = jnp.asarray(scene.target_mask, bool)
    table, occupied = fabric.table, fabric.occupied
    max_hops = params.resolved_max_hops(occupied.shape)
    if reselected:
        psi = heatmap.propagated_mass_of_entries(table, fabric.selected, occupied, max_hops)
    else:
        first = table.next_dir[..., 0]
        path_next = jnp.where((first >= 0) & (first < lattice.FALLBACK), first, -1)
        psi = heatmap.propagated_mass(fabric.value, occupied, path_next, max_hops)
    heat = heatmap.heat(psi, occupied, fabric.heading, hop_len, target, scene.cell_size)
    return fabric._replace(psi=psi, heat=heat, highways=highways_of(scene, params, heat))


def highways_of(scene, params: FabricParams, heat):
    """``bool[H, W]`` highways (Eq. 11) of a heatmap ``f32[H, W]`` with ``params``' settings."""
    return heatmap.highways(heat, jnp.asarray(scene.target_mask, bool), params.tau_h,
                            relative=params.highway_relative, smoothing=params.highway_smoothing,
                            nms=params.highway_nms)


def full_table(scene, params: FabricParams):
    """The continuation table of ``scene`` toward its target: ``(table, feasible[8,H,W], rounds, converged)``."""
    obj = jnp.asarray(scene.obj, jnp.float32)
    target = jnp.asarray(scene.target_mask, bool)
    return continuation_dp(
        obj, occupied_cells(obj, target, scene.dist), target, scene.dist, scene.tvec, params.theta_tol_deg,
        scene.cell_size, monotone=params.monotone, k=params.k, max_hops=params.resolved_max_hops(obj.shape),
        solver=params.solver, blocked=scene.blocked)


def fabric_of(scene, params: FabricParams) -> Fabric:
    """The hard fabric of ``scene``: ``build_fabric``'s traceable body, without validation or jit
    (call it inside a caller's own ``jit``/``vmap``)."""
    return derive(scene, params, *full_table(scene, params))


_build_jit = grid_jit(fabric_of)


def _is_concrete(scene) -> bool:
    return not traced(scene)


def check_fabric_inputs(scene, params: FabricParams, *, counts: bool = False) -> None:
    """The host-level checks of ``build_fabric``'s arguments, before any JAX call: ``TypeError``
    naming ``scene`` or ``params`` for a wrong type; ``ValueError`` naming the Scene field whose
    shape disagrees with ``obj: [H, W]``. Shapes are static, so this works on traced scenes and
    parameters too (inside ``jit``/``vmap``). counts: also refuse concrete NaN, infinite or negative
    counts (``Scene.check``; a host read of ``obj``, which the drivers ``run_episode`` and
    ``run_fleet`` do once, and ``build_fabric`` leaves to ``Scene.from_arrays`` and ``with_obj``)."""
    Scene.check(scene, "scene", counts=counts)
    if not isinstance(params, FabricParams):
        raise TypeError(f"params: expected a FabricParams, got {type(params).__name__}. Build one with "
                        "jaxplan.FabricParams(theta_tol_deg=...), or pass None for the defaults.")


def build_fabric(scene, params: FabricParams | None = None, spill=None) -> Fabric:
    """Build the whole fabric (visibility, DP, first hops, psi, heatmap, highways) for ``scene``.

    Jitted; ``vmap`` it over ``FabricParams`` (traced fields) or over stacked scenes of one shape.
    Inputs are checked first (``check_fabric_inputs``: ``TypeError`` for a ``scene`` that is not a
    Scene or ``params`` not a FabricParams, ``ValueError`` naming a Scene field whose shape disagrees
    with ``obj``); concrete parameters are validated and raise ``ValueError`` naming the bad field. With
    ``params.temperature`` set (> 0, or traced) it runs the soft kernels and returns a
    ``jaxplan.transport.soft.SoftFabric`` instead (``temperature=None`` or a concrete 0: the hard ``Fabric``).
    spill: soft kernels only, a ``SpillParams``: Eq. 6's choice among each source's candidates
    becomes a softmax over predicted delivered mass (``soft.soft_select``). The hard fabric applies
    Eq. 6 with ``selection.reselect``.
    """
    params = FabricParams() if params is None else params
    check_fabric_inputs(scene, params)
    if _is_concrete(params):
        validate_params(params)
    if params.temperature is not None:
        if params.is_soft:   # a temperature > 0 (or traced): the differentiable kernels
            from jaxplan.transport import soft
            return soft.build_soft_fabric(scene, params, spill)
        params = params.replace(temperature=None)   # a concrete 0: the exact hard kernels
    if spill is not None:
        raise ValueError("spill: build_fabric takes SpillParams with the soft kernels only (FabricParams."
                         "temperature > 0); for the hard fabric apply Eq. 6 with "
                         "jaxplan.transport.selection.reselect.")
    # "policy" with the monotone rule (or "wavefront" without) is what "auto" runs: one program for both
    return _build_jit(scene, params.with_canonical_solver())


# ----------------------------------------------------------------------------------------------
# What a build costs

# Peak memory of a first (compiling) build_fabric call over an idle process that imported jaxplan
# (~230 MB), measured with /usr/bin/time -v on the CPU backend (policy solver, 8x8 to 32x32 grids):
#   K      1    2    4    6    8    10    12    16
#   MiB   23   34   63  131  304   725  1670  6770
# Grid size hardly matters there: the compile dominates, and it grows with K because the K-best
# merge is unrolled (kbest.kbest_levels: O(K^2) merges of O(K)-entry lists). Least squares on the
# relative error gives COMPILE_MIB below, within 2% at every point. Grids above SMALL_GRID_CELLS
# compile with XLA's newer emitters, which took 110-300 MiB more at K = 1-8 on 70x70 (LARGE_GRID_MIB).
# The run itself (XLA's memory_analysis: temporaries ~7 K^2 + 16 K + 100 bytes per cell, outputs
# 16 K + 48, at K = 1-8) is counted twice, for the host copies of the outputs. The wavefront solver
# (monotone=False) measured below the policy solver (K = 8: 250 vs 304 MiB), so one estimate covers both.
_MIB = 2 ** 20


def _compile_mib(k: int, cells: int) -> float:
    mib = 11.4 * (1 + k) + 0.00616 * k ** 5
    return mib + (110.0 + 30.0 * k if cells > SMALL_GRID_CELLS else 0.0)


def estimate_build_bytes(shape, params: FabricParams | None = None) -> int:
    """Estimated peak memory, bytes, that a first ``build_fabric`` call on an ``(H, W)`` grid adds to
    the process (compiling it, then running it), above the ~230 MB of Python, JAX and jaxplan.

    Fitted to measurements on the CPU backend (comment above): the compile term is
    ``11.4 (1 + K) + 0.00616 K^5`` MiB (+ ``110 + 30 K`` MiB above 65x65 cells, XLA's newer emitters),
    the run term ``2 (7 K^2 + 32 K + 160)`` bytes per cell. About 0.3 GB at K = 8, 1.8 GB at K = 12,
    7 GB at K = 16 on the 25x25 default scene; the compile time grows alike (15 s, 45 s, 140 s).
    params: only ``k`` is read (default ``FabricParams()``).
    """
    params = FabricParams() if params is None else params
    h, w = (int(n) for n in shape)
    k = int(params.k)
    run = 2 * (7 * k * k + 32 * k + 160) * h * w
    return int(_compile_mib(k, h * w) * _MIB) + run


def check_build_memory(shape, params: FabricParams | None = None, available: int | None = None) -> int:
    """Raise ``ValueError`` naming ``FabricParams.k`` when ``estimate_build_bytes(shape, params)``
    exceeds ``available`` bytes (default ``jaxplan.core.available_memory_bytes()``; no check when that
    is unknown). Returns the estimate. The message names the largest K that fits."""
    params = FabricParams() if params is None else params
    need = estimate_build_bytes(shape, params)
    room = available_memory_bytes() if available is None else int(available)
    if room is None or need <= room:
        return need
    h, w = (int(n) for n in shape)
    fits = [k for k in range(1, int(params.k)) if estimate_build_bytes(shape, params.replace(k=k)) <= room]
    fix = (f"use k <= {fits[-1]} (about {_gb(estimate_build_bytes(shape, params.replace(k=fits[-1])))}) or "
           "free memory" if fits else "free memory or use a smaller grid")
    raise ValueError(f"FabricParams.k: K = {params.k} needs about {_gb(need)} to compile and build a {h}x{w} "
                     f"fabric (jaxplan.transport.fabric.estimate_build_bytes), more than the {_gb(room)} of "
                     f"memory available; {fix}.")


def _gb(n: int) -> str:
    return f"{n / 1e9:.1f} GB" if n >= 1e9 else f"{n / 1e6:.0f} MB"


# ----------------------------------------------------------------------------------------------
# Path extraction


class Paths(NamedTuple):
    """Paths read from a continuation table, one row per query.

    cells: i32[B, S, 2], (row, col) of the source, then each cell entered (the final goal cell
      included); rows padded with -1.
    n_cells: i32[B], valid rows of ``cells``.  raw: f32[B], length: f32[B] (world units) from the
    table.  fallback: bool[B], the path ends with a boundary fallback.  complete: bool[B], the walk
    ended within ``S - 1`` steps (False means ``max_steps`` was too small).
    """

    cells: jax.Array
    n_cells: jax.Array
    raw: jax.Array
    length: jax.Array
    fallback: jax.Array
    complete: jax.Array


def walk_table(table: Table, source, rank, max_steps: int, detour=None) -> Paths:
    """Follow one table entry from ``source: i32[2]`` (row, col), entry ``rank: i32[]``, for a static
    ``max_steps`` grid steps; a ``Paths`` row without the batch axis (cells ``i32[max_steps + 1, 2]``).
    detour: optional i32[H, W] (``Scene.detour``): a fallback from a cell with a detour drives the
    detour's steps, listed as the path's cells, up to the first cell without one, and goes straight
    from there. Traceable: ``extract_paths`` is its batched, jitted form. The walk stops when the
    path ends, so it costs the path's steps, not ``max_steps`` (batched, the longest path's).
    """
    source = source.astype(jnp.int32)
    cells, done, fell_back = follow_entries(
        lambda rc, rk: (table.next_dir[rc[0], rc[1], rk], table.next_rank[rc[0], rc[1], rk]),
        lambda rc, new_rc, d: new_rc, source, source, rank, max_steps, detour)
    n = jnp.sum(cells[:, 0] >= 0)
    r, c = source[0], source[1]
    return Paths(cells, n, table.raw[r, c, rank], table.length[r, c, rank], fell_back, done)


def follow_entries(entry, advance, source, at, rank, max_steps: int, detour=None):
    """``walk_table``'s walk over any store of table rows: ``(cells i32[max_steps + 1, 2], complete
    bool[], fell_back bool[])``. entry(at, rank) -> ``(next_dir, next_rank)`` of the row the walk is at
    (``at``: any key, starting at ``at``); advance(at, new_rc, d) -> the key of the cell ``new_rc``
    that step ``d`` entered. source: i32[2] the first cell; rank, detour as in ``walk_table``."""
    dirs = jnp.asarray(lattice.DIRS_ARRAY)

    def step(carry):
        rc, at, rk, done, fell_back = carry
        d, next_rank = entry(at, rk)
        falls = fell_back | (d == lattice.FALLBACK)          # on the fallback leg: detour steps, then straight
        if detour is not None:
            d = jnp.where(falls, jnp.where(detour[rc[0], rc[1]] >= 0, detour[rc[0], rc[1]], lattice.FALLBACK), d)
        moves = (~done) & (d >= 0) & (d < lattice.FALLBACK)
        nxt_rk = jnp.where(falls, 0, next_rank)
        way = jnp.clip(d, 0, 7)
        new_rc = jnp.where(moves, rc + dirs[way], rc)
        at = jnp.where(moves, advance(at, new_rc, way), at)
        fell_back = fell_back | ((~done) & falls)
        done = done | ~moves | (nxt_rk < 0)
        return (new_rc, at, jnp.where(moves, jnp.maximum(nxt_rk, 0), rk), done, fell_back), \
            jnp.where(moves, new_rc, -1)

    def more(carry):
        return (carry[0] < max_steps) & ~carry[1][3]

    def body(carry):
        i, walk, cells = carry
        walk, visited = step(walk)
        return i + 1, walk, cells.at[i + 1].set(visited)

    start = (source, at, jnp.asarray(rank, jnp.int32), jnp.bool_(False), jnp.bool_(False))
    cells = jnp.full((max_steps + 1, 2), -1, jnp.int32).at[0].set(source)
    _, (_, _, _, done, fell_back), cells = jax.lax.while_loop(more, body, (jnp.int32(0), start, cells))
    return cells, done, fell_back


def count_table_hops(table: Table, detour=None):
    """``i32[H, W, K]`` grid steps of every table entry, by pointer doubling over (cell, entry); with
    ``detour`` (``Scene.detour``) a fallback entry counts its detour's steps (``walk_table``)."""
    h, w, k = table.raw.shape
    n = h * w * k
    steps = (table.next_dir >= 0) & (table.next_dir < lattice.FALLBACK)
    nb = lattice.neighbour_index(table.next_dir)
    continues = steps & (table.next_rank >= 0)
    pointer = jnp.append(jnp.where(continues, (nb[..., 0] * w + nb[..., 1]) * k + table.next_rank, n).reshape(-1), n)
    own = steps.astype(jnp.int32)
    if detour is not None:
        own = own + jnp.where(table.next_dir == lattice.FALLBACK, obstacles.count_detour_hops(detour)[..., None], 0)
    (hops,) = lattice.sum_to_sink((jnp.append(own.reshape(-1), 0),), pointer)
    return hops[:-1].reshape(h, w, k)


table_hops = grid_jit(count_table_hops)


def extract_paths(fabric: Fabric, sources, ranks=None, *, max_steps: int | None = None, detour=None) -> Paths:
    """Read paths for many sources in one batched call (``vmap`` of a fixed-length walk).

    fabric: a ``Fabric`` (its continuation table is read); sources: i32[B, 2] (row, col); ranks:
    i32[B] table entries (default 0, the selected path). max_steps: static walk length; default =
    1 + the longest entry of the table (``table_hops``, read on the host, so pass it explicitly under
    ``jit``). detour: the scene's ``Scene.detour`` where it has blocked cells (``walk_table``).
    """
    sources = jnp.asarray(sources, jnp.int32).reshape(-1, 2)
    ranks = jnp.zeros(sources.shape[0], jnp.int32) if ranks is None else jnp.asarray(ranks, jnp.int32)
    if max_steps is None:   # +1: a final fallback is a scan step
        max_steps = 1 + int(jnp.max(table_hops(fabric.table, detour)))
    return _extract_jit(fabric.table, sources, ranks, max_steps, detour)


def _extract(table, sources, ranks, max_steps, detour):
    return jax.vmap(lambda s, r: walk_table(table, s, r, max_steps, detour))(sources, ranks)


_extract_jit = grid_jit(_extract, static_argnums=3)
