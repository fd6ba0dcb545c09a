"""Random small sites and fleets, every strategy: no conflict ever (the serial checker on the recorded
positions and reserved footprints), the mass identity exact at every step, finite outputs, a named
stop; the jitted step traces once, equals the step run without jit and the scanned rollout, and is
a no-op once done."""
from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan import FabricParams, SpillParams
from jaxplan.fleet import STOP_REASONS, STRATEGIES, FleetConfig, reset, rollout, run_fleet, step
from jaxplan.fleet import run as fleet_run
from jaxplan.fleet.motion import IDLE, PATIENCE
from jaxplan.transport.episode import EpisodeParams
from tests.fleet._sites import LAYOUTS, site

SITES = {2: (12, 12), 3: (16, 16), 5: (20, 20)}     # one grid per fleet size: one compile each
PARAMS = FabricParams()
SPILL = SpillParams(lam=0.1)


# A covering design, not the cross product: each case's fleet size and settings are a program of their own
# (minutes of compiling for the 10 of the product), while these 4 take each strategy, each fleet size and
# each candidate rule; independent and partitioned fleets of one size share one step (FleetConfig.kernel), and
# the coordinated pair of 2 is the selective-refresh test's program.
CASES = [(2, "coordinated", "rate"), (3, "independent", "value"), (3, "partitioned", "value"),
         (5, "coordinated", "value")]
assert {c[0] for c in CASES} == set(SITES) and {c[1] for c in CASES} == set(STRATEGIES)


@pytest.mark.parametrize("n, strategy, candidates_by", CASES)
@settings(max_examples=2, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=False)
@given(seed=st.integers(0, 10 ** 6), layout=st.sampled_from(LAYOUTS), fraction=st.sampled_from((0.02, 0.4)),
       pushes=st.integers(0, 12))
def test_random_fleets_keep_every_invariant(n, strategy, candidates_by, seed, layout, fraction, pushes):
    scene = site(seed, SITES[n], layout)
    ep = EpisodeParams(max_pushes=pushes, stop_fraction=fraction, rebuild="full")
    run = run_fleet(scene, n, strategy, PARAMS, SPILL, ep, max_steps=1_000,
                    config=FleetConfig(n, strategy, candidates_by=candidates_by))
    assert run.conflicts == 0 and run.kernel_conflicts == 0
    assert run.stop_reason in STOP_REASONS and run.stop_reason not in ("running", "max_steps"), run.message
    t = run.steps
    assert run.pos.shape == (t + 1, n, 2) and run.delivered.shape == run.outside.shape == (t + 1,)
    h, w = SITES[n]
    assert np.all((run.pos >= 0) & (run.pos < [h, w]))
    blocked = np.asarray(scene.blocked)
    assert not blocked[run.pos[..., 0], run.pos[..., 1]].any(), "a rover on a blocked cell"
    assert not np.asarray(run.final_scene.obj)[blocked].any(), "material on a blocked cell"
    for p in run.pushes:
        assert not blocked[tuple(np.asarray(p["cells"]).T)].any(), "a route through a blocked cell"
    for a in (run.delivered, run.outside, [p[k] for p in run.pushes for k in ("collected", "delivered", "spilled")]):
        assert np.all(np.isfinite(a))
    # mass identity, exact: counts are multiples of execute.QUANTUM
    np.testing.assert_array_equal(run.delivered + run.outside, np.full(t + 1, run.initial_mass))
    gained = np.zeros(t + 1)
    for p in run.pushes:
        gained[p["last_step"]] += p["delivered"]
        assert p["collected"] == pytest.approx(p["delivered"] + p["spilled"], abs=1e-4)
        assert p["first_step"] <= p["last_step"]
    np.testing.assert_allclose(np.diff(run.delivered), gained[1:], atol=1e-3)
    assert len(run.pushes) == int(run.rover_pushes.sum()) <= pushes
    assert np.all(run.idle_steps <= t)


