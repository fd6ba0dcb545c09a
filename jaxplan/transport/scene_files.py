"""Scene files: the ``.npz`` and ``.json`` formats of ``Scene.save`` / ``Scene.load``.

Reading is defensive: the grid's shape is checked before its counts are read, and every problem with
a file (unreadable, damaged, wrong keys or types) raises one ``ValueError("Scene file <path>: <what>;
<fix>")``. The formats and the checks are in ``docs/scene-files.md``. The values are validated by
``Scene.from_arrays`` afterwards, like any other input.

Format version 2 (written by ``Scene.save``) adds ``blocked``, the scene's blocked cells: a bool
``(H, W)`` array in ``.npz``, H strings of W characters (``@`` blocked, ``.`` free) in ``.json``.
Version-1 files (no ``blocked``) still load, with every cell free.
"""
from __future__ import annotations

import json
import math
import re
import struct
import tokenize
import zipfile
import zlib
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import MultiPolygon

__all__ = ["FORMAT_VERSION", "MAX_FILE_SIDE", "MAX_MEMBER_BYTES", "READ_VERSIONS", "read_scene_file",
           "scene_file_format", "write_scene_file"]

FORMAT_VERSION = 2
# the versions ``read_scene_file`` reads: 1 (no blocked cells) and 2 (``blocked``)
READ_VERSIONS = (1, 2)

# A scene file's grid has at most this many rows and columns (64 MiB of float32 counts): a bound on
# what a file can make ``Scene.load`` allocate, checked before the counts are read.
MAX_FILE_SIDE = 4096
# Every other member of a scene archive is small (a WKT target of 100,000 vertices is about 4 million
# characters, 16 MB as a NumPy string); the counts may be float64 on disk. Each member's size is
# checked, from the archive's directory and from its .npy header, before the member is read, so an
# archive cannot make ``Scene.load`` read more.
MAX_MEMBER_BYTES = 64 * 2**20
MAX_OBJ_BYTES = MAX_FILE_SIDE * MAX_FILE_SIDE * 8
NPY_HEADER_BYTES = 2**16   # room for the counts' .npy header within the obj member


def _ring_wkt(ring) -> str:
    return "(" + ", ".join(f"{x!r} {y!r}" for x, y, *_ in ring.coords) + ")"


def _polygon_wkt(poly) -> str:
    return "(" + ", ".join(_ring_wkt(r) for r in [poly.exterior, *poly.interiors]) + ")"


def _to_wkt(target) -> str:
    """2-D WKT with every coordinate as Python's shortest round-trip repr.

    shapely.to_wkt rounds some coordinates in the last bit even at full precision; repr + GEOS's
    parser round-trips exactly, so a loaded scene has bit-identical geometry.
    """
    if isinstance(target, MultiPolygon):
        return "MULTIPOLYGON (" + ", ".join(_polygon_wkt(p) for p in target.geoms) + ")"
    return "POLYGON " + _polygon_wkt(target)


def scene_file_format(path: Path) -> str:
    """``".npz"`` or ``".json"``, the format ``path``'s suffix names; ValueError for any other."""
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".json"):
        raise ValueError(f"Scene file {path}: unknown suffix {path.suffix!r}; use '.npz' or '.json'.")
    return suffix


class _FileProblem(ValueError):
    """What is wrong with a scene file, as ``"<what>; <fix>"``; :func:`_read_scene_file` adds the path."""


# What a broken file makes the decoders raise (a truncated or corrupted zip, binary noise, a .npy
# header that lies): each becomes one ValueError naming the file instead of a traceback.
_DECODE_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, struct.error, UnicodeDecodeError, ValueError,
                  KeyError, TypeError, IndexError, OverflowError, RecursionError, MemoryError,
                  NotImplementedError, SyntaxError, tokenize.TokenError)   # the last two: a damaged .npy header


