"""The ranking-weights experiment (experiments/fit_ranking.py) without its searches: records survive the
JSON round trip, the labelling picks each scene's best run, the paired table, and bad arguments. The
recorder and the fit are tested in tests/tune/test_ranking.py; a real run takes tens of minutes."""
import math

import numpy as np
import pytest

from experiments import fit_ranking
from jaxplan.pusharound.ranking import PresearchFeatures
from jaxplan.pusharound.search import ExpansionRecord


def _record(node=0, solution=(True, False), to_go=12.5):
    feats = PresearchFeatures(np.array([[1.0, 0.2], [2.0, 0.0]]), np.array([[[3.0, 0.1, 4.0]], [[0.0, 0.0, 0.0]]]),
                              np.array([[True], [True]]), np.array([0.0, 1000.0]))
    return ExpansionRecord(node=np.int64(node), depth=np.int64(0), visit=np.int64(0), chi=np.float64(0.0),
                           endpoint=np.array([False, False]), bodies=np.array([[0, 3], [1, 3]]), features=feats,
                           cost=np.array([5.2, 1002.0]), tried=np.array([3, 1]), children=np.array([2, 0]),
                           opened=np.array([1, 0]), child_node=np.array([4, 5]), child_target=np.array([0, 0]),
                           solution=np.array(solution), to_go_cost=np.float64(to_go),
                           to_go_pushes=np.int64(-1 if math.isnan(to_go) else 2))


@pytest.mark.parametrize("to_go", [12.5, math.nan])
def test_records_survive_the_json_round_trip(to_go):
    rec = _record(to_go=to_go)
    back = fit_ranking.record_from_json(fit_ranking.record_to_json(rec))
    for f in ExpansionRecord._fields:
        if f == "features":
            for a, b in zip(rec.features, back.features):
                np.testing.assert_array_equal(a, b)
        else:
            np.testing.assert_array_equal(getattr(rec, f), getattr(back, f))
    assert back.solution.dtype == bool and back.features.mask.dtype == bool


def test_labels_come_from_each_scenes_best_successful_run():
    rec = fit_ranking.record_to_json(_record())
    run = {"scene": "nominal", "seed": 1000, "density_n": None, "records": [rec], "pushes": 3}
    rows = [dict(run, draw=0, success=True, simulated_pushes=64), dict(run, draw=1, success=True, simulated_pushes=48),
            dict(run, draw=2, success=False, simulated_pushes=16)]
    records, weights = fit_ranking.labelled(rows, "best")
    assert len(records) == 1 and weights == [1.0]
    records, weights = fit_ranking.labelled(rows, "all")
    assert len(records) == 2 and sorted(weights) == [pytest.approx(math.exp(-16 / 48)), 1.0]


def test_the_paired_table():
    rows = []
    for seed, (a, b) in enumerate([(64, 48), (80, 80), (96, 112)]):
        for ws, sims in (("paper", a), ("tuned", b)):
            rows.append({"scene": "nominal", "seed": seed, "density_n": None, "weight_set": ws, "success": True,
                         "planning_time_s": 1.0, "expansions": sims // 16, "simulated_pushes": sims, "pushes": 3})
    (row,) = fit_ranking.paired_summary(rows)
    assert row["scenes"] == 3 and row["paper"]["median_simulated_pushes"] == 80
    assert row["paired"]["tuned_fewer"] == row["paired"]["equal"] == row["paired"]["tuned_more"] == 1
    assert row["paired"]["median_relative_change_sims"] == 0.0 and not row["target_met"]
    doc = {"note": "n", "rows": [row], "fit": {"weights": [1.0, 1.5, 0.2], "temperature": 0.7, "expansions": 10,
                                                "training_runs": 4, "training_scenes": 2}}
    text = fit_ranking.markdown(doc)
    row_md = "| nominal | 3 | 100.0 · 1.00 · 5 · 80 | 100.0 · 1.00 · 5 · 80 | +0.0% | +0.0% | 1 / 1 / 1 | not met |"
    assert row_md in text


@pytest.mark.parametrize("argv", [["--draws", "0"], ["--eval-nominal", "-1"], ["--lr", "0"], ["--label", "worst"]])
def test_bad_arguments_exit_before_any_work(argv, tmp_path, capsys):
    with pytest.raises(SystemExit) as err:
        fit_ranking.main([*argv, "--out", str(tmp_path / "out")])
    assert err.value.code == 2 and "error:" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
