"""Giving idle rovers tasks: the three strategies, sectors and start cells (docs/fleet.md, "Strategies").

A **task** is one planned push (``Task``): ``episode.plan_for_source`` from a source on the current
fabric, the delivered mass the spill model predicts for its route, the push's steps and its
footprint (``footprint``). A task may start only if its footprint is **free**: it meets no cell of a
running task's footprint (the ownership map) and holds no rover's cell but the assigned rover's.
Disjoint footprints are checked without painting a map per task: a footprint is its core grown by
r cells (the clearance) outside the targets plus its path, so it meets the reserved cells R exactly
when its core meets the non-target cells of R grown by r, or its path meets R (``footprint_free``);
and a rover stands in it exactly when a rover off the targets is within r cells of its core, or a
rover stands on its path.

- ``coordinated`` (``assign_greedy``): the top ``M`` sources by the source rule's score among the
  occupied cells outside every footprint, each planned (``vmap``); then, as long as a pair is left,
  the (idle rover, candidate) pair of the best score ``predicted / (approach + push steps)`` whose
  footprint is free of the footprints reserved so far is assigned and its footprint reserved.
  ``approach`` is the Chebyshev distance from the rover to the route's start, a lower bound of the
  steps it drives (detours around footprints only add). Greedy, because with footprint conflicts the
  choice is no linear assignment problem, and each round is one vectorised argmax over all pairs:
  the pair an auction's first round would settle first.
- ``independent`` and ``partitioned`` (``assign_each``): the single-rover rule, rover by rover in
  index order: the source ``choose_source`` picks among the occupied cells outside every footprint
  (and, partitioned, inside the rover's sector), planned with ``plan_for_source``. If that plan
  cannot be pushed (no complete route) the rover stays idle, as a lone rover would stop. If its
  footprint is not free, the source is skipped and the next best tried, up to ``retries`` times in
  all. With one rover this is ``run_episode``'s tick exactly.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.core import lattice
from jaxplan.fleet import footprint
from jaxplan.transport import execute, spillage
from jaxplan.transport.connectors import slot_anchors
from jaxplan.transport.episode import (
    CLEARED,
    NO_ROUTE,
    RUNNING,
    WALK_CAP,
    anchor_connector,
    choose_source,
    plan_code,
    plan_for_source,
    plan_with_connector,
    source_anchor,
)

__all__ = ["BLOCKED", "Candidates", "Task", "assign_each", "assign_greedy", "assign_planned", "failure_rank",
           "footprint_free", "greedy_choice", "plan_candidates", "plan_task", "reserve", "rover_maps", "sector_grid",
           "sector_starts", "sectors", "spread_starts"]

BLOCKED = 9
"""Code of an assignment that found pushable tasks whose footprints were all taken (the fleet's
stop code "no_reachable_task" when nothing else runs)."""

_BIG = 2 ** 30


class Task(NamedTuple):
    """One planned push (a leading batch axis when batched). C core cells.

    source: i32[2]; route: execute.Route; mode: i32[] (0 deliver, 1 rearrange); code: i32[] the
    episode's plan code (``RUNNING`` = pushable, ``CLEARED`` no source, ``NO_ROUTE``, ``WALK_CAP``);
    predicted: f32[] objects the spill model delivers; steps: i32[] push steps; core: i32[C, 2],
    core_valid, on_path: bool[C] the footprint's core and which of its rows are the push path
    (``footprint.core_cells``).
    """

    source: jax.Array
    route: execute.Route
    mode: jax.Array
    code: jax.Array
    predicted: jax.Array
    steps: jax.Array
    core: jax.Array
    core_valid: jax.Array
    on_path: jax.Array


def plan_task(scene, params, ep, spill, fabric, source, has_source, cap: int, evaluator, clearance: int,
              connector=None) -> Task:
    """The ``Task`` of pushing from ``source: i32[2]`` (``has_source``: it is a candidate at all);
    cap, evaluator, clearance: static. connector: optional ``(anchor i32[], Table)``, the source's
    anchor and its connector table when already computed (``plan_candidates``)."""
    if connector is None:
        plan = plan_for_source(scene, params, ep, spill, fabric, source, cap, evaluator)
    else:
        plan = plan_with_connector(scene, params, ep, spill, fabric, source, *connector, cap, evaluator)
    plan = plan._replace(has_source=has_source & plan.has_source)
    route = plan.route
    points, n_points = execute.waypoints(scene, route)
    pickup, _ = execute.waypoint_pickup(scene, route)
    predicted, _, samples = spillage.evaluate_route(points, n_points, pickup, spill, evaluator,
                                                    chunk=execute.SPLINE_CHUNK)
    core, valid, on_path = footprint.core_cells(scene, route, samples, clearance)
    return Task(plan.source, route, plan.mode, plan_code(plan, cap, scene.shape), predicted,
                footprint.push_steps(route), core, valid, on_path)


def failure_rank(code):
    """i32[]: how much an assignment failure says, to report the most telling one: none (0) <
    no source (``CLEARED``) < footprints taken (``BLOCKED``) < ``WALK_CAP`` < ``NO_ROUTE``."""
    return jnp.select([code == CLEARED, code == BLOCKED, code == WALK_CAP, code == NO_ROUTE], [1, 2, 3, 4], 0)


def _worse(a, b):
    return jnp.where(failure_rank(b) > failure_rank(a), b, a)


def rover_maps(pos, target_mask, clearance: int):
    """``(at, low, high)``, each i32[H, W]: the index of the rover on each cell (-1 none), and the
    lowest / highest index of the rovers off the targets within Chebyshev distance ``clearance``
    (static, 0 or 1) of each cell (``2**30`` / -1 none)."""
    h, w = target_mask.shape
    n = pos.shape[0]
    at = jnp.full(h * w, -1, jnp.int32).at[pos[:, 0] * w + pos[:, 1]].set(jnp.arange(n, dtype=jnp.int32))
    at = at.reshape(h, w)
    off = jnp.where(target_mask, -1, at)
    low0 = jnp.where(off >= 0, off, _BIG)
    if clearance == 0:
        return at, low0, off
    low = jnp.minimum(low0, jnp.min(lattice.neighbours(low0, _BIG), 0))
    high = jnp.maximum(off, jnp.max(lattice.neighbours(off, -1), 0))
    return at, low, high


def _take(a, cells, valid, fill):
    """``a``'s values at ``cells: i32[C, 2]``, ``fill`` where not ``valid``."""
    safe = jnp.maximum(cells, 0)
    return jnp.where(valid, a[safe[:, 0], safe[:, 1]], fill)