def _read_scene_file(path: Path, suffix: str) -> dict:
    """The raw fields of a scene file (format_version checked, types checked, values not yet).

    Returns ``{"obj": f64/f32[H, W], "cell_size": float, "origin": f64[2], "target": str (WKT),
    "name": str | None, "blocked": bool[H, W] | None}`` (``blocked`` None in a version-1 file).
    Raises ValueError ``"Scene file <path>: <what>; <fix>"``.
    """
    kind = "a NumPy .npz archive" if suffix == ".npz" else "JSON text (UTF-8)"
    try:
        if path.is_dir():
            raise _FileProblem(f"is a directory; give the path of a {suffix} scene file")
        if path.stat().st_size == 0:
            raise _FileProblem(f"is empty (0 bytes); a scene file is {kind} written by Scene.save")
        return _read_npz(path) if suffix == ".npz" else _read_json(path)
    except _FileProblem as exc:
        raise ValueError(f"Scene file {path}: {exc}.") from None
    except FileNotFoundError:
        raise ValueError(f"Scene file {path}: no such file; check the path.") from None
    except OSError as exc:  # permissions, a device error, ...
        raise ValueError(f"Scene file {path}: could not be read ({exc.strerror or exc}); check the "
                         "file's permissions.") from None
    except _DECODE_ERRORS as exc:
        raise ValueError(f"Scene file {path}: is not {kind} or is damaged ({type(exc).__name__}: "
                         f"{exc}); write scene files with Scene.save (docs/scene-files.md).") from None


def _check_keys(keys, allowed: tuple, optional: tuple = ()) -> None:
    """Refuse unknown keys (naming them and the allowed ones) and missing required keys."""
    unknown = [k for k in keys if k not in allowed]
    if unknown:
        hint = (" (blocked cells need format_version 2)" if "blocked" in unknown and "blocked" not in allowed
                else "")
        raise _FileProblem(f"unknown key(s) {', '.join(map(repr, unknown))}; a scene file has exactly the "
                           f"keys {', '.join(allowed)}{hint} (docs/scene-files.md)")
    missing = [k for k in allowed if k not in keys and k not in optional]
    if missing:
        raise _FileProblem(f"missing key(s) {', '.join(missing)}; see docs/scene-files.md")


_VERSIONS_TEXT = " or ".join(map(str, READ_VERSIONS))


def _check_version(version) -> int:
    if version not in READ_VERSIONS:
        raise _FileProblem(f"format_version is {version!r}; this version of jaxplan reads format_version "
                           f"{_VERSIONS_TEXT} only")
    return int(version)


def _file_version(keys, version) -> int:
    """The format version whose keys a file is checked against: its own, or (when ``format_version`` is
    missing, which ``_check_keys`` then reports) the one its keys suggest."""
    if version is not None:
        return _check_version(version)
    return 2 if "blocked" in keys else 1


def _blocked_shape_problem(shape, grid) -> None:
    if tuple(shape) != tuple(grid):
        raise _FileProblem(f"blocked: has shape {tuple(shape)} but obj has {tuple(grid)}; store one bool per "
                           "cell of obj (rows = y, columns = x), True on blocked cells")


def _check_grid_shape(shape) -> None:
    """``obj``'s shape, checked before its data is read: 2-D and at most MAX_FILE_SIDE a side."""
    if len(shape) != 2:
        raise _FileProblem(f"obj: must be 2-D [H, W] (rows = y, columns = x); got shape {tuple(shape)}")
    if max(shape) > MAX_FILE_SIDE:
        raise _FileProblem(f"obj: the grid is {shape[0]} x {shape[1]}; a scene file holds at most "
                           f"{MAX_FILE_SIDE} x {MAX_FILE_SIDE} cells. Use a coarser cell_size")


# --------------------------------------------------------------------------------------------------
# .npz
# --------------------------------------------------------------------------------------------------

_NPZ_KEYS = ("format_version", "obj", "cell_size", "origin", "target_wkt", "name", "blocked")
_NPZ_KEYS_V1 = _NPZ_KEYS[:-1]

# key -> (allowed dtype kinds, allowed shapes (None: any), what the key must hold)
_NPZ_FIELDS = {
    "format_version": ("iu", ((),), f"an integer scalar ({FORMAT_VERSION})"),
    "obj": ("iuf", None, "a 2-D array of numbers (float32 counts)"),
    "cell_size": ("iuf", ((),), "a number scalar (world units per cell side)"),
    "origin": ("iuf", ((2,),), "2 numbers (x, y)"),
    "target_wkt": ("U", ((),), "a string scalar (WKT)"),
    "name": ("U", ((), (0,)), "a string scalar, or an empty (0,) array for no name"),
    "blocked": ("b", None, "a bool (H, W) array of obj's shape, True on blocked cells "
                           "(np.asarray(blocked, bool))"),
}


