"""`jaxplan pusharound`: result.json with every field, an independent W-clearance check of the reported
corridor, the other outputs, planning failure, --help and bad scene files."""
import json
import os

import numpy as np
import pytest
from shapely.geometry import LineString, Polygon, box

from jaxplan.cli import main
from jaxplan.pusharound import PushScene
from jaxplan.pusharound.execution import load_schedule
from tests.pusharound.test_execution import TINY

RESULT_KEYS = {"format", "version", "success", "reason", "W", "start", "goal", "workspace", "robot_radius", "scene",
               "planning", "schedule", "execution", "final_state", "connectivity", "obstacles", "robots_final",
               "w_clear_path", "scene_final_check"}
PUSH_KEYS = {"index", "movable", "name", "gap", "active_robots", "contacts_world", "directions_world", "contacts_body",
             "directions_body", "active", "velocity", "duration_s", "cost", "target_before", "target_after",
             "poses_before", "poses_after", "robots_before", "robots_after"}
OUTPUTS = ("result.json", "scene_final.json", "pusharound.png", "pusharound.gif")


@pytest.fixture(scope="module")
def tiny_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "tiny.json"
    path.write_text(json.dumps(TINY))
    return path


@pytest.fixture(scope="module")
def run(tiny_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("pa")
    rc = main(["pusharound", "--scene", str(tiny_file), "--out", str(out), "--time-limit", "40", "--backend", "c",
               "--max-frames", "5", "--fps", "4"])
    return rc, out, json.loads((out / "result.json").read_text())


def test_cli_writes_every_output(run):
    rc, out, res = run
    assert rc == 0
    for name in OUTPUTS:
        assert (out / name).stat().st_size > 0, name
    assert not [p for p in os.listdir(out) if p.startswith(".")]          # no temp files left behind


def test_result_json_has_every_field(run):
    _, _, res = run
    assert RESULT_KEYS <= set(res)
    assert res["W"] == TINY["vehicle_width"] and res["start"] == TINY["start"] and res["goal"] == TINY["goal"]
    assert res["workspace"] == TINY["workspace"]
    assert res["success"] is True and res["connectivity"] is True
    assert res["planning"]["success"] and res["planning"]["stats"]["simulated_pushes"] > 0
    assert len(res["schedule"]) >= 1
    for push in res["schedule"]:
        assert PUSH_KEYS <= set(push)
        assert push["name"] == "box" and push["active_robots"]
        assert np.allclose(np.linalg.norm(push["directions_world"], axis=-1), 1.0, atol=1e-5)
    ex = res["execution"]
    assert ex["execution_time_s"] > 0 and ex["replans"] >= 0 and len(ex["pushes"]) >= 1
    kinds = sorted((o["kind"], o["name"]) for o in res["obstacles"])
    assert kinds == [("fixed", "wall"), ("movable", "box")]                # EVERY obstacle is reported


def test_reported_corridor_is_w_clear(run):
    """Independent of the library: shapely on the numbers in result.json only."""
    _, _, res = run
    path = np.asarray(res["w_clear_path"])
    assert path.ndim == 2 and path.shape[1] == 2 and len(path) >= 2
    assert np.allclose(path[0], res["start"]) and np.allclose(path[-1], res["goal"])
    line, half, tol = LineString(path), 0.5 * res["W"], 1e-5
    for o in res["obstacles"]:
        assert line.distance(Polygon(o["polygon"], o["holes"])) >= half - tol, o["name"]
        assert min(line.distance(Polygon(p)) for p in o["pieces"]) >= half - tol, o["name"]
    assert box(*res["workspace"]).buffer(-(half - tol)).covers(line)


def test_scene_final_matches_the_reported_state(run):
    _, out, res = run
    final = json.loads((out / "scene_final.json").read_text())
    assert final["format"] == "jaxplan.pusharound.scene"
    poses = {o["name"]: o["pose"] for o in res["obstacles"] if o["kind"] == "movable"}
    for m in final["movables"]:
        assert np.allclose(m["pose"], poses[m["name"]], atol=1e-5)
    assert np.allclose(final["robots"]["positions"], res["robots_final"], atol=1e-5)
    # the robots backed off after the last push, so the final scene loads as a scene file again
    assert res["scene_final_check"] == "valid"
    assert len(PushScene.load(out / "scene_final.json").movables) == 1


def test_schedule_loads_back_from_result_json(run):
    _, out, res = run
    schedule = load_schedule(out / "result.json")
    assert len(schedule) == len(res["schedule"])
    for item, rec in zip(schedule, res["schedule"]):
        assert int(item.task.movable) == rec["movable"]
        np.testing.assert_allclose(item.task.velocity, rec["velocity"])
        np.testing.assert_allclose(item.poses_after, rec["poses_after"])
    with pytest.raises(ValueError, match="result"):
        load_schedule({"format": "something else"})
    with pytest.raises(ValueError, match=r"schedule\[0\]"):
        load_schedule({**res, "schedule": [{"movable": 0}]})


def test_failed_planning_still_writes_the_result(tmp_path):
    # A box of 10^6 kg: the robots cannot move it, and the 0.01 s budget ends the search anyway, so
    # planning fails whatever the search's speed (the geometry itself is feasible).
    blocked = {**TINY, "movables": [{**TINY["movables"][0], "mass": 1e6}]}
    scene_file = tmp_path / "blocked.json"
    scene_file.write_text(json.dumps(blocked))
    # --fps 1: the animation holds its last frame for 2 frames, not 15 (the default 10 fps x 1.5 s), the
    # same picture drawn again
    rc = main(["pusharound", "--scene", str(scene_file), "--out", str(tmp_path), "--time-limit", "0.01",
               "--no-execute", "--max-frames", "2", "--fps", "1", "--backend", "c"])
    assert rc == 0
    res = json.loads((tmp_path / "result.json").read_text())
    assert res["success"] is False and res["reason"] and res["w_clear_path"] is None
    assert res["execution"] is None and res["planning"]["success"] is False
    assert len(res["obstacles"]) == 2
    for name in OUTPUTS:
        assert (tmp_path / name).exists(), name


def test_scene_without_movables_is_already_clear(tmp_path, capsys):
    """Nothing to push (found by tests/fuzz/fuzz_cli.py): no physics world is built, the empty plan is a
    success and every output is written."""
    scene_file = tmp_path / "empty.json"
    scene_file.write_text(json.dumps({**TINY, "movables": []}))
    out = tmp_path / "o"
    assert main(["pusharound", "--scene", str(scene_file), "--out", str(out), "--time-limit", "1",
                 "--max-frames", "2", "--fps", "1", "--backend", "c"]) == 0   # --fps 1: see above
    res = json.loads((out / "result.json").read_text())
    assert res["success"] is True and res["schedule"] == [] and res["execution"] is None
    assert json.loads((out / "run.json").read_text())["status"] == "complete"


def test_help_works(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["pusharound", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for opt in ("--scene", "--out", "--seed", "--backend", "--time-limit", "--no-execute", "--mode-table"):
        assert opt in text


@pytest.mark.parametrize("content, words", [
    ('{"workspace": [0, 0', "not valid JSON"),
    ('[1, 2]', "JSON object"),
    (json.dumps({**TINY, "movables": [{**TINY["movables"][0], "mass": -1}]}), "mass"),
    (json.dumps({**TINY, "movables": [{"name": "b"}]}), "pieces"),
    (None, "no such scene file"),
    (b"", "is empty"),
    (bytes(range(256)), "is not UTF-8 text"),
    ("dir", "is a directory"),
    (json.dumps({**TINY, "colour": 1}), "unknown key(s) 'colour'"),
    (json.dumps({**TINY, "robots": [1, 2]}), "robots: expected an object"),
    (json.dumps({**TINY, "fixed": 5}), "fixed: expected a list"),
    (json.dumps({**TINY, "movables": [{**TINY["movables"][0], "shape": 5}]}), "movables[0].shape"),
])
def test_bad_scene_file_is_a_clear_error(tmp_path, capsys, content, words):
    bad = tmp_path / "bad.json"
    if content == "dir":
        bad.mkdir()
    elif isinstance(content, bytes):
        bad.write_bytes(content)
    elif content is not None:
        bad.write_text(content)
    with pytest.raises(SystemExit) as exc:
        main(["pusharound", "--scene", str(bad), "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --scene") and words in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1 and "bad.json" in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("content, words", [
    (bytes(range(256)), "is not UTF-8 text"),
    (b"", "is empty"),
    (b"{", "not valid JSON"),
    ("dir", "is a directory"),
    ("no_folder", "does not exist"),
])
def test_bad_mode_table_is_a_clear_error(tmp_path, tiny_file, capsys, content, words):
    table = tmp_path / "modes.json"
    if content == "dir":
        table.mkdir()
    elif content == "no_folder":
        table = tmp_path / "missing" / "modes.json"
    else:
        table.write_bytes(content)
    with pytest.raises(SystemExit) as exc:
        main(["pusharound", "--scene", str(tiny_file), "--mode-table", str(table), "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --mode-table: ") and words in err[0], err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("change, words", [
    ({"vehicle_width": 10.0}, "vehicle_width: 10 m is not narrower than the workspace's narrow side (3 m"),
    ({"start": [0.2, 2.2]}, "start: (0.2, 2.2) is 0.2 m from a workspace wall"),
    # a fixed stub under the box leaves at most 0.75 m < W below the wall, wherever the box goes
    ({"fixed": TINY["fixed"] + [{"name": "stub", "pieces": [[[1.9, 0.0], [2.1, 0.0], [2.1, 0.25], [1.9, 0.25]]]}]},
     "fixed: the fixed obstacles and walls alone leave no W-clear corridor"),
    ({"robots": None}, "robots: the scene has no robot, and its movables block every W-clear corridor"),
])
def test_infeasible_scene_is_refused_before_planning(tmp_path, capsys, change, words):
    scene_file = tmp_path / "wide.json"
    scene_file.write_text(json.dumps({k: v for k, v in {**TINY, **change}.items() if v is not None}))
    with pytest.raises(SystemExit) as exc:
        main(["pusharound", "--scene", str(scene_file), "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: --scene: {scene_file}: ") and words in lines[0], lines
    assert not (tmp_path / "o").exists()


def test_unusable_mode_table_is_refused_before_planning(tmp_path, capsys):
    (tmp_path / "blocker").write_text("a file")
    for table in (tmp_path, tmp_path / "blocker" / "modes.json", tmp_path / "missing" / "modes.json"):
        with pytest.raises(SystemExit) as exc:
            main(["pusharound", "--out", str(tmp_path / "o"), "--mode-table", str(table)])
        assert exc.value.code == 2
        assert capsys.readouterr().err.startswith("error: --mode-table: ")
    assert not (tmp_path / "o").exists()
