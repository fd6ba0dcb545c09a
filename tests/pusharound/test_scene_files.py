"""PushScene.load / from_dict and ModeTable.load on broken input: one ValueError naming the file and the
field (``Scene file <path>: movables[0].mass: ...``), never a KeyError/TypeError/numpy message."""
from __future__ import annotations

import copy
import json

import pytest

from jaxplan.pusharound import ModeTable, PushScene

GOOD = {"workspace": [0, 0, 6, 4], "vehicle_width": 1.0, "start": [1, 2], "goal": [5, 2],
        "fixed": [{"name": "low", "pieces": [[[2.8, 0], [3.2, 0], [3.2, 1.6], [2.8, 1.6]]]}],
        "movables": [{"name": "high", "pieces": [[[2.8, 2.4], [3.2, 2.4], [3.2, 4], [2.8, 4]]], "mass": 8.0}],
        "robots": {"positions": [[0.5, 0.5], [1.0, 0.5]], "radius": 0.15}}
SELF_CROSSING = [[2.8, 2.4], [3.2, 4], [3.2, 2.4], [2.8, 4]]


def _changed(mutate) -> dict:
    doc = copy.deepcopy(GOOD)
    mutate(doc)
    return doc


def _movable(**changes):
    return lambda d: d["movables"][0].update(changes)


def _load_error(path) -> str:
    with pytest.raises(ValueError) as err:
        PushScene.load(path)
    message = str(err.value)
    assert message.startswith(f"Scene file {path}: ") and "\n" not in message, message
    return message


def test_the_good_scene_loads(tmp_path):
    path = tmp_path / "s.json"
    path.write_text(json.dumps(GOOD))
    assert len(PushScene.load(path).movables) == 1


@pytest.mark.parametrize("content, words", [
    (b"", "is empty"),
    (b" \n", "is empty"),
    (bytes(range(256)), "is not UTF-8 text"),
    (json.dumps(GOOD).encode()[:50], "not valid JSON"),
    (b"[" * 100_000, "nested too deeply"),
    (b"[1, 2]", "scene: expected a JSON object"),
    (b"null", "scene: expected a JSON object"),
])
def test_broken_file(tmp_path, content, words):
    path = tmp_path / "s.json"
    path.write_bytes(content)
    assert words in _load_error(path)


def test_directory_and_missing_file(tmp_path):
    assert "is a directory" in _load_error(tmp_path)
    assert "no such file" in _load_error(tmp_path / "missing.json")


@pytest.mark.parametrize("mutate, words", [
    (lambda d: d.update(colour=1), "scene: unknown key(s) 'colour'; the allowed keys are format"),
    (_movable(colour=1), "movables[0]: unknown key(s) 'colour'"),
    (lambda d: d["fixed"][0].update(colour=1), "fixed[0]: unknown key(s) 'colour'"),
    (lambda d: d["robots"].update(colour=1), "robots: unknown key(s) 'colour'"),
    (lambda d: d.pop("workspace"), "workspace: missing"),
    (lambda d: d.update(workspace="0064"), "workspace: expected [x0, y0, x1, y1]"),
    (lambda d: d.update(workspace=[False, 0, 6, 4]), "workspace: expected [x0, y0, x1, y1]"),
    (lambda d: d.update(workspace=[0, 0, 6, 2**64]), "workspace: values must lie within"),
    (lambda d: d.update(workspace=[0, 0, 2000, 4]), "workspace: sides of at most 1000 m"),
    (_movable(pieces=[[[2.8, 2.4], [3.2, 2.4], [3.2, 10**400]]]), "movables[0].pieces[0][2]: expected a vertex"),
    (_movable(pieces=[[[2.8, 2.4], [3.2, 2.4], [3.2, 1.7e308]]]), "movables[0].pieces[0][2]: values must lie within"),
    (lambda d: d.update(vehicle_width="1.0"), "vehicle_width: expected a number"),
    (lambda d: d.update(vehicle_width=float("nan")), "vehicle_width: must be finite"),
    (lambda d: d.update(vehicle_width=-1.0), "vehicle_width: must be > 0"),
    (lambda d: d.update(version=True), "format/version"),
    (_movable(mass="8"), "movables[0].mass: expected a number"),
    (_movable(mass=float("inf")), "movables[0].mass: must be finite"),
    (_movable(mass=-8.0), "movables[0].mass: must be > 0"),
    (_movable(inertia=-1.0), "movables[0].inertia: must be > 0"),
    (_movable(friction=-0.5), "movables[0].friction: must be >= 0"),
    (_movable(name=5), "movables[0].name: expected a string"),
    (_movable(shape="cylinder"), "movables[0].shape: expected an object"),
    (_movable(pose="abc"), "movables[0].pose: expected [x, y, psi]"),
    (_movable(pieces=5), "movables[0].pieces: expected a list"),
    (_movable(pieces=["abc"]), "movables[0].pieces[0]: expected a list of [x, y] vertices"),
    (_movable(pieces=[[[2.8, 2.4], [3.2, 2.4]]]), "movables[0].pieces[0]: expected at least 3"),
    (_movable(pieces=[[["2.8", 2.4], [3.2, 2.4], [3.2, 4]]]), "movables[0].pieces[0][0]: expected a vertex"),
    (_movable(pieces=[[[2.8, 2.4], [3.2], [3.2, 4]]]), "movables[0].pieces[0][1]: expected a vertex"),
    (_movable(pieces=[SELF_CROSSING]), "movables[0].pieces[0]: self-intersecting polygon"),
    (_movable(polygon=SELF_CROSSING), "movables[0]: has both 'pieces' and 'polygon'"),
    (lambda d: d["fixed"][0].update(pieces=[[[0, 0], [1, 1], [2, 2]]]), "fixed[0].pieces[0]: self-intersecting"),
    (lambda d: d.update(fixed=5), "fixed: expected a list"),
    (lambda d: d.update(movables={"a": 1}), "movables: expected a list"),
    (lambda d: d["movables"].append(5), "movables[1]: expected an object"),
    (lambda d: d.update(robots=[1, 2]), "robots: expected an object"),
    (lambda d: d["robots"].update(radius=-0.1), "robots.radius: must be > 0"),
    (lambda d: d["robots"].update(radius="0.1"), "robots.radius: expected a number"),
    (lambda d: d["robots"].update(positions=5), "robots.positions: expected a list"),
    (lambda d: d["robots"].update(positions=[[0.5, 0.5], [1.0]]), "robots.positions[1]: expected [x, y]"),
    (lambda d: d["robots"].update(positions=[["a", "b"]]), "robots.positions[0]: expected [x, y]"),
])
def test_bad_field_is_named(tmp_path, mutate, words):
    path = tmp_path / "s.json"
    path.write_text(json.dumps(_changed(mutate)))
    assert words in _load_error(path)