def _npy_header(zf: zipfile.ZipFile, key: str):
    """(shape, dtype) of the archive member ``<key>.npy``, read from its header only."""
    with zf.open(f"{key}.npy") as fp:
        version = np.lib.format.read_magic(fp)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(fp)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(fp)
        else:
            raise _FileProblem(f"{key}: .npy format version {version} is not supported; save with "
                               "numpy.savez")
    return shape, dtype


def _member_limit(key: str) -> int:
    return MAX_OBJ_BYTES if key == "obj" else MAX_MEMBER_BYTES


def _check_member_sizes(zf: zipfile.ZipFile) -> None:
    """Every member's uncompressed size, as the archive's directory states it (a member never yields
    more), within its bound."""
    for info in zf.infolist():
        key = info.filename[:-len(".npy")] if info.filename.endswith(".npy") else info.filename
        limit = _member_limit(key) + (NPY_HEADER_BYTES if key == "obj" else 0)
        if info.file_size > limit:
            raise _FileProblem(f"{key}: the archive member decompresses to {info.file_size:,} bytes; a scene "
                               f"file's {key} holds at most {limit:,}")


def _npz_array(zf: zipfile.ZipFile, key: str, grid=None) -> np.ndarray:
    """The member ``<key>.npy``, its dtype, shape and size checked (from the header) before reading it;
    ``grid``: obj's shape, which ``blocked`` must have."""
    shape, dtype = _npy_header(zf, key)
    kinds, shapes, what = _NPZ_FIELDS[key]
    if dtype.hasobject:
        raise _FileProblem(f"{key}: is an object (pickled) array, which is never loaded "
                           f"(allow_pickle=False); store {what}")
    if key == "obj":
        _check_grid_shape(shape)
    empty_name = key == "name" and shape == (0,)
    if (dtype.kind not in kinds and not empty_name) or (shapes is not None and shape not in shapes):
        raise _FileProblem(f"{key}: holds dtype {dtype} with shape {shape}; it must hold {what}")
    if key == "blocked":
        _blocked_shape_problem(shape, grid)
    nbytes = math.prod(shape) * dtype.itemsize
    if nbytes > _member_limit(key):
        raise _FileProblem(f"{key}: its header declares {nbytes:,} bytes ({dtype} {tuple(shape)}); a scene "
                           f"file's {key} holds at most {_member_limit(key):,}; store {what}")
    with zf.open(f"{key}.npy") as fp:
        return np.lib.format.read_array(fp, allow_pickle=False)


def _read_npz(path: Path) -> dict:
    with zipfile.ZipFile(path) as zf:
        _check_member_sizes(zf)
        members = zf.namelist()
        twice = sorted({m for m in members if members.count(m) > 1})
        if twice:   # a zip may hold one name twice; which copy a reader takes is not defined
            raise _FileProblem(f"holds the member {twice[0]!r} twice; write scene files with Scene.save")
        odd = [m for m in members if not m.endswith(".npy")]
        if odd:
            raise _FileProblem(f"holds {odd[0]!r}, which is not a .npy array; a scene archive holds "
                               f"only the arrays {', '.join(_NPZ_KEYS)}")
        keys = [m[:-len(".npy")] for m in members]
        # format_version first: another version may have other keys
        version = _file_version(keys, int(_npz_array(zf, "format_version")) if "format_version" in keys else None)
        wanted = _NPZ_KEYS if version == 2 else _NPZ_KEYS_V1
        _check_keys(keys, wanted)
        arrays = {}
        for key in wanted:   # obj before blocked: blocked must have obj's shape
            arrays[key] = _npz_array(zf, key, grid=arrays["obj"].shape if key == "blocked" else None)
    name = arrays["name"]
    return {
        "obj": arrays["obj"],
        "cell_size": float(arrays["cell_size"]),
        "origin": arrays["origin"].astype(np.float64),
        "target": str(arrays["target_wkt"]),
        "name": str(name) if name.ndim == 0 else None,
        "blocked": arrays.get("blocked"),
    }


