"""experiments/closed_loop.py on one held-out scene, one push: the table and the figure are written."""
from __future__ import annotations

import json

import pytest

from experiments import closed_loop


def test_one_scene_one_push_writes_results(tmp_path):
    result = closed_loop.main(["--pushes", "1", "--scenes", "1", "--no-gif", "--results-dir", str(tmp_path)])
    (row,) = result["rows"]
    assert row["heldout"] and row["pushes"] == 1 and len(row["physics"]) == len(row["predicted"]) == 2
    assert row["within_after"] in (0, 1) and row["relative_error"][0] >= 0
    assert json.loads((tmp_path / "closed_loop.json").read_text())["rows"] == result["rows"]
    assert (tmp_path / f"closed_loop_{row['scene']}.png").exists()
    assert "| scene | pushes |" in (tmp_path / "closed_loop.md").read_text()


@pytest.mark.parametrize("argv", [["--pushes", "0"], ["--scenes", "9"]])
def test_bad_arguments_exit_2(argv, tmp_path):
    with pytest.raises(SystemExit) as info:
        closed_loop.main([*argv, "--results-dir", str(tmp_path)])
    assert info.value.code == 2
