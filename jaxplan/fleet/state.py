"""The fleet as a pure state machine: ``FleetConfig``, ``FleetState``, ``reset``, ``step``, ``rollout``.

One ``step`` is one unit of simulated time (docs/fleet.md, "One step"):

1. **Assign**: idle rovers get tasks from the current fabric by the strategy (``assign``), while the
   push budget lasts (tasks started < ``FleetState.totals.max_pushes``, which ``reset`` takes from
   ``EpisodeParams.max_pushes``, so that the compiled step does not depend on the budget, a static
   field of ``EpisodeParams``: ``step`` ignores ``episode.max_pushes``). A rover already on its task's
   start pushes at once, the others approach. Coordinated, sources whose tasks meet a running
   task's footprint are set aside while it runs (``set_aside``), and parked rovers that hold up the
   best free task are sent to new homes (``make_way``).
2. **Distance fields**: a rover that drives (approaching its task's start, or idle and driving back
   to its home cell, its start cell) goes by the Chebyshev distance to its goal, which no other
   rover's reservation outdates (``motion.approach_distance``). Only a rover that waited
   ``motion.PATIENCE`` steps in a row gets a breadth-first field of its own in a slot of the
   ``FieldPool`` (``motion.update_fields``, stopped once the rover's own cell is reached), over the
   cells outside other rovers' footprints and off the cells of other idle rovers parked at home; it
   keeps the slot while it drives to that goal (a later wait recomputes it), and gives it back when
   its goal changes. When every slot is held the rover waits on. An approaching rover whose field
   says it cannot reach its start drops its task (footprint released, not counted against the
   budget) and idles.
3. **Move**: every rover moves at most one cell, in index order (``motion.move_rovers``): rovers not
   pushing down their field, pushing rovers one cell along the push path. Idle rovers thus drive
   home, out of the way of tasks their cells would block. A rover that reaches its start pushes
   from the next step on.
4. **Apply**: pushes that reached their path's last cell this step are applied to the counts with
   ``execute`` in rover order, on the counts at that moment, their footprints released; then one
   rebuild refreshes the shared fabric (``fleet_rebuild``: the selective update of the cells the
   pushes changed with ``episode.rebuild="selective"``, else a full build; the same fabric either
   way).
5. **Stop** (first that holds): the mass outside the targets is at most ``stop_fraction`` of its start
   ("done"); no task runs and the budget is spent ("budget"); no task runs, none could be assigned
   and the next step would be the same (the assignment's reason: "done" when no source is left,
   "no_route" / "walk_cap" as in an episode, "no_reachable_task" when every pushable task's
   footprint held another rover, every idle rover is parked at home and none was sent to make way);
   nothing moved or pushed for ``stall_steps`` steps while a task ran, a task was dropped or an idle
   rover was on its way home ("deadlock", or "no_reachable_task" when no task runs: rovers kept
   dropping unreachable tasks, or could not get home); the step limit ("max_steps").

Each step is a function of ``_advance`` (``advance``; ``step`` is ``advance`` then ``refresh``):
``_assign`` (``_plan_setting_aside``), ``_take_tasks`` and ``_make_way`` (1), ``_fields`` and ``_drop_unreachable`` (2),
``_move`` (3), ``_apply_pushes`` (4, the rebuild in ``refresh``, which keeps the cached tasks the
rebuild left unchanged: ``keep_tasks``), ``_stop`` (5); then ``_expire`` marks the cached tasks no
longer fresh. ``FleetState`` holds the shared scene and fabric,
the footprints and cached tasks, every rover's row in ``Rovers`` and the scalars in ``Totals``.

A finished state's step is a no-op, so ``rollout`` (``lax.scan``) may run past the end. Counts stay
multiples of ``execute.QUANTUM``, so the grid's total is exactly conserved by every push.
"""
from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.fleet import assign, footprint, make_way, motion, sectors, set_aside
from jaxplan.fleet.motion import APPROACH, FAR, IDLE, PUSH
from jaxplan.transport import (
    BUDGET,
    DONE,
    NO_MATERIAL,
    RUNNING,
    EpisodeParams,
    Fabric,
    FabricParams,
    Route,
    build_fabric,
    corner_free,
    default_walk_cap,
    estimate_build_bytes,
    execute_push,
    fabric_changes,
    outside_mass,
    quantize,
    require_hard,
    selective_rebuild,
)
from jaxplan.transport import STOP_REASONS as EPISODE_STOP_REASONS
from jaxplan.transport.spillage import Evaluator, SpillParams, evaluator_for

__all__ = ["DEADLOCK", "MAX_STEPS", "NO_REACHABLE", "STOP_REASONS", "STRATEGIES", "FleetConfig", "FleetRecord",
           "FleetState", "Rovers", "Totals", "advance", "estimate_fleet_bytes", "fleet_rebuild", "keep_tasks",
           "max_rovers", "refresh", "reset", "rollout", "step", "unchanged_tasks"]

STRATEGIES = ("coordinated", "independent", "partitioned")
# Stop codes (``Totals.stop``, ``FleetRecord.stop`` and ``failure``), indices into STOP_REASONS: the
# episode's table (``transport.STOP_REASONS``, 0-6: running, done, done (no source left), budget,
# no_material, no_route, walk_cap), then the fleet's own three, numbered after it.
STOP_REASONS = EPISODE_STOP_REASONS + ("max_steps", "deadlock", "no_reachable_task")
MAX_STEPS, DEADLOCK, NO_REACHABLE = range(len(EPISODE_STOP_REASONS), len(STOP_REASONS))
# an assignment's failure code becomes the fleet's stop code
assert assign.BLOCKED == NO_REACHABLE, "assign.BLOCKED must be the fleet's no_reachable_task code"
MAX_ROVERS = 1024
CANDIDATE_RULES = ("value", "rate")
MAX_CANDIDATES = 64
# Stuck rovers whose distance fields are computed together: a chunk runs as many rounds as its
# farthest rover needs, so small chunks waste little when one or two rovers are stuck.
FIELD_CHUNK = 4
# Slots of the field pool: the most rovers driving on fields of their own at once (the others drive by
# the Chebyshev distance, and a stuck rover waits for a free slot).
FIELD_SLOTS = 32
DEFAULT_MAX_STEPS = 100_000
# The walk length a coordinated planning tries first on long walk caps (FleetConfig.short_cap): the
# routes of the built-in sites are a few dozen cells against caps of thousands.
SHORT_CAP = 128


def field_slots(n_rovers: int) -> int:
    """R: slots of a fleet's ``FieldPool``, min(N, ``FIELD_SLOTS``)."""
    return min(n_rovers, FIELD_SLOTS)