# --------------------------------------------------------------------------------------------------
# .json
# --------------------------------------------------------------------------------------------------

_JSON_KEYS = ("format_version", "name", "cell_size", "origin", "obj", "blocked", "target")
_JSON_KEYS_V1 = tuple(k for k in _JSON_KEYS if k != "blocked")
BLOCKED_CHAR, FREE_CHAR = "@", "."
_NOT_A_CELL = re.compile(r"[^@.]")


def _is_number(v) -> bool:
    """A JSON number: int or float, not a bool (``True`` is an int in Python)."""
    return type(v) in (int, float)


def _json_type(v) -> str:
    if v is None:
        return "null"
    kind = {bool: "a boolean", str: "a string", list: "a list", dict: "an object"}.get(type(v), "a number")
    return f"{kind} ({json.dumps(v)[:40]})"


def _json_obj(rows) -> np.ndarray:
    """``obj`` from its JSON rows: f64[H, W]; names the first bad row or cell."""
    if not isinstance(rows, list) or not rows:
        raise _FileProblem(f"obj: must be a non-empty list of H rows, each a list of W numbers; got "
                           f"{_json_type(rows)}")
    width = len(rows[0]) if isinstance(rows[0], list) else 0
    _check_grid_shape((len(rows), width))
    for r, row in enumerate(rows):
        if not isinstance(row, list):
            raise _FileProblem(f"obj: row {r} is {_json_type(row)}, not a list of numbers")
        if len(row) != width:
            raise _FileProblem(f"obj: row {r} has {len(row)} value(s) but row 0 has {width}; every "
                               "row needs the same length W")
        if not all(map(_is_number, row)):
            c = next(c for c, v in enumerate(row) if not _is_number(v))
            hint = " (obj must be 2-D: one number per cell)" if isinstance(row[c], list) else ""
            raise _FileProblem(f"obj: row {r}, column {c} is {_json_type(row[c])}; counts must be "
                               f"numbers{hint}")
    try:
        return np.array(rows, np.float64)
    except OverflowError:  # an integer beyond float64
        raise _FileProblem("obj: holds an integer too large for a float; rescale the counts") from None


def _json_blocked(rows, grid) -> np.ndarray:
    """``blocked`` from its JSON rows (H strings of W characters, ``@`` blocked, ``.`` free, row 0
    first): bool[H, W]; names the first bad row or character."""
    h, w = grid
    form = (f"a list of {h} strings of {w} characters, one per row of obj (row 0 first), '{BLOCKED_CHAR}' "
            f"on a blocked cell and '{FREE_CHAR}' on a free one")
    if not isinstance(rows, list):
        raise _FileProblem(f"blocked: must be {form}; got {_json_type(rows)}")
    if len(rows) != h:
        raise _FileProblem(f"blocked: has {len(rows)} row(s) but obj has {h}; give {form}")
    for r, row in enumerate(rows):
        if not isinstance(row, str):
            raise _FileProblem(f"blocked: row {r} is {_json_type(row)}, not a string; give {form}")
        if len(row) != w:
            raise _FileProblem(f"blocked: row {r} has {len(row)} character(s) but obj has {w} column(s); "
                               f"give {form}")
        bad = _NOT_A_CELL.search(row)
        if bad:
            raise _FileProblem(f"blocked: row {r}, column {bad.start()} is {bad.group()!r}; use "
                               f"'{BLOCKED_CHAR}' for a blocked cell and '{FREE_CHAR}' for a free one")
    codes = np.frombuffer("".join(rows).encode("ascii"), np.uint8)
    return (codes == ord(BLOCKED_CHAR)).reshape(h, w)


