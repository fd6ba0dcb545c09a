"""Eq. 6 applied to every source (``selection.reselect``): psi, headings and heat follow the selected
table entries; checked against plain serial walks of the table and the reference heatmap."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan import FabricParams, Scene, box, build_fabric
from jaxplan.reference.heatmap import heat_map, psi_map, table_path
from jaxplan.transport import fabric as fab_mod
from jaxplan.transport import selection
from jaxplan.transport import spillage as sp
from jaxplan.transport.episode import EpisodeParams
from jaxplan.transport.run import run_episode
from tests._scenes import scenes

SETTINGS = settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
PARAMS = FabricParams()


def _random_entries(fabric, rng):
    """A random used table entry for every occupied cell."""
    used = np.isfinite(np.asarray(fabric.table.raw))          # [H, W, K]
    n_used = used.sum(-1)
    return (rng.integers(0, 1 << 30, n_used.shape) % np.maximum(n_used, 1)).astype(np.int32)


_derive_jit = jax.jit(fab_mod.derive)


def _derive(scene, fabric, entry):
    return _derive_jit(scene, PARAMS, fabric.table, jnp.moveaxis(fabric.feasible, -1, 0), fabric.rounds,
                       fabric.converged, jnp.asarray(entry))


@SETTINGS
@given(scene=scenes(max_side=13), seed=st.integers(0, 2**31 - 1))
def test_psi_and_heat_of_any_entries_equal_serial_walks(scene, seed):
    fabric = build_fabric(scene, PARAMS)
    entry = _random_entries(fabric, np.random.default_rng(seed))
    got = _derive(scene, fabric, entry)

    occupied = np.asarray(fabric.occupied)
    table = jax.tree.map(np.asarray, fabric.table)
    paths = {src: table_path(table.next_dir, table.next_rank, src, entry[src])
             for src in map(tuple, np.argwhere(occupied))}
    phi = np.where(occupied, np.take_along_axis(table.raw, entry[..., None], -1)[..., 0], 0.0)
    want_psi = psi_map(paths, phi.astype(np.float64))
    np.testing.assert_allclose(np.asarray(got.psi), want_psi, rtol=1e-6, atol=1e-4)

    np.testing.assert_array_equal(np.asarray(got.selected), np.where(occupied, entry, 0))
    for src, cells in paths.items():   # u(C) is the second cell of the selected path (or the fallback hop)
        if len(cells) > 1:
            assert tuple(np.asarray(got.first_hop[src])) == cells[1]
    want_heat = heat_map(occupied, np.asarray(got.first_hop), np.asarray(got.heading, np.float64),
                         np.asarray(got.psi, np.float64), np.asarray(scene.target_mask), float(scene.cell_size))
    np.testing.assert_allclose(np.asarray(got.heat), want_heat, rtol=1e-5, atol=1e-4)


@pytest.fixture(scope="module")
def bend():
    """Material that reaches the target by a bend or by a straighter, slightly poorer route."""
    rng = np.random.default_rng(3)
    obj = np.where(rng.random((10, 10)) < 0.7, rng.integers(1, 5, (10, 10)), 0).astype(np.float32)
    return Scene.from_arrays(obj, box(7.0, 7.0, 10.0, 10.0), cell_size=1.0)


def _cap(fabric):
    return 1 + int(jnp.max(fab_mod.table_hops(fabric.table)))


def test_entry_zero_is_the_plain_fabric(bend):
    fabric = build_fabric(bend, PARAMS)
    again = _derive(bend, fabric, np.zeros(bend.shape, np.int32))
    off = selection.reselect(bend, PARAMS, fabric, sp.SpillParams(enabled=False), max_steps=_cap(fabric))
    for name in fabric._fields:
        for a, b, c in zip(jax.tree.leaves(getattr(fabric, name)), jax.tree.leaves(getattr(again, name)),
                           jax.tree.leaves(getattr(off, name))):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=name)
            np.testing.assert_array_equal(np.asarray(a), np.asarray(c), err_msg=name)


def test_reselect_uses_the_eq6_choice_of_every_source(bend):
    fabric = build_fabric(bend, PARAMS)
    spill = sp.SpillParams(lam=0.5, threshold=0.0)
    cap = _cap(fabric)
    eager = selection.reselect(bend, PARAMS, fabric, spill, max_steps=cap)     # compact pairs
    jitted = selection.reselect_jit(bend, PARAMS, fabric, spill, max_steps=cap)  # every cell, one program
    for a, b in zip(jax.tree.leaves(eager), jax.tree.leaves(jitted)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    sources = np.argwhere(np.asarray(fabric.occupied))
    sel = selection.select_routes_jit(bend, fabric, sources, PARAMS.slack_tau, spill, max_steps=cap)
    np.testing.assert_array_equal(np.asarray(jitted.selected)[tuple(sources.T)], np.asarray(sel.entry))
    assert np.any(np.asarray(jitted.selected) > 0), "the scene should make Eq. 6 differ from Eq. 5 somewhere"
    for name in ("psi", "heat", "heading", "highways", "first_hop"):
        assert np.all(np.isfinite(np.asarray(getattr(jitted, name), np.float64))), name
    np.testing.assert_array_equal(np.asarray(jitted.value), np.asarray(fabric.value))   # J stays entry 0


_select_every_cell_jit = jax.jit(selection.select_all, static_argnames=("max_steps", "evaluator"))


@SETTINGS
@given(scene=scenes(max_side=13), lam=st.sampled_from((0.05, 0.5, 2.0)), slack=st.sampled_from((0.0, 1.0, 3.0)),
       short_walk=st.booleans())
def test_compact_selection_equals_evaluating_every_cell(scene, lam, slack, short_walk):
    """Only sources with two or more candidates are evaluated, on a shorter walk; the entries are
    those of evaluating every cell's every entry (also when the caller's walk cuts routes short)."""
    fabric = build_fabric(scene, PARAMS)
    spill = sp.SpillParams(lam=lam, threshold=0.0)
    walk = 3 if short_walk else _cap(fabric)
    compact = selection.select_all(scene, fabric, slack, spill, max_steps=walk)
    every = _select_every_cell_jit(scene, fabric, slack, spill, max_steps=walk)
    np.testing.assert_array_equal(np.asarray(compact), np.asarray(every))
    # the premise of skipping them: a source with one candidate gets entry 0 when it is evaluated too
    single = np.sum(np.asarray(selection.candidate_mask(fabric.table.raw, slack)), -1) < 2
    assert np.all(np.asarray(every)[single] == 0)


def test_episode_with_reselect_conserves_mass_and_records_the_selected_fabric(bend):
    ep = run_episode(bend, PARAMS, sp.SpillParams(lam=0.3), EpisodeParams(reselect=True, max_pushes=6), record=True)
    n = ep.n_pushes
    assert n >= 1
    final, target = ep.final_obj, np.asarray(bend.target_mask)
    assert final.sum() == pytest.approx(ep.initial_mass, rel=1e-5)
    in_target0 = float(np.asarray(bend.obj)[target].sum())
    assert final[target].sum() - in_target0 == pytest.approx(ep.delivered[-1], rel=1e-5, abs=1e-3)
    assert np.all(np.isfinite(ep.plan_ms)) and len(ep.frames) == n


def test_bad_reselect_flag_names_the_field(bend):
    with pytest.raises(ValueError, match="EpisodeParams.reselect"):
        run_episode(bend, PARAMS, episode=EpisodeParams(reselect="yes"))
