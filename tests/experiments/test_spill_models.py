"""experiments/spill_models.py on the first seeds of the committed data set: every model fitted and
scored on held-out routes, the results and the learned fit written, bad arguments refused."""
from __future__ import annotations

import json

import numpy as np
import pytest

from experiments import spill_models


def test_models_are_scored_on_held_out_routes_and_the_fit_is_written(tmp_path):
    fit_file = tmp_path / "fit.json"
    result = spill_models.main(["--seeds", "4", "--quick", "--results-dir", str(tmp_path), "--write-fit",
                                "--fit-file", str(fit_file), "--cost-size", "12", "--cost-repeats", "1",
                                "--no-progress", "--hidden", "4", "8"])
    assert result["models"] == ["curvature", "capacity", "ROVER_FIT", "learned"]
    held = result["scores"]["heldout"]
    assert held["all"]["routes"] == result["counts"]["heldout"] > 0
    for cls in ("density 0.15", "density 0.35", "density 0.6", "speckled", "piles"):
        assert cls in held
    for row in held["all"]["models"].values():
        assert 0.0 <= row["within_10pct"] <= 1.0 and row["delivered"] >= 0
    physics = held["all"]["physics"]
    assert physics["delivered"] + physics["spilled"] + physics["left_behind"] + physics["lost"] == pytest.approx(
        physics["collected"], abs=0.02)
    assert set(result["build_cost"]["ratio_to_ROVER_FIT"]) == {"ROVER_FIT", "learned"}   # --quick: the two
    assert result["default"] in ("learned", "ROVER_FIT")
    assert 0.0 <= result["fitted"]["capacity"]["miss"] <= 2.0                  # fit_miss's range
    written = json.loads((tmp_path / "spill_models.json").read_text())
    assert written["scores"] == result["scores"]
    assert "| density 0.6 |" in (tmp_path / "spill_models.md").read_text()
    from jaxplan.transport.spillage import load_learned

    assert set(result["learned"]["validation_within_10pct"]) == {4, 8}       # chosen on validation scenes
    assert load_learned(fit_file).w1.shape == (7, result["learned"]["hidden"])


def test_archives_on_the_same_scenes_are_read_as_one(tmp_path):
    whole = dict(np.load(spill_models.DEFAULT_DATA[0]))
    records = len(whole["n_cells"])
    halves = []
    for k, rows in enumerate((slice(0, 40), slice(40, 90))):
        part = {key: (v if key.startswith("scene_") else v[rows]) for key, v in whole.items()}
        part["cells"] = part["cells"][:, : int(part["n_cells"].max())]           # archives pad to their own longest
        np.savez(tmp_path / f"part{k}.npz", **part)
        halves.append(tmp_path / f"part{k}.npz")
    read = spill_models.read_archives(halves)
    assert records > 90 and len(read["n_cells"]) == 90
    assert not read["perturbed"].any()                                          # the committed set predates them
    for key in ("n_cells", "delivered", "scene", "entry"):
        np.testing.assert_array_equal(read[key], whole[key][:90])
    for j in (0, 45, 89):
        n = whole["n_cells"][j]
        np.testing.assert_array_equal(read["cells"][j, :n], whole["cells"][j, :n])
    other = {**dict(np.load(halves[1])), "scene_seed": whole["scene_seed"] + 1}
    np.savez(tmp_path / "other.npz", **other)
    with pytest.raises(ValueError, match="other.npz: its scenes differ"):
        spill_models.read_archives([halves[0], tmp_path / "other.npz"])


@pytest.mark.parametrize("argv, flag", [(["--steps", "0"], "--steps"), (["--seeds", "2"], "--seeds"),
                                        (["--data", "nope.npz"], "--data"),
                                        (["--hidden", "0"], "--hidden")])
def test_bad_arguments_exit_2(tmp_path, capsys, argv, flag):
    with pytest.raises(SystemExit) as info:
        spill_models.main([*argv, "--results-dir", str(tmp_path)])
    assert info.value.code == 2 and flag in capsys.readouterr().err