def max_rovers() -> int:
    """The most rovers a fleet may have (1024)."""
    return MAX_ROVERS


@dataclasses.dataclass(frozen=True)
class FleetConfig:
    """Static fleet settings (part of the jit cache key).

    n_rovers: N, an int in [1, 1024]. strategy: one of ``STRATEGIES``. candidates: M sources planned
    per coordinated assignment (None: 2 N, at least 8 and at most 64). walk_cap: static walk length of
    a plan (None: ``episode.default_walk_cap``); routes have S = 2 (walk_cap + 1) slots, and every
    planned task's arrays are sized by it, so a coordinated planning's time grows with it
    (docs/fleet.md, "API"). short_cap: the walk length a coordinated planning tries first
    (``assign.plan_candidates``): tasks whose walks all end within it are planned at its size and
    padded, the others planned again at walk_cap, and a push whose route ends within 2 (short_cap + 1)
    rows is applied on those rows; the same tasks and pushes either way (None: ``SHORT_CAP`` when
    walk_cap is at least ``4 SHORT_CAP``, else walk_cap, one planning). stall_steps: steps without
    any move or push before the fleet stops "deadlock" (None: 2 (H + W)). retries: sources an
    independent or partitioned rover tries per step when footprints are taken. clearance: cells
    reserved around a route beyond the cells its push changes: 0 (default), 1 or 2, the rover's body
    (``footprint``). candidates_by: the coordinated strategy's candidates, "rate" (default: each
    idle rover's two best sources by the rate the fabric promises it, ``assign.rate_sources``; it
    reached T90 sooner than "value" at every fleet size from 4 to 64 measured on site128 and
    site256, docs/benchmarks.md) or "value" (the top sources by the source rule). set_aside: the
    coordinated planning sets aside the sources whose tasks meet a running task's footprint while
    that task runs (``set_aside``; default True; False plans them again at every planning).

    ``step`` reads only whether the strategy is "coordinated": independent and partitioned fleets
    differ in their state (``FleetState.region`` and ``rovers.home``, made by ``reset``), so both run
    the program of ``kernel()``.
    """

    n_rovers: int
    strategy: str = "coordinated"
    candidates: int | None = None
    walk_cap: int | None = None
    stall_steps: int | None = None
    retries: int = 3
    clearance: int = 0
    candidates_by: str = "rate"
    set_aside: bool = True
    short_cap: int | None = None

    def resolved(self, shape) -> FleetConfig:
        """This config with every None replaced by its value for a grid of ``shape``."""
        h, w = shape
        cap = default_walk_cap(shape) if self.walk_cap is None else self.walk_cap
        if self.short_cap is None:
            short = SHORT_CAP if cap >= 4 * SHORT_CAP else cap
        else:
            short = min(self.short_cap, cap)
        return dataclasses.replace(
            self,
            candidates=min(max(2 * self.n_rovers, 8), MAX_CANDIDATES) if self.candidates is None else self.candidates,
            walk_cap=cap, short_cap=short,
            stall_steps=2 * (h + w) if self.stall_steps is None else self.stall_steps)

    def kernel(self) -> FleetConfig:
        """The config ``step`` compiles for: partitioned runs the independent program."""
        return dataclasses.replace(self, strategy="independent") if self.strategy == "partitioned" else self

    def validate(self) -> None:
        """Raise ``ValueError`` naming the field for a bad setting."""
        def is_int(v):
            return isinstance(v, int) and not isinstance(v, bool)

        if not is_int(self.n_rovers) or not 1 <= self.n_rovers <= MAX_ROVERS:
            raise ValueError(f"FleetConfig.n_rovers: {self.n_rovers!r} is out of range; a fleet has an int in "
                             f"[1, {MAX_ROVERS}] rovers.")
        if self.strategy not in STRATEGIES:
            raise ValueError(f"FleetConfig.strategy: {self.strategy!r} is not a strategy; use one of {STRATEGIES}.")
        for name, low, high in (("candidates", 1, 4096), ("walk_cap", 1, 1 << 24), ("short_cap", 1, 1 << 24),
                                ("stall_steps", 1, 1 << 30), ("retries", 1, 64)):
            value = getattr(self, name)
            if value is not None and (not is_int(value) or not low <= value <= high):
                raise ValueError(f"FleetConfig.{name}: {value!r} is out of range; it must be an int in "
                                 f"[{low}, {high}] (or None for the default).")
        if self.candidates_by not in CANDIDATE_RULES:
            raise ValueError(f"FleetConfig.candidates_by: {self.candidates_by!r} is not a rule; use one of "
                             f"{CANDIDATE_RULES}.")
        if self.clearance not in footprint.CLEARANCES:
            raise ValueError(f"FleetConfig.clearance: {self.clearance!r} is not allowed; use one of "
                             f"{footprint.CLEARANCES} (cells reserved around a route).")
        if not isinstance(self.set_aside, bool):
            raise ValueError(f"FleetConfig.set_aside: {self.set_aside!r} is not a bool; use True or False.")


class Rovers(NamedTuple):
    """Every rover's own state: a pytree whose every leaf leads with the rover axis N (row i is rover
    i). H x W grid, S route slots.

    pos: i32[N, 2] rover cells (row, col). home: i32[N, 2] start cells, where idle rovers park.
    base: i32[N, 2] where the rover last became idle (its last push's end, the cell where it dropped
      a task, or its start): the rate rule ranks an idle rover's sources from there
      (``FleetConfig.candidates_by``), so that its candidates change only when a rover takes or ends
      a task, and cached candidates stay exactly what planning again would give.
    phase: i32[N] (``motion.IDLE``, ``APPROACH``, ``PUSH``).
    route: execute.Route batched (cells i32[N, S, 2], n_cells i32[N], fallback bool[N], end f32[N, 2]),
      each rover's task (stale while idle). mode: i32[N] 0 deliver, 1 rearrange.
    task_step: i32[N] the step its task was assigned in (1 = the first step).
    progress: i32[N] index of the rover's cell on its push path while pushing.
    slot: i32[N] the rover's slot in the state's ``FieldPool`` (-1: it drives by the Chebyshev
      distance). wait: i32[N] steps in a row it drove nowhere while it wanted to.
    pushes: i32[N] pushes applied per rover.
    idle_steps: i32[N] steps each rover had no task (idle after step 2: no task, or its task dropped).
    """

    pos: jax.Array
    home: jax.Array
    base: jax.Array
    phase: jax.Array
    route: Route
    mode: jax.Array
    task_step: jax.Array
    progress: jax.Array
    slot: jax.Array
    wait: jax.Array
    pushes: jax.Array
    idle_steps: jax.Array


