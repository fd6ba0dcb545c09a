"""The batch-size throughput benchmark (experiments/bench_rover_throughput.py) on a tiny run."""
import json

import pytest

from experiments import bench_rover_throughput as bench


def test_small_scene_c_engine_run_writes_results(tmp_path):
    assert bench.main(["--scene", "small", "--routes", "2", "--batches", "3", "--ticks", "4", "--repeats", "1",
                       "--engines", "c", "--results-dir", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "rover_throughput_cpu.json").read_text())
    (row,) = result["rows"]
    assert row["batch"] == 3 and row["ticks"] == 4
    c = row["engines"]["c"]
    assert c["route_steps_per_s"] > 0 and c["finite"] == 1.0
    assert len(c["mean_lateral"]) == 3
    assert "| 3 | 4 | C engine |" in (tmp_path / "rover_throughput_cpu.md").read_text()


def test_bad_arguments_exit_with_a_message(capsys):
    with pytest.raises(SystemExit) as exc:
        bench.main(["--ticks", "-1"])
    assert exc.value.code == 2
    assert "--ticks: must be >= 0" in capsys.readouterr().err
