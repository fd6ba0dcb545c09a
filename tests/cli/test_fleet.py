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
    assert summary["scene"] == "random14x14_piles_d0.4_s3"      # the file's scene name
    assert summary["unreachable_mass"] == 0.0
    with np.load(out / "trajectory.npz") as data:
        t = summary["steps"]
        assert data["pos"].shape == (t + 1, 2, 2) and data["delivered"].shape == (t + 1,)
        total = data["delivered"] + data["outside"]
        np.testing.assert_allclose(total, float(data["initial_mass"]), rtol=0, atol=1e-6)   # mass identity
        assert data["obj_initial"].dtype == data["obj_final"].dtype == np.float32
        assert data["obj_initial"].shape == data["obj_final"].shape == (14, 14)
        assert str(data["convention"]) == "cells are (row, col); rows = y, columns = x"
        np.testing.assert_allclose(data["obj_initial"].sum(), float(data["initial_mass"]), rtol=1e-6)
        np.testing.assert_allclose(data["obj_final"].sum(), total[-1], rtol=1e-6)
    pushes = json.loads((out / "pushes.json").read_text())
    assert len(pushes) == summary["pushes"]
    assert (out / "fleet.png").read_bytes()[:8] == PNG_MAGIC
    assert (out / "fleet.gif").read_bytes()[:3] == b"GIF"
    physics = json.loads((out / "physics.json").read_text())
    assert physics["rovers"] == len(physics["pushes"]) >= 1 and physics["contacts"] >= 0


@pytest.fixture(scope="module")
def walled_file(tmp_path_factory):
    """The site of ``scene_file`` without a name, with a blocked L (row 10 and column 10 from 10 on)
    that cuts the corner pocket rows 11-13 x columns 11-13 (2 objects per cell, 18) off the targets."""
    from jaxplan import Scene

    base = random_scene(3, (14, 14), layout="piles")
    obj = np.asarray(base.obj).copy()
    blocked = np.zeros((14, 14), bool)
    blocked[10, 10:] = blocked[10:, 10] = True
    obj[blocked] = 0
    obj[11:, 11:] = 2
    path = tmp_path_factory.mktemp("walled") / "walled.npz"
    Scene.from_arrays(obj, base.target, blocked=blocked).save(path)
    return path


def test_fleet_names_an_unnamed_scene_file_by_its_path_and_counts_the_unreachable_mass(walled_file, tmp_path):
    out = tmp_path / "out"
    assert main(["fleet", "--scene", str(walled_file), "--rovers", "2", "--max-steps", "30", "--max-pushes", "2",
                 "--no-animation", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scene"] == str(walled_file) and summary["unreachable_mass"] == 18.0
    with np.load(out / "trajectory.npz") as data:
        assert data["obj_initial"].shape == data["obj_final"].shape == (14, 14)
        np.testing.assert_array_equal(data["obj_initial"][11:, 11:], 2.0)   # (row, col): the pocket ...
        np.testing.assert_array_equal(data["obj_final"][11:, 11:], 2.0)     # ... never pushed
        assert data["obj_initial"][10, 10:].sum() == 0 and data["obj_final"][10:, 10].sum() == 0


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
