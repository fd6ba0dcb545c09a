"""The vectorised motion and assignment kernels equal their serial references
(``jaxplan.reference.fleet``): BFS distance fields (full and stopped early), the stale-field update,
the prioritised one-step move, the greedy choice."""
from __future__ import annotations

import collections
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan.fleet import assign, footprint, motion
from jaxplan.fleet.conflicts import conflicts
from jaxplan.reference import fleet as ref
from jaxplan.reference.visibility import DIRS
from jaxplan.transport import corner_free, execute

from ._sites import owner_map

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
SHAPE = (10, 12)
N = 5          # rovers
M = 6          # greedy candidates
C = 12         # core cells per candidate

_fields = jax.jit(motion.distance_fields)
_field_to = jax.jit(motion.distance_field_to)
_update = jax.jit(motion.update_fields, static_argnames="chunk")
_move = jax.jit(motion.move_rovers)


@functools.partial(jax.jit, static_argnames="chunk")
def _update_by_function(dist, goals, passable, pos, stale, chunk):
    return motion.update_fields(dist, goals, lambda row: passable[row], pos, stale, chunk=chunk)


def _distinct_cells(rng, n):
    flat = rng.choice(SHAPE[0] * SHAPE[1], n, replace=False)
    return np.stack([flat // SHAPE[1], flat % SHAPE[1]], -1).astype(np.int32)


def _owner_map(rng):
    return owner_map(rng, SHAPE, N)


@SETTINGS
@given(seed=st.integers(0, 2 ** 31 - 1), density=st.sampled_from((0.5, 0.7, 0.9, 1.0)))
def test_distance_fields_equal_breadth_first_search(seed, density):
    rng = np.random.default_rng(seed)
    passable = rng.random((N,) + SHAPE) < density
    goals = _distinct_cells(rng, N)
    if rng.random() < 0.5:
        passable[0, goals[0, 0], goals[0, 1]] = False     # an impassable goal: FAR everywhere
    got = np.asarray(_fields(jnp.asarray(goals), jnp.asarray(passable)))
    for r in range(N):
        np.testing.assert_array_equal(got[r], ref.distance_field(goals[r], passable[r]))


@SETTINGS
@given(seed=st.integers(0, 2 ** 31 - 1), density=st.sampled_from((0.1, 0.25)))
def test_fields_around_blocked_cells_cut_no_corner(seed, density):
    rng = np.random.default_rng(seed)
    blocked = rng.random(SHAPE) < density
    goal, stop = _distinct_cells(rng, 2)
    blocked[goal[0], goal[1]] = blocked[stop[0], stop[1]] = False
    corner = corner_free(jnp.asarray(blocked))
    got = np.asarray(jax.jit(motion.distance_field)(jnp.asarray(goal), jnp.asarray(~blocked), corner))
    np.testing.assert_array_equal(got, ref.distance_field(goal, ~blocked, blocked=blocked))
    got_to = np.asarray(_field_to(jnp.asarray(goal), jnp.asarray(~blocked), jnp.asarray(stop), corner))
    np.testing.assert_array_equal(got_to, ref.distance_field_to(goal, ~blocked, stop, blocked))


def _field_case(rng, density):
    """A random mask, goal and stop cell; sometimes the goal is blocked, or the stop cell is the goal
    or blocked (then unreachable)."""
    passable = rng.random(SHAPE) < density
    goal, stop = _distinct_cells(rng, 2)
    kind = rng.integers(0, 6)
    if kind == 0:
        passable[goal[0], goal[1]] = False
    elif kind == 1:
        stop = goal.copy()
    elif kind == 2:
        passable[stop[0], stop[1]] = False
    return passable, goal, stop


def _assert_exact_up_to_stop(got, goal, passable, stop):
    """``got`` is the early-stopped field: the serial reference's, so exact at distance <= d(stop),
    FAR or exact beyond, and the full field when ``stop`` cannot reach the goal."""
    np.testing.assert_array_equal(got, ref.distance_field_to(goal, passable, stop))
    full = ref.distance_field(goal, passable)
    d_stop = full[stop[0], stop[1]]
    near = full <= d_stop
    np.testing.assert_array_equal(got[near], full[near])
    assert np.all((got == full) | (got == motion.FAR))
    if d_stop >= motion.FAR:
        np.testing.assert_array_equal(got, full)


@SETTINGS
@given(seed=st.integers(0, 2 ** 31 - 1), density=st.sampled_from((0.5, 0.7, 0.9, 1.0)))
def test_early_stopped_field_is_exact_up_to_the_stop_cell(seed, density):
    rng = np.random.default_rng(seed)
    passable, goal, stop = _field_case(rng, density)
    got = np.asarray(_field_to(jnp.asarray(goal), jnp.asarray(passable), jnp.asarray(stop)))
    _assert_exact_up_to_stop(got, goal, passable, stop)


@SETTINGS
@given(seed=st.integers(0, 2 ** 31 - 1), density=st.sampled_from((0.5, 0.7, 0.9, 1.0)),
       stale_kind=st.sampled_from(("some", "all", "none")), chunk=st.sampled_from((2, 8)),
       by_function=st.booleans())
def test_update_fields_recomputes_the_stale_rows_only(seed, density, stale_kind, chunk, by_function):
    """N = 5 rovers: chunk 2 runs up to three chunks (the last one filled up), chunk 8 one; the
    passable masks given as an array or as a function of the row."""
    rng = np.random.default_rng(seed)
    cases = [_field_case(rng, density) for _ in range(N)]
    passable = np.stack([c[0] for c in cases])
    goals = np.stack([c[1] for c in cases]).astype(np.int32)
    pos = np.stack([c[2] for c in cases]).astype(np.int32)
    stale = {"some": rng.random(N) < 0.5, "all": np.ones(N, bool), "none": np.zeros(N, bool)}[stale_kind]
    dist = rng.integers(0, motion.FAR + 1, (N,) + SHAPE, dtype=np.int32)    # old rows: anything
    args = [jnp.asarray(a) for a in (dist, goals, passable, pos, stale)]
    if by_function:
        got = _update_by_function(*args, chunk=chunk)
    else:
        got = _update(*args, chunk=chunk)
    got = np.asarray(got)
    for r in range(N):
        if stale[r]:
            _assert_exact_up_to_stop(got[r], goals[r], passable[r], pos[r])
        else:
            np.testing.assert_array_equal(got[r], dist[r])


@SETTINGS
@given(seed=st.integers(0, 2 ** 31 - 1), density=st.sampled_from((0.6, 0.8, 1.0)))
def test_strictly_decreasing_walk_in_the_early_stopped_field_reaches_the_goal(seed, density):
    """Any walk through strictly smaller neighbours (here a random one) from the stop cell reaches
    the goal in exactly its distance, as the move rule needs."""
    rng = np.random.default_rng(seed)
    passable, goal, stop = _field_case(rng, density)
    field = np.asarray(_field_to(jnp.asarray(goal), jnp.asarray(passable), jnp.asarray(stop)))
    d_stop = ref.distance_field(goal, passable)[stop[0], stop[1]]
    here, steps = (int(stop[0]), int(stop[1])), 0
    while field[here] > 0 and field[here] < motion.FAR:
        closer = [q for q in ((here[0] + dr, here[1] + dc) for dr, dc in DIRS)
                  if 0 <= q[0] < SHAPE[0] and 0 <= q[1] < SHAPE[1] and field[q] < field[here]]
        assert closer, "stuck: no strictly smaller neighbour"
        here = closer[rng.integers(0, len(closer))]
        assert passable[here]
        steps += 1
    if d_stop >= motion.FAR:
        assert field[here] == motion.FAR and steps == 0
    else:
        assert here == (int(goal[0]), int(goal[1])) and steps == d_stop


def _chebyshev(goal):
    rows, cols = np.indices(SHAPE)
    return np.maximum(np.abs(rows - goal[0]), np.abs(cols - goal[1]))


@SETTINGS
@given(seed=st.integers(0, 2 ** 31 - 1))
def test_one_step_equals_the_serial_move_rule(seed):
    """Rovers with a pool field (a breadth-first field over their passable cells) and rovers driving
    by the Chebyshev distance, around footprints and, half the time, blocked cells."""
    rng = np.random.default_rng(seed)
    pos = _distinct_cells(rng, N)
    phase = rng.integers(0, 3, N).astype(np.int32)
    owner = _owner_map(rng)
    goals = _distinct_cells(rng, N)
    step = rng.integers(-1, 2, (N, 2))
    push_next = np.clip(pos + step, 0, np.asarray(SHAPE) - 1).astype(np.int32)
    blocked = (rng.random(SHAPE) < 0.15) & (owner < 0) if rng.random() < 0.5 else None
    free = np.ones(SHAPE, bool)
    if blocked is not None:
        blocked[pos[:, 0], pos[:, 1]] = False
        free = ~blocked
    slots = 3
    slot = np.full(N, -1, np.int32)
    holders = rng.choice(N, rng.integers(0, slots + 1), replace=False)
    slot[holders] = np.arange(len(holders))
    pool = np.full((slots,) + SHAPE, motion.FAR, np.int32)
    for r in range(N):
        if slot[r] >= 0:
            pool[slot[r]] = ref.distance_field(goals[r], ((owner < 0) | (owner == r)) & free, blocked=blocked)
    dist = np.stack([pool[slot[r]] if slot[r] >= 0 else _chebyshev(goals[r]) for r in range(N)]).astype(np.int32)
    corner = None if blocked is None else corner_free(jnp.asarray(blocked))
    got_pos, got_moved = _move(*(jnp.asarray(a) for a in (pos, phase, goals, slot, pool, owner, push_next)),
                               None if blocked is None else jnp.asarray(blocked), corner)
    want_pos, want_moved = ref.move_rovers(pos, phase, dist, owner, push_next, blocked)
    np.testing.assert_array_equal(np.asarray(got_pos), want_pos)
    np.testing.assert_array_equal(np.asarray(got_moved), want_moved)
    after = np.asarray(got_pos)
    assert len({tuple(p) for p in after.tolist()}) == N                    # never two in one cell
    assert not conflicts(np.stack([pos, after]), [])                   # nor a swap or a jump
    if blocked is not None:
        assert not blocked[after[:, 0], after[:, 1]].any()


def _tasks(rng, clearance):
    """M synthetic candidates: footprints grown from a random walk of C cells (some invalid; the first
    few the path), scores."""
    h, w = SHAPE
    core = np.zeros((M, C, 2), np.int32)
    for c in range(M):
        cell = np.asarray([rng.integers(0, h), rng.integers(0, w)])
        for k in range(C):
            core[c, k] = cell
            cell = np.clip(cell + rng.integers(-1, 2, 2), 0, [h - 1, w - 1])
    valid = np.arange(C)[None] < rng.integers(1, C + 1, M)[:, None]
    on_path = np.arange(C)[None] < rng.integers(1, C + 1, M)[:, None]
    predicted = np.round(rng.uniform(0.5, 20.0, M), 3).astype(np.float32)
    steps = rng.integers(1, 10, M).astype(np.int32)
    route = execute.Route(jnp.zeros((M, 1, 2), jnp.int32), jnp.ones(M, jnp.int32), jnp.zeros(M, bool),
                          jnp.zeros((M, 2)))
    zeros = jnp.zeros(M, jnp.int32)
    masks = jax.vmap(lambda *core: footprint.mask_from_core(jnp.asarray(TARGET), *core, clearance))(
        jnp.asarray(core), jnp.asarray(valid), jnp.asarray(on_path))
    return assign.Task(jnp.asarray(core[:, 0]), route, zeros, zeros, jnp.asarray(predicted), jnp.asarray(steps),
                       masks)


TARGET = np.zeros(SHAPE, bool)
TARGET[3:6, 4:8] = True          # target cells: in a footprint only where its path runs


def _footprint_set(task, c):
    return {tuple(p) for p in np.argwhere(np.asarray(task.footprint[c])).tolist()}


_greedy = jax.jit(assign.greedy_choice)


@pytest.mark.parametrize("shape", [(10, 12), (7, 5), (4, 8)])
def test_packed_masks_unpack_to_themselves(shape):
    """32 cells a word, the last word padded: unpacked and read cell by cell, the same masks."""
    rng = np.random.default_rng(shape[0])
    masks = rng.random((3,) + shape) < 0.4
    words = assign.pack_bits(jnp.asarray(masks))
    assert words.shape == (3, -(-shape[0] * shape[1] // 32)) and words.dtype == jnp.uint32
    flat = jnp.arange(shape[0] * shape[1])
    for k in range(3):
        np.testing.assert_array_equal(np.asarray(assign.unpack_bits(words[k], shape)), masks[k])
        np.testing.assert_array_equal(np.asarray(assign.bits_at(words[k], flat)), masks[k].reshape(-1))


@SETTINGS
@given(seed=st.integers(0, 2 ** 31 - 1), clearance=st.sampled_from(footprint.CLEARANCES))
def test_greedy_choice_equals_the_serial_greedy(seed, clearance):
    rng = np.random.default_rng(seed)
    tasks = _tasks(rng, clearance)
    pos = _distinct_cells(rng, N)
    idle = rng.random(N) < 0.7
    usable = rng.random(M) < 0.8
    owner = np.where(rng.random() < 0.5, _owner_map(rng), -1).astype(np.int32)
    budget = int(rng.integers(0, N + 1))
    packed = tasks._replace(footprint=assign.pack_bits(tasks.footprint))       # as the candidates hold them
    relations = assign.footprint_relations(packed.footprint, jnp.asarray(usable), jnp.asarray(owner))
    choice, new_owner, count = _greedy(jnp.asarray(pos), jnp.asarray(idle), jnp.asarray(owner), jnp.int32(budget),
                                       jnp.asarray(usable), packed, relations)
    footprints = [_footprint_set(tasks, c) for c in range(M)]
    reserved = {tuple(p) for p in np.argwhere(owner >= 0).tolist()}
    want = ref.greedy_assign(idle, pos, np.asarray(tasks.source), np.asarray(tasks.steps),
                             np.asarray(tasks.predicted), usable, footprints, reserved)[:budget]
    choice = np.asarray(choice)
    assert {(r, int(choice[r])) for r in range(N) if choice[r] >= 0} == set(want)
    assert int(count) == len(want)
    new_owner = np.asarray(new_owner)
    for r, c in want:                                       # each chosen footprint reserved for its rover
        assert all(new_owner[p] == r for p in footprints[c])
    assert np.array_equal(new_owner[owner >= 0], owner[owner >= 0])


def test_the_checker_finds_every_kind_of_violation():
    pos = np.array([[[0, 0], [5, 5]], [[1, 1], [5, 5]], [[2, 2], [4, 4]], [[4, 4], [2, 2]], [[3, 3], [3, 3]]])
    found = conflicts(pos, [(1, 1, 2, [(2, 2), (3, 3)]), (0, 2, 3, [(3, 3)])])
    assert {(t, kind) for t, kind, _ in found} == {(2, "overlap"), (2, "footprint"), (3, "jump"), (3, "swap"),
                                                   (4, "same cell")}
    assert conflicts(pos[:2], [(1, 0, 1, [(5, 5)])]) == []        # a rover in its own footprint is fine


_rate = jax.jit(assign.rate_sources, static_argnums=4, static_argnames=("block", "blocks"))
_RateFields = collections.namedtuple("_RateFields", "value length occupied")   # what rate_sources reads


@SETTINGS
@given(seed=st.integers(0, 2 ** 31 - 1), m=st.integers(1, 2 * N + 2), tiles=st.sampled_from([(None, 4), (2, 1),
                                                                                            (3, 2), (4, 1)]))
def test_rate_sources_equal_the_serial_ranking(seed, m, tiles):
    """Over the whole grid, and by tiles (2 x 2 to 4 x 4 cells, one or two scored per rover before the
    check, which falls back to ``RATE_WIDEN`` times as many tiles, then to the grid): the serial
    ranking."""
    rng = np.random.default_rng(seed)
    occupied = rng.random(SHAPE) < 0.4
    value = np.where(occupied, rng.integers(1, 40, SHAPE), 0).astype(np.float32)      # ties happen
    length = np.where(occupied, rng.integers(1, 20, SHAPE), 0).astype(np.float32)
    owner = np.where(rng.random() < 0.5, _owner_map(rng), -1).astype(np.int32)
    pos = _distinct_cells(rng, N)
    idle = rng.random(N) < 0.7

    fabric = _RateFields(jnp.asarray(value), jnp.asarray(length), jnp.asarray(occupied))
    block, blocks = tiles
    flat, ok = _rate(fabric, jnp.asarray(owner), jnp.asarray(pos), jnp.asarray(idle), m, 1.0, block=block,
                     blocks=blocks)
    want = ref.rate_sources(value, length, occupied, owner, pos, idle, m, 1.0)
    assert np.asarray(flat)[np.asarray(ok)].tolist() == want
    assert not np.any(np.asarray(ok)[len(want):])
