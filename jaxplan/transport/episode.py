"""The job loop: query the fabric, choose Rearrange or Deliver, push, rebuild, until done (Section 3).

One tick (``docs/conventions.md``, "Episodes"):

1. **Source**: the occupied cell whose selected route collects the most (``argmax J``; rule
   ``"max_value"``), or the occupied cell nearest to the target (``"nearest"``). Ties: lowest
   row-major index.
2. **Deliver route**: among the source's slack-tau candidates, the one with the largest delivered mass
   under the spill model, then the shortest (Eq. 6; entry 0 with spillage off).
3. **Rearrange route**: if the source is a root with a highway anchor h* (Eq. 12), the connector to h*
   followed by h*'s selected path (Section 3.4; ``Fabric.selected``).
4. **Choice**: Rearrange when ``via_raw > (1 + rearrange_margin) * raw(Deliver route)``, i.e. when
   going through the highway collects clearly more; otherwise Deliver. ``rearrange_margin`` is a
   traced parameter (``inf`` never rearranges).
5. Push the route (``execute``), rebuild the fabric (selectively, ``rebuild``, or in full; ``rebuild_mode``),
   record the metrics.

With ``reselect`` (and spillage on) every tick first applies Eq. 6 to every source
(``selection.reselect``), so that headings, psi, the heatmap, highways and anchors follow the routes
selected by delivered mass, as the paper does; its cost is part of the tick's planning time. The
rebuild always continues from the entry-0 fabric, so it stays exact.

The loop stops when the mass outside the target is at most ``stop_fraction`` of its initial value,
when ``max_pushes`` pushes are spent, or when the chosen source has no complete route.

Pure form: ``EpisodeState`` holds everything carried from one push to the next (counts, fabric, rover
positions, tick, done flag and stop code, running totals). ``reset`` makes the first state; ``act``
plans and pushes one tick; ``step`` is ``act`` plus the full rebuild, one jittable program that leaves
a finished state as it is, so ``rollout`` (``jax.lax.scan``) runs an episode and ``rollout_scenes``
(``vmap``) a batch of scenes of one shape. The walk length is static there (``default_walk_cap``).
``run_episode`` drives the same pieces from the host, adding the timing, the selective rebuild, the
frames and a second, longer walk when a route does not fit the cap.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.core import lattice
from jaxplan.core.compilation import grid_jit
from jaxplan.core.timing import timed
from jaxplan.transport import connectors, execute, rebuild, selection, spillage
from jaxplan.transport.fabric import Fabric, Table, build_fabric, walk_table
from jaxplan.transport.params import FabricParams, validate_params

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
    """Parameters of ``run_episode``.

    Traced: rearrange_margin: f32[] (>= 0), see the choice rule; stop_fraction: f32[] in [0, 1).
    Static: max_pushes (push budget, an int in [0, ``MAX_PUSHES``] = 10^6); source_rule ("max_value" or
    "nearest"); rebuild ("auto", "selective" or "full": how the fabric is refreshed after a push; all give the same
    fabric, only the time differs; "auto" picks by ``rebuild_mode``);
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


# ------------------------------------------------------------------------------------------ one tick

class Plan(NamedTuple):
    """One tick's decision. S = 2 * (max_steps + 1) route slots.

    source: i32[2]; has_source: bool[]; mode: i32[] (0 deliver, 1 rearrange); route: execute.Route;
    raw: f32[] objects the route collects (pre-spill); complete: bool[] every walk ended in time;
    anchor: i32[2] (-1 none); entry: i32[] the Deliver route's table entry; connector: i32[S, 2]
    cells of the connector part (-1 padded) for plots.
    """

    source: jax.Array
    has_source: jax.Array
    mode: jax.Array
    route: execute.Route
    raw: jax.Array
    complete: jax.Array
    anchor: jax.Array
    entry: jax.Array
    connector: jax.Array


def _pad_rows(cells, rows: int):
    return jnp.concatenate([cells, jnp.full((rows - cells.shape[0], 2), -1, jnp.int32)])


