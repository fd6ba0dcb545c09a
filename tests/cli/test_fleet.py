"""`jaxplan fleet`: the files of the issue (summary.json, trajectory.npz, pushes.json, fleet.png,
fleet.gif, physics.json), a manifest, and bad input as one error line."""
from __future__ import annotations

import json

import numpy as np
import pytest

from jaxplan import random_scene
from jaxplan.cli import main

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("site") / "site.npz"
    random_scene(3, (14, 14), layout="piles").save(path)
    return path


@pytest.fixture(scope="module")
def fleet_run(scene_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("fleet") / "out"
    code = main(["fleet", "--scene", str(scene_file), "--rovers", "2", "--max-steps", "60", "--max-pushes", "4",
                 "--physics", "--fps", "4", "--out", str(out)])
    return code, out


def test_fleet_writes_every_file(fleet_run, capsys):
    code, out = fleet_run
    assert code == 0
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["status"] == "complete" and manifest["command"] == "fleet"
    assert sorted(manifest["files"]) == sorted(["summary.json", "trajectory.npz", "pushes.json", "fleet.png",
                                                "fleet.gif", "physics.json"])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_rovers"] == 2 and summary["strategy"] == "coordinated" and summary["conflicts"] == 0
    assert summary["pushes"] <= 4 and len(summary["pushes_per_rover"]) == 2
    with np.load(out / "trajectory.npz") as data:
        t = summary["steps"]
        assert data["pos"].shape == (t + 1, 2, 2) and data["delivered"].shape == (t + 1,)
        total = data["delivered"] + data["outside"]
        np.testing.assert_allclose(total, float(data["initial_mass"]), rtol=0, atol=1e-6)   # mass identity
    pushes = json.loads((out / "pushes.json").read_text())
    assert len(pushes) == summary["pushes"]
    assert (out / "fleet.png").read_bytes()[:8] == PNG_MAGIC
    assert (out / "fleet.gif").read_bytes()[:3] == b"GIF"
    physics = json.loads((out / "physics.json").read_text())
    assert physics["rovers"] == len(physics["pushes"]) >= 1 and physics["contacts"] >= 0


@pytest.mark.parametrize("argv, starts", [
    (["--rovers", "0"], "error: --rovers: must be an int in [1, 64]"),
    (["--rovers", "65"], "error: --rovers: must be an int in [1, 64]"),
    (["--strategy", "swarm"], "error: --strategy: invalid choice"),
    (["--max-steps", "0"], "error: --max-steps: must be an int in [1, 1000000]"),
    (["--scene", "site999"], "error: --scene: 'site999' is neither a built-in scene"),
])
def test_bad_input_is_one_line(argv, starts, tmp_path, capsys):
    base = ["fleet", "--scene", "default", "--out", str(tmp_path / "o")]
    with pytest.raises(SystemExit) as info:
        main(base + argv)
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(starts), err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("room, flag", [(10 ** 6, "--scene"), (335 * 10 ** 6, "--rovers")])
def test_a_fleet_too_large_for_the_memory_is_refused_before_the_folder_is_touched(room, flag, tmp_path,
                                                                                   monkeypatch, capsys):
    from jaxplan.fleet import run as fleet_run

    monkeypatch.setattr(fleet_run, "available_memory_bytes", lambda: room)
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as info:
        main(["fleet", "--scene", "site128", "--rovers", "64", "--out", str(out)])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {flag}:"), err
    assert not out.exists()
