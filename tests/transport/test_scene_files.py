"""Scene.load on broken files: every problem is one ValueError "Scene file <path>: ..." naming what is
wrong (docs/scene-files.md, "What is checked when a file is read"), never a decoder's traceback; and
format version 2, whose ``blocked`` key holds the blocked cells (version-1 files still load)."""
from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest

from jaxplan.transport import scene as S
from jaxplan.transport import scene_files as SF

WKT = "POLYGON ((2 0, 3 0, 3 2, 2 2, 2 0))"
DOC = {"format_version": 1, "name": "t", "cell_size": 1.0, "origin": [0.0, 0.0],
       "obj": [[0.0, 1.0, 2.0], [0.0, 0.0, 3.0], [1.0, 0.0, 0.0]], "target": WKT}


def _arrays(**changes) -> dict:
    arrays = {"format_version": np.int64(1), "obj": np.ones((3, 3), np.float32), "cell_size": np.float64(1.0),
              "origin": np.zeros(2), "target_wkt": np.str_(WKT), "name": np.str_("t")}
    arrays.update(changes)
    return {k: v for k, v in arrays.items() if v is not None}


def _load_error(path) -> str:
    with pytest.raises(ValueError) as err:
        S.Scene.load(path)
    message = str(err.value)
    assert message.startswith(f"Scene file {path}: "), message
    assert "\n" not in message
    return message


# --------------------------------------------------------------------------------------------------
# both formats: the file itself
# --------------------------------------------------------------------------------------------------

def test_valid_files_load(tmp_path):
    (tmp_path / "s.json").write_text(json.dumps(DOC))
    np.savez(tmp_path / "s.npz", **_arrays())
    assert S.Scene.load(tmp_path / "s.json").shape == (3, 3)
    assert S.Scene.load(tmp_path / "s.npz").name == "t"


@pytest.mark.parametrize("suffix", [".npz", ".json"])
def test_empty_missing_and_directory(tmp_path, suffix):
    empty = tmp_path / f"empty{suffix}"
    empty.write_bytes(b"")
    assert "is empty" in _load_error(empty)
    assert "no such file" in _load_error(tmp_path / f"missing{suffix}")
    folder = tmp_path / f"folder{suffix}"
    folder.mkdir()
    assert "is a directory" in _load_error(folder)


@pytest.mark.parametrize("suffix", [".npz", ".json"])
def test_unreadable_file(tmp_path, monkeypatch, suffix):
    path = tmp_path / f"s{suffix}"
    path.write_bytes(b"x")

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(zipfile.ZipFile, "__init__", refuse)
    monkeypatch.setattr(type(path), "read_bytes", refuse)
    assert "Permission denied" in _load_error(path)


# --------------------------------------------------------------------------------------------------
# .npz
# --------------------------------------------------------------------------------------------------

def test_truncated_npz(tmp_path):
    np.savez(tmp_path / "valid.npz", **_arrays())
    path = tmp_path / "trunc.npz"
    path.write_bytes((tmp_path / "valid.npz").read_bytes()[:1001])
    assert "damaged" in _load_error(path)


def test_crc_corrupted_npz(tmp_path):
    path = tmp_path / "crc.npz"
    np.savez(path, **_arrays())
    data = bytearray(path.read_bytes())
    at = data.index("POLYGON".encode("utf-32-le"))  # inside target_wkt.npy's stored bytes
    data[at] ^= 0xFF
    path.write_bytes(bytes(data))
    assert "CRC" in _load_error(path)


@pytest.mark.parametrize("content", [b"hello, not an archive", bytes(range(256)) * 4])
def test_text_or_noise_named_npz(tmp_path, content):
    path = tmp_path / "s.npz"
    path.write_bytes(content)
    message = _load_error(path)
    assert "not a NumPy .npz archive" in message and "allow_pickle" not in message


def test_object_array_is_never_unpickled(tmp_path):
    path = tmp_path / "s.npz"
    np.savez(path, **_arrays(obj=np.array([[1, "a"]], dtype=object)))
    assert "obj: is an object (pickled) array" in _load_error(path)


