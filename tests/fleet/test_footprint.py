"""A task's footprint holds every cell its push changes (``execute``'s real changes) and the cells
its rover drives on, and no other target cell; the push path is a chain of neighbouring cells from
the route's first cell to its last."""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan import FabricParams, SpillParams, build_fabric
from jaxplan.fleet import footprint
from jaxplan.transport import execute
from jaxplan.transport.episode import EpisodeParams, default_walk_cap
from jaxplan.transport.plan import plan_for_source
from tests.fleet._sites import LAYOUTS, site

SHAPE = (16, 16)
CAP = default_walk_cap(SHAPE)
SLOTS = 2 * (CAP + 1)
PARAMS = FabricParams()
SPILL = SpillParams(lam=0.3)      # a large spill: many spill cells
SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@functools.cache
def _site(seed: int, layout: str):
    scene = site(seed, SHAPE, layout)
    scene = scene.with_obj(execute.quantize(scene.obj))
    return scene, build_fabric(scene, PARAMS)


_plan = jax.jit(plan_for_source, static_argnames=("max_steps", "evaluator"))


@functools.partial(jax.jit, static_argnums=2)
def _observe(scene, route, clearance):
    _, push = execute.execute_push(scene, route, SPILL)
    mask = footprint.footprint_mask(scene, route, footprint.route_samples(scene, route, SPILL), clearance)
    k = jnp.arange(footprint.path_slots(SLOTS, SHAPE))
    path = jax.vmap(lambda i: footprint.path_cell(route, i))(k)
    return push.changed, mask, path, footprint.path_length(route)


def _check(scene, route):
    for clearance in footprint.CLEARANCES:
        _check_one(scene, route, clearance)
    if int(route.n_cells) > 1 or bool(route.fallback):     # a route with a spline to follow
        _check_body(scene, route)


def _check_body(scene, route):
    """The body footprint holds the clearance-1 footprint and every cell the physics rover's centre
    line passes over (``physics.route_footprint(swept=True)``, not grown), start pose included."""
    from jaxplan.fleet.physics import route_footprint

    body = np.asarray(_observe(scene, route, footprint.BODY)[1])
    one = np.asarray(_observe(scene, route, 1)[1])
    assert not np.any(one & ~body)
    swept = route_footprint(scene, route, 0, swept=True)
    assert not np.any(swept & ~body), np.argwhere(swept & ~body)


def _check_one(scene, route, clearance):
    changed, mask, path, n_path = (np.asarray(a) for a in _observe(scene, route, clearance))
    assert not np.any(changed & ~mask), (clearance, np.argwhere(changed & ~mask))
    n = int(route.n_cells)
    cells = np.asarray(route.cells)[:n]
    path = path[:int(n_path)]
    assert np.all(np.abs(np.diff(path, axis=0)).max(1, initial=0) <= 1)     # one cell per step
    assert tuple(path[0]) == tuple(cells[0]) and tuple(path[-1]) == tuple(cells[-1])
    assert {tuple(c) for c in cells} <= {tuple(c) for c in path}
    assert np.all(mask[path[:, 0], path[:, 1]])
    on_path = np.zeros(SHAPE, bool)
    on_path[path[:, 0], path[:, 1]] = True
    if clearance < footprint.BODY:      # target cells: only where it drives
        assert not np.any(mask & np.asarray(scene.target_mask) & ~on_path)


@SETTINGS
@given(seed=st.integers(0, 4), layout=st.sampled_from(LAYOUTS), pick=st.integers(0, 10 ** 6))
def test_planned_routes_change_only_their_footprint(seed, layout, pick):
    scene, fabric = _site(seed, layout)
    occupied = np.argwhere(np.asarray(fabric.occupied))
    source = jnp.asarray(occupied[pick % len(occupied)], jnp.int32)
    plan = _plan(scene, PARAMS, EpisodeParams(rearrange_margin=0.0), SPILL, fabric, source, max_steps=CAP)
    if bool(plan.complete):
        _check(scene, plan.route)


@st.composite
def _walks(draw):
    """Cells of a random route: a random walk, then maybe a jump (a straight fallback connector) and
    a second walk; sharp turns and revisits included."""
    h, w = SHAPE
    first = [draw(st.integers(0, h - 1)), draw(st.integers(0, w - 1))]
    steps = st.tuples(st.integers(-1, 1), st.integers(-1, 1)).filter(lambda d: d != (0, 0))
    cells = [first]
    for d in draw(st.lists(steps, min_size=0, max_size=8)):
        cells.append([min(max(cells[-1][0] + d[0], 0), h - 1), min(max(cells[-1][1] + d[1], 0), w - 1)])
        if cells[-1] == cells[-2]:
            cells.pop()
    if draw(st.booleans()):
        cells.append([draw(st.integers(0, h - 1)), draw(st.integers(0, w - 1))])
        for d in draw(st.lists(steps, min_size=0, max_size=5)):
            cells.append([min(max(cells[-1][0] + d[0], 0), h - 1), min(max(cells[-1][1] + d[1], 0), w - 1)])
            if cells[-1] == cells[-2]:
                cells.pop()
    dedup = [cells[0]] + [c for a, c in zip(cells, cells[1:]) if c != a]
    return np.asarray(dedup, np.int32)


@SETTINGS
@given(seed=st.integers(0, 4), layout=st.sampled_from(LAYOUTS), cells=_walks(), fallback=st.booleans())
def test_any_route_changes_only_its_footprint(seed, layout, cells, fallback):
    scene, _ = _site(seed, layout)
    buf = np.full((SLOTS, 2), -1, np.int32)
    buf[:len(cells)] = cells
    route = execute.route_from_path(scene, jnp.asarray(buf), jnp.int32(len(cells)), jnp.bool_(fallback))
    _check(scene, route)


def test_the_route_cells_dilated_by_one_are_not_enough():
    """Why clearance 1 grows the spline's cells: a U-turn beside a long jump spills two cells off the route."""
    scene, _ = _site(2, "uniform")
    cells = np.asarray([[9, 11], [10, 12], [10, 13], [11, 13], [10, 13], [10, 14], [1, 12], [2, 11]], np.int32)
    buf = np.full((SLOTS, 2), -1, np.int32)
    buf[:len(cells)] = cells
    route = execute.route_from_path(scene, jnp.asarray(buf), jnp.int32(len(cells)), jnp.bool_(True))
    changed, mask, path, n_path = (np.asarray(a) for a in _observe(scene, route, 1))
    near = np.zeros(SHAPE, bool)
    for r, c in path[:int(n_path)]:
        near[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2] = True
    assert np.any(changed & ~near) and not np.any(changed & ~mask)
