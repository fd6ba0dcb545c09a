"""The episode as a pure state machine: push, rebuild, until done (Section 3).

One tick plans (``plan``: source, mode and route), pushes the route (``execute``) and refreshes the
fabric (selectively, ``rebuild``, or in full; ``rebuild_mode``). The rebuild always continues from the
entry-0 fabric, so it stays exact.

The loop stops when the mass outside the target is at most ``stop_fraction`` of its initial value,
when ``max_pushes`` pushes are spent, or when the chosen source has no complete route.

``EpisodeState`` holds everything carried from one push to the next (counts, fabric, rover
positions, tick, done flag and stop code, running totals). ``reset`` makes the first state; ``act``
plans and pushes one tick; ``step`` is ``act`` plus the full rebuild, one jittable program that leaves
a finished state as it is, so ``rollout`` (``jax.lax.scan``) runs an episode and ``rollout_scenes``
(``vmap``) a batch of scenes of one shape. The walk length is static there (``default_walk_cap``).
``run.run_episode`` drives the same pieces from the host, adding the timing, the selective rebuild,
the frames and a second, longer walk when a route does not fit the cap.
"""
from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.core import grid_jit
from jaxplan.transport import execute, spillage
from jaxplan.transport.fabric import Fabric, build_fabric, check_fabric_inputs
from jaxplan.transport.params import FabricParams
from jaxplan.transport.plan import Plan, plan_episode_tick

MODES = ("deliver", "rearrange")
SOURCE_RULES = ("max_value", "nearest")
REBUILD_MODES = ("auto", "selective", "full")
# Grids below this many cells rebuild in full under rebuild="auto" on a CPU: there the selective
# update's listing and compact solver, a fixed number of small sequential steps, cost as much as the
# whole build. Table 2 and the whole-episode benchmark (experiments/rebuild_modes.py,
# docs/benchmarks.md) put the crossover near 50 cells a side.
SELECTIVE_MIN_CELLS = 2_500
# The push budget is compared with the tick counter, an int32, inside the compiled step; an episode
# of a million pushes already runs for hours.
MAX_PUSHES = 1_000_000


def _check_rebuild(rebuild) -> None:
    if rebuild not in REBUILD_MODES:
        raise ValueError(f"EpisodeParams.rebuild: must be one of {REBUILD_MODES}; got {rebuild!r}.")


def rebuild_mode(rebuild: str, shape, backend: str | None = None) -> str:
    """The rebuild an episode runs: ``rebuild`` itself unless it is "auto".

    "auto" is "full" on an accelerator (the full build is launch-bound there, and the selective update
    launches more kernels) and on CPU grids of fewer than
    ``SELECTIVE_MIN_CELLS`` cells; otherwise "selective". shape: (H, W); backend: JAX's platform name,
    default ``jax.default_backend()``. Both modes give the same fabric.
    """
    _check_rebuild(rebuild)
    if rebuild != "auto":
        return rebuild
    backend = jax.default_backend() if backend is None else backend
    if backend != "cpu":
        return "full"
    return "selective" if shape[0] * shape[1] >= SELECTIVE_MIN_CELLS else "full"


@dataclasses.dataclass(frozen=True)
class EpisodeParams:
    """Parameters of an episode (``reset``, ``step``, ``run.run_episode``).

    Traced: rearrange_margin: f32[] (>= 0), see the choice rule; stop_fraction: f32[] in [0, 1).
    Static: max_pushes (push budget, an int in [0, ``MAX_PUSHES``] = 10^6; ``run.run_episode`` hands it
    to its compiled programs as an array, so a sweep over budgets compiles them once; ``step_jit``
    and the rollouts compile per budget); source_rule ("max_value" or "nearest"); rebuild ("auto",
    "selective" or "full": how the fabric is refreshed after a push; all give the same fabric, only
    the time differs; "auto" picks by ``rebuild_mode``);
    reselect (apply Eq. 6 to every source before planning, module docstring; off by default: it
    costs a spill evaluation of every candidate route of every source with two or more per tick).
    """

    rearrange_margin: Any = 0.1
    stop_fraction: Any = 0.02
    max_pushes: int = 200
    source_rule: str = "max_value"
    rebuild: str = "auto"
    reselect: bool = False

    def replace(self, **changes) -> EpisodeParams:
        return dataclasses.replace(self, **changes)


