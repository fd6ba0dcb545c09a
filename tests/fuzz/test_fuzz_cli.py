"""The CLI fuzzer (tests/fuzz/fuzz_cli.py) on a tiny run: its worker process runs the cases, the results are
written and every case is counted once."""
import json

from tests.fuzz import fuzz_cli


def test_a_tiny_run_counts_every_case_and_writes_the_tables(tmp_path):
    argv = ["--cases", "4", "--seed", "1", "--kinds", "scene.json", "--results-dir", str(tmp_path), "--no-progress"]
    assert fuzz_cli.main(argv) == 0
    result = json.loads((tmp_path / "fuzz_cli.json").read_text())
    assert result["cases"] == 4 and result["outcomes"]["total"] == 4
    assert sum(result["outcomes"][o] for o in fuzz_cli.OUTCOMES) == 4
    assert set(result["kinds"]) == {"scene.json"}
    for finding in result["findings"]:
        assert finding["outcome"] not in fuzz_cli.PASSING and finding["count"] == len(finding["cases"])
        assert finding["example"]["replay"].startswith("python -m tests.fuzz.fuzz_cli --seed 1 --replay ")
    assert "| scene.json |" in (tmp_path / "fuzz_cli.md").read_text()


def test_a_run_of_chosen_classes_counts_them_and_replays_with_them(tmp_path):
    argv = ["--cases", "4", "--seed", "2", "--classes", "archive", "nesting", "--kinds", "scene.npz", "scene.json",
            "--results-dir", str(tmp_path), "--name", "r", "--no-progress"]
    assert fuzz_cli.main(argv) == 0
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["cases"] == 4 and set(result["classes"]) <= {"archive", "nesting"}
    assert sum(t["total"] for t in result["classes"].values()) == 4
    assert result["classes_requested"] == ["archive", "nesting"]
    assert "## Cases per class" in (tmp_path / "r.md").read_text()
    assert fuzz_cli.replay_command(2, 3, ["scene.npz"], ["fs"]).endswith(
        "--replay 3 --kinds scene.npz --classes fs --keep out/fuzz_case3")
