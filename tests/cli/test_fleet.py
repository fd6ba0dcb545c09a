"""`jaxplan fleet`: the files of the issue (summary.json, trajectory.npz, pushes.json, fleet.png,
fleet.gif, physics.json), a manifest, and bad input as one error line."""
from __future__ import annotations

import contextlib
import io
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
    stdout = io.StringIO()
    # two pushes: the run stops after 18 steps rather than 26 with four, and the GIF draws a frame per step
    with contextlib.redirect_stdout(stdout):
        code = main(["fleet", "--scene", str(scene_file), "--rovers", "2", "--max-steps", "60", "--max-pushes", "2",
                     "--physics", "--fps", "4", "--out", str(out)])
    return code, out, stdout.getvalue()


def test_fleet_writes_every_file(fleet_run, capsys):
    code, out, _ = fleet_run
    assert code == 0
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["status"] == "complete" and manifest["command"] == "fleet"
    assert sorted(manifest["files"]) == sorted(["summary.json", "trajectory.npz", "pushes.json", "fleet.png",
                                                "fleet.gif", "physics.json"])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_rovers"] == 2 and summary["strategy"] == "coordinated" and summary["conflicts"] == 0
    assert summary["pushes"] <= 2 and len(summary["pushes_per_rover"]) == 2
    assert summary["scene"] == "random14x14_piles_d0.4_s3"      # the file's scene name
    assert summary["unreachable_mass"] == 0.0
    # --physics without a spill option: the fleet plans and predicts with the rover's learned model
    assert summary["spill"]["model"] == "LearnedSpillParams"
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


def test_physics_prints_its_findings(fleet_run):
    """--physics says on stdout what physics.json holds: contacts, each push's simulated against
    predicted delivery, and how many agree within 15%."""
    _, out, stdout = fleet_run
    physics = json.loads((out / "physics.json").read_text())
    lines = stdout.splitlines()
    (head,) = [line for line in lines if line.startswith("physics: ")]
    assert f"the first round of {physics['rovers']} concurrent push(es)" in head
    assert f"{physics['contacts']} rover-rover contact step(s)" in head
    rows = [line.strip() for line in lines if line.startswith("  rover ")]
    assert len(rows) == len(physics["pushes"])
    for line, push in zip(rows, physics["pushes"]):
        assert line.startswith(f"rover {push['rover']}: delivered {push['delivered']:.1f} simulated vs "
                               f"{push['predicted_delivered']:.1f} predicted objects"), line
        assert ("within 15%" if push["within"] else "outside 15%") in line
    within = sum(p["within"] for p in physics["pushes"])
    assert f"  {within} of {len(rows)} push(es) within 15% of the predicted delivery" in lines
    assert lines.index(f"  {within} of {len(rows)} push(es) within 15% of the predicted delivery") < \
        lines.index(f"wrote {out / 'summary.json'}")     # before the list of files


def test_physics_lines_of_a_run_without_pushes():
    from jaxplan.cli.fleet import physics_lines

    assert physics_lines({"rovers": 0, "note": "the run made no push; nothing to check"}) == \
        ["physics: the run made no push; nothing to check"]


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