def _concat_paths(first, first_n, second, second_n):
    """Rows ``first[:first_n]`` then ``second[:second_n]`` in one padded ``[2S, 2]`` array."""
    rows = first.shape[0] + second.shape[0]
    i = jnp.arange(rows)
    from_second = jnp.clip(i - first_n, 0, second.shape[0] - 1)
    out = jnp.where((i < first_n)[:, None], first[jnp.minimum(i, first.shape[0] - 1)], second[from_second])
    return jnp.where((i < first_n + second_n)[:, None], out, -1), first_n + second_n


def choose_source(scene, fabric: Fabric, rule: str, allowed=None):
    """``(source i32[2], has_source bool[])``: the occupied cell the rule picks (``argmax J`` for
    "max_value", the one nearest to the target for "nearest"; ties to the lowest row-major index).

    allowed: optional bool[H, W]; only occupied cells where it is True are candidates (a fleet skips
    the cells other rovers have reserved). has_source is False when no candidate is left; the
    source is then (0, 0).
    """
    h, w = scene.shape
    score = fabric.value if rule == "max_value" else -scene.dist
    candidates = fabric.occupied if allowed is None else fabric.occupied & allowed
    flat = jnp.argmax(jnp.where(candidates, score, -jnp.inf).reshape(-1))
    return jnp.stack([flat // w, flat % w]).astype(jnp.int32), jnp.any(candidates)


def plan_tick(scene, params: FabricParams, ep: EpisodeParams, spill: spillage.SpillParams, fabric: Fabric,
              max_steps: int, evaluator: spillage.Evaluator = spillage.curvature_spill) -> Plan:
    """Choose the source, the mode and the route for one push (the module docstring's rule):
    ``choose_source`` then ``plan_for_source``."""
    source, has_source = choose_source(scene, fabric, ep.source_rule)
    plan = plan_for_source(scene, params, ep, spill, fabric, source, max_steps, evaluator)
    return plan._replace(has_source=has_source)


def plan_for_source(scene, params: FabricParams, ep: EpisodeParams, spill: spillage.SpillParams, fabric: Fabric,
                    source, max_steps: int, evaluator: spillage.Evaluator = spillage.curvature_spill) -> Plan:
    """The mode and the route of one push from a given ``source: i32[2]`` (steps 2-4 of the module
    docstring). ``Plan.has_source`` says whether the source is an occupied cell. max_steps,
    evaluator: static, as in ``plan_tick``. Pure and jittable; ``vmap`` it over sources."""
    source = jnp.asarray(source, jnp.int32)
    anchor = source_anchor(scene, params, fabric, source)
    return plan_with_connector(scene, params, ep, spill, fabric, source, anchor,
                               anchor_connector(scene, params, fabric, anchor), max_steps, evaluator)


def source_anchor(scene, params: FabricParams, fabric: Fabric, source):
    """i32[]: flat index of the highway anchor h* of ``source: i32[2]`` (Eq. 12; -1 none)."""
    centers = lattice.cell_centers(scene.shape, scene.cell_size, scene.origin)
    return connectors.anchor_for(fabric.heat, fabric.highways, fabric.occupied, centers, params.anchor_lambda,
                                 jnp.asarray(source, jnp.int32))


def anchor_connector(scene, params: FabricParams, fabric: Fabric, anchor) -> Table:
    """The K=1 connector table toward ``anchor`` (flat index); a one-entry empty table when it is -1,
    without running the DP (under ``vmap`` both run: batch by distinct anchor instead)."""
    h, w = scene.shape

    def no_connector(_):
        shape = (h, w, 1)
        return Table(jnp.full(shape, -jnp.inf), jnp.full(shape, jnp.inf), jnp.full(shape, -1, jnp.int32),
                     jnp.full(shape, -1, jnp.int32))

    return jax.lax.cond(anchor >= 0, lambda _: connectors.connector_table(scene, fabric, params,
                                                                         jnp.maximum(anchor, 0)),
                        no_connector, None)


def plan_with_connector(scene, params: FabricParams, ep: EpisodeParams, spill: spillage.SpillParams,
                        fabric: Fabric, source, anchor, ctable: Table, max_steps: int,
                        evaluator: spillage.Evaluator = spillage.curvature_spill) -> Plan:
    """``plan_for_source`` with the source's anchor (``source_anchor``) and its connector table
    (``anchor_connector``) given, so that sources sharing an anchor share one connector DP."""
    h, w = scene.shape
    source = jnp.asarray(source, jnp.int32)
    has_source = fabric.occupied[source[0], source[1]]
    sel = selection.select_routes(scene, fabric, source[None], params.slack_tau, spill,
                                  max_steps=max_steps, evaluator=evaluator)
    entry = sel.entry[0]
    direct = walk_table(fabric.table, source, entry, max_steps)
    safe_anchor = jnp.maximum(anchor, 0)
    anchor_rc = jnp.stack([safe_anchor // w, safe_anchor % w]).astype(jnp.int32)
    conn = walk_table(ctable, source, jnp.int32(0), max_steps)
    anchor_entry = fabric.selected[anchor_rc[0], anchor_rc[1]]
    tail = walk_table(fabric.table, anchor_rc, anchor_entry, max_steps)
    # a connector that enters h* lists it last; the tail starts at h*, so drop the duplicate
    conn_cells = jnp.where(conn.fallback, conn.n_cells, conn.n_cells - 1)
    via_cells, via_n = _concat_paths(conn.cells, conn_cells, tail.cells, tail.n_cells)
    via_raw = conn.raw + fabric.table.raw[anchor_rc[0], anchor_rc[1], anchor_entry]
    can_rearrange = (anchor >= 0) & jnp.isfinite(conn.raw) & conn.complete & tail.complete
    rearrange = can_rearrange & (via_raw > (1.0 + ep.rearrange_margin) * direct.raw)

    rows = via_cells.shape[0]
    cells = jnp.where(rearrange, via_cells, _pad_rows(direct.cells, rows))
    n_cells = jnp.where(rearrange, via_n, direct.n_cells)
    fallback = jnp.where(rearrange, tail.fallback, direct.fallback)
    route = execute.route_from_path(scene, cells, n_cells, fallback)
    connector = jnp.where(rearrange & (jnp.arange(rows) < conn.n_cells)[:, None], _pad_rows(conn.cells, rows), -1)
    return Plan(source, has_source, rearrange.astype(jnp.int32), route,
                jnp.where(rearrange, via_raw, direct.raw),
                jnp.where(rearrange, conn.complete & tail.complete, direct.complete),
                jnp.where(anchor >= 0, anchor_rc, -1), entry, connector)


_plan_tick_jit = grid_jit(plan_tick, static_argnames=("max_steps", "evaluator"))


def _plan(scene, params, ep: EpisodeParams, spill, fabric: Fabric, cap: int, evaluator):
    """One tick's plan and the fabric it was planned on (Eq. 6 applied to every source with
    ``ep.reselect`` and spillage on)."""
    if ep.reselect and spill.enabled:
        fabric = selection.reselect(scene, params, fabric, spill, max_steps=cap, evaluator=evaluator)
    return _plan_tick_jit(scene, params, ep, spill, fabric, max_steps=cap, evaluator=evaluator), fabric


_rebuild_full_jit = grid_jit(lambda scene, params: build_fabric(scene, params))


# ------------------------------------------------------------------------------------------ the loop

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


def default_walk_cap(shape) -> int:
    """The static walk length ``step`` uses unless told otherwise: ``min(H W + 1, 4 (H + W))`` steps for
    a grid of ``shape = (H, W)``. Longer routes are rare; ``run_episode`` then walks again with room
    for any simple path (``H W + 1``), which a jitted ``step`` cannot (stop reason "walk_cap")."""
    h, w = shape
    return min(h * w + 1, 4 * (h + w))


# ------------------------------------------------------------------------------ the episode's state

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


def _stop_code(remaining, initial_remaining, stop_at, tick, max_pushes: int):
    """i32[]: the stop code checked before each push (run_episode's order: no material, done, budget)."""
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
    ``step``. Concrete parameters are not validated here (``run_episode`` does)."""
    params = FabricParams() if params is None else params
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


def _advance(state: EpisodeState, plan: Plan, push: execute.Push, new_obj, go, ep: EpisodeParams):
    """``(state, record)`` after pushing ``plan`` (``push``, ``new_obj``: ``execute``'s output) when
    ``go``; otherwise ``state`` unchanged and an invalid record. The fabric is left as it was."""
    scene = state.scene.with_obj(new_obj)
    remaining = _f32(outside_mass(scene))
    approach = jnp.linalg.norm(scene.cell_centers()[plan.source[0], plan.source[1]] - state.rovers[0])
    tick = state.tick + 1
    delivered = state.delivered + push.delivered
    spilled = state.spilled + push.spilled
    driven = state.driven + approach + push.length
    stop = _stop_code(remaining, state.initial_remaining, state.stop_at, tick, ep.max_pushes)
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


_advance_jit = grid_jit(_advance)


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
    plan, _ = _plan(state.scene, params, episode, spill, state.fabric, cap, evaluator)
    code = plan_code(plan, cap, shape)
    go = ~state.done & (code == RUNNING)
    new_obj, push = execute.execute(state.scene, plan.route, spill, evaluator)
    new, record = _advance(state, plan, push, new_obj, go, episode)
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


# ------------------------------------------------------------------------------------------ the loop

def _stop_message(code: int, state: EpisodeState, ep: EpisodeParams, plan: Plan | None) -> str:
    if code == NO_MATERIAL:
        return "the scene has no material outside the target: nothing to push"
    if code == DONE:
        remaining, initial = float(state.remaining), float(state.initial_remaining)
        return f"{remaining:.3g} objects left outside the target (<= {float(ep.stop_fraction):.3g} of {initial:.3g})"
    if code == CLEARED:
        return "no occupied cell left outside the target"
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
    validate_params(params)
    require_hard(params)
    if params.temperature is not None:   # a concrete 0 is the hard fabric; None keeps it so under jit
        params = params.replace(temperature=None)
    spillage.validate_spill_params(spill)
    plan_spill = spill if plan_spill is None else plan_spill
    spillage.validate_spill_params(plan_spill)
    validate_episode_params(ep)

    state = reset(scene, params, spill, ep)
    shape = state.scene.shape
    initial_mass, initial_remaining = float(state.initial_mass), float(state.initial_remaining)
    cap = default_walk_cap(shape)
    mode = rebuild_mode(ep.rebuild, shape)
    rows: list[dict] = []
    frames: list[dict] = []
    bar = _progress(ep.max_pushes, progress)
    try:
        for t in range(ep.max_pushes + 1):
            code, plan = int(state.stop), None
            if code == RUNNING:
                (plan, planned), plan_ms = timed(lambda: _plan(state.scene, params, ep, plan_spill, state.fabric, cap,
                                                               evaluator))
                code = int(plan_code(plan, cap, shape))
                if code == WALK_CAP:
                    cap = shape[0] * shape[1] + 1
                    (plan, planned), plan_ms = timed(lambda: _plan(state.scene, params, ep, plan_spill, state.fabric,
                                                                   cap, evaluator))
                    code = int(plan_code(plan, cap, shape))
            if code != RUNNING:
                break
            (new_obj, push), execute_ms = timed(lambda: execute.execute_jit(state.scene, plan.route, spill, evaluator))
            state, rec = _advance_jit(state, plan, push, new_obj, True, ep)
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
        message=message, final_obj=np.asarray(scene.obj), frames=frames, rebuild=mode)


def _progress(total: int, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc="pushes", unit="push", leave=False, disable=not enabled)