jax.tree_util.register_dataclass(EpisodeParams, data_fields=["rearrange_margin", "stop_fraction"],
                                 meta_fields=["max_pushes", "source_rule", "rebuild", "reselect"])


def validate_episode_params(ep: EpisodeParams) -> None:
    """Raise ``ValueError`` naming the field for bad episode parameters."""
    if not isinstance(ep, EpisodeParams):
        raise ValueError(f"episode: expected an EpisodeParams, got {type(ep).__name__}.")
    margin = float(ep.rearrange_margin)
    if not margin >= 0:
        raise ValueError(f"EpisodeParams.rearrange_margin: must be >= 0 (inf = never rearrange); got {margin!r}.")
    frac = float(ep.stop_fraction)
    if not 0 <= frac < 1:
        raise ValueError(f"EpisodeParams.stop_fraction: must lie in [0, 1); got {frac!r}.")
    if (isinstance(ep.max_pushes, (bool, np.bool_)) or not isinstance(ep.max_pushes, (int, np.integer))
            or not 0 <= ep.max_pushes <= MAX_PUSHES):
        raise ValueError(f"EpisodeParams.max_pushes: must be an int in [0, {MAX_PUSHES}] (the tick counter "
                         f"is an int32 in the compiled step; 10^6 pushes take hours); got {ep.max_pushes!r}.")
    if ep.source_rule not in SOURCE_RULES:
        raise ValueError(f"EpisodeParams.source_rule: must be one of {SOURCE_RULES}; got {ep.source_rule!r}.")
    _check_rebuild(ep.rebuild)
    if not isinstance(ep.reselect, (bool, np.bool_)):
        raise ValueError(f"EpisodeParams.reselect: must be a bool; got {ep.reselect!r}.")


def require_hard(params: FabricParams, where: str = "run_episode") -> None:
    """Raise ``ValueError`` for a soft ``FabricParams`` (``temperature`` set and not a concrete 0).

    An episode reads the hard fabric's continuation table to pick and walk routes; the soft fabric
    (``jaxplan.transport.soft``) is a relaxation for gradients (``jaxplan.tune``) and has no table.
    Structural, so it also works on traced parameters (a traced temperature is soft).
    """
    if isinstance(params, FabricParams) and params.is_soft:
        t = params.temperature
        shown = "a traced value" if isinstance(t, jax.core.Tracer) else repr(t)
        raise ValueError(f"FabricParams.temperature: {shown}; {where} pushes on the hard fabric (its "
                         "continuation table), and a temperature > 0 builds the soft fabric, a relaxation for "
                         "gradients (jaxplan.tune) without one. Use temperature=None (or 0) for episodes.")


def default_walk_cap(shape) -> int:
    """The static walk length ``step`` uses unless told otherwise: ``min(H W + 1, 4 (H + W))`` steps for
    a grid of ``shape = (H, W)``. Longer routes are rare; ``run_episode`` then walks again with room
    for any simple path (``H W + 1``), which a jitted ``step`` cannot (stop reason "walk_cap")."""
    h, w = shape
    return min(h * w + 1, 4 * (h + w))


# Stop codes (EpisodeState.stop, StepRecord.stop), indices into STOP_REASONS. DONE: the mass outside
# the target fell to stop_fraction of its initial value; CLEARED: no occupied cell is left outside the
# target (also "done"); WALK_CAP: the chosen route is longer than the static walk cap.
RUNNING, DONE, CLEARED, BUDGET, NO_MATERIAL, NO_ROUTE, WALK_CAP = range(7)
STOP_REASONS = ("running", "done", "done", "budget", "no_material", "no_route", "walk_cap")


