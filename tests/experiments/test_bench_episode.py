"""The episode throughput benchmark (experiments/bench_episode.py) on a tiny run."""
import json

from experiments import bench_episode


def test_the_batch_and_the_host_loop_push_alike_and_the_table_is_written(tmp_path):
    argv = ["--quick", "--batch", "2", "--max-pushes", "2", "--no-breakdown", "--results-dir", str(tmp_path)]
    assert bench_episode.main(argv) == 0
    result = json.loads((tmp_path / "episode.json").read_text())
    (row,) = result["batched"]
    assert row["same_pushes"] and row["pushes"] == result["host"]["pushes"] == 4
    assert row["pushes_per_s"] > 0 and row["ratio"] > 0 and row["walk_cap"] == result["default_walk_cap"]
    assert "| vmap + scan | 96 | 4 |" in (tmp_path / "episode.md").read_text()