def test_the_fleet_stop_codes_extend_the_episodes():
    """The fleet's stop table is the episode's with three codes after it; an assignment's failure
    code for taken footprints is the fleet's "no_reachable_task"."""
    from jaxplan import transport
    from jaxplan.fleet import assign, state

    assert STOP_REASONS[:len(transport.STOP_REASONS)] == transport.STOP_REASONS
    assert STOP_REASONS[len(transport.STOP_REASONS):] == ("max_steps", "deadlock", "no_reachable_task")
    assert (state.MAX_STEPS, state.DEADLOCK, state.NO_REACHABLE, assign.BLOCKED) == (7, 8, 9, 9)
    assert STOP_REASONS[assign.BLOCKED] == "no_reachable_task"


@pytest.fixture(scope="module")
def traced_run():
    """Twelve steps of a jitted step that may be traced only once, with their states."""
    chex.clear_trace_counter()
    scene = site(0, SITES[2], "uniform")
    config = FleetConfig(2, "coordinated")
    ep = EpisodeParams(max_pushes=3, stop_fraction=0.02, rebuild="full")
    jitted = jax.jit(chex.assert_max_traces(step, n=1), static_argnames=("config", "evaluator"))
    state = reset(scene, PARAMS, SPILL, ep, config, max_steps=500)
    states, records = [state], []
    while not bool(state.totals.done):
        state, rec = jitted(state, PARAMS, SPILL, ep, config=config)
        states.append(state)
        records.append(rec)
    after, idle = jitted(state, PARAMS, SPILL, ep, config=config)
    return dict(config=config, ep=ep, states=states, records=records, after=after, idle=idle, jitted=jitted)


def test_step_traces_once_and_a_done_state_stays_as_it_is(traced_run):
    final, after, idle = traced_run["states"][-1], traced_run["after"], traced_run["idle"]
    assert STOP_REASONS[int(final.totals.stop)] == "budget" and len(traced_run["records"]) > 3
    chex.assert_trees_all_equal(final, after)
    assert not bool(idle.valid) and not np.any(np.asarray(idle.ended))


def test_the_step_without_jit_equals_the_jitted_step(traced_run):
    """On a step that plans nothing (every rover busy, or the budget spent), computes no distance field
    and applies no push, run op by op (the whole step without jit takes minutes)."""
    states, records, ep = traced_run["states"], traced_run["records"], traced_run["ep"]
    busy = [t for t in range(len(records) - 1)
            if (np.all(np.asarray(states[t].rovers.phase) != IDLE) or int(states[t].totals.started) >= ep.max_pushes)
            and np.all(np.asarray(states[t].rovers.wait) < PATIENCE) and not np.any(np.asarray(records[t].ended))
            and np.any(np.asarray(records[t].pos != states[t].rovers.pos))]
    assert busy
    t = busy[0]
    with jax.disable_jit():
        state, rec = step(states[t], PARAMS, SPILL, traced_run["ep"], traced_run["config"])
    chex.assert_trees_all_equal(rec, records[t])
    chex.assert_trees_all_equal(state, states[t + 1])


def test_rollout_scans_the_same_steps(traced_run):
    states, records = traced_run["states"], traced_run["records"]
    n = len(records) + 2                       # two steps past the end: no-ops
    final, scanned = jax.jit(rollout, static_argnames=("config", "n_steps", "evaluator"))(
        states[0], PARAMS, SPILL, traced_run["ep"], traced_run["config"], n_steps=n)
    stepped = jax.tree.map(lambda *xs: np.stack(xs), *records)
    for name in ("pos", "phase", "assigned", "dropped", "ended", "stop", "valid"):
        np.testing.assert_array_equal(np.asarray(getattr(scanned, name))[:len(records)], getattr(stepped, name))
    for name in ("delivered", "outside", "inside"):
        np.testing.assert_allclose(np.asarray(getattr(scanned, name))[:len(records)], getattr(stepped, name),
                                   rtol=1e-6)
    assert not np.any(np.asarray(scanned.valid)[len(records):])
    np.testing.assert_array_equal(np.asarray(final.rovers.pos), np.asarray(states[-1].rovers.pos))
    np.testing.assert_allclose(np.asarray(final.scene.obj), np.asarray(states[-1].scene.obj), atol=1e-6)