class EpisodeState(NamedTuple):
    """Everything an episode carries from one push to the next. A pytree of arrays; N rovers.

    scene: Scene, the counts now in ``scene.obj`` (f32[H, W], objects, multiples of
      ``execute.QUANTUM``) and the fixed geometry.
    fabric: Fabric built (entry 0, Eq. 5) for ``scene.obj``; ``reselect`` is applied when planning.
    rovers: f32[N, 2], world (x, y) of each rover: where its last route delivered, at the start the
      centroid of the target cells' centres. N = 1.
    tick: i32[], pushes done so far.
    done: bool[], the episode has stopped; ``step`` leaves a done state as it is.
    stop: i32[], stop code (``STOP_REASONS[stop]``; ``RUNNING`` = 0 until done).
    delivered, spilled: f32[], objects delivered to the target / spilled beside routes, all pushes.
    remaining: f32[], objects outside the target now.
    driven: f32[], world units driven (approaches plus pushed splines), all pushes.
    initial_mass: f32[], objects on the grid at the start (target included; conserved by pushes).
    initial_remaining: f32[], objects outside the target at the start.
    stop_at: f32[], objects: the episode is done once ``remaining <= stop_at``
      (``stop_fraction * initial_remaining``).
    """

    scene: Any
    fabric: Fabric
    rovers: jax.Array
    tick: jax.Array
    done: jax.Array
    stop: jax.Array
    delivered: jax.Array
    spilled: jax.Array
    remaining: jax.Array
    driven: jax.Array
    initial_mass: jax.Array
    initial_remaining: jax.Array
    stop_at: jax.Array


class StepRecord(NamedTuple):
    """One push's metrics (the columns of ``Episode``). All zero, ``source`` -1, when not ``valid``.

    source: i32[2], (row, col) of the pushed source.  mode: i32[] (0 deliver, 1 rearrange).
    collected, push_delivered, push_spilled: f32[] objects picked up, added to the target, dropped
      beside the route by this push (collected = push_delivered + push_spilled).
    route_length: f32[] world units pushed (spline length).  approach: f32[] world units driven
      straight from the rover's position to the source before the push.
    remaining: f32[] objects outside the target after the push.
    mass: f32[] objects on the whole grid after the push (a push conserves it: ``initial_mass``).
    delivered, spilled: f32[] objects, cumulative over the episode's pushes so far (float32 sums).
    driven: f32[] world units, cumulative approaches plus routes.
    push: i32[] the push's number (1, 2, ...; 0 when not valid).
    valid: bool[] a push happened; False for the step that found the episode done (or ended it
      without pushing: no source, no route, walk cap).
    stop: i32[] the state's stop code after this step (``STOP_REASONS``).
    """

    source: jax.Array
    mode: jax.Array
    collected: jax.Array
    push_delivered: jax.Array
    push_spilled: jax.Array
    route_length: jax.Array
    approach: jax.Array
    remaining: jax.Array
    mass: jax.Array
    delivered: jax.Array
    spilled: jax.Array
    driven: jax.Array
    push: jax.Array
    valid: jax.Array
    stop: jax.Array


def _f32(x):
    return jnp.asarray(x, jnp.float32)


def _i32(x):
    return jnp.asarray(x, jnp.int32)


def outside_mass(scene):
    """f32[]: objects outside the target (exact: counts are multiples of QUANTUM)."""
    return jnp.sum(jnp.where(scene.target_mask, 0.0, scene.obj))


def _stop_code(remaining, initial_remaining, stop_at, tick, max_pushes):
    """i32[]: the stop code checked before each push (run_episode's order: no material, done, budget).
    max_pushes: the push budget, an int or i32[]."""
    return _i32(jnp.select([initial_remaining <= 0, remaining <= stop_at, tick >= max_pushes],
                           [NO_MATERIAL, DONE, BUDGET], RUNNING))


def plan_code(plan: Plan, cap: int, shape):
    """i32[]: why ``plan`` cannot be pushed (RUNNING when it can). An incomplete walk under a cap
    shorter than any simple path is WALK_CAP (walking again may complete it), otherwise NO_ROUTE."""
    incomplete = ~plan.complete
    return _i32(jnp.select([~plan.has_source, incomplete & (cap < shape[0] * shape[1] + 1),
                            incomplete | ~jnp.isfinite(plan.raw)],
                           [CLEARED, WALK_CAP, NO_ROUTE], RUNNING))