# The runs on walled_file take --physics like fleet_run: it picks the spill model the fleet plans with (the
# rover's learned one), and the fleet's step program is compiled per model, about 10 s on a 2-core CPU;
# with the same model (and grid shape and rover count) these runs reuse what fleet_run compiled. The
# physics check itself costs little. (Without --physics the command line's default spill model is the
# library's default: test_run_fleet_defaults_equal_the_command_lines.)
def test_fleet_names_an_unnamed_scene_file_by_its_path_and_counts_the_unreachable_mass(walled_file, tmp_path):
    out = tmp_path / "out"
    assert main(["fleet", "--scene", str(walled_file), "--rovers", "2", "--max-steps", "30", "--max-pushes", "2",
                 "--physics", "--no-animation", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scene"] == str(walled_file) and summary["unreachable_mass"] == 18.0
    with np.load(out / "trajectory.npz") as data:
        assert data["obj_initial"].shape == data["obj_final"].shape == (14, 14)
        np.testing.assert_array_equal(data["obj_initial"][11:, 11:], 2.0)   # (row, col): the pocket ...
        np.testing.assert_array_equal(data["obj_final"][11:, 11:], 2.0)     # ... never pushed
        assert data["obj_initial"][10, 10:].sum() == 0 and data["obj_final"][10:, 10].sum() == 0


@pytest.mark.parametrize("argv, starts", [
    (["--rovers", "0"], "error: --rovers: must be an int in [1, 1024]"),
    (["--rovers", "1025"], "error: --rovers: must be an int in [1, 1024]"),
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


# --------------------------------------------------------------------------------------------------
# --starts FILE: one [row, col] per rover. Every refusal is one line naming --starts and the file, exit
# 2, before any work (the output folder is not created).


def test_starts_place_the_rovers(walled_file, tmp_path):
    starts = tmp_path / "starts.json"
    starts.write_text("[[0, 0], [9, 13]]\n")
    out = tmp_path / "out"     # the walled run's settings but the steps: its compiled programs serve
    assert main(["fleet", "--scene", str(walled_file), "--rovers", "2", "--starts", str(starts), "--max-steps", "3",
                 "--max-pushes", "2", "--physics", "--no-animation", "--out", str(out)]) == 0
    with np.load(out / "trajectory.npz") as data:
        np.testing.assert_array_equal(data["pos"][0], [[0, 0], [9, 13]])


def test_help_shows_starts(capsys):
    with pytest.raises(SystemExit) as info:
        main(["fleet", "--help"])
    assert info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--starts FILE" in text and "[row, col]" in text and "--starts starts.json" in text


# walled_file: targets in rows 4-7 of columns 0-3 (random_scene(3, (14, 14), layout="piles")); the blocked L
# is row 10 and column 10 from 10 on; the pocket rows 11-13 x columns 11-13 is cut off from every target
@pytest.mark.parametrize("content, says", [
    (None, "no such file"),
    ("", "is empty"),
    (b"\xff\xfe[[0, 0]]", "is not UTF-8"),
    ("[" * 10 + " " * 70_000, "is longer than 65,536 bytes"),
    ("[[0, 0], [0, 5]", "is not JSON (line 1, column 16"),
    ("[" * 60_000, "nests lists too deeply"),
    ('{"starts": [[0, 0], [0, 5]]}', "holds a JSON object, not a list"),
    ("[[0, 0], [0, 5, 1]]", "entry 1 ([0, 5, 1]) is not a [row, col] pair"),
    ("[0, 0]", "entry 0 (0) is not a [row, col] pair"),
    ("[[0, 0], [0, 5.0]]", "entry 1 ([0, 5.0]): a cell's row and col are whole numbers"),
    ('[["0", 0], [0, 5]]', "entry 0 ([\"0\", 0]): a cell's row and col are whole numbers"),
    ("[[0, 0], [true, 5]]", "entry 1 ([true, 5]): a cell's row and col are whole numbers"),
    ("[[0, 0], [99999999999999999999, 5]]", "entry 1 ([99999999999999999999, 5]) lies far outside the grid"),
    ("[[0, 0]]", "holds 1 start cell(s) for 2 rover(s) (--rovers 2)"),
    ("[[0, 0], [0, 5], [0, 9]]", "holds 3 start cell(s) for 2 rover(s)"),
    ("[[0, 0], [14, 5]]", "every cell must lie in the 14 x 14 grid"),
    ("[[0, 0], [0, -1]]", "every cell must lie in the 14 x 14 grid"),
    ("[[0, 5], [0, 5]]", "two rovers start on one cell"),
    ("[[0, 0], [5, 0]]", "a rover starts inside a target"),
    ("[[0, 0], [10, 12]]", "rover 1 starts on a blocked cell (row 10, col 12)"),
    ("[[12, 12], [0, 0]]", "rover 0 starts on a cell cut off from every target (row 12, col 12)"),
])
def test_bad_starts_are_one_line_naming_the_flag_and_the_file(content, says, walled_file, tmp_path, capsys):
    path = tmp_path / "starts.json"
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        path.write_text(content)
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as info:
        main(["fleet", "--scene", str(walled_file), "--rovers", "2", "--starts", str(path), "--out", str(out)])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    # the path is named, shortened in the middle when long (jaxplan.core.shown_path)
    assert len(err) == 1 and err[0].startswith("error: --starts: '") and "starts.json': " in err[0], err
    assert says in err[0], err
    assert not out.exists()


def test_starts_that_is_a_folder(walled_file, tmp_path, capsys):
    with pytest.raises(SystemExit) as info:
        main(["fleet", "--scene", str(walled_file), "--rovers", "2", "--starts", str(tmp_path), "--out",
              str(tmp_path / "out")])
    assert info.value.code == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"error: --starts: {str(tmp_path)!r}: is a directory"), line


def test_run_fleet_defaults_equal_the_command_lines():
    import inspect

    from jaxplan.cli.app import build_parser
    from jaxplan.cli.transport import spill_params
    from jaxplan.fleet import run_fleet
    from jaxplan.fleet.run import DEFAULT_MAX_PUSHES
    from jaxplan.transport import EpisodeParams, SpillParams

    args = build_parser().parse_args(["fleet", "--scene", "default", "--out", "out"])
    signature = inspect.signature(run_fleet)
    assert args.max_steps == signature.parameters["max_steps"].default
    assert args.max_pushes == DEFAULT_MAX_PUSHES
    assert (args.stop_fraction, args.rearrange_margin) == (EpisodeParams().stop_fraction,
                                                           EpisodeParams().rearrange_margin)
    assert args.strategy == signature.parameters["strategy"].default
    assert spill_params(args) == SpillParams()
