"""The soft fabric convergence benchmark (experiments/soft_convergence.py) on a tiny run."""
import json

from experiments import soft_convergence


def test_tiny_run_writes_the_table_and_the_gradient_checks(tmp_path):
    # seed 79: both random grids are 8 x 8 (one integer, one real; a two-circle and a box target), so the hard
    # and the soft fabric compile for one small shape (seed 0 drew 32 x 32 and 8 x 8: twice the compiling)
    assert soft_convergence.main(["--grids", "2", "--fd-grids", "1", "--seed", "79", "--no-plot",
                                  "--results-dir", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "soft_convergence.json").read_text())
    assert set(result["table"]) == {str(t) for t in soft_convergence.TEMPERATURES}
    for row in result["table"].values():
        assert 0 <= row["within_5pct"] <= 2
        assert all(row[f]["median"] >= 0 for f in soft_convergence.FIELDS)
    assert len(result["gradients"]) == len(soft_convergence.FD_TEMPERATURES) * len(soft_convergence.FD_ARGS)
    assert all(r["finite"] for r in result["gradients"])
    assert [g["side"] for g in result["per_grid"]] == [8, 8] and result["seed"] == 79
    assert "| 0.05 |" in (tmp_path / "soft_convergence.md").read_text()
