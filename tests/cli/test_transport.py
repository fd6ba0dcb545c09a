"""The ``jaxplan`` CLI, run in-process through ``jaxplan.cli.app``: fabric, demo, scenes, --help and
bad input (one ``error:`` line, exit code 2, never a traceback)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from jaxplan import BUILTIN_SCENES, FabricParams, build_fabric, builtin_scene
from jaxplan.cli import main
from jaxplan.cli.transport import FABRIC_ARRAYS, SUMMARY_KEYS

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
SMALL_MAP = Path(__file__).resolve().parents[1] / "data" / "small.map"


def _bad_input(argv, capsys) -> str:
    """Run ``main(argv)``, expect exit code 2, return the single stderr line."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0]


# --------------------------------------------------------------------------------------------------
# fabric
# --------------------------------------------------------------------------------------------------

def test_fabric_writes_documented_arrays(tmp_path, capsys):
    out = tmp_path / "sub" / "fabric.npz"
    assert main(["fabric", "--scene", "default", "--out", str(out)]) == 0
    assert str(out) in capsys.readouterr().out
    scene = builtin_scene("default")
    h, w = scene.shape
    k = FabricParams().k
    shapes = {
        "value": (h, w), "length": (h, w), "first_hop": (h, w, 2), "heading": (h, w, 2),
        "psi": (h, w), "heat": (h, w), "highways": (h, w), "fallback": (h, w), "occupied": (h, w),
        "table_raw": (h, w, k), "table_len": (h, w, k), "table_next_dir": (h, w, k),
        "table_next_rank": (h, w, k), "rounds": (), "converged": (),
    }
    assert set(shapes) == set(FABRIC_ARRAYS)
    with np.load(out, allow_pickle=False) as data:
        for key, shape in shapes.items():
            assert key in data.files, key
            assert data[key].shape == shape, key
        assert data["highways"].dtype == bool and data["first_hop"].dtype.kind == "i"
        # the saved arrays are the library's fabric
        fabric = build_fabric(scene, FabricParams())
        np.testing.assert_array_equal(data["value"], np.asarray(fabric.value))
        np.testing.assert_array_equal(data["table_next_dir"], np.asarray(fabric.table.next_dir))
        assert bool(data["converged"]) and int(data["rounds"]) == int(fabric.rounds)
    # nothing but the output file is left in the directory (the temp file was renamed)
    assert sorted(p.name for p in out.parent.iterdir()) == ["fabric.npz"]


def test_fabric_options_and_scene_file(tmp_path):
    scene_file = tmp_path / "scene.json"
    builtin_scene("default").save(scene_file)
    out = tmp_path / "f.npz"
    assert main(["fabric", "--scene", str(scene_file), "--theta-tol", "45", "--tau-h", "0.3",
                 "--k", "2", "--no-monotone", "--out", str(out)]) == 0
    with np.load(out) as data:
        assert data["table_raw"].shape == (25, 25, 2)
        assert float(data["theta_tol_deg"]) == 45.0 and not bool(data["monotone"])


def test_fabric_on_a_movingai_map_site(tmp_path, capsys):
    out = tmp_path / "f.npz"
    assert main(["fabric", "--scene", str(SMALL_MAP), "--site-seed", "3", "--out", str(out)]) == 0
    assert "fabric of small_site3 (24x32)" in capsys.readouterr().out
    with np.load(out) as data:
        assert data["value"].shape == (24, 32) and data["target_mask"].any()


@pytest.mark.parametrize("command", ["fabric", "demo", "episode", "rover", "fleet"])
def test_every_command_with_scene_takes_site_seed(command):
    from jaxplan.cli.app import build_parser

    argv = [command, "--scene", str(SMALL_MAP), "--out", "o", "--site-seed", "7"]
    assert build_parser().parse_args(argv).site_seed == 7
    assert build_parser().parse_args(argv[:-2]).site_seed is None   # used as 0 with a .map


