"""The spill data generator (experiments/spill_data.py): one scene's records, pushed in physics,
conserve mass and stay on the grid; the writer splits records by scene, counts them in its manifest
and leaves no partial file; the scene families are deterministic; bad arguments stop before any
work."""
import json

import numpy as np
import pytest

from experiments import spill_data


def test_one_scenes_records_conserve_mass_in_physics():
    scene = spill_data.family_scene("piles", 0.35, 0)
    records = spill_data.scene_records(scene, sources=2, entries=1, layouts=1)
    assert len(records) == 2
    for r in records:
        # the particles rasterised back to the grid, with what left the world, are the counts before
        np.testing.assert_allclose(r["obj_after"].sum() + r["lost"], r["obj_before"].sum(), rtol=1e-5)
        assert r["finite"] and r["collected"] >= r["delivered"] - 1e-4
        assert np.all((r["cells"] >= 0) & (r["cells"] < np.asarray(spill_data.SHAPE)))
        np.testing.assert_array_equal(r["obj_before"], np.asarray(scene.obj))


def _fake_records(scene, sources, entries, layouts, backend="auto", perturbed=0, planned=True):
    """Records shaped like ``scene_records``'s, without the physics (the writer is under test)."""
    obj = np.asarray(scene.obj, np.float32)
    return [{"obj_before": obj, "obj_after": obj, "cells": np.asarray([[1, 1], [1, 2], [2, 3]][: 2 + k % 2], np.int16),
             "source": np.asarray([1, 1], np.int32), "entry": k % entries, "perturbed": 0,
             "layout": k // (sources * entries),
             **dict.fromkeys(("collected", "delivered", "left_behind", "spilled", "lost", "predicted_delivered",
                              "predicted_spilled", "mean_lateral"), 1.0), "finite": True, "reached": True}
            for k in range(sources * entries * layouts)]


def test_the_writer_splits_by_scene_and_counts_in_its_manifest(tmp_path, monkeypatch):
    monkeypatch.setattr(spill_data, "scene_records", _fake_records)
    out = tmp_path / "quick"
    manifest = spill_data.main(["--quick", "--backend", "c", "--out", str(out)])
    assert manifest["arguments"]["backend"] == "c"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["quick.json", "quick.npz"]     # no partial file
    assert json.loads(out.with_suffix(".json").read_text()) == manifest
    data = dict(np.load(out.with_suffix(".npz")))
    heldout = data["scene_heldout"][data["scene"]]
    assert heldout.any() and (~heldout).any()
    counts = manifest["counts"]
    assert counts["heldout"]["records"] == int(heldout.sum()) and counts["train"]["records"] == int((~heldout).sum())
    assert list(data["scene_family"]) == list(spill_data.FAMILIES) * 2          # two seeds, one held out
    np.testing.assert_array_equal(data["scene_heldout"], [spill_data.is_heldout(s) for s in data["scene_seed"]])
    valid = np.arange(data["cells"].shape[1])[None] < data["n_cells"][:, None]
    assert np.all(data["cells"][~valid] == -1) and np.all(data["cells"][valid] >= 0)


def test_scene_families_are_deterministic():
    for family in spill_data.FAMILIES:
        a, b = spill_data.family_scene(family, 0.35, 3), spill_data.family_scene(family, 0.35, 3)
        np.testing.assert_array_equal(np.asarray(a.obj), np.asarray(b.obj))
        assert float(np.asarray(a.obj).sum()) > 0 and not np.asarray(a.obj)[np.asarray(a.target_mask)].any()


@pytest.mark.parametrize("argv", [["--layouts", "0"], ["--seeds", "-1"], ["--perturbed", "-1"], ["--only-perturbed"]])
def test_bad_arguments_exit_before_any_work(argv, tmp_path, capsys):
    with pytest.raises(SystemExit) as err:
        spill_data.main([*argv, "--out", str(tmp_path / "x")])
    assert err.value.code == 2 and "error:" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_perturbed_routes_are_walks_with_one_interior_cell_moved():
    scene = spill_data.family_scene("uniform", 0.35, 0)
    routes, src, rank, variant = spill_data.scene_routes(scene, sources=3, entries=1, perturbed=2)
    planned = np.flatnonzero(variant == 0)
    assert len(planned) == 3 and set(variant.tolist()) <= {0, 1, 2} and (variant > 0).any()
    free = ~(np.asarray(scene.blocked) | np.asarray(scene.target_mask))
    for j in np.flatnonzero(variant > 0):
        (i,) = [p for p in planned if (src[p] == src[j]).all() and rank[p] == rank[j]]
        n = int(routes.n_cells[j])
        assert n == int(routes.n_cells[i]) and bool(routes.fallback[j]) == bool(routes.fallback[i])
        a, b = routes.cells[i][:n], routes.cells[j][:n]
        moved = np.flatnonzero((a != b).any(-1))
        assert len(moved) == 1 and 0 < moved[0] < n - 1                     # one interior cell, ends kept
        assert np.abs(np.diff(b, axis=0)).max() <= 1                          # still an 8-connected walk
        assert free[tuple(b[moved[0]])] and len({tuple(c) for c in b.tolist()}) == n


def test_only_perturbed_keeps_the_same_perturbations_without_the_planned_routes():
    scene = spill_data.family_scene("uniform", 0.35, 0)
    both = spill_data.scene_routes(scene, sources=3, entries=1, perturbed=1)
    only = spill_data.scene_routes(scene, sources=3, entries=1, perturbed=1, planned=False)
    moved = both[3] > 0
    assert (only[3] == 1).all() and len(only[3]) == int(moved.sum()) > 0
    np.testing.assert_array_equal(only[0].cells, both[0].cells[moved])
    np.testing.assert_array_equal(only[1], both[1][moved])


def test_perturb_route_gives_up_where_nothing_can_move():
    scene = spill_data.family_scene("uniform", 0.35, 0)
    assert spill_data.perturb_route(scene, np.array([[5, 5], [5, 6]]), np.random.default_rng(0)) is None
