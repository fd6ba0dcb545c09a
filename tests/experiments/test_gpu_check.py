"""experiments/gpu_check.py on a tiny CPU configuration (C engine; MJX and Warp are tested elsewhere)."""
import json

from experiments import gpu_check


def test_tiny_run_writes_every_part(tmp_path):
    gpu_check.main(["--tiny", "--engines", "c", "--results-dir", str(tmp_path)])
    result = json.loads((tmp_path / "gpu_check.json").read_text())
    assert result["device"].startswith("cpu")
    parts = {r["part"]: r for r in result["rows"]}
    assert set(parts) == {"pusharound", "rover", "fabric"}
    assert parts["pusharound"]["per_s"] > 0 and parts["pusharound"]["unit"] == "candidates/s"
    assert parts["rover"]["per_s"] > 0 and parts["rover"]["batch"] == 2
    assert parts["fabric"]["ms"] > 0
    md = (tmp_path / "gpu_check.md").read_text()
    assert md.startswith("# GPU check: cpu") and "route-steps/s" in md


def test_budget_skips_rows(tmp_path):
    result = gpu_check.main(["--tiny", "--engines", "c", "--budget-s", "0", "--results-dir", str(tmp_path)])
    assert all(r.get("skipped") == "time budget" for r in result["rows"])