@pytest.mark.parametrize("strategy", ["coordinated", "partitioned"])
def test_what_is_not_planned_again_changes_nothing(traced_run, strategy):
    """A longer run, once reusing fresh candidates (coordinated) or failed attempts (the others) and
    once planning at every assignment: the same positions, counts and reservations at every step.
    Without the set-aside list, since with it a waiting rover's sources change at most steps and the
    candidates are rarely fresh."""
    config, ep = FleetConfig(2, strategy, set_aside=False), traced_run["ep"]
    jitted = jax.jit(step, static_argnames=("config", "evaluator"))
    kept = planned = reset(site(3, SITES[2], "two_targets"), PARAMS, SPILL, ep, config, max_steps=400,
                           max_pushes=40)
    reused = 0
    while not bool(kept.totals.done):
        idle = np.any(np.asarray(kept.rovers.phase) == IDLE) and int(kept.totals.started) < int(kept.totals.max_pushes)
        recorded = strategy == "coordinated" or bool(np.any(np.asarray(kept.attempts.valid)))
        reused += int(idle and bool(kept.fresh) and recorded)
        kept, _ = jitted(kept, PARAMS, SPILL, ep, config=config)
        planned, _ = jitted(planned._replace(fresh=np.bool_(False)), PARAMS, SPILL, ep, config=config)
        for name in ("pos", "phase", "route", "pushes"):
            chex.assert_trees_all_equal(getattr(kept.rovers, name), getattr(planned.rovers, name))
        chex.assert_trees_all_equal(kept.owner, planned.owner)
        chex.assert_trees_all_equal(kept.totals.stop, planned.totals.stop)
        np.testing.assert_array_equal(np.asarray(kept.scene.obj), np.asarray(planned.scene.obj))
    assert reused > 0


def test_tasks_kept_across_a_refresh_equal_tasks_planned_again(traced_run):
    """After a push ends and the fabric is refreshed, the cached tasks the refresh left unchanged
    (``keep_tasks``) are the tasks planning their sources again on the new fabric gives, and their
    footprints overlap as recomputed; the refresh keeps some and drops others; the record counts the
    tasks planned."""
    from jaxplan.fleet import assign
    from jaxplan.transport import spillage

    config, ep = traced_run["config"], traced_run["ep"]
    state = reset(site(3, SITES[2], "two_targets"), PARAMS, SPILL, ep, config, max_steps=400, max_pushes=40)
    cap = config.resolved(SITES[2]).walk_cap
    again = jax.jit(jax.vmap(lambda scene, fabric, source: assign.plan_task(
        scene, PARAMS, ep, SPILL, fabric, source, True, cap, spillage.curvature_spill, config.clearance),
        in_axes=(None, None, 0)))
    kept = dropped = planned = set_aside_held = 0
    while not bool(state.totals.done):
        cached, was_fresh = np.asarray(state.candidates.exists), bool(state.fresh)
        state, record = traced_run["jitted"](state, PARAMS, SPILL, ep, config=config)
        assert int(record.planned) == 0 or not was_fresh          # fresh candidates are reused, not planned
        planned += int(record.planned)
        candidates = state.candidates
        exists = np.asarray(candidates.exists)
        set_aside_held += _assert_no_free_candidate_is_set_aside(state)
        _, overlap = assign.footprint_relations(candidates.tasks.footprint, candidates.usable, state.owner)
        pairs = exists[:, None] & exists[None]
        np.testing.assert_array_equal(np.asarray(candidates.overlap) & pairs, np.asarray(overlap) & pairs)
        if not np.any(np.asarray(record.ended)) or not exists.any():
            continue
        dropped += int(np.sum(cached & ~exists))
        fresh = again(state.scene, state.fabric, candidates.tasks.source)
        fresh = fresh._replace(footprint=assign.pack_bits(fresh.footprint))
        for name in ("route", "mode", "code", "predicted", "steps", "footprint"):
            _same_tasks(name, jax.tree.map(lambda a: a[exists], getattr(candidates.tasks, name)),
                        jax.tree.map(lambda a: a[exists], getattr(fresh, name)))
        kept += int(exists.sum())
    assert kept > 0 and dropped > 0 and planned > 0 and set_aside_held > 0


