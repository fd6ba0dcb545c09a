"""``run_fleet``: the host driver. The jitted ``advance`` in a Python loop, the shared fabric refreshed
on the host after it (``rebuild_mode``: the selective update, its buffers sized on the host, on large
CPU grids; the same fabric as ``step``'s), with what needs the host: validation, timing (the step,
its planning and the refresh apart), the pushes' list, the serial invariant check, frames, a progress
bar."""
from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.core import available_memory_bytes, check_interrupt, grid_jit
from jaxplan.fleet import footprint
from jaxplan.fleet.assign import keep_only
from jaxplan.fleet.conflicts import conflicts
from jaxplan.fleet.motion import IDLE
from jaxplan.fleet.state import (
    STOP_REASONS,
    FleetConfig,
    advance,
    estimate_fleet_bytes,
    reset,
    rover_bytes,
    unchanged_tasks,
)
from jaxplan.transport import (
    EpisodeParams,
    FabricParams,
    Scene,
    build_fabric,
    estimate_build_bytes,
    rebuild_mode,
    require_hard,
    selective_rebuild,
    validate_episode_params,
    validate_params,
)
from jaxplan.transport.spillage import Evaluator, SpillParams, evaluator_for, validate_spill_params

__all__ = ["DEFAULT_MAX_PUSHES", "DEFAULT_MAX_STEPS", "MAX_STEPS_LIMIT", "FleetRun", "check_fleet_memory",
           "run_fleet", "validate_fleet_inputs"]

MAX_STEPS_LIMIT = 1 << 30
DEFAULT_MAX_STEPS = 5_000
"""``run_fleet``'s step limit, and ``jaxplan fleet --max-steps``'s default."""
DEFAULT_MAX_PUSHES = 100_000
"""``run_fleet``'s push budget (``EpisodeParams.max_pushes``) when no episode is given, and ``jaxplan
fleet --max-pushes``'s default: a site runs until done rather than until a budget."""
MODES = ("deliver", "rearrange")


@dataclasses.dataclass
class FleetRun:
    """A finished fleet run. T steps, N rovers; arrays indexed by step hold the state after it (0 = start).

    scene: the initial Scene (counts quantized); final_scene: the counts at the end.
    pos: i32[T+1, N, 2] (row, col) of every rover. delivered: f64[T+1] mass inside the targets
    (objects); outside: f64[T+1] mass outside them. initial_mass, initial_outside: floats.
    pushes: one dict per applied push, in order of application: rover, first_step (the step its task
    was assigned), last_step (the step it was applied), cells [[r, c], ...] (the route), collected,
    delivered, spilled (objects), mode ("deliver" / "rearrange").
    rover_pushes: i32[N]; idle_steps: i32[N] steps each rover had no task.
    step_ms, plan_ms, refresh_ms: wall ms of every step: the whole step, everything but the shared
    fabric's refresh (assignment, distance fields, motion, the pushes applied), and the refresh (0
    where no push ended). full_build_ms: one warm full build of the initial fabric, ms, in the same
    process (``build_fabric``; None when the fleet was done at its start). conflicts: invariant
    violations the serial checker
    (``jaxplan.fleet.conflicts``) found in ``pos`` and the reserved footprints (must be 0).
    stop_reason: one of ``STOP_REASONS``; message: a sentence for people.
    frames: with ``record=True``, T+1 dicts (0 = start) {"obj": f32[H, W], "heat": f32[H, W],
    "highways": bool[H, W], "routes": N entries, i32[k, 2] cells of the rover's task or None}.
    kernel_conflicts: the step's own count of the same violations (``FleetRecord.conflicts``), summed.
    dropped: tasks dropped because their start could not be reached. made_way: times a parked rover
    was sent to a new home, out of a task's footprint (coordinated; ``jaxplan.fleet.make_way``).
    scene_name: the name of the scene the run was given (``scene`` is the compiled step's copy, which
    carries no name); None when it had none. summary.json's ``scene`` (``report.summary_of``).
    tasks_planned: i32 per step, the tasks the coordinated assignment planned (``FleetRecord.planned``).
    """

    scene: Scene
    final_scene: Scene
    n_rovers: int
    strategy: str
    steps: int
    pos: np.ndarray
    delivered: np.ndarray
    outside: np.ndarray
    initial_mass: float
    initial_outside: float
    pushes: list
    rover_pushes: np.ndarray
    idle_steps: np.ndarray
    plan_ms: list
    conflicts: int
    stop_reason: str
    message: str
    frames: list | None = None
    kernel_conflicts: int = 0
    dropped: int = 0
    made_way: int = 0
    scene_name: str | None = None
    step_ms: list = dataclasses.field(default_factory=list)
    refresh_ms: list = dataclasses.field(default_factory=list)
    full_build_ms: float | None = None
    tasks_planned: list = dataclasses.field(default_factory=list)


