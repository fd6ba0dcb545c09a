"""``run_episode``: the host driver of one aggregate-transport job, and its result ``Episode``.

The jitted pieces of ``episode.step`` (``plan``, ``execute``, ``episode.advance``) in a Python loop,
with what needs the host: validation, timing, the selective rebuild (its buffer size is chosen by a
host read), frames for animations, a progress bar, and a second walk with room for any simple path
when a route is longer than ``episode.default_walk_cap``.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import numpy as np

from jaxplan.core import check_interrupt, grid_jit, timed
from jaxplan.transport import execute, rebuild, spillage
from jaxplan.transport.episode import (
    CLEARED,
    DONE,
    NO_MATERIAL,
    NO_ROUTE,
    RUNNING,
    STOP_REASONS,
    WALK_CAP,
    EpisodeParams,
    EpisodeState,
    advance_jit,
    default_walk_cap,
    plan_code,
    rebuild_mode,
    require_hard,
    reset,
    validate_episode_params,
)
from jaxplan.transport.fabric import Fabric, build_fabric, check_fabric_inputs
from jaxplan.transport.params import FabricParams, validate_params
from jaxplan.transport.plan import Plan, plan_episode_tick

_rebuild_full_jit = grid_jit(lambda scene, params: build_fabric(scene, params))


@dataclasses.dataclass
class Episode:
    """A finished episode. T = number of pushes; per-tick arrays hold the state after each push.

    delivered, spilled: f64[T] cumulative objects delivered to / spilled by pushes so far.
    remaining: f64[T] objects outside the target after the push.  pushes: i32[T] = 1..T.
    collected, push_delivered, push_spilled: f64[T] per push.  mode: i32[T] (0 deliver, 1 rearrange).
    source: i32[T, 2].  route_length: f64[T] world units pushed.  driven: f64[T] cumulative world
    units driven (the approach from the previous route's end, plus the pushed route).
    plan_ms, rebuild_ms, execute_ms: f64[T] wall clock per tick.  dirty: i32[T] cells whose tables
    the rebuild recomputed; full_rebuild: bool[T] the rebuild fell back to a full build.
    initial_mass: total objects; initial_remaining: objects outside the target at the start.
    stop_reason: "done" | "budget" | "no_material" | "no_route"; message: a sentence for people.
    final_obj: f32[H, W] counts at the end.  frames: per-tick snapshots when ``record=True``.
    rebuild: the rebuild the ticks ran, "selective" or "full" (``rebuild_mode`` of EpisodeParams.rebuild).
    unreachable_mass: objects on cells cut off from every target by blocked cells (never planned).
    """

    delivered: np.ndarray
    spilled: np.ndarray
    remaining: np.ndarray
    pushes: np.ndarray
    collected: np.ndarray
    push_delivered: np.ndarray
    push_spilled: np.ndarray
    mode: np.ndarray
    source: np.ndarray
    route_length: np.ndarray
    driven: np.ndarray
    plan_ms: np.ndarray
    rebuild_ms: np.ndarray
    execute_ms: np.ndarray
    dirty: np.ndarray
    full_rebuild: np.ndarray
    initial_mass: float
    initial_remaining: float
    stop_reason: str
    message: str
    final_obj: np.ndarray
    frames: list = dataclasses.field(default_factory=list)
    rebuild: str = "selective"
    unreachable_mass: float = 0.0

    @property
    def n_pushes(self) -> int:
        return int(len(self.pushes))

    def totals(self) -> dict:
        """The summary numbers: initial mass and the final delivered, spilled and remaining mass."""
        last = lambda a, default: float(a[-1]) if len(a) else default  # noqa: E731
        return dict(initial_mass=self.initial_mass, initial_remaining=self.initial_remaining,
                    delivered=last(self.delivered, 0.0), spilled=last(self.spilled, 0.0),
                    remaining=last(self.remaining, self.initial_remaining), pushes=self.n_pushes,
                    rearrange_pushes=int(np.sum(self.mode)), driven=last(self.driven, 0.0),
                    stop_reason=self.stop_reason, message=self.message, rebuild=self.rebuild,
                    unreachable_mass=self.unreachable_mass,
                    median_plan_ms=float(np.median(self.plan_ms)) if len(self.plan_ms) else None,
                    median_rebuild_ms=float(np.median(self.rebuild_ms)) if len(self.rebuild_ms) else None)

    def per_tick(self) -> dict:
        """Per-tick metrics as lists (JSON/CSV friendly)."""
        cols = ("pushes", "delivered", "spilled", "remaining", "collected", "push_delivered", "push_spilled",
                "mode", "route_length", "driven", "plan_ms", "rebuild_ms", "execute_ms", "dirty", "full_rebuild")
        out = {c: np.asarray(getattr(self, c)).tolist() for c in cols}
        out["source_row"] = np.asarray(self.source)[:, 0].tolist() if len(self.source) else []
        out["source_col"] = np.asarray(self.source)[:, 1].tolist() if len(self.source) else []
        return out


def _stop_message(code: int, state: EpisodeState, ep: EpisodeParams, plan: Plan | None) -> str:
    if code == NO_MATERIAL:
        return "the scene has no material outside the target: nothing to push"
    if code == DONE:
        remaining, initial = float(state.remaining), float(state.initial_remaining)
        return f"{remaining:.3g} objects left outside the target (<= {float(ep.stop_fraction):.3g} of {initial:.3g})"
    if code == CLEARED:
        cut_off = float(state.scene.unreachable_mass)
        return "no occupied cell left outside the target" + (
            f" that a target can be reached from ({cut_off:.3g} objects are cut off by blocked cells)"
            if cut_off > 0 else "")
    if code == NO_ROUTE:
        return (f"no complete route from cell {tuple(np.asarray(plan.source))} "
                "to the target (raise FabricParams.max_hops or use monotone=True)")
    if ep.max_pushes == 0:
        return "the push budget is 0 (EpisodeParams.max_pushes): nothing was pushed"
    return f"push budget of {ep.max_pushes} spent"


def run_episode(scene, params: FabricParams | None = None, spill: spillage.SpillParams | None = None,
                episode: EpisodeParams | None = None, *, record: bool = False, progress: bool = False,
                evaluator: spillage.Evaluator = spillage.curvature_spill,
                on_tick: Callable[[int, dict], None] | None = None,
                plan_spill: spillage.SpillParams | None = None) -> Episode:
    """Run one aggregate-transport job on ``scene`` until done (module docstring). Returns ``Episode``.

    spill: the spill model the pushes are executed with (what the world spills). plan_spill: the
    one the planner selects routes with (Eq. 6); None (default) means ``spill``. Tuning the planner's
    spill lambda against a fixed world (``experiments/tune_fabric.py --tune-spill``) sets both.

    All inputs are checked before any work: a ``scene`` that is not a Scene or ``params`` not a
    FabricParams is a ``TypeError``; leaves of disagreeing shapes, NaN, infinite or negative counts
    (a raw ``Scene(...)``) and out-of-range parameters are a ``ValueError`` naming the field.
    Counts are rounded to ``execute.QUANTUM`` first (exact sums; see ``execute``). record: keep a
    per-tick snapshot (heat, headings, highways, route, connector) for ``viz.animate_episode``.
    progress: a progress bar on stderr. on_tick(t, metrics): called after every push (e.g. to log).

    The host driver of the pieces ``step`` is made of (``reset``, the plan, ``execute``, the state's
    update), adding what needs the host: timing, the selective rebuild, frames, and a second walk
    with room for any simple path when a route is longer than ``default_walk_cap``.
    """
    params = FabricParams() if params is None else params
    spill = spillage.SpillParams() if spill is None else spill
    ep = EpisodeParams() if episode is None else episode
    check_fabric_inputs(scene, params, counts=True)
    validate_params(params)
    require_hard(params)
    if params.temperature is not None:   # a concrete 0 is the hard fabric; None keeps it so under jit
        params = params.replace(temperature=None)
    # the solver that "auto" runs is spelled "auto", as build_fabric does: one set of programs for both
    params = params.with_canonical_solver()
    spillage.validate_spill_params(spill)
    plan_spill = spill if plan_spill is None else plan_spill
    spillage.validate_spill_params(plan_spill)
    validate_episode_params(ep)

    state = reset(scene, params, spill, ep)
    shape = state.scene.shape
    initial_mass, initial_remaining = float(state.initial_mass), float(state.initial_remaining)
    cap = default_walk_cap(shape)
    mode = rebuild_mode(ep.rebuild, shape)
    # advance reads no field of EpisodeParams but the budget, which it takes traced here: runs that
    # differ in any of them share one compiled program
    bookkeeping = EpisodeParams(max_pushes=0)
    rows: list[dict] = []
    frames: list[dict] = []
    bar = _progress(ep.max_pushes, progress)
    try:
        for t in range(ep.max_pushes + 1):
            check_interrupt()
            code, plan = int(state.stop), None
            if code == RUNNING:
                (plan, planned), plan_ms = timed(lambda: plan_episode_tick(state.scene, params, ep, plan_spill,
                                                                           state.fabric, cap, evaluator))
                code = int(plan_code(plan, cap, shape))
                if code == WALK_CAP:
                    cap = shape[0] * shape[1] + 1
                    (plan, planned), plan_ms = timed(lambda: plan_episode_tick(state.scene, params, ep, plan_spill,
                                                                               state.fabric, cap, evaluator))
                    code = int(plan_code(plan, cap, shape))
            if code != RUNNING:
                break
            (new_obj, push), execute_ms = timed(lambda: execute.execute_jit(state.scene, plan.route, spill, evaluator))
            state, rec = advance_jit(state, plan, push, new_obj, True, bookkeeping, budget=ep.max_pushes)
            if mode == "selective":
                (fabric, affected), rebuild_ms = timed(lambda: rebuild.selective_rebuild(state.scene, params,
                                                                                         state.fabric, push.changed))
                dirty, full = int(affected.n_dirty), bool(affected.full)
            else:
                fabric, rebuild_ms = timed(lambda: _rebuild_full_jit(state.scene, params))
                dirty, full = shape[0] * shape[1], True
            state = state._replace(fabric=fabric)
            rec = jax.device_get(rec)
            row = dict(collected=float(rec.collected), push_delivered=float(rec.push_delivered),
                       push_spilled=float(rec.push_spilled), mode=int(rec.mode), source=np.asarray(rec.source),
                       route_length=float(rec.route_length), approach=float(rec.approach), plan_ms=plan_ms,
                       rebuild_ms=rebuild_ms, execute_ms=execute_ms, dirty=dirty, full_rebuild=full,
                       remaining=float(rec.remaining))
            rows.append(row)
            if record:
                frames.append(_frame(planned, plan, push))
            if on_tick is not None:
                on_tick(t, row)
            bar.update(1)
    finally:
        bar.close()
    stop_reason = STOP_REASONS[code]
    message = _stop_message(code, state, ep, plan)
    return _assemble(rows, frames, initial_mass, initial_remaining, stop_reason, message, state.scene, mode)


def _frame(fabric: Fabric, plan: Plan, push: execute.Push) -> dict:
    n = int(plan.route.n_cells)
    conn = np.asarray(plan.connector)
    return dict(heat=np.asarray(fabric.heat), heading=np.asarray(fabric.heading),
                occupied=np.asarray(fabric.occupied), highways=np.asarray(fabric.highways),
                route=np.asarray(plan.route.cells)[:n], route_end=np.asarray(plan.route.end),
                connector=conn[conn[:, 0] >= 0], mode=int(plan.mode),
                spline=np.asarray(push.samples.pos)[np.asarray(push.samples.valid)])


def _assemble(rows, frames, initial_mass, initial_remaining, stop_reason, message, scene, mode) -> Episode:
    col = lambda key, dtype=np.float64: np.asarray([r[key] for r in rows], dtype)  # noqa: E731
    n = len(rows)
    pushed = col("route_length")
    return Episode(
        delivered=np.cumsum(col("push_delivered")), spilled=np.cumsum(col("push_spilled")),
        remaining=col("remaining"), pushes=np.arange(1, n + 1, dtype=np.int32), collected=col("collected"),
        push_delivered=col("push_delivered"), push_spilled=col("push_spilled"), mode=col("mode", np.int32),
        source=np.asarray([r["source"] for r in rows], np.int32).reshape(n, 2), route_length=pushed,
        driven=np.cumsum(pushed + col("approach")), plan_ms=col("plan_ms"), rebuild_ms=col("rebuild_ms"),
        execute_ms=col("execute_ms"), dirty=col("dirty", np.int32), full_rebuild=col("full_rebuild", bool),
        initial_mass=initial_mass, initial_remaining=initial_remaining, stop_reason=stop_reason,
        message=message, final_obj=np.asarray(scene.obj), frames=frames, rebuild=mode,
        unreachable_mass=float(scene.unreachable_mass))


def _progress(total: int, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc="pushes", unit="push", leave=False, disable=not enabled)