def _assert_no_free_candidate_is_set_aside(state) -> int:
    """No candidate whose footprint is free is a source set aside, and every entry that holds names a
    rover on a task; returns the entries that hold."""
    from jaxplan.fleet import set_aside

    rovers, candidates = state.rovers, state.candidates
    holds = np.asarray(set_aside.holding(state.aside, rovers.phase, rovers.task_step))
    held = set(np.asarray(state.aside.cells)[holds].tolist())
    source = np.asarray(candidates.tasks.source)
    free = np.asarray(candidates.usable & candidates.clear)
    assert not held & set((source[free, 0] * state.owner.shape[1] + source[free, 1]).tolist())
    assert np.all(np.asarray(rovers.phase)[np.asarray(state.aside.rover)[holds]] != IDLE)
    return int(holds.sum())


def _same_tasks(name, got, want):
    """The same tasks: equal routes, modes, codes, steps and footprints; the predicted mass, summed by
    XLA in another batch, within a unit in its last place or two."""
    if name == "predicted":
        chex.assert_trees_all_close(got, want, rtol=1e-6)
    else:
        chex.assert_trees_all_equal(got, want)


def test_candidates_equal_tasks_planned_alone_and_plan_only_what_is_wanted():
    """``plan_candidates`` (chunked, each source's connector DP on its anchor's window) gives each
    source the task ``plan_task`` plans alone; with ``wanted`` = k only the first k slots are planned."""
    from jaxplan import build_fabric
    from jaxplan.fleet import assign
    from jaxplan.transport import execute, spillage

    scene = site(1, SITES[3], "two_targets")
    scene = scene.with_obj(execute.quantize(scene.obj))
    ep, cap, m = EpisodeParams(), 64, 10
    fabric = build_fabric(scene, PARAMS)
    owner = np.full(SITES[3], -1, np.int32)
    # one program plans afresh (previous None) for any owner map and wanted count, one reuses previous ones
    plan = jax.jit(lambda owner, wanted, previous: assign.plan_candidates(
        scene, PARAMS, ep, SPILL, fabric, owner, candidates=m, cap=cap, evaluator=spillage.curvature_spill,
        clearance=0, wanted=wanted, previous=previous))
    full, part = plan(owner, jnp.int32(m), None), plan(owner, jnp.int32(3), None)
    alone = jax.jit(jax.vmap(lambda s: assign.plan_task(scene, PARAMS, ep, SPILL, fabric, s, True, cap,
                                                         spillage.curvature_spill, 0)))(full.tasks.source)
    alone = alone._replace(footprint=assign.pack_bits(alone.footprint))      # candidates keep them packed
    exists = np.asarray(full.exists)
    assert exists.sum() > 3 and len(set(map(tuple, np.asarray(full.tasks.source)[exists].tolist()))) == exists.sum()
    for name in ("route", "mode", "code", "predicted", "steps", "footprint"):
        _same_tasks(name, jax.tree.map(lambda a: a[exists], getattr(full.tasks, name)),
                    jax.tree.map(lambda a: a[exists], getattr(alone, name)))
        _same_tasks(name, jax.tree.map(lambda a: a[:3], getattr(part.tasks, name)),
                    jax.tree.map(lambda a: a[:3], getattr(full.tasks, name)))
    assert np.array_equal(np.asarray(part.exists), exists & (np.arange(m) < 3))
    # the empty candidates a reset starts from are built without planning, in the planned ones' shapes
    shapes = lambda tree: jax.tree.map(lambda a: (a.shape, a.dtype), tree)   # noqa: E731
    assert shapes(assign.no_candidates(m, scene.shape, PARAMS.k, cap)) == shapes(full)
    # a footprint reserved: planning again with the previous candidates keeps their sources' tasks and
    # plans only the new ones, and gives what planning them all gives
    taken = np.asarray(assign.unpack_bits(full.tasks.footprint[0], scene.shape))
    reserved = np.where(taken, 0, owner).astype(np.int32)
    fresh, kept = plan(reserved, jnp.int32(m), None), plan(reserved, jnp.int32(m), full)
    now = np.asarray(fresh.exists)
    assert np.array_equal(np.asarray(kept.exists), now) and now.sum() > 3
    assert set(map(tuple, np.asarray(fresh.tasks.source)[now].tolist())) & \
        set(map(tuple, np.asarray(full.tasks.source)[exists].tolist()))          # some sources are kept
    for name in ("source", "route", "mode", "code", "predicted", "steps", "footprint"):
        _same_tasks(name, jax.tree.map(lambda a: a[now], getattr(kept.tasks, name)),
                    jax.tree.map(lambda a: a[now], getattr(fresh.tasks, name)))
    for name in ("usable", "clear", "overlap"):
        np.testing.assert_array_equal(np.asarray(getattr(kept, name)), np.asarray(getattr(fresh, name)))