@pytest.mark.parametrize("changes, words", [
    ({"obj": np.zeros((3, 3, 3), np.float32)}, "obj: must be 2-D"),
    ({"obj": np.ones((3, 3), bool)}, "obj: holds dtype bool"),
    ({"obj": np.array([["a", "b"]])}, "obj: holds dtype <U1"),
    ({"obj": np.zeros((1, S.MAX_FILE_SIDE + 1), np.float32)}, "at most 4096 x 4096"),
    ({"format_version": np.str_("1")}, "format_version: holds dtype <U1"),
    ({"format_version": np.int64(3)}, "reads format_version 1 or 2 only"),
    ({"cell_size": np.array([1.0, 2.0])}, "cell_size: holds dtype float64 with shape (2,)"),
    ({"origin": np.array(["a", "b"])}, "origin: holds dtype <U1"),
    ({"target_wkt": np.float64(1.0)}, "target_wkt: holds dtype float64"),
    ({"target_wkt": np.str_("POLYGON ((0 0, 1")}, "target: could not parse the WKT"),
    ({"name": np.float64(1.0)}, "name: holds dtype float64"),
    ({"cell_size": np.float64(np.nan)}, "cell_size: must be finite"),
    ({"obj": -np.ones((3, 3), np.float32)}, "obj: counts must be finite and >= 0"),
    ({"colour": np.int64(1)}, "unknown key(s) 'colour'"),
    ({"origin": None}, "missing key(s) origin"),
])
def test_bad_npz_fields(tmp_path, changes, words):
    path = tmp_path / "s.npz"
    np.savez(path, **_arrays(**changes))
    assert words in _load_error(path)


def test_huge_shape_in_the_header_is_refused_before_reading(tmp_path):
    """A header claiming 100000 x 100000 floats (40 GB) over a few bytes: refused, nothing allocated."""
    path = tmp_path / "huge.npz"
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f4", "fortran_order": False,
                                                  "shape": (100_000, 100_000)})
    with zipfile.ZipFile(path, "w") as zf:
        for key, value in _arrays(obj=None).items():
            buf = io.BytesIO()
            np.save(buf, value)
            zf.writestr(f"{key}.npy", buf.getvalue())
        zf.writestr("obj.npy", header.getvalue() + b"\0" * 16)
    assert "100000 x 100000" in _load_error(path)


@pytest.mark.parametrize("garbage", [b"{'descr': '<f4', (((", b"\xff\xfe not python", b"{" * 200])
def test_damaged_npy_header_is_named(tmp_path, garbage):
    """A header that is not the dict literal numpy writes (found by tests/fuzz/fuzz_cli.py)."""
    path = tmp_path / "bad_header.npz"
    magic = np.lib.format.magic(1, 0)
    body = garbage.ljust(118) + b"\n"
    with zipfile.ZipFile(path, "w") as zf:
        for key, value in _arrays().items():
            buf = io.BytesIO()
            np.save(buf, value)
            zf.writestr(f"{key}.npy", buf.getvalue())
        zf.writestr("target_wkt.npy", magic + len(body).to_bytes(2, "little") + body)
    assert "is damaged" in _load_error(path) or "target_wkt" in _load_error(path)


# --------------------------------------------------------------------------------------------------
# .json
# --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("content, words", [
    (bytes(range(256)), "is not UTF-8 text"),
    (b'{"format_version": 1, "obj": [[0', "not valid JSON"),
    (b"[1, 2]", "the top level must be a JSON object"),
    (b"[" * 100_000, "damaged"),
])
def test_bad_json_text(tmp_path, content, words):
    path = tmp_path / "s.json"
    path.write_bytes(content)
    assert words in _load_error(path)