def validate_fleet_inputs(scene, n_rovers, strategy, params, spill, episode, max_steps, starts,
                          config: FleetConfig | None = None) -> None:
    """Raise for bad inputs of ``run_fleet``, before any work: ``TypeError`` naming ``scene`` when it is
    not a Scene; ``ValueError`` naming the argument or field otherwise: the scene's leaves (shapes,
    NaN / infinite / negative counts, as ``run_episode``), the fleet's settings, the parameters, the
    start cells, and the memory the run needs (``check_fleet_memory``)."""
    Scene.check(scene, "scene")
    FleetConfig(n_rovers, strategy).validate()
    config = _matching_config(config, n_rovers, strategy)
    validate_params(params)
    require_hard(params, "run_fleet")
    validate_spill_params(spill)
    validate_episode_params(episode)
    if episode.reselect:
        raise ValueError("EpisodeParams.reselect: True is not supported by the fleet, which plans on the "
                         "entry-0 fabric; use reselect=False.")
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or \
            not 1 <= max_steps <= MAX_STEPS_LIMIT:
        raise ValueError(f"max_steps: {max_steps!r} is out of range; it must be an int in [1, {MAX_STEPS_LIMIT}].")
    target = np.asarray(scene.target_mask)
    no_start = target | ~np.isfinite(np.asarray(scene.dist))
    free = int(no_start.size - no_start.sum())
    if free < n_rovers:
        raise ValueError(f"n_rovers: {n_rovers} rovers need as many free cells outside the targets (not blocked, "
                         f"not cut off from every target); the scene has {free}. Use at most {free} rovers.")
    if starts is not None:
        _check_starts(starts, n_rovers, target, np.asarray(scene.blocked), np.asarray(scene.cut_off))
    check_fleet_memory(scene.shape, config, params)


def _matching_config(config: FleetConfig | None, n_rovers: int, strategy: str) -> FleetConfig:
    """``config`` (default ``FleetConfig(n_rovers, strategy)``), validated and matching the arguments."""
    if config is None:
        return FleetConfig(n_rovers, strategy)
    if not isinstance(config, FleetConfig):
        raise TypeError(f"config: expected a FleetConfig or None, got {type(config).__name__}.")
    config.validate()
    if (config.n_rovers, config.strategy) != (n_rovers, strategy):
        raise ValueError(f"config: its n_rovers and strategy ({config.n_rovers}, {config.strategy!r}) differ from "
                         f"the arguments ({n_rovers}, {strategy!r}); pass the same.")
    return config


def _check_starts(starts, n_rovers: int, target: np.ndarray, blocked: np.ndarray, cut_off: np.ndarray) -> None:
    """ValueError naming ``starts`` unless it holds ``n_rovers`` distinct (row, col) cells of the grid
    outside the targets (``target: bool[H, W]``), none blocked or cut off from every target."""
    cells = np.asarray(starts)
    h, w = target.shape
    if cells.shape != (n_rovers, 2) or not np.issubdtype(cells.dtype, np.integer):
        raise ValueError(f"starts: expected {n_rovers} (row, col) integer pairs, shape ({n_rovers}, 2); "
                         f"got shape {cells.shape} of {cells.dtype}.")
    if np.any(cells < 0) or np.any(cells[:, 0] >= h) or np.any(cells[:, 1] >= w):
        raise ValueError(f"starts: every cell must lie in the {h} x {w} grid (rows 0..{h - 1}, "
                         f"cols 0..{w - 1}); got {cells.tolist()}.")
    if len({tuple(c) for c in cells.tolist()}) != n_rovers:
        raise ValueError(f"starts: two rovers start on one cell; give {n_rovers} distinct cells.")
    if np.any(target[cells[:, 0], cells[:, 1]]):
        raise ValueError("starts: a rover starts inside a target; start every rover outside the targets.")
    for bad, what in ((blocked, "on a blocked cell"), (cut_off, "on a cell cut off from every target")):
        hit = bad[cells[:, 0], cells[:, 1]]
        if np.any(hit):
            r, c = cells[np.argmax(hit)]
            raise ValueError(f"starts: rover {int(np.argmax(hit))} starts {what} (row {r}, col {c}); start it on a "
                             "free cell a target can be reached from.")