def test_self_crossing_outline_is_named():
    doc = _changed(lambda d: d["movables"][0].pop("pieces"))
    doc["movables"][0]["polygon"] = SELF_CROSSING
    with pytest.raises(ValueError, match=r"^movables\[0\]\.polygon: self-intersecting polygon"):
        PushScene.from_dict(doc)


# --------------------------------------------------------------------------------------------------
# ModeTable files
# --------------------------------------------------------------------------------------------------

RECORD = {"bin": 1, "n_robots": 2, "speed": 0.3, "omega": 0.0, "success": 1, "trials": 2, "contacts": None}


def _table(**record) -> dict:
    return {"format": "jaxplan.pusharound.modetable", "version": 1, "resolution": 0.1, "angle_bins": 16,
            "entries": {"sig": [{**RECORD, **record}]}}


def test_mode_table_round_trip(tmp_path):
    path = tmp_path / "t.json"
    path.write_text(json.dumps(_table()))
    assert len(ModeTable.load(path)) == 1


@pytest.mark.parametrize("content, words", [
    (b"", "is empty"),
    (bytes(range(256)), "is not UTF-8 text"),
    (b"{", "not valid JSON"),
    (b"[]", "format: not a ModeTable file"),
    (json.dumps(_table(bin="1")).encode(), "entries['sig'][0].bin: malformed mode record"),
    (json.dumps(_table(bin=16)).encode(), "entries['sig'][0].bin: malformed mode record (must be an int in [0, 15]"),
    (json.dumps(_table(speed=float("nan"))).encode(), "entries['sig'][0].speed"),
    (json.dumps(_table(success=3)).encode(), "success 3 > trials 2"),
    (json.dumps(_table(contacts="x")).encode(), "entries['sig'][0].contacts"),
    (json.dumps(_table(colour=1)).encode(), "unknown key(s) ['colour']"),
    (json.dumps({**_table(), "entries": []}).encode(), "entries: expected an object"),
    (json.dumps({**_table(), "resolution": "0.1"}).encode(), "resolution: must be a finite number"),
    (json.dumps({**_table(), "extra": 1}).encode(), "unknown key(s) 'extra'"),
])
def test_broken_mode_table(tmp_path, content, words):
    path = tmp_path / "t.json"
    path.write_bytes(content)
    with pytest.raises(ValueError) as err:
        ModeTable.load(path)
    assert str(err.value).startswith(f"ModeTable file {path}: ") and words in str(err.value), str(err.value)


def test_mode_table_directory(tmp_path):
    with pytest.raises(ValueError, match="is a directory"):
        ModeTable.load(tmp_path)