def _read_json(path: Path) -> dict:
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise _FileProblem(f"is not UTF-8 text (byte {exc.start}: {exc.reason}), so not a JSON scene "
                           "file; a binary scene file must be named .npz") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise _FileProblem(f"not valid JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise _FileProblem(f"the top level must be a JSON object with the keys {', '.join(_JSON_KEYS)}; "
                           f"got {_json_type(doc)}")
    version = None
    if "format_version" in doc:  # first: another version may have other keys
        version = doc["format_version"]
        if type(version) is not int:
            raise _FileProblem(f"format_version: must be the integer {_VERSIONS_TEXT}; got "
                               f"{_json_type(version)}")
    version = _file_version(list(doc), version)
    _check_keys(list(doc), _JSON_KEYS if version == 2 else _JSON_KEYS_V1, optional=("name",))
    cell_size, origin, target, name = (doc.get(k) for k in ("cell_size", "origin", "target", "name"))
    if not _is_number(cell_size):
        raise _FileProblem(f"cell_size: must be a number (world units per cell side); got "
                           f"{_json_type(cell_size)}")
    if not (isinstance(origin, list) and len(origin) == 2 and all(map(_is_number, origin))):
        raise _FileProblem(f"origin: must be a list of 2 numbers [x, y]; got {_json_type(origin)}")
    if not isinstance(target, str):
        raise _FileProblem(f"target: must be a WKT string (POLYGON or MULTIPOLYGON); got "
                           f"{_json_type(target)}")
    if name is not None and not isinstance(name, str):
        raise _FileProblem(f"name: must be a string or null; got {_json_type(name)}")
    obj = _json_obj(doc["obj"])
    blocked = _json_blocked(doc["blocked"], obj.shape) if version == 2 else None
    return {"obj": obj, "cell_size": float(cell_size), "origin": np.asarray(origin, np.float64),
            "target": target, "name": name, "blocked": blocked}


def parse_wkt(wkt: str):
    """The shapely geometry of ``wkt``; ValueError naming ``target`` when it does not parse."""
    try:
        geom = shapely.from_wkt(wkt)
    except Exception as exc:  # shapely raises its own GEOSException
        raise ValueError(f"target: could not parse the WKT ({exc}); give a POLYGON or MULTIPOLYGON, "
                         "e.g. 'POLYGON ((0 0, 1 0, 1 1, 0 1, 0 0))'.") from None
    if geom is None:
        raise ValueError("target: the WKT is empty; give a POLYGON or MULTIPOLYGON.")
    return geom


def write_scene_file(path: Path, scene) -> Path:
    """Write ``scene`` (a Scene with its shapely target) to ``path``, ``.npz`` or ``.json`` by suffix."""
    suffix = scene_file_format(path)
    obj = np.asarray(scene.obj, np.float32)
    cell_size = float(np.asarray(scene.cell_size))
    origin = [float(v) for v in np.asarray(scene.origin)]
    wkt = _to_wkt(scene.target)
    blocked = np.asarray(scene.blocked, bool) if scene.blocked is not None else np.zeros(obj.shape, bool)
    if suffix == ".npz":
        np.savez(path, format_version=np.int64(FORMAT_VERSION), obj=obj,
                 cell_size=np.float64(cell_size), origin=np.asarray(origin, np.float64),
                 target_wkt=np.str_(wkt),
                 name=np.str_(scene.name) if scene.name is not None else np.zeros(0, np.str_),
                 blocked=blocked)
    else:
        chars = np.where(blocked, ord(BLOCKED_CHAR), ord(FREE_CHAR)).astype(np.uint8)
        doc = {"format_version": FORMAT_VERSION, "name": scene.name, "cell_size": cell_size,
               "origin": origin, "obj": obj.astype(np.float64).tolist(),
               "blocked": [row.tobytes().decode("ascii") for row in chars], "target": wkt}
        path.write_text(json.dumps(doc))
    return path


def read_scene_file(path: Path) -> dict:
    """The fields of the scene file at ``path``: ``{"obj": [H, W], "cell_size": float, "origin":
    f64[2], "target": shapely geometry, "name": str | None, "blocked": bool[H, W] | None}`` (``blocked``
    None in a version-1 file: no blocked cells), types checked, values not yet (the caller builds the
    Scene). Raises ValueError naming the file, or naming ``target`` for bad WKT."""
    fields = _read_scene_file(path, scene_file_format(path))
    return {**fields, "target": parse_wkt(fields["target"])}
