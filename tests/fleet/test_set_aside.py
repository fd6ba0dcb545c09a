"""The set-aside list (``jaxplan.fleet.set_aside``): the rover a footprint or a source's fabric path
meets first equals the serial reference; entries hold while their rover runs the task they met; the
ring keeps the newest."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan import build_fabric
from jaxplan.fleet import assign, set_aside
from jaxplan.fleet.motion import APPROACH, IDLE, PUSH
from jaxplan.reference import fleet as ref

from ._sites import owner_map, site

SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
SHAPE = (9, 11)              # 99 cells: the last packed word is partly padding
N = 4                        # rovers

_blockers = jax.jit(set_aside.blockers)
_path_blockers = jax.jit(set_aside.path_blockers, static_argnums=5)


@SETTINGS
@given(seed=st.integers(0, 2 ** 31 - 1), density=st.sampled_from((0.02, 0.2, 0.6)))
def test_blockers_equal_the_serial_first_blocker(seed, density):
    rng = np.random.default_rng(seed)
    masks = rng.random((6,) + SHAPE) < density
    owner = owner_map(rng, SHAPE, N)
    got = np.asarray(_blockers(assign.pack_bits(jnp.asarray(masks)), jnp.asarray(owner)))
    np.testing.assert_array_equal(got, [ref.first_blocker(m, owner) for m in masks])


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2 ** 31 - 1), layout=st.sampled_from(("piles", "two_targets")))
def test_path_blockers_equal_the_serial_walk(seed, layout):
    scene = site(seed % 3, (12, 12), layout)
    fabric = build_fabric(scene)
    rng = np.random.default_rng(seed)
    owner = owner_map(rng, scene.shape, N)
    flat = rng.choice(scene.shape[0] * scene.shape[1], 8, replace=False).astype(np.int32)
    todo = rng.random(8) < 0.75
    got = np.asarray(_path_blockers(scene, fabric, jnp.asarray(owner), jnp.asarray(flat), jnp.asarray(todo), 200))
    table = fabric.table
    want = [ref.path_blocker(table.next_dir, table.next_rank, np.asarray(fabric.selected), owner,
                             divmod(int(f), scene.shape[1])) if do else -1 for f, do in zip(flat, todo)]
    np.testing.assert_array_equal(got, want)
    assert np.isfinite(np.asarray(fabric.value)).all()


def test_entries_hold_while_their_rover_runs_the_task_they_met():
    aside = set_aside.empty(4)
    task_step = jnp.asarray([3, 5, 0, 7], jnp.int32)
    cells = jnp.asarray([10, 20, 30], jnp.int32)
    aside = set_aside.add(aside, cells, jnp.asarray([1, 3, 0], jnp.int32), jnp.asarray([True, False, True]), task_step)
    np.testing.assert_array_equal(np.asarray(aside.cells), [10, 30, -1, -1])
    np.testing.assert_array_equal(np.asarray(aside.task), [5, 3, -1, -1])
    phase = jnp.asarray([PUSH, APPROACH, IDLE, PUSH], jnp.int32)
    np.testing.assert_array_equal(np.asarray(set_aside.holding(aside, phase, task_step)), [True, True, False, False])
    # rover 0 took another task, rover 1 went idle: neither entry holds
    later = jnp.asarray([9, 5, 0, 7], jnp.int32)
    np.testing.assert_array_equal(np.asarray(set_aside.holding(aside, phase.at[1].set(IDLE), later)), [False] * 4)
    mask = set_aside.withheld(aside, jnp.asarray([True, False, False, False]), SHAPE)
    assert np.flatnonzero(np.asarray(mask)).tolist() == [10]
    # the ring overwrites the oldest entries first
    aside = set_aside.add(aside, jnp.asarray([40, 50, 60], jnp.int32), jnp.asarray([3, 3, 3], jnp.int32),
                          jnp.ones(3, bool), task_step)
    np.testing.assert_array_equal(np.asarray(aside.cells), [60, 30, 40, 50])
    assert int(aside.next) == 1


def test_no_candidate_left_is_a_cleared_site_unless_sources_wait():
    """``assign.assign_planned`` with no candidate: the site is cleared, unless sources set aside wait
    for a running task; then the footprints are taken (``BLOCKED``)."""
    from jaxplan.transport import CLEARED, Route

    m, n, slots = 2, 3, 5

    def routes(k):
        return Route(cells=jnp.full((k, slots, 2), -1, jnp.int32), n_cells=jnp.ones(k, jnp.int32),
                     fallback=jnp.zeros(k, bool), end=jnp.zeros((k, 2), jnp.float32))

    tasks = assign.Task(source=jnp.zeros((m, 2), jnp.int32), route=routes(m), mode=jnp.zeros(m, jnp.int32),
                        code=jnp.full(m, CLEARED, jnp.int32), predicted=jnp.zeros(m, jnp.float32),
                        steps=jnp.ones(m, jnp.int32), footprint=jnp.zeros((m, 4), jnp.uint32))
    none = jnp.zeros(m, bool)
    planned = assign.Candidates(tasks, none, none, none, jnp.zeros((m, m), bool), reads=None)
    pos = jnp.asarray([[0, 0], [1, 1], [2, 2]], jnp.int32)

    def failure(waiting):
        return assign.assign_planned(planned, pos, jnp.ones(n, bool), jnp.full(SHAPE, -1, jnp.int32), jnp.int32(5),
                                     routes(n), waiting)[4]

    for run in (failure, jax.jit(failure)):
        assert int(run(jnp.bool_(False))) == CLEARED
        assert int(run(jnp.bool_(True))) == assign.BLOCKED