def _rovers_inside(task: Task, maps):
    """``(low, high)``: lowest and highest index of the rovers standing in the task's footprint."""
    at, low, high = maps
    path = task.core_valid & task.on_path
    on_path = _take(at, task.core, path, -1)
    lo = jnp.minimum(jnp.min(_take(low, task.core, task.core_valid, _BIG)),
                     jnp.min(jnp.where(on_path >= 0, on_path, _BIG)))
    hi = jnp.maximum(jnp.max(_take(high, task.core, task.core_valid, -1)), jnp.max(on_path))
    return lo, hi


def _blocked(owner, target_mask, clearance: int):
    """bool[H, W]: cells within ``clearance`` cells of a reserved cell off the targets."""
    return footprint.dilate((owner >= 0) & ~target_mask, clearance)


def _clear(task: Task, owner, blocked):
    """bool[]: the task's footprint meets no reserved cell (``blocked``: ``_blocked(owner, ...)``)."""
    hits = jnp.any(_take(blocked, task.core, task.core_valid, False))
    return ~hits & ~jnp.any(_take(owner, task.core, task.core_valid & task.on_path, -1) >= 0)


def footprint_free(task: Task, owner, target_mask, maps, rover, clearance: int):
    """bool[]: ``task``'s footprint is free for ``rover`` (module docstring). owner: i32[H, W] (-1
    free); maps: ``rover_maps`` of the rovers' cells; rover: i32[]; clearance: static."""
    lo, hi = _rovers_inside(task, maps)
    alone = (hi < 0) | ((lo == rover) & (hi == rover))
    return _clear(task, owner, _blocked(owner, target_mask, clearance)) & alone


def reserve(owner, task: Task, rover, target_mask, clearance: int):
    """i32[H, W]: ``owner`` with the task's footprint given to ``rover``."""
    mask = footprint.mask_from_core(target_mask, task.core, task.core_valid, task.on_path, clearance)
    return jnp.where(mask, rover, owner)


def _source_score(scene, fabric, rule: str):
    return fabric.value if rule == "max_value" else -scene.dist


class Candidates(NamedTuple):
    """The coordinated strategy's planned candidates (M of them), valid while the fabric and the
    reserved footprints they were planned on stay the same.

    tasks: Task[M]; exists: bool[M] the slot holds an occupied source; usable: bool[M] it holds a
    pushable task.
    """

    tasks: Task
    exists: jax.Array
    usable: jax.Array