def reset(scene, params: FabricParams | None = None, spill: spillage.SpillParams | None = None,
          episode: EpisodeParams | None = None) -> EpisodeState:
    """The state before the first push: counts rounded to ``execute.QUANTUM``, the fabric built, the
    rover on the target's centroid, the start's stop checks applied (no material, budget 0). Pure and
    jittable (``vmap`` it over scenes of one shape). spill is not read; it keeps the signature of
    ``step``. Concrete parameters and counts are not validated here (``run_episode`` does); the
    arguments' types and the scene's shapes are (``fabric.check_fabric_inputs``, also under ``jit``)."""
    params = FabricParams() if params is None else params
    check_fabric_inputs(scene, params)
    require_hard(params, "reset")
    ep = EpisodeParams() if episode is None else episode
    del spill
    scene = scene.with_obj(execute.quantize(scene.obj))
    fabric = build_fabric(scene, params)
    target = jnp.asarray(scene.target_mask, bool)
    centres = scene.cell_centers()
    rover = jnp.sum(jnp.where(target[..., None], centres, 0.0), (0, 1)) / jnp.maximum(jnp.sum(target), 1)
    initial_mass = _f32(jnp.sum(scene.obj))
    initial_remaining = _f32(outside_mass(scene))
    stop_at = _f32(_f32(ep.stop_fraction) * initial_remaining)
    tick = _i32(0)
    stop = _stop_code(initial_remaining, initial_remaining, stop_at, tick, ep.max_pushes)
    zero = _f32(0.0)
    return EpisodeState(scene, fabric, _f32(rover)[None], tick, stop != RUNNING, stop, zero, zero,
                        initial_remaining, zero, initial_mass, initial_remaining, stop_at)


def advance(state: EpisodeState, plan: Plan, push: execute.Push, new_obj, go, ep: EpisodeParams, budget=None):
    """``(state, record)`` after pushing ``plan`` (``push``, ``new_obj``: ``execute``'s output) when
    ``go: bool[]``; otherwise ``state`` unchanged and an invalid record. The fabric is left as it was:
    the caller refreshes it (``step`` in full, ``run.run_episode`` selectively).

    budget: the push budget, an int or i32[] (default ``ep.max_pushes``, the only field of ``ep`` that
    ``advance`` reads). Given as an argument it is traced under ``jit``: ``run.run_episode`` passes it
    with ``ep.max_pushes`` set to 0, so that ``advance_jit`` compiles once for every budget.
    """
    scene = state.scene.with_obj(new_obj)
    remaining = _f32(outside_mass(scene))
    approach = jnp.linalg.norm(scene.cell_centers()[plan.source[0], plan.source[1]] - state.rovers[0])
    tick = state.tick + 1
    delivered = state.delivered + push.delivered
    spilled = state.spilled + push.spilled
    driven = state.driven + approach + push.length
    budget = ep.max_pushes if budget is None else budget
    stop = _stop_code(remaining, state.initial_remaining, state.stop_at, tick, budget)
    pushed = EpisodeState(scene, state.fabric, state.rovers.at[0].set(plan.route.end), tick, stop != RUNNING,
                          stop, delivered, spilled, remaining, driven, state.initial_mass,
                          state.initial_remaining, state.stop_at)
    new = jax.tree.map(lambda a, b: jnp.where(go, a, b), pushed, state)
    keep = lambda x: jnp.where(go, x, jnp.zeros_like(x))  # noqa: E731
    record = StepRecord(jnp.where(go, plan.source, -1), keep(plan.mode), keep(push.collected),
                        keep(push.delivered), keep(push.spilled), keep(push.length), keep(approach),
                        keep(remaining), keep(jnp.sum(new_obj)), keep(delivered), keep(spilled), keep(driven),
                        keep(tick), jnp.asarray(go, bool), new.stop)
    return new, jax.tree.map(lambda a, like: jnp.asarray(a, like.dtype), record, _record_like())


def _record_like() -> StepRecord:
    """The dtypes of a StepRecord's fields."""
    f, i = jnp.zeros((), jnp.float32), jnp.zeros((), jnp.int32)
    return StepRecord(jnp.zeros(2, jnp.int32), i, f, f, f, f, f, f, f, f, f, f, i, jnp.zeros((), bool), i)


def _idle_record(state: EpisodeState) -> StepRecord:
    like = _record_like()
    return like._replace(source=jnp.full(2, -1, jnp.int32), stop=state.stop)


advance_jit = grid_jit(advance)