def _gb(n: int) -> str:
    return f"{n / 1e9:.1f} GB" if n >= 1e9 else f"{n / 1e6:.0f} MB"


def check_fleet_memory(shape, config: FleetConfig, params: FabricParams | None = None,
                       available: int | None = None) -> int:
    """Refuse a fleet whose ``state.estimate_fleet_bytes(shape, config, params)`` exceeds ``available``
    bytes (default ``jaxplan.core.available_memory_bytes()``; no check when that is unknown). The
    ``ValueError`` names the bytes needed and available and the argument to change: ``n_rovers`` with
    the most rovers that fit; else ``strategy`` when an independent fleet fits (the coordinated one
    plans eight candidates at once); else ``scene`` (the grid is too large). Returns the estimate."""
    need = estimate_fleet_bytes(shape, config, params)
    room = available_memory_bytes() if available is None else int(available)
    if room is None or need <= room:
        return need
    h, w = (int(v) for v in shape)
    name, fix = _memory_fix(shape, config, params, room)
    raise ValueError(f"{name}: a fleet of {config.n_rovers} rovers on a {h}x{w} grid needs about {_gb(need)} "
                     f"(the shared fabric {_gb(estimate_build_bytes(shape, params))}, the rovers' distance fields, "
                     f"footprint masks, planned candidates and routes {_gb(rover_bytes(shape, config, params))}; "
                     f"jaxplan.fleet.state.estimate_fleet_bytes), more than the {_gb(room)} of memory available; "
                     f"{fix}.")


def _memory_fix(shape, config: FleetConfig, params, room: int) -> tuple[str, str]:
    """``(argument, advice)`` for a fleet that does not fit in ``room`` bytes, in the fleet's own
    settings (``--rovers``, ``--strategy``, the scene)."""
    def need(**changes) -> int:
        return estimate_fleet_bytes(shape, dataclasses.replace(config, **changes), params)

    scene_fix = "a smaller scene, or a coarser one (a larger cell size: fewer cells)"
    fits = max((n for n in range(1, config.n_rovers) if need(n_rovers=n) <= room), default=None)
    if fits is not None:
        return "n_rovers", (f"use at most {fits} rovers (--rovers {fits}, about {_gb(need(n_rovers=fits))}), "
                            f"or {scene_fix}")
    if config.strategy == "coordinated" and need(strategy="independent") <= room:
        return "strategy", (f"the independent strategy (--strategy independent) needs about "
                            f"{_gb(need(strategy='independent'))}; or use {scene_fix}")
    return "scene", f"use {scene_fix}, or free memory; the fabric and every rover's grids grow with H x W"


_reset_jit = grid_jit(reset, static_argnames=("config",))
def _advance_keeping_counts(state, params, spill, episode, config, evaluator):
    """``(state, record, before)``: ``advance``, and the counts the step started from (the fabric's)."""
    return (*advance(state, params, spill, episode, config, evaluator), state.scene.obj)


# the state is donated: its unchanged leaves (the fabric, the fields, the cached candidates) are not
# copied each step, which cost more than the step's own work with many rovers
_advance_jit = grid_jit(_advance_keeping_counts, static_argnames=("config", "evaluator"), donate_argnums=0)


def _refresh_fabric(state, params: FabricParams, rebuild: str, before):
    """The state with its fabric brought up to its counts (``before``: the counts it was built for), on
    the host: ``transport.selective_rebuild`` (its buffers sized on the host, the fastest on large
    CPU grids) or a full build, as ``rebuild_mode`` picks; the same fabric either way."""
    if rebuild == "selective":
        changed = (state.scene.obj != before) & ~state.scene.target_mask
        fabric = selective_rebuild(state.scene, params, state.fabric, changed)[0]
    else:
        fabric = build_fabric(state.scene, params)
    return state._replace(fabric=jax.block_until_ready(fabric))


# only the mask is computed jitted: a jitted keep_tasks would return (and so copy) the whole state
_unchanged_tasks_jit = grid_jit(unchanged_tasks)


def _warm_build_ms(scene, params: FabricParams, repeats: int = 7) -> float:
    """Median wall ms of a full build of ``scene``'s fabric, compiled first."""
    jax.block_until_ready(build_fabric(scene, params))
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(build_fabric(scene, params))
        runs.append(1e3 * (time.perf_counter() - start))
    return float(np.median(runs))


def _footprint(scene, route, spill, clearance: int):
    return footprint.footprint_mask(scene, route, footprint.route_samples(scene, route, spill), clearance)