def plan_candidates(scene, params, ep, spill, fabric, owner, *, candidates: int, cap: int, evaluator,
                    clearance: int) -> Candidates:
    """The top ``M = candidates`` sources by the source rule's score among the occupied cells outside
    every footprint (``owner: i32[H, W]``, -1 free), each planned as a ``Task``.

    Sources that share a highway anchor share its connector DP: the distinct anchors are listed
    (at most M) and their tables computed one after another, skipping empty slots, so the cost
    grows with the number of distinct anchors, not with M.
    """
    h, w = scene.shape
    m = min(int(candidates), h * w)
    score_src = _source_score(scene, fabric, ep.source_rule)
    vals = jnp.where(fabric.occupied & (owner < 0), score_src, -jnp.inf).reshape(-1)
    top, idx = jax.lax.top_k(vals, m)
    exists = top > -jnp.inf
    sources = jnp.stack([idx // w, idx % w], -1).astype(jnp.int32)
    anchors = jax.vmap(lambda s: source_anchor(scene, params, fabric, s))(sources)
    anchors = jnp.where(exists, anchors, -1)
    distinct = slot_anchors(anchors, m)
    tables = jax.lax.map(lambda a: anchor_connector(scene, params, fabric, a), distinct)
    slot = jnp.argmax(distinct[None] == anchors[:, None], -1)
    tasks = jax.vmap(lambda s, e, a, k: plan_task(
        scene, params, ep, spill, fabric, s, e, cap, evaluator, clearance,
        connector=(a, jax.tree.map(lambda t: t[k], tables))))(sources, exists, anchors, slot)
    return Candidates(tasks, exists, exists & (tasks.code == RUNNING))


def assign_greedy(scene, params, ep, spill, fabric, pos, idle, owner, budget, routes, *, candidates: int,
                  cap: int, evaluator, clearance: int):
    """The coordinated strategy (module docstring): ``(route, mode i32[N], assigned bool[N], owner, failure)``.

    pos: i32[N, 2]; idle: bool[N] rovers that may take a task; owner: i32[H, W]; budget: i32[] most
    tasks to start; routes: the rovers' current ``execute.Route`` batch (kept where none is assigned);
    candidates (M), cap (walk cap), evaluator, clearance: static. route[r] and mode[r] are rover r's new task
    where assigned[r]; failure: i32[] the episode's code saying why nothing could be assigned
    (``RUNNING`` when something was).
    """
    planned = plan_candidates(scene, params, ep, spill, fabric, owner, candidates=candidates, cap=cap,
                              evaluator=evaluator, clearance=clearance)
    return assign_planned(planned, scene.target_mask, pos, idle, owner, budget, routes, clearance)


def assign_planned(planned: Candidates, target_mask, pos, idle, owner, budget, routes, clearance: int):
    """``assign_greedy`` on candidates already planned (``plan_candidates`` on this fabric and this
    ``owner``); the same results."""
    tasks = planned.tasks
    choice, owner, count = greedy_choice(pos, idle, owner, budget, planned.usable, tasks, target_mask, clearance)
    assigned = choice >= 0
    mine = jax.tree.map(lambda a: a[jnp.maximum(choice, 0)], (tasks.route, tasks.mode))
    route, mode = _keep_rows(assigned, mine, (routes, jnp.zeros(pos.shape[0], jnp.int32)))
    failure = jnp.select([count > 0, ~jnp.any(planned.exists), ~jnp.any(planned.usable)],
                         [RUNNING, CLEARED, tasks.code[0]], BLOCKED)
    return route, mode, assigned, owner, failure.astype(jnp.int32)


def _keep_rows(mask, new, old):
    """``new`` where ``mask: bool[N]`` else ``old``, leaf by leaf (leading axis N)."""
    return jax.tree.map(lambda a, b: jnp.where(mask.reshape((-1,) + (1,) * (a.ndim - 1)), a, b), new, old)


def greedy_choice(pos, idle, owner, budget, usable, tasks: Task, target_mask, clearance: int = 1):
    """The greedy rounds of ``assign_greedy``: ``(choice i32[N], owner, count i32[])``.

    pos: i32[N, 2]; idle: bool[N]; owner: i32[H, W]; budget: i32[] most assignments; usable: bool[M]
    candidates that may be assigned; tasks: Task[M] (its source, predicted, steps, core, core_valid,
    on_path are read); target_mask: bool[H, W]; clearance: static. choice[r] is the candidate rover r took (-1 none);
    owner has their footprints.
    Each round assigns the best-scoring free pair (module docstring; ties: lowest rover, then
    candidate); rounds stop when no pair is left.
    """
    n = pos.shape[0]
    m = usable.shape[0]
    maps = rover_maps(pos, target_mask, clearance)
    lo, hi = jax.vmap(lambda t: _rovers_inside(t, maps))(tasks)
    rovers = jnp.arange(n, dtype=jnp.int32)
    alone = (hi < 0)[None] | ((lo == hi)[None] & (hi[None] == rovers[:, None]))          # [N, M]
    approach = jnp.max(jnp.abs(pos[:, None, :] - tasks.source[None]), -1)
    score = tasks.predicted[None] / (approach + tasks.steps[None]).astype(jnp.float32)
    pairs = alone & usable[None]

    def more(carry):
        return carry[-1]

    def round_(carry):
        owner, idle, unused, choice, count, _ = carry
        blocked = _blocked(owner, target_mask, clearance)
        clear = jax.vmap(lambda t: _clear(t, owner, blocked))(tasks)
        ok = pairs & idle[:, None] & (unused & clear)[None] & (count < budget)
        best = jnp.argmax(jnp.where(ok, score, -jnp.inf).reshape(-1))
        r, c = best // m, best % m
        found = jnp.any(ok)
        chosen = jax.tree.map(lambda a: a[c], tasks)
        owner = jnp.where(found, reserve(owner, chosen, r, target_mask, clearance), owner)
        idle = idle.at[r].set(idle[r] & ~found)
        unused = unused.at[c].set(unused[c] & ~found)
        choice = choice.at[r].set(jnp.where(found, c, choice[r]))
        count = count + found
        return owner, idle, unused, choice, count, found & jnp.any(idle) & (count < budget)

    start = (owner, idle, jnp.ones(m, bool), jnp.full(n, -1, jnp.int32), jnp.int32(0),
             jnp.any(idle) & (budget > 0))
    owner, _, _, choice, count, _ = jax.lax.while_loop(more, round_, start)
    return choice, owner, count


def assign_each(scene, params, ep, spill, fabric, pos, idle, owner, budget, routes, region, *, retries: int,
                cap: int, evaluator, clearance: int):
    """The independent and partitioned strategies (module docstring); arguments and results as
    ``assign_greedy``.

    region: i32[H, W] the sector each cell belongs to, -1 everywhere for ``independent`` (rover r
    takes sources where region is -1 or r); retries (static): sources tried per rover and step.
    """
    h, w = scene.shape
    n = pos.shape[0]
    maps = rover_maps(pos, scene.target_mask, clearance)

    def rover(r, carry):
        owner, tasks, assigned, count, failure = carry
        mine = (region < 0) | (region == r)

        def attempt(carry):
            owner, tasks, assigned, count, failure = carry

            def more(c):
                return c[-1]

            def try_(c):
                excluded, tries, owner, tasks, assigned, failure, _ = c
                source, has = choose_source(scene, fabric, ep.source_rule, mine & (owner < 0) & ~excluded)
                task = plan_task(scene, params, ep, spill, fabric, source, has, cap, evaluator, clearance)
                pushable = task.code == RUNNING
                free = pushable & footprint_free(task, owner, scene.target_mask, maps, r, clearance)
                owner = jnp.where(free, reserve(owner, task, r, scene.target_mask, clearance), owner)
                tasks = jax.tree.map(lambda all_, one: all_.at[r].set(jnp.where(free, one, all_[r])), tasks,
                                     (task.route, task.mode))
                assigned = assigned.at[r].set(free)
                failure = jnp.where(free, failure, jnp.where(pushable, BLOCKED, task.code))
                excluded = excluded.at[source[0], source[1]].set(True)
                again = pushable & ~free & (tries + 1 < retries)
                return excluded, tries + 1, owner, tasks, assigned, failure, again

            start = (jnp.zeros((h, w), bool), jnp.int32(0), owner, tasks, assigned, jnp.int32(RUNNING), jnp.bool_(True))
            _, _, owner, tasks, assigned, mine_failure, _ = jax.lax.while_loop(more, try_, start)
            return owner, tasks, assigned, count + assigned[r], _worse(failure, mine_failure)

        return jax.lax.cond(idle[r] & (count < budget), attempt, lambda c: c, carry)

    start = (owner, (routes, jnp.zeros(n, jnp.int32)), jnp.zeros(n, bool), jnp.int32(0), jnp.int32(RUNNING))
    owner, (route, mode), assigned, count, failure = jax.lax.fori_loop(0, n, rover, start)
    return route, mode, assigned, owner, jnp.where(count > 0, RUNNING, failure).astype(jnp.int32)


# ------------------------------------------------------------------------------------ sectors, starts

def sector_grid(n: int) -> tuple[int, int]:
    """``(rows, cols)`` of the sector grid for n rovers: rows = the largest divisor of n that is at
    most sqrt(n), so the sectors are as near square as n allows (a prime n gives vertical strips)."""
    rows = max(d for d in range(1, int(np.sqrt(n)) + 1) if n % d == 0)
    return rows, n // rows


def sectors(shape, n: int) -> np.ndarray:
    """i32[H, W]: the sector of every cell for ``partitioned`` with n rovers: ``sector_grid(n)``
    bands of equal height and width (up to one cell), numbered row-major."""
    h, w = shape
    rows, cols = sector_grid(n)
    band_r = (np.arange(h) * rows) // h
    band_c = (np.arange(w) * cols) // w
    return (band_r[:, None] * cols + band_c[None, :]).astype(np.int32)


def _border_order(shape) -> np.ndarray:
    """i32[H W]: flat cell indices, the border clockwise from (0, 0) first, then the rest row-major."""
    h, w = shape
    ring = [(0, c) for c in range(w)] + [(r, w - 1) for r in range(1, h)]
    ring += [(h - 1, c) for c in range(w - 2, -1, -1)] if h > 1 else []
    ring += [(r, 0) for r in range(h - 2, 0, -1)] if w > 1 else []
    seen, order = set(), []
    for r, c in ring:
        if (r, c) not in seen:
            seen.add((r, c))
            order.append(r * w + c)
    order += [i for i in range(h * w) if (i // w, i % w) not in seen]
    return np.asarray(order, np.int32)


def spread_starts(target_mask, n: int):
    """i32[N, 2]: n distinct cells outside the target, spread evenly along the grid's border
    (clockwise from the top-left corner; the interior row-major where the border has too few). The
    grid must have at least n cells outside the target."""
    h, w = target_mask.shape
    order = jnp.asarray(_border_order((h, w)))
    border = jnp.arange(h * w) < (2 * (h + w) - 4 if h > 1 and w > 1 else h * w)
    ok = ~target_mask.reshape(-1)[order]
    listed = order[jnp.nonzero(ok, size=h * w, fill_value=0)[0]]
    k_border = jnp.sum(ok & border)
    k = jnp.where(k_border >= n, k_border, jnp.sum(ok))
    pick = (jnp.arange(n) * k) // n
    flat = listed[pick]
    return jnp.stack([flat // w, flat % w], -1).astype(jnp.int32)


def sector_starts(target_mask, region: np.ndarray):
    """i32[N, 2]: for each sector i of ``region`` (a concrete i32[H, W], ``sectors``), the cell outside
    the target nearest the sector's centre (ties: row-major), chosen in sector order among cells
    not yet taken; a sector with no such cell takes the nearest free cell outside it."""
    h, w = target_mask.shape
    region = np.asarray(region)
    n = int(region.max()) + 1
    rows, cols = np.meshgrid(np.arange(h, dtype=np.float32), np.arange(w, dtype=np.float32), indexing="ij")
    centres = np.asarray([(rows[region == i].mean(), cols[region == i].mean()) for i in range(n)], np.float32)
    inside = region[None] == np.arange(n)[:, None, None]
    cost = (rows[None] - centres[:, 0, None, None]) ** 2 + (cols[None] - centres[:, 1, None, None]) ** 2
    cost = jnp.asarray(np.where(inside, cost, cost + 1e9), jnp.float32)

    def one(i, carry):
        taken, out = carry
        flat = jnp.argmin(jnp.where(target_mask | taken, jnp.inf, cost[i]).reshape(-1))
        cell = jnp.stack([flat // w, flat % w]).astype(jnp.int32)
        return taken.at[cell[0], cell[1]].set(True), out.at[i].set(cell)

    _, out = jax.lax.fori_loop(0, n, one, (jnp.zeros((h, w), bool), jnp.zeros((n, 2), jnp.int32)))
    return out
