"""The pure episode (``reset``, ``step``, ``rollout``): scanned and vmapped episodes equal the host loop.

Mass identity checked at every step (``execute``'s bookkeeping): a push conserves the grid's total
count (``StepRecord.mass == initial_mass``), splits what it collects into delivered and spilled
(``collected == push_delivered + push_spilled``), and spills land outside the target while the
delivered load lands inside it, so the mass outside the target drops by exactly what was delivered
(``remaining_before - remaining_after == push_delivered``, hence ``remaining + delivered ==
initial_remaining``). Counts are multiples of ``execute.QUANTUM``, so these sums are exact in float32
up to the rounding of the totals; the tolerances below are loose float ones.
"""
from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan import FabricParams, SpillParams, random_scene, run_episode
from jaxplan.transport.episode import (
    BUDGET,
    RUNNING,
    STOP_REASONS,
    EpisodeParams,
    EpisodeState,
    StepRecord,
    default_walk_cap,
    reset,
    rollout,
    step,
)

SHAPE = (24, 24)
N_SCENES = 8
MAX_PUSHES = 30
N_STEPS = MAX_PUSHES + 2          # two steps past the budget: they must be no-ops
PARAMS = FabricParams()
SPILL = SpillParams(lam=0.1)
# stop_fraction is traced, so the batch runs each member with its own; the large ones end "done"
FRACTIONS = (0.02, 0.9, 0.02, 0.8, 0.02, 0.02, 0.95, 0.02)


def _episode(fraction) -> EpisodeParams:
    return EpisodeParams(max_pushes=MAX_PUSHES, rebuild="full", stop_fraction=fraction)


def _stack(trees):
    return jax.tree.map(lambda *xs: jnp.stack(xs), *trees)


@pytest.fixture(scope="module")
def scenes():
    return [random_scene(seed, SHAPE, 0.4) for seed in range(N_SCENES)]


@pytest.fixture(scope="module")
def batch(scenes):
    """``(initial states, final states, records [B, N_STEPS])`` of one jitted vmap of reset + rollout."""
    def one(scene, episode):
        start = reset(scene, PARAMS, SPILL, episode)
        final, records = rollout(start, PARAMS, SPILL, episode, N_STEPS)
        return start, final, records

    episodes = _stack([_episode(f) for f in FRACTIONS])
    return jax.device_get(jax.jit(jax.vmap(one))(_stack(scenes), episodes))


@pytest.fixture(scope="module")
def host(scenes):
    return [run_episode(s, PARAMS, SPILL, _episode(f)) for s, f in zip(scenes, FRACTIONS)]


def test_scanned_vmapped_episodes_equal_the_host_loop(batch, host):
    _, final, rec = batch
    assert {e.stop_reason for e in host} >= {"done", "budget"}   # both kinds of end are covered
    for b, ep in enumerate(host):
        n = ep.n_pushes
        valid = rec.valid[b]
        assert valid[:n].all() and not valid[n:].any()
        np.testing.assert_array_equal(rec.push[b, :n], ep.pushes)
        np.testing.assert_array_equal(rec.source[b, :n], ep.source)
        np.testing.assert_array_equal(rec.mode[b, :n], ep.mode)
        for col in ("collected", "push_delivered", "push_spilled", "route_length", "remaining"):
            np.testing.assert_allclose(getattr(rec, col)[b, :n], getattr(ep, col), rtol=1e-5, atol=1e-4, err_msg=col)
        np.testing.assert_allclose(rec.delivered[b, :n], ep.delivered, rtol=1e-5, atol=1e-3)
        np.testing.assert_allclose(rec.spilled[b, :n], ep.spilled, rtol=1e-5, atol=1e-3)
        np.testing.assert_allclose(rec.driven[b, :n], ep.driven, rtol=1e-5, atol=1e-3)
        assert STOP_REASONS[int(final.stop[b])] == ep.stop_reason and int(final.tick[b]) == n
        assert bool(final.done[b])
        np.testing.assert_array_equal(final.scene.obj[b], ep.final_obj)
        assert float(final.initial_mass[b]) == pytest.approx(ep.initial_mass)
        assert float(final.initial_remaining[b]) == pytest.approx(ep.initial_remaining)


