"""MovingAI ``.map`` files (``read_movingai_map``) and the sites built on them (``site_from_map``):
parsing, the character classes, the row flip, errors naming the file and the line, and the sites'
guarantees (deterministic by seed, no material or target on a blocked cell, cut-off material reported)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely

from jaxplan.transport import MAX_FILE_SIDE, Scene, read_movingai_map, site_from_map
from jaxplan.transport import maps as M

SMALL = Path(__file__).resolve().parents[1] / "data" / "small.map"


def _map(tmp_path, rows, name="m.map", header=None) -> Path:
    h, w = len(rows), len(rows[0]) if rows else 0
    header = header if header is not None else f"type octile\nheight {h}\nwidth {w}\nmap\n"
    path = tmp_path / name
    path.write_text(header + "\n".join(rows) + "\n")
    return path


def _error(path) -> str:
    with pytest.raises(ValueError) as err:
        read_movingai_map(path)
    message = str(err.value)
    assert message.startswith(f"Map file {path}: ") and "\n" not in message, message
    return message


# --------------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------------

def test_small_map_parses_with_rows_flipped():
    blocked = read_movingai_map(SMALL)
    assert blocked.shape == (24, 32) and blocked.dtype == bool
    assert int(blocked.sum()) == 48 + 54 + 8 + 12 + 4   # buildings, trees, pond, out of bounds
    lines = SMALL.read_text().splitlines()[4:]
    for y, line in enumerate(lines):   # file line y (0 = top) is row H - 1 - y
        np.testing.assert_array_equal(blocked[23 - y], [ch in "@OTW" for ch in line])
    assert blocked[23 - 3, 4] and blocked[23 - 5, 14] and not blocked[23 - 5, 15]   # building, a tree
    assert not blocked[23 - 11, 8] and not blocked[23, 26]                          # swamp, ground


@pytest.mark.parametrize("char, is_blocked", [(".", False), ("G", False), ("S", False), ("@", True), ("O", True),
                                              ("T", True), ("W", True)])
def test_each_character_class(tmp_path, char, is_blocked):
    blocked = read_movingai_map(_map(tmp_path, ["." + char + ".", "..."]))
    assert blocked.tolist() == [[False, False, False], [False, is_blocked, False]]


def test_width_before_height_and_crlf_line_ends(tmp_path):
    path = tmp_path / "crlf.map"
    path.write_bytes(b"type octile\r\nwidth 3\r\nheight 2\r\nmap\r\n@..\r\n..T\r\n\r\n")
    assert read_movingai_map(path).tolist() == [[False, False, True], [True, False, False]]


@pytest.mark.parametrize("content, words", [
    ("type grid\nheight 1\nwidth 1\nmap\n.\n", "line 1: expected 'type octile'"),
    ("type octile\nheight x\nwidth 1\nmap\n.\n", "line 2: height must be an integer in [1, 4096]"),
    ("type octile\nheight 0\nwidth 1\nmap\n", "line 2: height must be an integer in [1, 4096] (a map holds at most"),
    (f"type octile\nheight 1\nwidth {MAX_FILE_SIDE + 1}\nmap\n.\n", "line 3: width must be an integer in [1, 4096]"),
    ("type octile\nheight 1\ndepth 1\nmap\n.\n", "line 3: expected 'width N'"),
    ("type octile\nheight 1\nwidth 1\nmaps\n.\n", "line 4: expected 'map'"),
    ("type octile\nheight 1\n", "has 3 line(s), fewer than the 4 header lines"),
    ("type octile\nheight 3\nwidth 2\nmap\n..\n..\n", "has 2 grid line(s) after 'map' but the header says height 3"),
    ("type octile\nheight 2\nwidth 3\nmap\n...\n....\n", "line 6: has 4 character(s) but the header says width 3"),
    ("type octile\nheight 2\nwidth 3\nmap\n...\n. .\n", "line 6, character 2: ' ' is not a map character"),
    ("type octile\nheight 2\nwidth 3\nmap\n..x\n...\n", "line 5, character 3: 'x' is not a map character; a "
                                                        "MovingAI map cell is '.', 'G', 'S' (free) or '@', 'O', "
                                                        "'T', 'W' (blocked)"),
    ("type octile\nheight 1\nwidth 3\nmap\n...\n...\n", "line 6: more grid lines than the header's height 1"),
])
def test_bad_maps_name_the_line(tmp_path, content, words):
    path = tmp_path / "bad.map"
    path.write_text(content)
    message = _error(path)
    assert words in message, message


def test_a_stray_byte_is_named_not_a_decoder_error(tmp_path):
    path = tmp_path / "bytes.map"
    path.write_bytes(b"type octile\nheight 1\nwidth 3\nmap\n.\xff.\n")
    assert "line 5, character 2: the byte 0xff is not a map character" in _error(path)


def test_the_file_itself(tmp_path, monkeypatch):
    assert "no such file" in _error(tmp_path / "missing.map")
    (tmp_path / "folder.map").mkdir()
    assert "is a directory" in _error(tmp_path / "folder.map")
    (tmp_path / "empty.map").write_bytes(b"")
    assert "is empty" in _error(tmp_path / "empty.map")
    monkeypatch.setattr(M, "_MAX_MAP_BYTES", 40)   # a file larger than any map it could hold is not read
    assert "is 41 bytes, more than a map of 4096 x 4096 cells takes (40)" in _error(_map(tmp_path, ["..."] * 2))


# --------------------------------------------------------------------------------------------------
# sites
# --------------------------------------------------------------------------------------------------

def _cell_centres(mask) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = np.nonzero(mask)
    return cols + 0.5, rows + 0.5


@pytest.mark.parametrize("seed", range(6))
def test_sites_keep_blocked_cells_clear(seed):
    scene = site_from_map(SMALL, seed)
    blocked, obj, mask = (np.asarray(a) for a in (scene.blocked, scene.obj, scene.target_mask))
    np.testing.assert_array_equal(blocked, read_movingai_map(SMALL))
    assert scene.name == f"small_site{seed}" and scene.shape == (24, 32)
    assert not (obj[blocked] > 0).any() and not (obj[mask] > 0).any()          # material on free cells only
    assert not (mask & blocked).any()
    assert not shapely.intersects_xy(scene.target, *_cell_centres(blocked)).any()   # not even on the boundary
    parts = list(getattr(scene.target, "geoms", [scene.target]))
    assert len(parts) == 2 and parts[0].distance(parts[1]) > 0.5
    assert obj.sum() > 0 and np.all(obj == np.rint(obj)) and obj.max() <= M.MAX_PILE_COUNT


def test_sites_are_deterministic_by_seed():
    a, b, c = site_from_map(SMALL, 3), site_from_map(SMALL, 3), site_from_map(SMALL, 4)
    np.testing.assert_array_equal(np.asarray(a.obj), np.asarray(b.obj))
    assert a.target.equals_exact(b.target, 0.0)
    assert not (np.array_equal(np.asarray(a.obj), np.asarray(c.obj)) and a.target.equals(c.target))


def test_site_options(tmp_path):
    scene = site_from_map(SMALL, 1, n_targets=1, target_radius=1.0, n_piles=3, fill=0.5, cell_size=2.0, name="s")
    assert scene.name == "s" and float(scene.cell_size) == 2.0 and scene.target.geom_type == "Polygon"
    free = ~np.asarray(scene.blocked) & ~np.asarray(scene.target_mask)
    assert 0.3 < float(np.asarray(scene.obj)[free].mean()) < 0.7    # about fill objects per free cell
    empty = site_from_map(SMALL, 1, fill=0.0)
    assert float(empty.total_mass) == 0.0
    saved = Scene.load(scene.save(tmp_path / "site.json"))            # a site is a scene like any other
    np.testing.assert_array_equal(np.asarray(saved.blocked), np.asarray(scene.blocked))


def test_material_cut_off_from_every_target_is_reported(tmp_path):
    """A closed courtyard: targets go to the map's largest open area, material anywhere free; what lies in
    the courtyard is ``unreachable_mass``."""
    rows = ["." * 20] * 3 + ["......@@@@@@........", "......@....@........", "......@....@........",
                             "......@@@@@@........"] + ["." * 20] * 5
    path = _map(tmp_path, rows, name="courtyard.map")
    seen = 0.0
    for seed in range(6):
        scene = site_from_map(path, seed, n_piles=30, fill=1.0)
        cut = np.asarray(scene.cut_off)
        assert cut.sum() == 8 and not (np.asarray(scene.target_mask) & cut).any()
        assert float(scene.unreachable_mass) == float(np.asarray(scene.obj)[cut].sum())
        seen += float(scene.unreachable_mass)
    assert seen > 0


@pytest.mark.parametrize("kwargs, words", [
    ({"seed": -1}, "site_from_map: seed: must be an int >= 0; got -1"),
    ({"seed": 1.5}, "site_from_map: seed: must be an int >= 0"),
    ({"n_targets": 0}, "site_from_map: n_targets: must be an int in [1, 64]"),
    ({"target_radius": 0.0}, "site_from_map: target_radius (cells): must be a finite number > 0"),
    ({"target_radius": float("nan")}, "site_from_map: target_radius (cells): must be a finite number > 0"),
    ({"fill": -1.0}, "site_from_map: fill: must be a finite number >= 0"),
    ({"n_piles": -1}, "site_from_map: n_piles: must be an int in [0, 1000000]"),
    ({"cell_size": 0}, "site_from_map: cell_size: must be a finite number > 0"),
    ({"name": 5}, "site_from_map: name: must be a str or None"),
])
def test_bad_site_arguments(kwargs, words):
    with pytest.raises(ValueError) as err:
        site_from_map(SMALL, **kwargs)
    assert words in str(err.value), str(err.value)


def test_no_room_for_the_targets_names_the_map(tmp_path):
    with pytest.raises(ValueError, match=r"^Map file .*small.map: has no room for a square of 21 x 21 free cells "
                                         r"for target 1 of 2 \(target_radius 10 cells\)"):
        site_from_map(SMALL, target_radius=10.0)
    walled = _map(tmp_path, ["@@@", "@.@", "@@@"], name="walled.map")
    with pytest.raises(ValueError, match="has no room for a free cell for target 2 of 2"):
        site_from_map(walled)
    assert site_from_map(walled, n_targets=1, n_piles=0).target_mask.sum() == 1   # the default radius shrinks
    with pytest.raises(ValueError, match="every cell is blocked"):
        site_from_map(_map(tmp_path, ["@@", "TW"], name="full.map"))