class Totals(NamedTuple):
    """The fleet's scalars: its clock, limits, running totals and stop code. A pytree of 0-d leaves.

    t: i32[] steps done. stall: i32[] consecutive steps without a move or push. max_steps: i32[] the
    step limit. max_pushes: i32[] the push budget (tasks started, dropped ones not counted).
    started: i32[] tasks started and not dropped.
    delivered, spilled: f32[] objects, all pushes. outside: f32[] objects outside the targets now.
    initial_mass: f32[] the grid's total, objects. initial_outside: f32[] objects outside the targets
    at the start. stop_at: f32[] objects outside at which the fleet is done (stop_fraction *
    initial_outside).
    done: bool[]; stop: i32[] (``STOP_REASONS``; ``RUNNING`` = 0 until done).
    """

    t: jax.Array
    stall: jax.Array
    max_steps: jax.Array
    max_pushes: jax.Array
    started: jax.Array
    delivered: jax.Array
    spilled: jax.Array
    outside: jax.Array
    initial_mass: jax.Array
    initial_outside: jax.Array
    stop_at: jax.Array
    done: jax.Array
    stop: jax.Array


class FleetState(NamedTuple):
    """Everything the fleet carries from one step to the next. A pytree; N rovers, H x W grid.

    scene: Scene, counts now (multiples of ``execute.QUANTUM``). fabric: Fabric of those counts.
    rovers: ``Rovers``, each rover's cell, task, phase and field slot.
    fields: ``motion.FieldPool``, R = min(N, ``FIELD_SLOTS``) distance fields of stuck rovers.
    owner: i32[H, W] the rover whose footprint holds the cell (-1 none).
    region: i32[H, W] partitioned sectors (-1 everywhere for the other strategies).
    candidates: ``assign.Candidates`` (M slots for ``coordinated``, none otherwise), the tasks the
      last coordinated assignment planned; fresh: bool[] they were planned on this fabric and this
      ownership map (no push ended, no task started or was dropped since), so the next assignment
      reuses them instead of planning again: the same tasks, at the cost of the greedy rounds only.
      When only the ownership changed, the next planning keeps the tasks of the sources it planned
      before and plans the new ones; when a push ended, the refresh clears ``exists`` of the tasks
      whose plans read something the new fabric or counts changed (``keep_tasks``), and the next
      planning plans those sources again with the new ones.
    aside: ``set_aside.SetAside`` (``set_aside.CAPACITY`` slots for ``coordinated``, none otherwise):
      sources whose planned tasks met a running task's footprint, not offered as candidates while that
      task runs.
    attempts: ``assign.Attempts`` (N rovers for ``independent`` and ``partitioned``, none for
      ``coordinated``): each rover's last failed attempt, not planned again while fresh and no rover
      moved through the footprints it tried.
    totals: ``Totals``, the step count, limits, running totals and stop code.
    """

    scene: Any
    fabric: Fabric
    rovers: Rovers
    fields: motion.FieldPool
    owner: jax.Array
    region: jax.Array
    candidates: assign.Candidates
    aside: set_aside.SetAside
    attempts: assign.Attempts
    fresh: jax.Array
    totals: Totals


class FleetRecord(NamedTuple):
    """What one step did (all zero for a finished state's step). N rovers.

    pos: i32[N, 2] cells after the step. phase: i32[N] after the step. assigned: bool[N] a task
    started; dropped: bool[N] an unreachable task was dropped; ended: bool[N] a push was applied.
    collected, delivered, spilled: f32[N] objects of the pushes applied (0 elsewhere).
    delivered_total: f32[] objects delivered by all pushes so far. outside, inside: f32[] objects
    outside / inside the targets after the step. mass: f32[] the grid's total. made_way: bool[N]
    parked rovers sent to a new home, out of a task's footprint (``make_way``). planned: i32[] tasks
    the coordinated assignment planned (sources not kept from its last planning; 0 when it reused
    fresh candidates, ran none, or for the other strategies). conflicts: i32[]
    invariant violations of this step found in the step itself (two rovers in one cell, a swap, a
    rover in another's footprint); must be 0. failure: i32[] why an assignment found nothing
    (``STOP_REASONS`` code, 0 when it did or none ran). stop: i32[] the stop code after the step.
    valid: bool[] the step ran (the state was not done).
    """

    pos: jax.Array
    phase: jax.Array
    assigned: jax.Array
    dropped: jax.Array
    ended: jax.Array
    collected: jax.Array
    delivered: jax.Array
    spilled: jax.Array
    delivered_total: jax.Array
    outside: jax.Array
    inside: jax.Array
    mass: jax.Array
    made_way: jax.Array
    planned: jax.Array
    conflicts: jax.Array
    failure: jax.Array
    stop: jax.Array
    valid: jax.Array


def _f32(x):
    return jnp.asarray(x, jnp.float32)


def _i32(x):
    return jnp.asarray(x, jnp.int32)


def _check_static(params: FabricParams, ep: EpisodeParams, config: FleetConfig, where: str) -> None:
    require_hard(params, where)
    config.validate()
    if ep.reselect:
        raise ValueError("EpisodeParams.reselect: True is not supported by the fleet, which plans on the "
                         "entry-0 fabric (Eq. 5 sources, Eq. 6 per planned source); use reselect=False.")


def route_slots(config: FleetConfig, shape) -> int:
    """S: route slots of a fleet's tasks (``2 (walk_cap + 1)``, as ``episode.plan_tick``'s routes)."""
    return 2 * (config.resolved(shape).walk_cap + 1)


# Working memory of one coordinated assignment, bytes per route slot for each candidate planned at
# once (assign.PLAN_CHUNK of them, vmapped), and of the rovers' fields, bytes per cell and rover.
# XLA's memory_analysis of the compiled step (CPU): temporaries of 3.46 MB (K = 4, 2 coordinated
# rovers, 48x48, S = 770 slots), 3.51 MB (8 rovers), 8.20 MB (2 rovers, 96x96, S = 1538) and
# 5.07 MB (K = 8, 2 rovers, 48x48), against 0.65 MB for 8 independent rovers (K = 4, 48x48). That is
# the fabric rebuild's own temporaries per cell (~280 B at K = 4, which estimate_build_bytes counts),
# per route slot 3,660 B (K = 4) and 4,570 B (K = 8) for the coordinated assignment, 340 + 29 K B per
# slot and candidate, and ~4 B per cell and rover (the fields' update).
PLANNED_SLOT_BYTES = (340, 29)
FIELD_TEMP_BYTES_PER_CELL = 4