@pytest.mark.parametrize("changes, words", [
    ({"obj": [[0, 1, 2], [0, 1]]}, "obj: row 1 has 2 value(s) but row 0 has 3"),
    ({"obj": [[0, "a", 2]]}, "obj: row 0, column 1 is a string"),
    ({"obj": [[0, True, 2]]}, "obj: row 0, column 1 is a boolean"),
    ({"obj": [[[0], [1]], [[2], [3]]]}, "obj must be 2-D"),
    ({"obj": {"a": 1}}, "obj: must be a non-empty list of H rows"),
    ({"obj": []}, "obj: must be a non-empty list of H rows"),
    ({"obj": [[0.0]] * (S.MAX_FILE_SIDE + 1)}, "at most 4096 x 4096"),
    ({"obj": [[0, float("nan"), 2]]}, "NaN"),
    ({"obj": [[0, float("inf"), 2]]}, "infinite"),
    ({"obj": [[0, -1, 2]]}, "negative"),
    ({"cell_size": "1"}, "cell_size: must be a number"),
    ({"cell_size": True}, "cell_size: must be a number"),
    ({"cell_size": -1.0}, "cell_size: must be finite and > 0"),
    ({"origin": [0, 0, 0]}, "origin: must be a list of 2 numbers"),
    ({"origin": "0,0"}, "origin: must be a list of 2 numbers"),
    ({"origin": [True, False]}, "origin: must be a list of 2 numbers"),
    ({"target": 5}, "target: must be a WKT string"),
    ({"target": "POLYGON ((0 0, 1"}, "target: could not parse the WKT"),
    ({"target": "POINT (1 1)"}, "target: must be a shapely Polygon or MultiPolygon"),
    ({"target": "POLYGON ((0 0, 2 2, 2 0, 0 2, 0 0))"}, "target: the geometry is invalid"),
    ({"format_version": "1"}, "format_version: must be the integer 1"),
    ({"format_version": 1.0}, "format_version: must be the integer 1"),
    ({"format_version": 3}, "reads format_version 1 or 2 only"),
    ({"name": 5}, "name: must be a string or null"),
    ({"colour": "red"}, "unknown key(s) 'colour'; a scene file has exactly the keys format_version, name"),
    ({"cell_size": None}, "cell_size: must be a number"),
])
def test_bad_json_fields(tmp_path, changes, words):
    path = tmp_path / "s.json"
    path.write_text(json.dumps({**DOC, **changes}))
    assert words in _load_error(path)


@pytest.mark.parametrize("key", ["format_version", "obj", "cell_size", "origin", "target"])
def test_missing_json_key(tmp_path, key):
    path = tmp_path / "s.json"
    path.write_text(json.dumps({k: v for k, v in DOC.items() if k != key}))
    assert f"missing key(s) {key}" in _load_error(path)


def test_save_refuses_a_grid_load_could_not_read(tmp_path, monkeypatch):
    path = tmp_path / "s.json"
    path.write_text(json.dumps(DOC))
    scene = S.Scene.load(path)
    monkeypatch.setattr(S, "MAX_FILE_SIDE", 2)
    with pytest.raises(ValueError, match="at most 2 x 2"):
        scene.save(tmp_path / "big.npz")
    assert not (tmp_path / "big.npz").exists()


def _archive(path, members: dict) -> None:
    """A scene archive of ``members`` (key -> raw .npy bytes), the rest from ``_arrays``."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for key, value in _arrays().items():
            if key not in members:
                buf = io.BytesIO()
                np.save(buf, value)
                zf.writestr(f"{key}.npy", buf.getvalue())
        for key, raw in members.items():
            zf.writestr(f"{key}.npy", raw)


def test_a_member_that_decompresses_beyond_its_bound_is_refused_unread(tmp_path, monkeypatch):
    """The defect: a 5 MB deflated member that decompressed to a 1 GiB string was read (2.6 GB); here a
    target of 2,000 characters against a bound of 1,000 bytes, checked from the archive's directory."""
    buf = io.BytesIO()
    np.save(buf, np.str_("POLYGON ((2 0, 3 0, 3 2, 2 2, 2 0))" + " " * 2000))
    path = tmp_path / "big.npz"
    _archive(path, {"target_wkt": buf.getvalue()})
    monkeypatch.setattr(SF, "MAX_MEMBER_BYTES", 1000)
    message = _load_error(path)
    assert "target_wkt: the archive member decompresses to" in message and "at most 1,000" in message