def test_mass_identity_holds_at_every_step(batch):
    start, final, rec = batch
    valid = rec.valid
    mass0 = start.initial_mass[:, None]
    # state in: the remaining mass before each step (the start, then each step's output)
    before = np.concatenate([start.remaining[:, None], rec.remaining[:, :-1]], 1)
    before = np.where(np.concatenate([np.ones((N_SCENES, 1), bool), valid[:, :-1]], 1), before, np.nan)
    np.testing.assert_allclose(np.where(valid, rec.mass, mass0), np.broadcast_to(mass0, valid.shape), rtol=1e-6)
    np.testing.assert_allclose(rec.collected, rec.push_delivered + rec.push_spilled, atol=1e-4)
    drop = np.where(valid, before - rec.remaining, 0.0)
    np.testing.assert_allclose(drop, np.where(valid, rec.push_delivered, 0.0), rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(np.where(valid, rec.remaining + rec.delivered, start.initial_remaining[:, None]),
                               np.broadcast_to(start.initial_remaining[:, None], valid.shape), rtol=1e-5)
    assert np.all(rec.push_spilled >= 0) and np.all(rec.push_delivered >= 0)
    # state out: the final counts
    np.testing.assert_allclose(final.scene.obj.sum((1, 2)), start.initial_mass, rtol=1e-6)
    np.testing.assert_allclose(final.remaining + final.delivered, start.initial_remaining, rtol=1e-5)
    target = start.scene.target_mask
    gained = np.where(target, final.scene.obj, 0).sum((1, 2)) - np.where(target, start.scene.obj, 0).sum((1, 2))
    np.testing.assert_allclose(gained, final.delivered, rtol=1e-5, atol=1e-3)


def test_records_after_the_end_are_invalid_and_finite(batch):
    _, final, rec = batch
    for leaf in jax.tree.leaves(rec):
        assert np.all(np.isfinite(np.asarray(leaf, np.float64)))
    for leaf in (final.scene.obj, final.rovers, final.delivered, final.spilled, final.remaining, final.driven):
        assert np.all(np.isfinite(leaf))
    assert np.all(np.where(rec.valid, True, (rec.source == -1).all(-1) & (rec.collected == 0) & (rec.push == 0)))


@pytest.fixture(scope="module")
def counted_step():
    """``step`` jitted behind ``chex.assert_max_traces``: a second trace (a recompile) fails."""
    return jax.jit(chex.assert_max_traces(step, n=1), static_argnames=("walk_cap", "evaluator"))


@pytest.fixture(scope="module")
def short_episode(scenes):
    return EpisodeParams(max_pushes=3, rebuild="full")


def test_jitted_and_eager_step_agree_without_recompiling(scenes, counted_step, short_episode):
    state = reset(scenes[0], PARAMS, SPILL, short_episode)
    assert isinstance(state, EpisodeState) and state.rovers.shape == (1, 2)
    assert state.rovers.dtype == jnp.float32 and not bool(state.done) and int(state.stop) == RUNNING
    eager_state = state
    for t in range(3):
        state, rec = counted_step(state, PARAMS, SPILL, short_episode)
        eager_state, eager_rec = step(eager_state, PARAMS, SPILL, short_episode)
        assert isinstance(rec, StepRecord) and bool(rec.valid) and int(rec.push) == t + 1
        chex.assert_trees_all_close(rec, eager_rec, rtol=1e-5, atol=1e-4)
        chex.assert_trees_all_close(state.scene.obj, eager_state.scene.obj, atol=1e-4)
        chex.assert_trees_all_equal(state.fabric.table.next_dir, eager_state.fabric.table.next_dir)
        for leaf in jax.tree.leaves(rec):
            assert np.all(np.isfinite(np.asarray(leaf, np.float64)))
    assert bool(state.done) and STOP_REASONS[int(state.stop)] == "budget" and int(state.stop) == BUDGET
    # the same shapes again, under another scene and margin (traced): no new trace
    other = reset(scenes[1], PARAMS, SPILL, short_episode.replace(rearrange_margin=0.5))
    counted_step(other, PARAMS, SPILL, short_episode.replace(rearrange_margin=0.5))


def test_a_finished_episode_step_is_a_no_op(scenes, counted_step, short_episode):
    state = reset(scenes[2], PARAMS, SPILL, short_episode)
    for _ in range(3):
        state, _ = counted_step(state, PARAMS, SPILL, short_episode)
    assert bool(state.done)
    after, rec = counted_step(state, PARAMS, SPILL, short_episode)
    chex.assert_trees_all_equal(after, state)
    assert not bool(rec.valid) and int(rec.push) == 0 and int(rec.stop) == int(state.stop)
    np.testing.assert_array_equal(rec.source, [-1, -1])


def test_no_material_is_done_at_reset(scenes):
    scene = scenes[0]
    empty = scene.with_obj(np.where(np.asarray(scene.target_mask), 3.0, 0.0).astype(np.float32))
    state = reset(empty, PARAMS, SPILL, EpisodeParams())
    assert bool(state.done) and STOP_REASONS[int(state.stop)] == "no_material"
    assert default_walk_cap(SHAPE) == 4 * (SHAPE[0] + SHAPE[1])
