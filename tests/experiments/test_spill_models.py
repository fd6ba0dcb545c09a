"""experiments/spill_models.py on the first seeds of the committed data set: every model fitted and
scored on held-out routes, the results and the learned fit written, bad arguments refused."""
from __future__ import annotations

import json

import pytest

from experiments import spill_models


def test_models_are_scored_on_held_out_routes_and_the_fit_is_written(tmp_path):
    fit_file = tmp_path / "fit.json"
    result = spill_models.main(["--seeds", "4", "--quick", "--results-dir", str(tmp_path), "--write-fit",
                                "--fit-file", str(fit_file), "--cost-size", "12", "--cost-repeats", "1",
                                "--no-progress"])
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
    written = json.loads((tmp_path / "spill_models.json").read_text())
    assert written["scores"] == result["scores"]
    assert "| density 0.6 |" in (tmp_path / "spill_models.md").read_text()
    from jaxplan.transport.spillage import load_learned

    assert load_learned(fit_file).w1.shape == (7, 8)


@pytest.mark.parametrize("argv, flag", [(["--steps", "0"], "--steps"), (["--seeds", "2"], "--seeds"),
                                        (["--data", "nope.npz"], "--data")])
def test_bad_arguments_exit_2(tmp_path, capsys, argv, flag):
    with pytest.raises(SystemExit) as info:
        spill_models.main([*argv, "--results-dir", str(tmp_path)])
    assert info.value.code == 2 and flag in capsys.readouterr().err