def rover_bytes(shape, config: FleetConfig, params: FabricParams | None = None) -> int:
    """Bytes of the fleet's own arrays on an ``(H, W)`` grid, beyond the shared fabric: the state's
    per-rover grids and routes, counted twice (a step's input state and its output state are alive
    together), plus the step's temporaries. Per cell: each of the R field slots (``field_slots``,
    i32, 4 B) twice and its update's temporaries (``FIELD_TEMP_BYTES_PER_CELL``); for independent
    and partitioned fleets the tried footprints (``Attempts.tried`` bool, 1 B) twice; for the
    coordinated strategy the M cached candidates' packed footprints (1 bit) twice and, with
    ``candidates_by="rate"``, the distance and rate grids of ``assign.RATE_CHUNK`` rovers at a time
    (8 B each). Per route slot (S = ``route_slots``): N (+ M) routes x 8 B twice, and for the
    coordinated strategy the ``PLAN_CHUNK`` candidates planned at once (``PLANNED_SLOT_BYTES``: 340
    + 29 K each, K = ``params.k``, default ``FabricParams()``) and the K + 1 walks of walk_cap + 1 cells
    each of the M cached tasks read (``transport.PlanReads``; i32 flat indices, twice); with
    ``set_aside``, the withheld cells (1 B per cell), the M screened sources' walks and the list
    (three i32 per slot, twice)."""
    k = int((FabricParams() if params is None else params).k)
    cfg = config.resolved(shape)
    h, w = (int(v) for v in shape)
    n = cfg.n_rovers
    m = min(cfg.candidates, h * w) if cfg.strategy == "coordinated" else 0
    per_cell = field_slots(n) * (2 * 4 + FIELD_TEMP_BYTES_PER_CELL)
    packed = 2 * m * 4 * -(-h * w // 32)
    per_slot = 2 * (n + m) * 8
    if cfg.strategy != "coordinated":
        per_cell += 2 * n
    else:
        per_cell += 8 * min(n, assign.RATE_CHUNK) if cfg.candidates_by == "rate" else 0
        per_slot += min(assign.PLAN_CHUNK, m) * (PLANNED_SLOT_BYTES[0] + PLANNED_SLOT_BYTES[1] * k)
        per_slot += m * (k + 1) * 4        # the walks each cached task read (PlanReads), half a slot's cells each
        if cfg.set_aside:
            per_cell += 1                  # the withheld sources
            per_slot += m * 4              # the screened sources' walks, half a slot's cells each
    listed = 2 * 3 * 4 * _aside_slots(cfg, shape)
    return per_cell * h * w + packed + per_slot * route_slots(cfg, shape) + listed


def estimate_fleet_bytes(shape, config: FleetConfig, params: FabricParams | None = None) -> int:
    """Estimated peak memory, bytes, that a fleet run on an ``(H, W)`` grid adds to the process:
    ``transport.estimate_build_bytes(shape, params)`` (compiling and building the shared fabric; its
    run term already holds two copies of the fabric, the step's input and output) plus
    ``rover_bytes(shape, config, params)`` (the pool's distance fields, footprint masks, routes and
    planned candidates; the fields grow as min(N, FIELD_SLOTS) x H x W). ``run_fleet`` refuses a
    fleet whose estimate exceeds the memory available. Frames kept with ``record=True`` come on top:
    9 B per cell per step (obj, heat, highways)."""
    return estimate_build_bytes(shape, params) + rover_bytes(shape, config, params)


def reset(scene, params: FabricParams | None = None, spill: SpillParams | None = None,
          episode: EpisodeParams | None = None, config: FleetConfig | None = None, starts=None,
          max_steps: int | None = None, max_pushes=None) -> FleetState:
    """The state before the first step: counts rounded to ``execute.QUANTUM``, the fabric built,
    every rover idle at its start cell, the stop checks of an episode's start applied (no material,
    done, budget 0). Pure and jittable (``vmap`` it over scenes of one shape).

    starts: i32[N, 2] distinct free cells outside the targets (default: ``sectors.spread_starts``, or
    ``sectors.sector_starts`` for ``partitioned``, so rover i starts in sector i); not checked here
    (``run_fleet`` does). max_steps: step limit (default 100,000). max_pushes: the push budget
    (default ``episode.max_pushes``; an argument so a traced one needs no recompile). Only spill's
    static sizes are read (they shape the candidate cache): pass the spill ``step`` will get.
    """
    params = FabricParams() if params is None else params
    ep = EpisodeParams() if episode is None else episode
    config = FleetConfig(1, "independent") if config is None else config
    _check_static(params, ep, config, "reset")
    spill = SpillParams() if spill is None else spill
    shape = scene.shape
    cfg = config.resolved(shape)
    n = cfg.n_rovers
    scene = scene.with_obj(quantize(scene.obj))
    fabric = build_fabric(scene, params)
    # no rover starts in a target, on a blocked cell or on a cell cut off from every target
    no_start = jnp.asarray(scene.target_mask, bool) | ~jnp.isfinite(scene.dist)
    if cfg.strategy == "partitioned":
        cells = sectors.sectors(shape, n)
        region = jnp.asarray(cells)
        default_starts = sectors.sector_starts(no_start, cells)
    else:
        region = jnp.full(shape, -1, jnp.int32)
        default_starts = sectors.spread_starts(no_start, n)
    pos = default_starts if starts is None else _i32(starts).reshape(n, 2)
    s = route_slots(cfg, shape)
    route = Route(cells=jnp.full((n, s, 2), -1, jnp.int32), n_cells=jnp.ones(n, jnp.int32),
                  fallback=jnp.zeros(n, bool), end=jnp.zeros((n, 2), jnp.float32))
    outside = _f32(outside_mass(scene))
    stop_at = _f32(_f32(ep.stop_fraction) * outside)
    budget = _i32(ep.max_pushes if max_pushes is None else max_pushes)
    stop = _i32(jnp.select([outside <= 0, outside <= stop_at, budget <= 0], [NO_MATERIAL, DONE, BUDGET],
                           RUNNING))
    zeros_n = jnp.zeros(n, jnp.int32)
    limit = DEFAULT_MAX_STEPS if max_steps is None else max_steps
    rovers = Rovers(pos=pos, home=pos, base=pos, phase=zeros_n, route=route, mode=zeros_n, task_step=zeros_n,
                    progress=zeros_n, slot=jnp.full(n, -1, jnp.int32), wait=zeros_n, pushes=zeros_n,
                    idle_steps=zeros_n)
    totals = Totals(t=_i32(0), stall=_i32(0), max_steps=_i32(limit), max_pushes=budget, started=_i32(0),
                    delivered=_f32(0.0), spilled=_f32(0.0), outside=outside, initial_mass=_f32(jnp.sum(scene.obj)),
                    initial_outside=outside, stop_at=stop_at, done=stop != RUNNING, stop=stop)
    return FleetState(scene=scene, fabric=fabric, rovers=rovers, fields=motion.empty_pool(field_slots(n), shape),
                      owner=jnp.full(shape, -1, jnp.int32), region=region,
                      candidates=_no_candidates(scene, params, cfg),
                      aside=set_aside.empty(_aside_slots(cfg, shape)),
                      attempts=assign.no_attempts(0 if cfg.strategy == "coordinated" else n, shape),
                      fresh=jnp.bool_(False), totals=totals)


def _no_candidates(scene, params, cfg: FleetConfig) -> assign.Candidates:
    """Empty candidates shaped like ``assign.plan_candidates``'s result: M slots for the coordinated
    strategy, none for the others (which do not cache)."""
    m = min(cfg.candidates, scene.shape[0] * scene.shape[1]) if cfg.strategy == "coordinated" else 0
    return assign.no_candidates(m, scene.shape, params.k, cfg.walk_cap)


def _aside_slots(cfg: FleetConfig, shape) -> int:
    """T: slots of the set-aside list, at least M (one planning's candidates); 0 for the strategies
    that plan no candidates."""
    if cfg.strategy != "coordinated" or not cfg.set_aside:
        return 0
    return max(set_aside.CAPACITY, min(cfg.candidates, shape[0] * shape[1]))


def _idle_record(state: FleetState) -> FleetRecord:
    rovers, totals, scene = state.rovers, state.totals, state.scene
    n = rovers.pos.shape[0]
    f, b = jnp.zeros(n, jnp.float32), jnp.zeros(n, bool)
    inside = jnp.sum(jnp.where(scene.target_mask, scene.obj, 0.0))
    return FleetRecord(pos=rovers.pos, phase=rovers.phase, assigned=b, dropped=b, ended=b, collected=f, delivered=f,
                       spilled=f, delivered_total=totals.delivered, outside=totals.outside, inside=_f32(inside),
                       mass=_f32(jnp.sum(scene.obj)), made_way=b, planned=_i32(0), conflicts=_i32(0),
                       failure=_i32(RUNNING),
                       stop=totals.stop, valid=jnp.bool_(False))


def _assign(state: FleetState, params, spill, ep: EpisodeParams, cfg: FleetConfig, evaluator):
    """Step 1: ``(route, mode, assigned bool[N], owner, failure, candidates, aside, attempts, fresh, planned)``
    (``assign.assign_greedy`` on the cached candidates while they are fresh, or ``assign_each``;
    planned: i32[] tasks the coordinated planning planned); nothing runs when no rover is idle or the
    budget is spent."""
    rovers = state.rovers
    idle = rovers.phase == IDLE
    budget = state.totals.max_pushes - state.totals.started
    scene = state.scene

    def run(_):
        if cfg.strategy == "coordinated":
            planned, aside, fresh = jax.lax.cond(state.fresh, lambda: (state.candidates, state.aside, state.fresh),
                                                 lambda: _plan_setting_aside(state, params, spill, ep, cfg, evaluator))
            count = jnp.where(state.fresh, 0, assign.newly_planned(planned, state.candidates))
            waiting = jnp.any(set_aside.holding(aside, rovers.phase, rovers.task_step))
            route, mode, assigned, owner, failure = assign.assign_planned(planned, rovers.pos, idle, state.owner,
                                                                          budget, rovers.route, waiting)
            return route, mode, assigned, owner, failure, planned, aside, state.attempts, fresh, count
        *out, attempts = assign.assign_each(scene, params, ep, spill, state.fabric, rovers.pos, idle, state.owner,
                                            budget, rovers.route, state.region, state.attempts, state.fresh,
                                            retries=cfg.retries, cap=cfg.walk_cap, evaluator=evaluator,
                                            clearance=cfg.clearance)
        return (*out, state.candidates, state.aside, attempts, jnp.bool_(True), _i32(0))

    def skip(_):
        return (rovers.route, rovers.mode, jnp.zeros(idle.shape, bool), state.owner, _i32(RUNNING),
                state.candidates, state.aside, state.attempts, state.fresh, _i32(0))

    return jax.lax.cond(jnp.any(idle) & (budget > 0), run, skip, None)


def _plan_setting_aside(state: FleetState, params, spill, ep: EpisodeParams, cfg: FleetConfig, evaluator):
    """The coordinated planning: ``(candidates, aside, fresh bool[])``. The sources set aside are not
    planned; the candidates whose tasks meet a reservation are set aside in turn, and then the
    candidates are not fresh, so that the next step offers their rovers other sources."""
    rovers, shape = state.rovers, state.owner.shape
    idle = rovers.phase == IDLE
    if not cfg.set_aside:
        return assign.plan_candidates(
            state.scene, params, ep, spill, state.fabric, state.owner, candidates=cfg.candidates, cap=cfg.walk_cap,
            short_cap=cfg.short_cap, evaluator=evaluator, clearance=cfg.clearance,
            wanted=assign.wanted_candidates(idle, cfg.candidates),
            by_rate=(rovers.base, idle) if cfg.candidates_by == "rate" else None,
            previous=state.candidates), state.aside, jnp.bool_(True)
    holds = set_aside.holding(state.aside, rovers.phase, rovers.task_step)
    m = state.candidates.exists.shape[0]
    flat, exists = assign.choose_sources(
        state.scene, ep, state.fabric, state.owner, m, assign.wanted_candidates(idle, cfg.candidates),
        (rovers.base, idle) if cfg.candidates_by == "rate" else None, set_aside.withheld(state.aside, holds, shape))
    met = set_aside.path_blockers(state.scene, state.fabric, state.owner, flat, exists, cfg.walk_cap)
    screened = met >= 0
    aside = set_aside.add(state.aside, flat, met, screened, rovers.task_step)
    planned = assign.plan_candidates(
        state.scene, params, ep, spill, state.fabric, state.owner, candidates=cfg.candidates, cap=cfg.walk_cap,
        short_cap=cfg.short_cap, evaluator=evaluator, clearance=cfg.clearance, previous=state.candidates,
        chosen=(flat, exists & ~screened))
    blocked = planned.usable & ~planned.clear
    cells = planned.tasks.source[:, 0] * shape[1] + planned.tasks.source[:, 1]
    aside = jax.lax.cond(jnp.any(blocked), lambda: set_aside.add(
        aside, cells, set_aside.blockers(planned.tasks.footprint, state.owner), blocked, rovers.task_step),
        lambda: aside)
    return planned, aside, ~jnp.any(blocked | screened)


def _take_tasks(rovers: Rovers, assigned, route, mode, step_no) -> Rovers:
    """Step 1's tasks given to the ``assigned: bool[N]`` rovers (``route``, ``mode``: the assignment's,
    every rover's row): a rover already on its task's start pushes at once, the others approach."""
    route = assign.select_rows(assigned, route, rovers.route)
    at_start = jnp.all(rovers.pos == route.cells[:, 0], -1)
    return rovers._replace(route=route, phase=jnp.where(assigned, jnp.where(at_start, PUSH, APPROACH), rovers.phase),
                           mode=jnp.where(assigned, mode, rovers.mode),
                           task_step=jnp.where(assigned, step_no, rovers.task_step),
                           progress=jnp.where(assigned, 0, rovers.progress))


def _make_way(state: FleetState, rovers: Rovers, candidates, owner, assigned):
    """Step 1b, coordinated: ``(rovers, made_way bool[N])``, the parked rovers that hold up the best
    free candidate sent to new homes while an idle rover is left without a task and the budget
    allows another (``make_way``)."""
    room = state.totals.max_pushes - state.totals.started - jnp.sum(assigned) > 0
    wanted = jnp.any(rovers.phase == IDLE) & room
    home, moved = make_way.make_way(candidates, owner, rovers.pos, rovers.home,
                                    _parked(rovers.pos, rovers.home, rovers.phase), wanted, state.scene)
    return rovers._replace(home=home), moved


def _release(owner, rovers):
    """``owner`` without the footprints of the ``rovers: bool[N]``."""
    return jnp.where((owner >= 0) & rovers[jnp.maximum(owner, 0)], -1, owner)


def _parked(pos, home, phase):
    """bool[N]: idle rovers standing on their home cell."""
    return (phase == IDLE) & jnp.all(pos == home, -1)


def _goals(rovers: Rovers):
    """i32[N, 2]: where each rover drives: its task's start while approaching, else its home cell."""
    return jnp.where((rovers.phase == APPROACH)[:, None], rovers.route.cells[:, 0], rovers.home)


def _drives(rovers: Rovers):
    """bool[N]: rovers that drive toward a goal: approaching, or idle and not parked at home."""
    return (rovers.phase == APPROACH) | ((rovers.phase == IDLE) & ~_parked(rovers.pos, rovers.home, rovers.phase))


def _fields(rovers: Rovers, pool: motion.FieldPool, owner, blocked):
    """Step 2: ``(rovers, pool)`` (module docstring): a slot stays with its rover
    while the rover drives to the goal it was computed for; a rover that waited ``motion.PATIENCE``
    steps gets its field (re)computed in its slot, or in a free one (in rover order; none left: it
    waits on). blocked: bool[H, W], the scene's blocked cells (never passable, their corners never
    cut)."""
    pos = rovers.pos
    n, r_slots = pos.shape[0], pool.rover.shape[0]
    h, w = owner.shape
    ids = jnp.arange(n, dtype=jnp.int32)
    goals, drives = _goals(rovers), _drives(rovers)
    slot = rovers.slot
    keep = (slot >= 0) & drives & jnp.all(pool.goal[jnp.maximum(slot, 0)] == goals, -1)
    slot = jnp.where(keep, slot, -1)
    holder = jnp.full(r_slots, -1, jnp.int32).at[jnp.where(keep, slot, r_slots)].set(ids, mode="drop")
    need = drives & (rovers.wait >= motion.PATIENCE)
    want = need & (slot < 0)
    free = jnp.nonzero(holder < 0, size=r_slots, fill_value=0)[0]
    rank = jnp.cumsum(want) - 1
    slot = jnp.where(want & (rank < jnp.sum(holder < 0)), free[jnp.clip(rank, 0, r_slots - 1)], slot)
    computed = need & (slot >= 0)
    into = jnp.where(computed, slot, r_slots)
    holder = holder.at[into].set(ids, mode="drop")
    goal = pool.goal.at[into].set(goals, mode="drop")
    stale = jnp.zeros(r_slots, bool).at[into].set(True, mode="drop")
    parked = jnp.full(h * w, -1, jnp.int32).at[pos[:, 0] * w + pos[:, 1]].set(
        jnp.where(_parked(pos, rovers.home, rovers.phase), ids, -1)).reshape(h, w)

    def passable(s):
        rover = holder[s]
        return ((owner < 0) | (owner == rover)) & ((parked < 0) | (parked == rover)) & ~blocked

    dist = motion.update_fields(pool.dist, goal, passable, pos[jnp.maximum(holder, 0)], stale, chunk=FIELD_CHUNK,
                                corner=corner_free(blocked), use_corner=jnp.any(blocked))
    rovers = rovers._replace(slot=slot, wait=jnp.where(computed, 0, rovers.wait))
    return rovers, motion.FieldPool(dist, goal, holder)


def _drop_unreachable(rovers: Rovers, pool: motion.FieldPool, owner):
    """Step 2's drops: ``(rovers, owner, dropped bool[N])``, the approaching rovers whose field says
    they cannot reach their start idle, their footprints and field slots released."""
    slot, pos = rovers.slot, rovers.pos
    here = pool.dist[jnp.maximum(slot, 0), pos[:, 0], pos[:, 1]]
    dropped = (rovers.phase == APPROACH) & (slot >= 0) & (here >= FAR)
    rovers = rovers._replace(phase=jnp.where(dropped, IDLE, rovers.phase), slot=jnp.where(dropped, -1, slot),
                             base=jnp.where(dropped[:, None], pos, rovers.base))
    return rovers, _release(owner, dropped), dropped


def _conflicts(before, after, moved, owner):
    """i32[]: pairs in one cell, swapping pairs, and rovers in another rover's footprint."""
    n = before.shape[0]
    pair = ~jnp.eye(n, dtype=bool)
    same = jnp.all(after[:, None] == after[None], -1) & pair
    swap = jnp.all(after[:, None] == before[None], -1) & jnp.all(before[:, None] == after[None], -1) & pair \
        & moved[:, None]
    held = owner[after[:, 0], after[:, 1]]
    foreign = (held >= 0) & (held != jnp.arange(n))
    return _i32(jnp.sum(same) // 2 + jnp.sum(swap) // 2 + jnp.sum(foreign))


def _move(rovers: Rovers, pool: motion.FieldPool, owner, blocked):
    """Step 3: ``(rovers, moved bool[N], ended bool[N], conflicts i32[])``: every rover moved at most
    one cell (``motion.move_rovers``); ``ended``: pushes that reached their path's last cell; a rover
    that reached its start pushes from the next step on; ``conflicts`` (``_conflicts``) of the move.
    A driving rover that did not move and is not at its goal counts one more step of waiting."""
    route, progress = rovers.route, rovers.progress
    goals = _goals(rovers)
    push_next = jax.vmap(lambda r, k: footprint.path_cell(r, k))(route, progress + 1)
    pos, moved = motion.move_rovers(rovers.pos, rovers.phase, goals, rovers.slot, pool.dist, owner, push_next,
                                    blocked, corner_free(blocked))
    waited = _drives(rovers) & ~moved & jnp.any(rovers.pos != goals, -1)
    rovers = rovers._replace(wait=jnp.where(waited, rovers.wait + 1, 0))
    conflicts = _conflicts(rovers.pos, pos, moved, owner)
    pushing = rovers.phase == PUSH
    progress = jnp.where(pushing & moved, progress + 1, progress)
    ended = pushing & (progress >= jax.vmap(footprint.path_length)(route) - 1)
    arrived = (rovers.phase == APPROACH) & jnp.all(pos == route.cells[:, 0], -1)
    rovers = rovers._replace(pos=pos, phase=jnp.where(arrived, PUSH, rovers.phase),
                             progress=jnp.where(arrived, 0, progress))
    return rovers, moved, ended, conflicts


def _apply_pushes(scene, rovers: Rovers, owner, ended, spill, evaluator, short_cap: int):
    """Step 4: the ``ended`` pushes applied in rover order, on the counts at that moment, their
    footprints released and their rovers idle: ``(scene, rovers, owner, (collected, delivered,
    spilled))``, f32[N] objects each (0 for the other rovers). The fabric is left as it is.
    short_cap: static, ``FleetConfig.short_cap`` (``_push_fitted``)."""
    n = ended.shape[0]
    zeros = jnp.zeros(n, jnp.float32)
    # the loop visits the rovers whose push ended only, in rover order
    order = jnp.nonzero(ended, size=n, fill_value=0)[0]

    def one(i, carry):
        obj, collected, delivered, spilled = carry
        r = order[i]
        mine = jax.tree.map(lambda a: a[r], rovers.route)
        new_obj, got = _push_fitted(scene.with_obj(obj), mine, spill, evaluator, short_cap)
        return (new_obj, collected.at[r].set(got[0]), delivered.at[r].set(got[1]), spilled.at[r].set(got[2]))

    obj, *applied = jax.lax.fori_loop(0, jnp.sum(ended, dtype=jnp.int32), one, (scene.obj, zeros, zeros, zeros))
    rovers = rovers._replace(phase=jnp.where(ended, IDLE, rovers.phase), pushes=rovers.pushes + ended,
                             base=jnp.where(ended[:, None], rovers.pos, rovers.base))
    return scene.with_obj(obj), rovers, _release(owner, ended), tuple(applied)


def _push_fitted(scene, route: Route, spill, evaluator, short_cap: int):
    """``(obj, (collected, delivered, spilled))`` of ``execute_push``: on the route's first 2 (short_cap
    + 1) rows when its cells end before them, the same push at a route's size rather than the walk
    cap's (the rows after ``n_cells`` are padding), else on all its rows."""
    rows = 2 * (short_cap + 1)

    def push(cells):
        obj, result = execute_push(scene, route._replace(cells=cells), spill, evaluator)
        return obj, (result.collected, result.delivered, result.spilled)

    if rows >= route.cells.shape[0]:
        return push(route.cells)
    return jax.lax.cond(route.n_cells < rows, lambda: push(route.cells[:rows]), lambda: push(route.cells))


def _stop(totals: Totals, scene, phase, parked, made_way, assigned, dropped, moved, ended, applied, failure,
          stall_steps: int) -> Totals:
    """Step 5: the totals after the step and its stop code (module docstring, first that holds).
    phase: i32[N] after the step; parked: bool[N] idle on the home cell after the step; made_way,
    assigned, dropped, moved, ended: bool[N] what it did; applied:
    ``(collected, delivered, spilled)`` f32[N] of its pushes; failure: i32[] the assignment's."""
    t = totals.t + 1
    outside = _f32(outside_mass(scene))
    started = totals.started + jnp.sum(assigned) - jnp.sum(dropped)
    has_task = jnp.any(phase != IDLE)
    homing = jnp.any(~parked & (phase == IDLE)) | jnp.any(made_way)
    progressed = jnp.any(moved) | jnp.any(ended)
    stall = jnp.where(progressed, 0, jnp.where(has_task | jnp.any(dropped) | homing, totals.stall + 1, totals.stall))
    # all idle and nothing assigned: the next step is this one again, unless rovers are driving home
    # out of the way of the tasks their cells blocked (a rover that cannot get home stalls)
    stuck = ~has_task & ~jnp.any(assigned) & (failure != RUNNING) & ((failure != NO_REACHABLE) | ~homing)
    stop = _i32(jnp.select(
        [outside <= totals.stop_at, ~has_task & (started >= totals.max_pushes), stuck, stall >= stall_steps,
         t >= totals.max_steps],
        [DONE, BUDGET, failure, jnp.where(has_task, DEADLOCK, NO_REACHABLE), MAX_STEPS], RUNNING))
    _, delivered, spilled = applied
    return totals._replace(t=t, stall=_i32(stall), started=started, delivered=totals.delivered + jnp.sum(delivered),
                           spilled=totals.spilled + jnp.sum(spilled), outside=outside, done=stop != RUNNING,
                           stop=stop)


def _expire(fresh, assigned, dropped, ended):
    """bool[]: whether the cached candidates are still fresh after the step: not once a task started or
    was dropped or a push ended. A task depends on the fabric and its source only: the next planning
    keeps the cached ones (``plan_candidates``'s previous); when a push ended, the refresh keeps those
    whose plans read nothing it changed (``keep_tasks``)."""
    return fresh & ~(jnp.any(assigned) | jnp.any(dropped) | jnp.any(ended))


def unchanged_tasks(state: FleetState, params: FabricParams, old: Fabric, before):
    """bool[M]: which cached tasks a refresh of the state's fabric from ``old`` (built for the counts
    ``before``: f32[H, W]) to ``state.fabric`` left as planning them again would give
    (``assign.unchanged_tasks``). Pure and jittable."""
    changes = fabric_changes(before, state.scene.obj, old, state.fabric)
    return assign.unchanged_tasks(state.candidates, state.scene, params, old, state.fabric, changes)


def keep_tasks(state: FleetState, params: FabricParams, old: Fabric, before) -> FleetState:
    """The state after its fabric was refreshed from ``old`` (built for the counts ``before``) to
    ``state.fabric``, with only the cached tasks the refresh left unchanged (``unchanged_tasks``), so
    that the next planning plans just the others' sources again. Pure and jittable."""
    if state.candidates.exists.shape[0] == 0:
        return state
    return state._replace(candidates=assign.keep_only(state.candidates, unchanged_tasks(state, params, old, before)))


def fleet_rebuild(rebuild: str) -> str:
    """The fleet's fabric refresh for ``EpisodeParams.rebuild``: "selective" or "full" as asked;
    "auto" is "full". Inside the fleet's one compiled step the selective update is traced with every
    dirty-buffer size behind a ``lax.switch``: on ``site128`` with 4 rovers it compiles in minutes
    against half a minute for the whole step with the full build, more than it saves in a run
    (``experiments/fleet_rebuild.py``)."""
    return "selective" if rebuild == "selective" else "full"


def _refresh(scene, params, fabric, before, rebuild: str):
    """Step 4's rebuild of the shared fabric for ``scene``'s counts (``before``: f32[H, W] the counts
    it was built for). rebuild (static): "selective" updates the cells the pushes changed (the same
    fabric as a full build, ``transport.rebuild``), "full" builds it anew."""
    if rebuild == "selective":
        changed = (scene.obj != before) & ~scene.target_mask
        return selective_rebuild(scene, params, fabric, changed)[0]
    return build_fabric(scene, params)


def _live(state: FleetState, params, spill, ep: EpisodeParams, cfg: FleetConfig, evaluator):
    before = state.scene.obj
    state, record = _advance(state, params, spill, ep, cfg, evaluator)
    return refresh(state, params, ep, before), record


def refresh(state: FleetState, params: FabricParams, episode: EpisodeParams, before) -> FleetState:
    """The shared fabric brought up to the state's counts after ``advance``: rebuilt when the counts
    differ from ``before`` (f32[H, W], the counts it was built for), by ``fleet_rebuild(episode.rebuild)``
    (the same fabric either way), and the cached tasks it did not change kept (``keep_tasks``). Pure
    and jittable."""
    def rebuilt(state):
        fabric = _refresh(state.scene, params, state.fabric, before, fleet_rebuild(episode.rebuild))
        return keep_tasks(state._replace(fabric=fabric), params, state.fabric, before)

    return jax.lax.cond(jnp.any(state.scene.obj != before), rebuilt, lambda s: s, state)


def advance(state: FleetState, params: FabricParams, spill: SpillParams, episode: EpisodeParams,
            config: FleetConfig, evaluator: Evaluator | None = None):
    """A live state's step without the fabric's refresh: ``(state, FleetRecord)``, whose fabric is still
    that of the counts before the step. ``step`` is ``advance`` then ``refresh``; a host driver may
    refresh on its own (``run_fleet`` times the two apart), and then keeps only the cached tasks the
    new fabric left unchanged (``keep_tasks``, or ``unchanged_tasks`` and ``assign.keep_only``).
    Pure and jittable; config and evaluator
    static (None: the model ``spill`` is for, ``evaluator_for(spill)``). The state must not be done."""
    _check_static(params, episode, config, "advance")
    evaluator = evaluator_for(spill) if evaluator is None else evaluator
    return _advance(state, params, spill, episode, config.resolved(state.scene.shape), evaluator)


def _advance(state: FleetState, params, spill, ep: EpisodeParams, cfg: FleetConfig, evaluator):
    blocked = state.scene.blocked
    # 1. assign
    route, mode, assigned, owner, failure, candidates, aside, attempts, fresh, planned = _assign(
        state, params, spill, ep, cfg, evaluator)
    rovers = _take_tasks(state.rovers, assigned, route, mode, state.totals.t + 1)
    if cfg.strategy == "coordinated":
        rovers, made_way = _make_way(state, rovers, candidates, owner, assigned)
    else:
        made_way = jnp.zeros(assigned.shape, bool)
    # 2. distance fields, unreachable starts dropped
    rovers, fields = _fields(rovers, state.fields, owner, blocked)
    rovers, owner, dropped = _drop_unreachable(rovers, fields, owner)
    rovers = rovers._replace(idle_steps=rovers.idle_steps + (rovers.phase == IDLE))
    # 3. move
    rovers, moved, ended, conflicts = _move(rovers, fields, owner, blocked)
    # 4. apply the pushes that ended, release their footprints (the fabric is refreshed by ``refresh``)
    scene, rovers, owner, applied = _apply_pushes(state.scene, rovers, owner, ended, spill, evaluator,
                                                  cfg.short_cap)
    # 5. totals and stop
    totals = _stop(state.totals, scene, rovers.phase, _parked(rovers.pos, rovers.home, rovers.phase), made_way,
                   assigned, dropped, moved, ended, applied, failure, cfg.stall_steps)
    # what the step outdated for the next: the cached candidates
    fresh = _expire(fresh, assigned, dropped, ended)
    new = state._replace(scene=scene, rovers=rovers, fields=fields, owner=owner, candidates=candidates,
                         aside=aside, attempts=attempts, fresh=fresh, totals=totals)
    collected, delivered, spilled = applied
    record = FleetRecord(pos=rovers.pos, phase=rovers.phase, assigned=assigned, dropped=dropped, ended=ended,
                         collected=collected, delivered=delivered, spilled=spilled, delivered_total=totals.delivered,
                         outside=totals.outside, inside=_f32(jnp.sum(jnp.where(scene.target_mask, scene.obj, 0.0))),
                         mass=_f32(jnp.sum(scene.obj)), made_way=made_way, planned=_i32(planned),
                         conflicts=conflicts, failure=_i32(failure),
                         stop=totals.stop, valid=jnp.bool_(True))
    return new, record


def step(state: FleetState, params: FabricParams, spill: SpillParams, episode: EpisodeParams,
         config: FleetConfig, evaluator: Evaluator | None = None):
    """One step of the fleet (module docstring): ``(state, FleetRecord)``. Pure, one jittable program;
    config and evaluator are static (evaluator None: ``evaluator_for(spill)``). A done state is
    returned as it is, with an invalid record. The push budget is ``state.totals.max_pushes``
    (``episode.max_pushes`` is not read); ``episode.rebuild`` picks the fabric's refresh (step 4)."""
    _check_static(params, episode, config, "step")
    evaluator = evaluator_for(spill) if evaluator is None else evaluator
    cfg = config.resolved(state.scene.shape)
    return jax.lax.cond(state.totals.done, lambda s: (s, _idle_record(s)),
                        lambda s: _live(s, params, spill, episode, cfg, evaluator), state)


def rollout(state: FleetState, params: FabricParams, spill: SpillParams, episode: EpisodeParams,
            config: FleetConfig, n_steps: int, evaluator: Evaluator | None = None):
    """``n_steps`` (static) steps in one ``lax.scan``: ``(state, FleetRecord stacked over n_steps)``."""
    return jax.lax.scan(lambda s, _: step(s, params, spill, episode, config, evaluator), state, None,
                        length=n_steps)