_footprint_jit = grid_jit(_footprint, static_argnums=3)


def _message(reason: str, state, episode: EpisodeParams, max_steps: int) -> str:
    outside, initial = float(state.totals.outside), float(state.totals.initial_outside)
    return {
        "done": f"{outside:.3g} objects left outside the targets (<= {float(episode.stop_fraction):.3g} of "
                f"{initial:.3g}) or no source left",
        "budget": f"push budget of {episode.max_pushes} spent",
        "no_material": "the scene has no material outside the targets: nothing to push",
        "no_route": "the best source has no complete route to a target (raise FabricParams.max_hops or use "
                    "monotone=True)",
        "walk_cap": "a route is longer than the fleet's walk cap (FleetConfig.walk_cap)",
        "max_steps": f"the step limit of {max_steps} was reached",
        "deadlock": "no rover moved or pushed for FleetConfig.stall_steps steps while tasks were assigned",
        "no_reachable_task": "every pushable task's footprint held another rover, or its start could not be reached",
    }.get(reason, reason)


def _frame(state, shown) -> dict:
    cells = np.asarray(state.rovers.route.cells)
    n_cells = np.asarray(state.rovers.route.n_cells)
    return dict(obj=np.asarray(state.scene.obj), heat=np.asarray(state.fabric.heat),
                highways=np.asarray(state.fabric.highways),
                routes=[cells[r, :n_cells[r]].copy() if shown[r] else None for r in range(len(shown))])