@pytest.fixture(scope="module")
def piles_run():
    """Two coordinated rovers on a 12 x 12 site with piles, six pushes, the fabric rebuilt in full: the
    run the selective refresh and the short walk first are compared with (one compiled program, one run)."""
    ep = EpisodeParams(max_pushes=6, rebuild="full")
    return run_fleet(site(2, SITES[2], "piles"), 2, "coordinated", PARAMS, SPILL, ep, max_steps=300)


def _assert_same_run(got, want):
    np.testing.assert_array_equal(got.pos, want.pos)
    np.testing.assert_array_equal(got.delivered, want.delivered)
    np.testing.assert_array_equal(np.asarray(got.final_scene.obj), np.asarray(want.final_scene.obj))


def test_the_selective_refresh_gives_the_full_refresh_run(piles_run):
    """``EpisodeParams.rebuild="selective"`` updates the shared fabric selectively after each push: the
    same run as the full build, step by step, with the same compiled step (the host refreshes)."""
    compiled = fleet_run._advance_jit._cache_size()
    selective = run_fleet(site(2, SITES[2], "piles"), 2, "coordinated", PARAMS, SPILL,
                          EpisodeParams(max_pushes=6, rebuild="selective"), max_steps=300)
    assert fleet_run._advance_jit._cache_size() == compiled
    assert len(piles_run.pushes) > 2
    _assert_same_run(selective, piles_run)


def test_a_fleet_with_a_short_walk_first_runs_as_with_the_whole_cap(piles_run):
    """The same run, step by step, when tasks are planned with a walk of 3 first and pushes whose
    routes end within 2 (3 + 1) = 8 rows are applied on those rows only: some of its pushes are, some
    are not (``FleetConfig.short_cap``; tests/fleet/test_short_cap.py tests the planning itself). Here,
    not in that module, so that the whole-cap run is ``piles_run``: its program is compiled once."""
    assert FleetConfig(2, short_cap=None) == FleetConfig(2, "coordinated")      # piles_run's: the whole cap's
    short = run_fleet(site(2, SITES[2], "piles"), 2, "coordinated", PARAMS, SPILL,
                      EpisodeParams(max_pushes=6, rebuild="full"), max_steps=300, config=FleetConfig(2, short_cap=3))
    lengths = [len(p["cells"]) for p in short.pushes]
    assert min(lengths) < 8 <= max(lengths), lengths
    _assert_same_run(short, piles_run)
    assert [p["delivered"] for p in piles_run.pushes] == [p["delivered"] for p in short.pushes]
    assert short.conflicts == 0
