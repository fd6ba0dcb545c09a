"""The episode rebuild benchmark (experiments/rebuild_modes.py) on a tiny run."""
import json

import pytest

from experiments import rebuild_modes


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One run checked by every test: a built-in scene and a random grid. The random grid is 25 x 25,
    the default scene's shape, so both scenes' episodes run the same compiled programs (each new grid
    shape compiles both rebuilds' episode programs anew: a 12 x 12 grid doubled the module's time)."""
    out = tmp_path_factory.mktemp("rebuild_modes")
    code = rebuild_modes.main(["--scenes", "default", "--random", "25", "--repeats", "1", "--max-pushes", "3",
                               "--results-dir", str(out)])
    return code, out


def test_both_rebuilds_run_the_same_episode_and_the_table_is_written(run):
    code, out = run
    assert code == 0
    row = json.loads((out / "rebuild_modes.json").read_text())["scenes"][0]
    assert row["scene"] == "default"
    assert row["same_episode"] and row["auto"] == "full" and row["pushes"] == 3
    assert all(ms > 0 for ms in row["median_rebuild_ms"].values())
    assert "| default | 25x25 | 3 |" in (out / "rebuild_modes.md").read_text()


def test_random_grids_join_the_table(run):
    code, out = run
    assert code == 0
    rows = json.loads((out / "rebuild_modes.json").read_text())["scenes"]
    assert [r["scene"] for r in rows] == ["default", "random25"]
    assert rows[1]["shape"] == [25, 25] and rows[1]["same_episode"] and rows[1]["pushes"] >= 2
    table = (out / "rebuild_modes.md").read_text()
    assert "| random25 | 25x25 |" in table and table.index("| default |") < table.index("| random25 |")