def act(state: EpisodeState, params: FabricParams, spill: spillage.SpillParams, episode: EpisodeParams, *,
        walk_cap: int | None = None, evaluator: spillage.Evaluator = spillage.curvature_spill):
    """Plan and push one tick: ``(state, record, push)``. Pure and jittable.

    The returned state's counts, rover, totals and stop code are after the push, but its fabric is
    still the one planned on: refresh it (``step`` builds it in full; ``run_episode`` may update it
    selectively from ``push.changed``). A state that is done, or whose plan cannot be pushed (no
    source, no route, a route longer than ``walk_cap``), is returned unchanged but for the stop code,
    with an invalid record. walk_cap: static walk length (default ``default_walk_cap``).
    """
    require_hard(params, "act")
    shape = state.scene.obj.shape
    cap = default_walk_cap(shape) if walk_cap is None else int(walk_cap)
    plan, _ = plan_episode_tick(state.scene, params, episode, spill, state.fabric, cap, evaluator)
    code = plan_code(plan, cap, shape)
    go = ~state.done & (code == RUNNING)
    new_obj, push = execute.execute_push(state.scene, plan.route, spill, evaluator)
    new, record = advance(state, plan, push, new_obj, go, episode)
    stop = jnp.where(state.done | go, new.stop, code)
    return new._replace(done=stop != RUNNING, stop=stop), record._replace(stop=stop), push


def step(state: EpisodeState, params: FabricParams, spill: spillage.SpillParams, episode: EpisodeParams, *,
         walk_cap: int | None = None, evaluator: spillage.Evaluator = spillage.curvature_spill):
    """One tick with the full rebuild: ``(state, StepRecord)``. Pure, one jittable program.

    A done state is returned as it is, with an invalid record, so ``jax.lax.scan`` may run more
    steps than the episode needs (``rollout``). walk_cap, evaluator: static (``act``). Equals a tick
    of ``run_episode(rebuild="full")``, except that a route longer than ``walk_cap`` ends the episode
    (stop reason "walk_cap") where ``run_episode`` walks again with a longer cap.
    """
    require_hard(params, "step")

    def live(state):
        new, record, _ = act(state, params, spill, episode, walk_cap=walk_cap, evaluator=evaluator)
        fabric = jax.lax.cond(record.valid, lambda s: build_fabric(s, params), lambda s: state.fabric, new.scene)
        return new._replace(fabric=fabric), record

    return jax.lax.cond(state.done, lambda s: (s, _idle_record(s)), live, state)


def rollout(state: EpisodeState, params: FabricParams, spill: spillage.SpillParams, episode: EpisodeParams,
            n_steps: int, *, walk_cap: int | None = None, evaluator: spillage.Evaluator = spillage.curvature_spill):
    """``n_steps`` (static) ticks of ``step`` in one ``jax.lax.scan``: ``(state, StepRecord)`` with the
    records stacked along a leading axis of n_steps (rows after the episode stopped are invalid)."""
    require_hard(params, "rollout")
    return jax.lax.scan(lambda s, _: step(s, params, spill, episode, walk_cap=walk_cap, evaluator=evaluator),
                        state, None, length=n_steps)


def rollout_scenes(scenes, params: FabricParams, spill: spillage.SpillParams, episode: EpisodeParams, n_steps: int,
                   *, walk_cap: int | None = None, evaluator: spillage.Evaluator = spillage.curvature_spill):
    """``reset`` then ``rollout`` for a batch of scenes of one shape in one program (``vmap``):
    ``(initial states, final states, records)`` with a leading batch axis B; records are [B, n_steps].

    scenes: one Scene whose leaves are stacked along a leading axis B
    (``jaxplan.transport.scene.stack_scenes``); params, spill, episode are shared. Jitted as ``rollout_scenes_jit``.
    """
    require_hard(params, "rollout_scenes")

    def one(scene):
        start = reset(scene, params, spill, episode)
        final, records = rollout(start, params, spill, episode, n_steps, walk_cap=walk_cap, evaluator=evaluator)
        return start, final, records

    return jax.vmap(one)(scenes)


step_jit = grid_jit(step, static_argnames=("walk_cap", "evaluator"))
rollout_jit = grid_jit(rollout, static_argnames=("n_steps", "walk_cap", "evaluator"))
# the code generator is picked by the batch's cells, B H W: the older one that suits single small
# grids ran a batch of 64 episodes of 32 x 32 at half the speed
rollout_scenes_jit = grid_jit(rollout_scenes, static_argnames=("n_steps", "walk_cap", "evaluator"),
                              cells_of=lambda scenes, *args, **kwargs: int(np.prod(scenes.obj.shape)))
