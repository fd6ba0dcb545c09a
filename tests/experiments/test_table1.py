"""The Table I harness (experiments/table1.py) on its smoke scene: the results files, the resume and the
replanning column."""
import json

from experiments import table1


def test_table1_quick_run_writes_json_and_resumes(tmp_path):
    argv = ["--quick", "--planners", "SL-Push (offline),Rec-NAMO", "--out", str(tmp_path), "--no-progress",
            "--no-execute"]
    doc = table1.main(argv)
    data = json.loads((tmp_path / "table1.json").read_text())
    assert data == json.loads(json.dumps(doc))
    assert {r["planner"] for r in data["rows"]} == {"SL-Push (offline)", "Rec-NAMO"}
    for r in data["rows"]:
        assert r["trials"] == 1 and 0.0 <= r["success_pct"] <= 100.0
    assert "Table I" in (tmp_path / "table1.md").read_text()
    lines = (tmp_path / "table1_trials.jsonl").read_text().splitlines()
    assert len(lines) == 2
    table1.main(argv)                           # resume: nothing left to run
    assert (tmp_path / "table1_trials.jsonl").read_text().splitlines() == lines


def test_table1_replan_column_executes_ours_with_online_replanning(tmp_path):
    table1.main(["--quick", "--planners", "ours", "--replan", "--out", str(tmp_path), "--no-progress"])
    rec = json.loads((tmp_path / "table1_trials.jsonl").read_text().splitlines()[0])
    assert rec["success"] and rec["exec_success"] is not None
    assert isinstance(rec["replan_exec_success"], bool) and rec["replans"] >= 0
    row = json.loads((tmp_path / "table1.json").read_text())["rows"][0]
    assert row["replan_exec_success_pct"] in (0.0, 100.0)
    assert "+replan" in (tmp_path / "table1.md").read_text()