def run_fleet(scene, n_rovers: int, strategy: str = "coordinated", params: FabricParams | None = None,
              spill: SpillParams | None = None, episode: EpisodeParams | None = None,
              max_steps: int = DEFAULT_MAX_STEPS, *, starts=None, record: bool = False, progress: bool = False,
              config: FleetConfig | None = None,
              evaluator: Evaluator | None = None) -> FleetRun:
    """Run a fleet of ``n_rovers`` on ``scene`` with ``strategy`` until it stops (``state`` module
    docstring) or ``max_steps`` steps. Returns ``FleetRun``.

    starts: optional i32[N, 2] distinct start cells outside the targets. record: keep per-step frames.
    progress: a progress bar on stderr. config: a ``FleetConfig`` for the other static settings
    (its n_rovers and strategy must match). evaluator: the spill model's (default: the one ``spill`` is
    for, ``evaluator_for(spill)``). All inputs are checked before any work.
    """
    params = FabricParams() if params is None else params
    spill = SpillParams() if spill is None else spill
    evaluator = evaluator_for(spill) if evaluator is None else evaluator
    episode = EpisodeParams(max_pushes=DEFAULT_MAX_PUSHES) if episode is None else episode
    validate_fleet_inputs(scene, n_rovers, strategy, params, spill, episode, max_steps, starts, config)
    if params.temperature is not None:    # a concrete 0 is the hard fabric
        params = params.replace(temperature=None)
    config = (FleetConfig(n_rovers, strategy) if config is None else config).resolved(scene.shape)

    # the compiled programs depend on neither the budget (reset copies it into the state) nor the rebuild
    # mode (the host refreshes the fabric): runs that differ only in these static fields share them
    planning = episode.replace(max_pushes=0, rebuild="auto")
    state = _reset_jit(scene, params, spill, planning, config=config, starts=starts, max_steps=int(max_steps),
                       max_pushes=int(episode.max_pushes))
    # not the whole start state (its fabric and fields would stay alive), and a copy: the steps donate theirs
    initial_scene = jax.tree.map(jnp.copy, state.scene)
    first = jax.device_get(state)
    target = np.asarray(first.scene.target_mask)
    positions = [np.asarray(first.rovers.pos)]
    inside = [float(np.asarray(first.scene.obj)[target].sum())]
    outside = [float(first.totals.outside)]
    frames = [_frame(first, np.zeros(n_rovers, bool))] if record else None
    initial_mass, initial_outside = float(first.totals.initial_mass), float(first.totals.initial_outside)
    done_at_start = bool(first.totals.done)
    del first                        # the host copy of the start state (fabric, distance fields)
    plan_ms, refresh_ms, step_ms, tasks_planned, pushes, reservations = [], [], [], [], [], []
    open_tasks: dict[int, dict] = {}
    kernel_conflicts = dropped = made_way = 0
    kernel = config.kernel()
    rebuild = rebuild_mode(episode.rebuild, scene.shape)
    run_step = lambda s: _advance_jit(s, params, spill, planning, kernel, evaluator)  # noqa: E731
    full_build_ms = None
    if not done_at_start:
        jax.block_until_ready(run_step(jax.tree.map(jnp.copy, state)))     # compile outside the timed steps
        full_build_ms = _warm_build_ms(initial_scene, params)
    from tqdm.auto import tqdm

    bar = tqdm(total=int(max_steps), desc=f"fleet {strategy} x{n_rovers}", unit="step", leave=False,
               disable=not progress)
    try:
        while not bool(state.totals.done):
            check_interrupt()
            start = time.perf_counter()
            state, rec, before = run_step(state)
            rec = jax.device_get(rec)
            planned = refreshed = time.perf_counter()
            if np.asarray(rec.ended).any():
                old = state.fabric
                state = _refresh_fabric(state, params, rebuild, before)
                refreshed = time.perf_counter()
                if config.strategy == "coordinated":
                    kept = _unchanged_tasks_jit(state, params, old, before)
                    state = state._replace(candidates=jax.block_until_ready(keep_only(state.candidates, kept)))
                del old
            end = time.perf_counter()
            # keeping the cached tasks is planning work: only the rebuild counts as the refresh
            plan_ms.append(1e3 * ((planned - start) + (end - refreshed)))
            refresh_ms.append(1e3 * (refreshed - planned))
            step_ms.append(1e3 * (end - start))
            t = len(positions)
            positions.append(np.asarray(rec.pos))
            inside.append(float(rec.inside))
            outside.append(float(rec.outside))
            kernel_conflicts += int(rec.conflicts)
            made_way += int(np.asarray(rec.made_way).sum())
            tasks_planned.append(int(rec.planned))
            assigned, ended, gone = np.asarray(rec.assigned), np.asarray(rec.ended), np.asarray(rec.dropped)
            if assigned.any():
                routes = jax.device_get(state.rovers.route)
                modes = np.asarray(state.rovers.mode)
                for r in np.flatnonzero(assigned):
                    one = jax.tree.map(lambda a, r=r: a[r], routes)
                    cells = np.asarray(one.cells)[: int(one.n_cells)]
                    mask = np.asarray(_footprint_jit(initial_scene, one, spill, config.clearance))
                    open_tasks[int(r)] = dict(rover=int(r), first_step=t, cells=cells.tolist(),
                                              mode=MODES[int(modes[r])], footprint=np.argwhere(mask))
            for r in np.flatnonzero(gone):
                task = open_tasks.pop(int(r))
                reservations.append((int(r), task["first_step"], t - 1, task["footprint"]))
                dropped += 1
            for r in np.flatnonzero(ended):
                task = open_tasks.pop(int(r))
                reservations.append((int(r), task["first_step"], t, task["footprint"]))
                pushes.append(dict(rover=int(r), first_step=task["first_step"], last_step=t, cells=task["cells"],
                                   collected=float(rec.collected[r]), delivered=float(rec.delivered[r]),
                                   spilled=float(rec.spilled[r]), mode=task["mode"]))
            if record:
                frames.append(_frame(jax.device_get(state), (np.asarray(rec.phase) != IDLE) | ended))
            bar.update(1)
            if inside[0] + outside[0] > 0:
                bar.set_postfix(outside=f"{outside[-1] / max(outside[0], 1e-9):.0%}", refresh=False)
    finally:
        bar.close()
    for r, task in open_tasks.items():          # tasks still running when the fleet stopped
        reservations.append((r, task["first_step"], len(positions) - 1, task["footprint"]))
    final = jax.device_get(state)
    pos = np.asarray(positions, np.int32)
    reason = STOP_REASONS[int(final.totals.stop)]
    return FleetRun(
        scene=initial_scene, final_scene=state.scene, n_rovers=n_rovers, strategy=strategy, steps=len(positions) - 1,
        pos=pos, delivered=np.asarray(inside, np.float64), outside=np.asarray(outside, np.float64),
        initial_mass=initial_mass, initial_outside=initial_outside, pushes=pushes,
        rover_pushes=np.asarray(final.rovers.pushes, np.int32),
        idle_steps=np.asarray(final.rovers.idle_steps, np.int32),
        plan_ms=plan_ms, conflicts=len(conflicts(pos, reservations)), stop_reason=reason,
        message=_message(reason, final, episode, int(max_steps)), frames=frames,
        kernel_conflicts=kernel_conflicts, dropped=dropped, made_way=made_way, scene_name=getattr(scene, "name", None),
        step_ms=step_ms, refresh_ms=refresh_ms, full_build_ms=full_build_ms,
        tasks_planned=tasks_planned)