def test_fabric_failed_write_leaves_nothing(tmp_path, monkeypatch, capsys):
    def broken(fh, **arrays):
        fh.write(b"partial")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez_compressed", broken)
    out = tmp_path / "fabric.npz"
    line = _bad_input(["fabric", "--scene", "default", "--out", str(out)], capsys)
    assert "--out" in line
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------------------------------
# demo
# --------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    """The demo with its defaults but for the push budget: the default 200 runs the default scene to the
    end (about 90 pushes and a GIF frame each, about 5 s more on a 2-core CPU), and what the tests check
    (the files, the summary's fields, the mass balance) holds after any number of pushes."""
    out = tmp_path_factory.mktemp("demo") / "out"
    code = main(["demo", "--max-pushes", "3", "--out", str(out)])
    return code, out


def test_demo_outputs(demo_run, capsys):
    code, out = demo_run
    assert code == 0
    png = out / "fabric.png"
    assert png.is_file() and png.stat().st_size > 1000
    assert png.read_bytes()[:8] == PNG_MAGIC
    summary = json.loads((out / "summary.json").read_text())
    for key in SUMMARY_KEYS:
        assert key in summary, key
    scene = builtin_scene("default")
    assert summary["scene"] == "default"
    assert summary["shape"] == list(scene.shape)
    assert summary["total_mass"] == pytest.approx(float(scene.total_mass))
    assert summary["occupied_cells"] == int(np.asarray(scene.occupied).sum())
    assert summary["params"]["theta_tol_deg"] == 60.0
    assert summary["converged"] is True and summary["solver_iterations"] >= 1
    assert summary["max_value_J"] > 0 and summary["highway_cells"] >= 1
    assert 0 <= summary["roots_with_connector"] <= summary["occupied_cells"]
    assert summary["compile_ms"] > 0 and summary["warm_build_ms"] > 0
    # the main job: an episode on the default scene
    episode = summary["episode"]
    assert episode["initial_mass"] == pytest.approx(float(scene.total_mass))
    assert episode["pushes"] >= 1 and episode["stop_reason"] in ("done", "budget")
    assert episode["delivered"] + episode["remaining"] == pytest.approx(episode["initial_remaining"], rel=1e-5)
    for name in ("episode.png", "episode.gif", "metrics.json", "metrics.csv"):
        assert (out / name).is_file() and (out / name).stat().st_size > 100, name
    assert (out / "episode.gif").read_bytes()[:6] in (b"GIF89a", b"GIF87a")


def test_demo_prints_summary(tmp_path, capsys):
    out = tmp_path / "d"
    assert main(["demo", "--scene", "default", "--theta-tol", "45", "--out", str(out), "--max-pushes", "3",
                 "--no-animation"]) == 0
    text = capsys.readouterr().out
    assert "max J" in text and str(out / "fabric.png") in text and str(out / "summary.json") in text
    assert "episode: 3 pushes" in text
    summary = json.loads((out / "summary.json").read_text())
    assert summary["params"]["theta_tol_deg"] == 45.0
    assert summary["episode"]["pushes"] == 3 and summary["episode"]["stop_reason"] == "budget"
    assert not (out / "episode.gif").exists()


# --------------------------------------------------------------------------------------------------
# scenes and --help
# --------------------------------------------------------------------------------------------------

def test_scenes_lists_builtins(capsys):
    assert main(["scenes"]) == 0
    text = capsys.readouterr().out
    for name in BUILTIN_SCENES:
        assert name in text
    assert "25x25" in text and "MultiPolygon" in text and "Polygon" in text


@pytest.mark.parametrize("argv, expected", [
    ([], ["fabric", "demo", "episode", "scenes", "example"]),
    (["episode"], ["--scene", "--out", "--lam", "--max-pushes", "--rearrange-margin", "--stop-fraction",
                   "--source-rule", "--reselect", "--no-animation", "summary.json", "metrics.csv", "episode.gif",
                   "example"]),
    (["fabric"], ["--scene", "--theta-tol", "--tau-h", "--k", "--no-monotone", "--out", "example", "--site-seed",
                  ".map", "--scene tests/data/small.map --site-seed 3"]),
    (["demo"], ["--scene", "--out", "--theta-tol", "example", "summary.json", "fabric.png", "--site-seed"]),
    (["scenes"], ["example"]),
])
def test_help(argv, expected, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv + ["--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    for word in expected:
        assert word in text, word


# --------------------------------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("argv, field", [
    (["fabric", "--scene", "no_such_scene", "--out", "x.npz"], "--scene"),
    (["fabric", "--scene", "missing/scene.npz", "--out", "x.npz"], "--scene"),
    (["fabric", "--scene", "default", "--theta-tol", "0", "--out", "x.npz"], "--theta-tol"),
    (["fabric", "--scene", "default", "--theta-tol", "200", "--out", "x.npz"], "--theta-tol"),
    (["fabric", "--scene", "default", "--k", "0", "--out", "x.npz"], "--k"),
    (["fabric", "--scene", "default", "--tau-h", "-1", "--out", "x.npz"], "--tau-h"),
    (["fabric", "--scene", "default", "--out", "x.txt"], "--out"),
    (["demo", "--theta-tol", "200"], "--theta-tol"),
    (["demo", "--scene", "nope"], "--scene"),
    (["demo", "--lam", "-1"], "--lam"),
    (["episode", "--scene", "default", "--out", "o", "--max-pushes", "-1"], "--max-pushes"),
    (["episode", "--scene", "default", "--out", "o", "--stop-fraction", "1.5"], "--stop-fraction"),
    (["episode", "--scene", "default", "--out", "o", "--rearrange-margin", "-2"], "--rearrange-margin"),
    (["episode", "--scene", "nope", "--out", "o"], "--scene"),
    (["fabric", "--scene", "default", "--site-seed", "3", "--out", "x.npz"], "--site-seed"),
    (["episode", "--scene", "missing.map", "--out", "o"], "--scene"),
    (["fabric", "--scene", str(SMALL_MAP), "--site-seed", "-1", "--out", "x.npz"], "--site-seed"),
])
def test_bad_input(argv, field, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    line = _bad_input(argv, capsys)
    assert field in line
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_bad_scene_file_content(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    line = _bad_input(["fabric", "--scene", str(bad), "--out", str(tmp_path / "f.npz")], capsys)
    assert "bad.json" in line
    assert not (tmp_path / "f.npz").exists()


def test_bad_map_file_is_one_error_line(tmp_path, capsys):
    bad = tmp_path / "bad.map"
    bad.write_text("type octile\nheight 2\nwidth 3\nmap\n...\n.x.\n")
    line = _bad_input(["fabric", "--scene", str(bad), "--out", str(tmp_path / "f.npz")], capsys)
    assert line.startswith(f"error: --scene: Map file {bad}: line 6, character 2: 'x'"), line
    assert not (tmp_path / "f.npz").exists()


def _broken_scene_files(tmp_path) -> dict:
    """Scene files that are broken as files, by kind: what ``--scene`` must refuse in one line."""
    from jaxplan.transport.scene import box

    valid = builtin_scene("default").save(tmp_path / "valid.npz")
    data = valid.read_bytes()
    crc = bytearray(data)
    crc[data.index("POLYGON".encode("utf-32-le"))] ^= 0xFF  # inside target_wkt.npy's stored bytes
    doc = {"format_version": 1, "cell_size": 1.0, "origin": [0, 0], "obj": [[0, 1], [2]],
           "target": box(0, 0, 1, 1).wkt}
    files = {"truncated.npz": data[:1001], "crc.npz": bytes(crc), "text.npz": b"not an archive",
             "noise.json": bytes(range(256)), "empty.npz": b"", "ragged.json": json.dumps(doc).encode()}
    for name, content in files.items():
        (tmp_path / name).write_bytes(content)
    (tmp_path / "folder.npz").mkdir()
    return {"truncated.npz": "damaged", "crc.npz": "CRC", "text.npz": "not a NumPy .npz archive",
            "noise.json": "not UTF-8", "empty.npz": "empty", "ragged.json": "row 1",
            "folder.npz": "is a directory"}


@pytest.mark.parametrize("command", [["fabric", "--out", "OUT/f.npz"], ["demo", "--out", "OUT"],
                                     ["episode", "--out", "OUT"], ["rover", "--out", "OUT"]])
def test_broken_scene_file_is_one_error_line(tmp_path, capsys, command):
    """A truncated, corrupted, mislabelled, empty or ragged scene file, or a folder: exit 2, one
    ``error: --scene: ...`` line naming the file and the problem, nothing written."""
    out = tmp_path / "out"
    for name, words in _broken_scene_files(tmp_path).items():
        argv = [a.replace("OUT", str(out)) for a in command] + ["--scene", str(tmp_path / name)]
        line = _bad_input(argv, capsys)
        assert line.startswith("error: --scene: ") and name in line and words in line, line
        assert "allow_pickle" not in line and "codec" not in line
    assert not out.exists()


def test_unparsable_angle_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as info:
        main(["fabric", "--scene", "default", "--theta-tol", "abc", "--out", "x.npz"])
    assert info.value.code == 2
    assert "--theta-tol" in capsys.readouterr().err


# --------------------------------------------------------------------------------------------------
# episode
# --------------------------------------------------------------------------------------------------

def test_episode_writes_summary_metrics_figure_and_animation(tmp_path, capsys):
    out = tmp_path / "ep"
    assert main(["episode", "--scene", "default", "--out", str(out), "--max-pushes", "4"]) == 0
    text = capsys.readouterr().out
    assert "episode: " in text and str(out / "summary.json") in text
    summary = json.loads((out / "summary.json").read_text())
    for key in ("initial_mass", "delivered", "spilled", "remaining", "pushes", "stop_reason", "message"):
        assert key in summary, key
    assert summary["pushes"] <= 4
    assert summary["unreachable_mass"] == 0.0      # the default scene has no blocked cells
    metrics = json.loads((out / "metrics.json").read_text())
    assert len(metrics["per_tick"]["delivered"]) == summary["pushes"]
    assert metrics["totals"]["delivered"] == pytest.approx(summary["delivered"])
    header = (out / "metrics.csv").read_text().splitlines()[0].split(",")
    for column in ("pushes", "delivered", "spilled", "remaining", "plan_ms", "driven"):
        assert column in header
    assert (out / "episode.png").read_bytes()[:8] == PNG_MAGIC
    assert (out / "episode.gif").read_bytes()[:3] == b"GIF"
    assert not list(out.glob(".*"))   # no temp files left


def test_episode_summary_counts_the_mass_cut_off_by_blocked_cells():
    from collections import defaultdict

    from jaxplan import EpisodeParams, Scene, SpillParams, box
    from jaxplan.cli.transport import _episode_summary

    class Episode:            # the summary reads totals(), stop_reason and message
        stop_reason, message = "done", "done"

        def totals(self):
            return defaultdict(float)

    obj = np.zeros((6, 6))
    obj[0, 0] = 2.5                 # behind the blocked column 1 and row 1 corner: cut off
    obj[4, 3] = 1.0
    blocked = np.zeros((6, 6), bool)
    blocked[0:2, 1] = blocked[1, 0] = True
    scene = Scene.from_arrays(obj, box(4.0, 4.0, 6.0, 6.0), blocked=blocked)
    summary = _episode_summary(scene, "walls.json", FabricParams(), SpillParams(), EpisodeParams(), Episode())
    assert summary["scene"] == "walls.json" and summary["unreachable_mass"] == 2.5
    json.dumps(summary, allow_nan=False)


def test_episode_reselect_flag_reaches_the_episode_params():
    from jaxplan.cli.app import build_parser
    from jaxplan.cli.transport import episode_params

    args = build_parser().parse_args(["episode", "--scene", "default", "--out", "o", "--reselect"])
    assert episode_params(args).reselect is True
    args = build_parser().parse_args(["episode", "--scene", "default", "--out", "o"])
    assert episode_params(args).reselect is False


def test_episode_with_zero_budget_is_empty_but_valid(tmp_path, capsys):
    out = tmp_path / "ep0"
    assert main(["episode", "--scene", "default", "--out", str(out), "--max-pushes", "0"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["pushes"] == 0 and summary["stop_reason"] == "budget"
    assert summary["remaining"] == pytest.approx(summary["initial_mass"])
    assert "budget" in capsys.readouterr().out
