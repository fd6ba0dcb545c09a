"""The episode rebuild benchmark (experiments/rebuild_modes.py) on a tiny run."""
import json

from experiments import rebuild_modes


def test_both_rebuilds_run_the_same_episode_and_the_table_is_written(tmp_path):
    assert rebuild_modes.main(["--scenes", "default", "--repeats", "1", "--max-pushes", "3",
                               "--results-dir", str(tmp_path)]) == 0
    (row,) = json.loads((tmp_path / "rebuild_modes.json").read_text())["scenes"]
    assert row["same_episode"] and row["auto"] == "full" and row["pushes"] == 3
    assert all(ms > 0 for ms in row["median_rebuild_ms"].values())
    assert "| default | 25x25 | 3 |" in (tmp_path / "rebuild_modes.md").read_text()


def test_random_grids_join_the_table(tmp_path):
    assert rebuild_modes.main(["--scenes", "default", "--random", "12", "--repeats", "1", "--max-pushes", "2",
                               "--results-dir", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "rebuild_modes.json").read_text())["scenes"]
    assert [r["scene"] for r in rows] == ["default", "random12"]
    assert rows[1]["shape"] == [12, 12] and rows[1]["same_episode"]
