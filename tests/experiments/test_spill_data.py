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


def _fake_records(scene, sources, entries, layouts, backend="auto"):
    """Records shaped like ``scene_records``'s, without the physics (the writer is under test)."""
    obj = np.asarray(scene.obj, np.float32)
    return [{"obj_before": obj, "obj_after": obj, "cells": np.asarray([[1, 1], [1, 2], [2, 3]][: 2 + k % 2], np.int16),
             "source": np.asarray([1, 1], np.int32), "entry": k % entries, "layout": k // (sources * entries),
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


@pytest.mark.parametrize("argv", [["--layouts", "0"], ["--seeds", "-1"]])
def test_bad_arguments_exit_before_any_work(argv, tmp_path, capsys):
    with pytest.raises(SystemExit) as err:
        spill_data.main([*argv, "--out", str(tmp_path / "x")])
    assert err.value.code == 2 and "error:" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())
