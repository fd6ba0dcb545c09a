"""Making way (``jaxplan.fleet.make_way``): the kernel equals its serial reference on random inputs,
and in a fleet two rovers parked in the only task's footprint leave it, so the task is pushed."""
from __future__ import annotations

import collections

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan import FabricParams, SpillParams, random_scene
from jaxplan.fleet import FleetConfig, make_way, run_fleet, summary_of
from jaxplan.fleet.assign import Candidates, pack_bits
from jaxplan.reference import fleet as ref
from jaxplan.transport import EpisodeParams

SHAPE = (9, 11)
N, M = 6, 5
_Tasks = collections.namedtuple("_Tasks", "footprint predicted steps")      # what make_way reads of a Task
_Scene = collections.namedtuple("_Scene", "blocked target_mask obj")


def _inputs(rng):
    cells = rng.choice(SHAPE[0] * SHAPE[1], 2 * N, replace=False)
    pos = np.stack(np.unravel_index(cells[:N], SHAPE), -1).astype(np.int32)
    parked = rng.random(N) < 0.7
    home = np.where(parked[:, None], pos, np.stack(np.unravel_index(cells[N:], SHAPE), -1)).astype(np.int32)
    footprints = np.zeros((M,) + SHAPE, bool)
    for c in range(M):                      # a rectangle, often over a rover
        r0, c0 = rng.integers(0, SHAPE[0] - 2), rng.integers(0, SHAPE[1] - 2)
        footprints[c, r0:r0 + rng.integers(2, 5), c0:c0 + rng.integers(2, 6)] = True
    owner = np.full(SHAPE, -1, np.int32)
    if rng.random() < 0.5:
        owner[rng.integers(SHAPE[0]), :rng.integers(1, SHAPE[1])] = 0
    blocked = rng.random(SHAPE) < 0.15
    target = np.zeros(SHAPE, bool)
    target[-2:, -3:] = True
    return dict(footprints=footprints, exists=rng.random(M) < 0.9, usable=rng.random(M) < 0.8,
                predicted=rng.integers(1, 30, M).astype(np.float32), steps=rng.integers(0, 12, M).astype(np.int32),
                owner=owner, pos=pos, home=home, parked=parked, wanted=bool(rng.random() < 0.9),
                blocked=blocked & ~target, target=target, obj=np.where(rng.random(SHAPE) < 0.4, 2.0, 0.0))


@jax.jit
def _kernel(footprints, exists, usable, predicted, steps, owner, pos, home, parked, wanted, blocked, target, obj):
    tasks = _Tasks(pack_bits(footprints), predicted, steps)
    planned = Candidates(tasks, exists, usable, jnp.ones_like(exists), jnp.zeros((M, M), bool), reads=None)
    return make_way.make_way(planned, owner, pos, home, parked, wanted, _Scene(blocked, target, obj))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2 ** 31 - 1))
def test_make_way_equals_the_serial_reference(seed):
    x = _inputs(np.random.default_rng(seed))
    home, moved = _kernel(**{k: jnp.asarray(v) for k, v in x.items()})
    sets = [{tuple(p) for p in np.argwhere(f).tolist()} for f in x["footprints"]]
    want_home, want_moved = ref.make_way(sets, *(x[k] for k in ("exists", "usable", "predicted", "steps", "owner",
                                                                "pos", "home", "parked", "wanted", "blocked",
                                                                "target", "obj")))
    np.testing.assert_array_equal(np.asarray(moved), want_moved)
    np.testing.assert_array_equal(np.asarray(home), want_home)
    homes = {tuple(h) for h in np.asarray(home).tolist()}
    assert len(homes) == N                                   # no two rovers share a home


def test_without_a_parked_rover_in_the_way_nobody_moves():
    x = _inputs(np.random.default_rng(3))
    x["parked"] = np.zeros(N, bool)
    home, moved = _kernel(**{k: jnp.asarray(v) for k, v in x.items()})
    assert not np.asarray(moved).any() and np.array_equal(np.asarray(home), x["home"])


def test_two_rovers_parked_in_the_only_task_leave_it_and_the_task_is_pushed():
    """Each of two rovers standing in a task's footprint keeps the other from taking it; without
    making way the fleet would stop at once with no reachable task."""
    base = random_scene(0, (12, 12), layout="piles")            # its target: rows 0-2, columns 3-6
    obj = np.zeros(base.shape, np.float32)
    obj[9, 9] = 6.0                                             # one source, far from the target
    scene = base.with_obj(obj)
    params, spill, ep = FabricParams(), SpillParams(), EpisodeParams(max_pushes=1)
    config = FleetConfig(2, "coordinated", clearance=1)      # the source's neighbours are in its footprint
    inside = [(8, 9), (9, 8)]
    run = run_fleet(scene, 2, "coordinated", params, spill, ep, max_steps=200, starts=np.asarray(inside),
                    config=config)
    s = summary_of(run)
    assert s["made_way"] >= 1 and s["pushes"] == 1 and s["conflicts"] == 0 and run.kernel_conflicts == 0
    assert s["stop_reason"] == "done"                                      # the only source pushed