def test_a_header_declaring_a_huge_string_is_refused_before_reading(tmp_path):
    """A target whose .npy header declares a 400 MB string over a few bytes of data."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<U100000000", "fortran_order": False, "shape": ()})
    path = tmp_path / "huge.npz"
    _archive(path, {"target_wkt": header.getvalue() + b"\0" * 16})
    message = _load_error(path)
    assert "target_wkt: its header declares 400,000,000 bytes" in message


def test_a_member_held_twice_is_refused(tmp_path):
    """Which copy of a duplicated name a reader takes is not defined: a bad copy first and a good one
    last was read without complaint (found by tests/fuzz/fuzz_cli.py, class archive)."""
    buf = io.BytesIO()
    np.save(buf, np.float64(-1.0))
    path = tmp_path / "twice.npz"
    _archive(path, {})
    with zipfile.ZipFile(path, "a") as zf:
        zf.writestr("cell_size.npy", buf.getvalue())
    assert "holds the member 'cell_size.npy' twice" in _load_error(path)


# --------------------------------------------------------------------------------------------------
# format version 2: blocked cells
# --------------------------------------------------------------------------------------------------

BLOCKED = np.array([[False, False, False], [True, False, False], [False, True, False]])
DOC2 = {**DOC, "format_version": 2, "obj": [[0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]],
        "blocked": ["...", "@..", ".@."]}


def _arrays2(**changes) -> dict:
    return _arrays(**{"format_version": np.int64(2), "obj": np.array(DOC2["obj"], np.float32),
                      "blocked": BLOCKED, **changes})


def _blocked_scene(name="walls"):
    """7 x 9 with a wall (rows 1..5 of column 4, a gap at the top), material on both sides, a target on the
    right and a pocket closed on all sides holding material that no target reaches."""
    blocked = np.zeros((7, 9), bool)
    blocked[0:6, 4] = True
    blocked[0:3, 0] = blocked[0:3, 2] = blocked[3, 0:3] = True   # closes the pocket (rows 0..2, col 1)
    obj = np.zeros((7, 9))
    obj[5, 1], obj[6, 6], obj[1, 1] = 2.0, 3.0, 4.0
    return S.Scene.from_arrays(obj, S.box(7.0, 2.0, 9.0, 5.0), name=name, blocked=blocked)


def test_blocked_scene_fixture_is_what_it_says():
    scene = _blocked_scene()
    assert np.asarray(scene.blocked).sum() == 6 + 3 + 3 + 3
    assert float(scene.unreachable_mass) == 4.0


@pytest.mark.parametrize("suffix", [".npz", ".json"])
def test_version_2_round_trip_keeps_blocked(tmp_path, suffix):
    scene = _blocked_scene()
    back = S.Scene.load(scene.save(tmp_path / f"s{suffix}"))
    for key in ("obj", "blocked", "target_mask", "dist", "tvec", "detour", "cell_size", "origin"):
        np.testing.assert_array_equal(np.asarray(getattr(back, key)), np.asarray(getattr(scene, key)), err_msg=key)
        assert np.asarray(getattr(back, key)).dtype == np.asarray(getattr(scene, key)).dtype, key
    assert float(back.unreachable_mass) == 4.0 and back.name == "walls"


def test_save_writes_version_2_with_blocked_in_both_formats(tmp_path):
    scene = _blocked_scene()
    doc = json.loads(scene.save(tmp_path / "s.json").read_text())
    assert doc["format_version"] == SF.FORMAT_VERSION == 2
    assert len(doc["blocked"]) == 7 and doc["blocked"][0] == "@.@.@...." and doc["blocked"][6] == "." * 9
    assert list(doc) == ["format_version", "name", "cell_size", "origin", "obj", "blocked", "target"]
    with np.load(scene.save(tmp_path / "s.npz"), allow_pickle=False) as data:
        assert int(data["format_version"]) == 2
        assert data["blocked"].dtype == bool and data["blocked"].shape == (7, 9)
        np.testing.assert_array_equal(data["blocked"], np.asarray(scene.blocked))


@pytest.mark.parametrize("suffix", [".npz", ".json"])
def test_a_scene_without_blocked_cells_is_saved_all_free(tmp_path, suffix):
    path = tmp_path / "v1.json"
    path.write_text(json.dumps(DOC))
    back = S.Scene.load(S.Scene.load(path).save(tmp_path / f"s{suffix}"))
    assert not np.asarray(back.blocked).any()
    if suffix == ".json":
        assert json.loads((tmp_path / "s.json").read_text())["blocked"] == ["..."] * 3


def test_version_1_files_load_with_every_cell_free(tmp_path):
    (tmp_path / "s.json").write_text(json.dumps(DOC))
    np.savez(tmp_path / "s.npz", **_arrays())
    for name in ("s.json", "s.npz"):
        scene = S.Scene.load(tmp_path / name)
        assert scene.shape == (3, 3) and not np.asarray(scene.blocked).any(), name
        assert float(scene.unreachable_mass) == 0.0


def test_version_2_files_written_by_hand_load(tmp_path):
    (tmp_path / "s.json").write_text(json.dumps(DOC2))
    np.savez(tmp_path / "s.npz", **_arrays2())
    for name in ("s.json", "s.npz"):
        np.testing.assert_array_equal(np.asarray(S.Scene.load(tmp_path / name).blocked), BLOCKED, err_msg=name)


def test_blocked_needs_version_2_and_version_2_needs_blocked(tmp_path):
    (tmp_path / "v1.json").write_text(json.dumps({**DOC, "blocked": DOC2["blocked"]}))
    assert "unknown key(s) 'blocked'" in (m := _load_error(tmp_path / "v1.json")) and "format_version 2" in m
    np.savez(tmp_path / "v1.npz", **_arrays(blocked=BLOCKED))
    assert "unknown key(s) 'blocked'" in (m := _load_error(tmp_path / "v1.npz")) and "format_version 2" in m
    (tmp_path / "v2.json").write_text(json.dumps({k: v for k, v in DOC2.items() if k != "blocked"}))
    assert "missing key(s) blocked" in _load_error(tmp_path / "v2.json")
    np.savez(tmp_path / "v2.npz", **_arrays2(blocked=None))
    assert "missing key(s) blocked" in _load_error(tmp_path / "v2.npz")


@pytest.mark.parametrize("blocked, words", [
    (np.zeros((3, 3), np.uint8), "blocked: holds dtype uint8 with shape (3, 3); it must hold a bool (H, W) array"),
    (np.zeros((3, 3), np.float32), "blocked: holds dtype float32"),
    (np.array([["@", ".", "."]] * 3), "blocked: holds dtype <U1"),
    (np.zeros((3, 4), bool), "blocked: has shape (3, 4) but obj has (3, 3)"),
    (np.zeros((3, 3, 1), bool), "blocked: has shape (3, 3, 1) but obj has (3, 3)"),
    (np.zeros(9, bool), "blocked: has shape (9,) but obj has (3, 3)"),
    (np.array([[True, None, False]] * 3, dtype=object), "blocked: is an object (pickled) array"),
])
def test_bad_npz_blocked(tmp_path, blocked, words):
    path = tmp_path / "s.npz"
    np.savez(path, **_arrays2(blocked=blocked))
    message = _load_error(path)
    assert words in message, message


@pytest.mark.parametrize("blocked, words", [
    ("@..\n...\n...", "blocked: must be a list of 3 strings of 3 characters"),
    ([[True, False, False]] * 3, "blocked: row 0 is a list ([true, false, false]), not a string"),
    (["...", "..."], "blocked: has 2 row(s) but obj has 3"),
    (["...", "....", "..."], "blocked: row 1 has 4 character(s) but obj has 3 column(s)"),
    (["...", "..", "..."], "blocked: row 1 has 2 character(s)"),
    (["...", ".#.", "..."], "blocked: row 1, column 1 is '#'; use '@' for a blocked cell and '.' for a free one"),
    (["...", "...", "..T"], "blocked: row 2, column 2 is 'T'"),
    (["...", "...", ".. "], "blocked: row 2, column 2 is ' '"),
    (["...", None, "..."], "blocked: row 1 is null"),
    (None, "blocked: must be a list of 3 strings"),
])
def test_bad_json_blocked(tmp_path, blocked, words):
    path = tmp_path / "s.json"
    path.write_text(json.dumps({**DOC2, "blocked": blocked}))
    message = _load_error(path)
    assert words in message, message


@pytest.mark.parametrize("suffix", [".json", ".npz"])
def test_material_or_target_on_a_blocked_cell_is_refused_naming_the_first(tmp_path, suffix):
    path = tmp_path / f"s{suffix}"
    on_material = ["...", "...", "@@."]            # row 2 holds 1.0 at col 0
    on_target = ["..@", "...", "..."]              # the target covers col 2 of rows 0 and 1
    for rows, words in ((on_material, "blocked: 1 blocked cell(s) hold material (first at row 2, col 0)"),
                        (on_target, "blocked: 1 blocked cell(s) hold target area (first at row 0, col 2)")):
        if suffix == ".json":
            path.write_text(json.dumps({**DOC2, "blocked": rows}))
        else:
            np.savez(path, **_arrays2(blocked=np.array([[ch == "@" for ch in row] for row in rows])))
        assert _load_error(path).startswith(f"Scene file {path}: {words}")
