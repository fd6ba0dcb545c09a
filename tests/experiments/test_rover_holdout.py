"""The out-of-sample rover check (experiments/rover_holdout.py) on a tiny run."""
import json

from experiments import rover_holdout


def test_holdout_scores_both_models_and_writes_strict_json(tmp_path):
    # both scenes 12 x 12: the planner's programs compile for one grid shape (12 and 8 compiled them twice)
    assert rover_holdout.main(["--routes", "1", "--layouts", "1", "--sparse", "12", "--dense", "12",
                               "--results-dir", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "rover_holdout.json").read_text(),
                        parse_constant=lambda name: (_ for _ in ()).throw(ValueError(name)))   # no Infinity/NaN
    assert [r["scene"] for r in result["rows"]] == ["random12_sparse", "random12_dense"]
    for row in result["rows"]:
        assert row["finite"] and row["collected"] > 0
        assert set(row["predicted"]) == set(result["models"]) and "turning (ROVER_FIT)" in row["predicted"]
        assert all(0.0 <= p <= row["collected"] + 1e-3 for p in row["predicted"].values())
    assert "| turning (ROVER_FIT) |" in (tmp_path / "rover_holdout.md").read_text()
