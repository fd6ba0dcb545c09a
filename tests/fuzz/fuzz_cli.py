"""Fuzz the CLI's input files: mutate valid scene files, sweep specs and PushAround scenes, run the
``jaxplan`` CLI in-process (``jaxplan.cli.app.main(argv)``) on each, and check how it fails.

Kinds of input (each case picks one, writes a fresh valid file and mutates it, or leaves it valid):

- ``scene.npz`` / ``scene.json``: a 6x6 transport scene with a box target (docs/scene-files.md), run
  through ``jaxplan fabric --scene F --out D/out/f.npz`` or, one case in six, ``jaxplan episode --scene F
  --out D/out --no-animation --max-pushes 2``;
- ``sweep.toml``: a sweep spec (docs/sweeps.md) over a 6x6 scene file beside it and one 5x5 random scene,
  run through ``jaxplan sweep SPEC --out D/out/s.csv --no-progress``;
- ``pusharound.json``: a one-box PushAround scene (docs/pusharound.md), run through ``jaxplan pusharound
  --scene F --out D/out --no-execute --time-limit 0.3 --backend c --max-frames 2 --fps 1`` (a scene that
  still loads is planned in full, about 2 s; ``--fps 1`` holds the last frame for 2 frames instead of
  15 at the default 10 fps, which were most of a case's time, drawing the same picture again).

Mutations. Of the parsed document (JSON, TOML): wrong types, NaN and +-inf, negated values, zeros,
huge numbers (1e308, 2**64, 10**400, ...), missing keys, extra keys, values wrapped in or stripped of a
list (nested wrong shapes), ragged rows, emptied containers, grown lists, mangled strings and WKT. Of
the bytes: truncation at a random offset, bit flips, random noise written over or into the file, an
empty file, random bytes, other text encodings. Of a ``.npz``: per-array dtype and shape changes,
special and huge values, missing, extra and renamed arrays, and zip corruption (truncated archives,
flipped bits in a local header, the central directory or a member's data, a bad ``.npy`` header
inside the zip, a plain ``.npy`` or a pickle instead of a zip, a duplicated member).

Classes of case (``--classes``; the default draws all: ``inputs`` 82%, the others 6% each). ``inputs``:
the mutations above. ``archive`` (``scene.npz``): a member whose ``.npy`` header declares a huge array
over a few bytes (``target_wkt`` as ``<U100000000``, ``obj`` of 100000 x 100000, shapes whose byte count
overflows), a deflated member that inflates past its bound (65 MiB of zeros: ``target_wkt``, trailing
data after ``cell_size``, an ``extra.npy``, ``obj`` over its own bound, or a member whose zip entry
states a false small size; built once and cached), a member twice (the same, or another array first or
second), an extra member of 1 or 8 MiB. ``nesting`` (JSON scenes, PushAround scenes, sweep specs): one
value, or the whole JSON document, inside 2,000-5,000 lists or objects (written as text: neither
``json.dumps`` nor ``to_toml`` recurses that deep). ``fs`` (``episode`` and ``pusharound``, which write
an output folder; the input is unmutated in 60% of these cases): ``--out`` prepared before the run
(``prepare_out``) as one of ``FS_MODES``: a planted jaxplan ``run.json`` listing paths through a
symlinked folder that points outside ``--out`` at a victim file (and ``..`` and absolute paths to it);
a planted ``run.json`` listing symlinked files that point at the victim; a ``run.json`` that is not
jaxplan's (text, other JSON, empty, a folder, a link to the victim); a folder held busy (this process
holds ``flock(LOCK_EX)`` on ``DIR/.jaxplan.lock`` while the case runs, ``Case.running``); a stale lock
file of a dead pid.

Checks per case (``check_case``): the CLI exits 0 or 2 and never raises; on exit 2 stderr is exactly
one line (as a terminal shows it: progress bars erased by ``\\r`` do not count), it starts with
``error:`` and names the file, a flag or a field; on exit 2 the ``--out`` path was not created (every
case starts with a fresh one); on exit 0 the output exists and, where the command wrote a manifest
``DIR/run.json``, its status is ``complete`` and every file it lists exists; no temp file (a name
starting with ``.`` and containing ``.tmp``) is left anywhere in the case's folder. For ``fs`` cases:
every victim file outside ``--out`` still exists with its content (else ``touched_outside``, whatever
the exit code); the "--out path was created" check is skipped (the folder existed before); a busy
folder or a foreign ``run.json`` must not give exit 0, and their planted files must be left as they
were; an error line may name the ``--out`` path instead of the input.

Outcomes: ``exit0``, ``exit2_good`` (a good error line), ``exit2_bad_line``, ``traceback`` (any other
exception), ``half_written`` (an output check failed), ``other_exit`` (another exit code),
``touched_outside`` (a file outside ``--out`` changed or removed), and in the
standalone run ``timeout`` and ``crash`` (the worker process died). Each case runs in one long-lived
worker process, so a case that hangs or kills the interpreter is recorded and the next case starts a
new worker. Like the test suite, the run asks XLA for cheap code generation (``FAST_COMPILE_FLAGS``)
unless ``XLA_FLAGS`` is set: compiling dominates on these tiny grids.

Results: ``experiments/results/<name>.{json,md}`` (``--name``, default ``fuzz_cli``): cases per kind,
command and outcome, and the distinct findings (non-passing outcomes grouped by command and cause:
the exception type and the innermost jaxplan function for a traceback, the normalised line for a bad
error line), each with one example and the command that replays it. ``tests/cli/test_fuzz.py`` runs a
bounded, deterministic set of cases through the same ``make_case`` / ``execute`` / ``check_case``.

Examples (from the repository root)::

    python -m tests.fuzz.fuzz_cli --cases 1000 --seed 0
    python -m tests.fuzz.fuzz_cli --cases 50 --seed 1 --kinds scene.npz scene.json
    python -m tests.fuzz.fuzz_cli --cases 300 --seed 0 --classes archive nesting fs --name fuzz_cli_round2
    python -m tests.fuzz.fuzz_cli --seed 0 --replay 17 --keep out/fuzz17   # rerun one case, keep its files
"""
from __future__ import annotations

import argparse
import contextlib
import copy
import datetime as _dt
import fcntl
import functools
import io
import json
import math
import os
import platform
import re
import shutil
import statistics
import sys
import tempfile
import time
import traceback
import warnings
import zipfile
from collections import Counter, defaultdict
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

RESULTS_DIR = Path(__file__).resolve().parents[2] / "experiments" / "results"   # beside the benchmarks' results
FAST_COMPILE_FLAGS = "--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false"

KINDS = ("scene.npz", "scene.json", "sweep.toml", "pusharound.json")
# how often each kind is drawn: the transport scenes are cheap, a PushAround scene that loads is planned
KIND_WEIGHTS = (0.33, 0.27, 0.22, 0.18)
EPISODE_SHARE = 1 / 6   # of the transport scene cases, run through `episode` instead of `fabric`
OUTCOMES = ("exit0", "exit2_good", "exit2_bad_line", "traceback", "half_written", "other_exit", "touched_outside",
            "timeout", "crash")
PASSING = ("exit0", "exit2_good")
PUSH_TIME_LIMIT_S = 0.3
# Classes of cases: "inputs" (the mutations above: types, values, keys, bytes, arrays, zip damage),
# "archive" (.npz members: huge declared sizes, members that inflate past their bound, duplicated and
# extra large members), "nesting" (a value inside thousands of lists or objects), "fs" (--out prepared:
# links out of it, a foreign manifest, a held or stale lock). The class is drawn from its own
# random stream, so case I of seed S in class "inputs" is the same input as before the classes.
CLASSES = ("inputs", "archive", "nesting", "fs")
CLASS_WEIGHTS = (0.82, 0.06, 0.06, 0.06)
CLASS_KINDS = {"inputs": KINDS, "archive": ("scene.npz",), "nesting": ("scene.json", "sweep.toml", "pusharound.json"),
               "fs": ("scene.npz", "scene.json", "pusharound.json")}
FS_VALID_SHARE = 0.6   # of the fs cases, an unmutated input (the run gets as far as --out)
# who reads each kind: tracebacks and bad error lines are grouped by reader (fabric and episode share one)
READERS = {"scene.npz": "scene file (fabric/episode)", "scene.json": "scene file (fabric/episode)",
           "sweep.toml": "sweep spec", "pusharound.json": "pusharound scene"}

# A one-box PushAround scene: a wall splits the workspace, the box blocks the way below it.
PUSH_SCENE = {"format": "jaxplan.pusharound.scene", "version": 1,
              "workspace": [0, 0, 4, 3], "vehicle_width": 0.8, "start": [1.0, 2.2], "goal": [3.0, 2.2],
              "fixed": [{"name": "wall", "pieces": [[[1.9, 1.0], [2.1, 1.0], [2.1, 3.0], [1.9, 3.0]]]}],
              "movables": [{"name": "box", "pieces": [[[-0.2, -0.2], [0.2, -0.2], [0.2, 0.2], [-0.2, 0.2]]],
                            "pose": [2.0, 0.5, 0.0], "mass": 6.0, "friction": 0.5}],
              "robots": {"positions": [[0.5, 0.4], [0.5, 0.9]], "radius": 0.15}}

SWEEP_SPEC = {"scenes": ["site.json"],
              "random_scenes": {"seeds": [0], "shape": [5, 5], "density": 0.4},
              "fabric": {"theta_tol_deg": [45.0, 60.0], "tau_h": 0.5},
              "spill": {"lam": [0.0, 0.05]},
              "static": {"k": 2},
              "metrics": {"top_sources": 2}}

SCENE_FIELDS = ("format_version", "obj", "cell_size", "origin", "target", "target_wkt", "name", "Scene")
PUSH_FIELDS = ("format", "version", "workspace", "vehicle_width", "start", "goal", "fixed", "movables", "robots",
               "positions", "radius", "pieces", "polygon", "pose", "mass", "inertia", "friction", "shape", "scene")


# --------------------------------------------------------------------------------------------------
# Valid inputs
# --------------------------------------------------------------------------------------------------

@functools.cache
def _base_scene_files() -> tuple[bytes, str]:
    """The ``.npz`` bytes and ``.json`` text of a valid 6x6 scene (two rows of objects, a box target)."""
    from jaxplan.transport import Scene, box

    obj = np.zeros((6, 6), np.float32)
    obj[1:3, 0:3] = 2.0
    scene = Scene.from_arrays(obj, box(3.5, 3.5, 6.0, 6.0), name="fuzz")
    with tempfile.TemporaryDirectory() as tmp:
        scene.save(Path(tmp) / "s.npz")
        scene.save(Path(tmp) / "s.json")
        return (Path(tmp) / "s.npz").read_bytes(), (Path(tmp) / "s.json").read_text()


def base_npz_arrays() -> dict:
    """The arrays of the valid ``.npz`` scene, by key (fresh copies)."""
    with np.load(io.BytesIO(_base_scene_files()[0]), allow_pickle=False) as data:
        return {k: np.array(data[k]) for k in data.files}


def base_scene_doc() -> dict:
    return json.loads(_base_scene_files()[1])


def npz_bytes(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _toml_key(k) -> str:
    k = str(k)
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k, ensure_ascii=False)


def toml_value(v) -> str:
    """``v`` as a TOML value (arrays and inline tables for lists and dicts)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v if x is not None) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_toml_key(k)} = {toml_value(x)}" for k, x in v.items() if x is not None) + "}"
    return json.dumps(str(v))


def to_toml(doc: dict) -> str:
    """A TOML text of ``doc``: top-level values first, then one ``[table]`` per top-level dict; deeper
    dicts as inline tables. ``None`` (no TOML value) is left out."""
    key, value = _toml_key, toml_value
    lines = [f"{key(k)} = {value(v)}" for k, v in doc.items() if v is not None and not isinstance(v, dict)]
    for k, table in doc.items():
        if isinstance(table, dict):
            lines += ["", f"[{key(k)}]"] + [f"{key(kk)} = {value(v)}" for kk, v in table.items() if v is not None]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------------
# Mutators of parsed documents (JSON / TOML). Each takes the document (changed in place) and a
# random.Random-like rng (only random, randrange, randint, choice, shuffle are used, so hypothesis's
# st.randoms() drives them too) and returns a description.
# --------------------------------------------------------------------------------------------------

NAN, INF = float("nan"), float("inf")
WRONG_TYPES = ("text", "", True, False, None, 0, -1, 1.5, [], {}, [1, 2], {"a": 1}, [[1, 2], [3]], "1.0")
HUGE = (1e308, -1e308, 1.7976931348623157e308, 3.5e38, 10**30, 2**63, 2**64, -(2**63) - 1, 10**400, 5e-324)
WKT_VARIANTS = ("", "POLYGON EMPTY", "POINT (1 2)", "LINESTRING (0 0, 6 6)", "POLYGON ((0 0, 6 6, 6 0, 0 6, 0 0))",
                "POLYGON ((0 0, 1 0, 1 1, 0 0))", "POLYGON ((100 100, 101 100, 101 101, 100 101, 100 100))",
                "POLYGON ((3.5 3.5, 6 3.5, 6 6, 3.5 6))", "POLYGON ((nan 3.5, 6 3.5, 6 6, 3.5 6, nan 3.5))",
                "POLYGON ((3.5 3.5, inf 3.5, inf 6, 3.5 6, 3.5 3.5))",
                "POLYGON ((3.5 3.5, 1e308 3.5, 1e308 1e308, 3.5 1e308, 3.5 3.5))",
                "POLYGON Z ((3.5 3.5 1, 6 3.5 1, 6 6 1, 3.5 6 1, 3.5 3.5 1))",
                "MULTIPOLYGON (((3.5 3.5, 6 3.5, 6 6, 3.5 6, 3.5 3.5)), ((0 4, 1 4, 1 5, 0 5, 0 4)))",
                "GEOMETRYCOLLECTION (POLYGON ((3.5 3.5, 6 3.5, 6 6, 3.5 6, 3.5 3.5)))",
                "POLYGON ((3.5 3.5, 6 3.5, 6 6, 3.5 6, 3.5 3.5), (4 4, 5 4, 5 5, 4 5, 4 4))", "POLYGON ((",
                "not wkt at all", "\x00", "POLYGON ((0 0, 1e-300 0, 1e-300 1e-300, 0 1e-300, 0 0))")
STRING_VARIANTS = ("", "x" * 10_000, "\x00", "é日本\U0001F600", "../../etc/passwd", "default", "null", "1.0", " ")


def _paths(doc, prefix: tuple = ()) -> list[tuple]:
    """Every path (dict keys and list indices) into a JSON-like tree, the root excluded, depth first."""
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    out = []
    for k, v in items:
        out.append(prefix + (k,))
        out += _paths(v, prefix + (k,))
    return out


def _get(doc, path):
    for k in path:
        doc = doc[k]
    return doc


def _set(doc, path, value) -> None:
    _get(doc, path[:-1])[path[-1]] = value


def label(path) -> str:
    """``movables[0].pose`` for the path ``("movables", 0, "pose")``."""
    out = ""
    for k in path:
        out += f"[{k}]" if isinstance(k, int) else (f".{k}" if out else str(k))
    return out or "<root>"


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _pick(rng, doc, want=None):
    """A random path whose value satisfies ``want`` (any path if None); None if there is none."""
    paths = [p for p in _paths(doc) if want is None or want(_get(doc, p))]
    return paths[rng.randrange(len(paths))] if paths else None


def _op_wrong_type(doc, rng, toml):
    path = _pick(rng, doc)
    choices = [v for v in WRONG_TYPES if not (toml and v is None)]
    value = copy.deepcopy(choices[rng.randrange(len(choices))])
    _set(doc, path, value)
    return f"{label(path)} -> {value!r}"


def _op_special(doc, rng, toml):
    path = _pick(rng, doc, _is_number) or _pick(rng, doc)
    value = rng.choice((NAN, INF, -INF))
    _set(doc, path, value)
    return f"{label(path)} -> {value!r}"


def _op_negate(doc, rng, toml):
    path = _pick(rng, doc, _is_number)
    if path is None:
        return _op_wrong_type(doc, rng, toml)
    old = _get(doc, path)
    _set(doc, path, -old if old else -1)
    return f"{label(path)} negated ({old!r})"


def _op_zero(doc, rng, toml):
    path = _pick(rng, doc, _is_number) or _pick(rng, doc)
    value = rng.choice((0, 0.0, -0.0))
    _set(doc, path, value)
    return f"{label(path)} -> {value!r}"


def _op_huge(doc, rng, toml):
    path = _pick(rng, doc, _is_number) or _pick(rng, doc)
    value = rng.choice(HUGE)
    _set(doc, path, value)
    shown = repr(value) if len(repr(value)) < 30 else f"an int of {len(str(value))} digits"
    return f"{label(path)} -> {shown}"


def _op_delete(doc, rng, toml):
    path = _pick(rng, doc)
    del _get(doc, path[:-1])[path[-1]]
    return f"{label(path)} deleted"


def _op_extra_key(doc, rng, toml):
    dicts = [()] + [p for p in _paths(doc) if isinstance(_get(doc, p), dict)]
    path = dicts[rng.randrange(len(dicts))]
    name = rng.choice(("extra", "zz_unknown", "OBJ", "Format_Version", "seeds", "mass", ""))
    value = rng.choice((1, "x", [1, 2], {"a": 1}, 1.5, True))
    _get(doc, path)[name] = copy.deepcopy(value)
    return f"extra key {name!r} = {value!r} in {label(path)}"


def _op_wrap(doc, rng, toml):
    path = _pick(rng, doc)
    old = _get(doc, path)
    depth = rng.choice((1, 1, 2))
    new = old
    for _ in range(depth):
        new = [new]
    _set(doc, path, new)
    return f"{label(path)} wrapped in {depth} list(s)"


def _op_unwrap(doc, rng, toml):
    path = _pick(rng, doc, lambda v: isinstance(v, list) and v)
    if path is None:
        return _op_wrap(doc, rng, toml)
    old = _get(doc, path)
    if all(isinstance(x, list) for x in old) and rng.random() < 0.5:
        _set(doc, path, [y for x in old for y in x])
        return f"{label(path)} flattened one level"
    _set(doc, path, old[0])
    return f"{label(path)} -> its first element"


def _op_ragged(doc, rng, toml):
    path = _pick(rng, doc, lambda v: isinstance(v, list) and len(v) > 1 and all(isinstance(x, list) for x in v))
    if path is None:
        return _op_unwrap(doc, rng, toml)
    rows = _get(doc, path)
    r = rng.randrange(len(rows))
    how = rng.choice(("drop", "append", "scalar", "empty"))
    if how == "drop" and rows[r]:
        rows[r].pop()
    elif how == "append":
        rows[r].append(copy.deepcopy(rows[r][-1]) if rows[r] else 1.0)
    elif how == "scalar":
        rows[r] = 1.0
    else:
        rows[r] = []
    return f"{label(path)}[{r}] made ragged ({how})"


def _op_empty(doc, rng, toml):
    path = _pick(rng, doc)
    value = rng.choice(([], {}, ""))
    _set(doc, path, copy.deepcopy(value))
    return f"{label(path)} -> {value!r}"


def _op_grow(doc, rng, toml):
    path = _pick(rng, doc, lambda v: isinstance(v, list) and v)
    if path is None:
        return _op_wrong_type(doc, rng, toml)
    old = _get(doc, path)
    times = rng.choice((2, 3))
    _set(doc, path, [copy.deepcopy(x) for _ in range(times) for x in old])
    return f"{label(path)} repeated {times}x"


def _op_string(doc, rng, toml):
    path = _pick(rng, doc, lambda v: isinstance(v, str))
    if path is None:
        return _op_wrong_type(doc, rng, toml)
    old = _get(doc, path)
    if old.startswith(("POLYGON", "MULTIPOLYGON")) and rng.random() < 0.7:
        if rng.random() < 0.5:
            new = WKT_VARIANTS[rng.randrange(len(WKT_VARIANTS))]
        else:   # one coordinate replaced, or the text cut
            nums = list(re.finditer(r"-?\d+(\.\d+)?", old))
            m = nums[rng.randrange(len(nums))]
            rep = rng.choice(("nan", "inf", "-1e308", "1e400", "x", "", "0"))
            new = old[:m.start()] + rep if rng.random() < 0.2 else old[:m.start()] + rep + old[m.end():]
    else:
        new = STRING_VARIANTS[rng.randrange(len(STRING_VARIANTS))]
    _set(doc, path, new)
    return f"{label(path)} -> {new[:60]!r}{'...' if len(new) > 60 else ''}"


def _op_retype_number(doc, rng, toml):
    path = _pick(rng, doc, _is_number)
    if path is None:
        return _op_wrong_type(doc, rng, toml)
    old = _get(doc, path)
    try:
        as_float = float(old)
    except OverflowError:   # an int beyond float range, put there by an earlier mutation
        as_float = math.inf
    new = rng.choice((str(old), as_float + 0.5 if math.isfinite(as_float) else 0.5, bool(old),
                      int(old) if isinstance(old, float) and math.isfinite(old) else as_float))
    _set(doc, path, new)
    return f"{label(path)} {old!r} -> {new!r}"


TREE_OPS = (_op_wrong_type, _op_special, _op_negate, _op_zero, _op_huge, _op_delete, _op_extra_key, _op_wrap,
            _op_unwrap, _op_ragged, _op_empty, _op_grow, _op_string, _op_retype_number)


def mutate_tree(doc, rng, *, toml: bool = False) -> str:
    """Apply one random tree mutation to ``doc`` (in place); returns its description."""
    op = TREE_OPS[rng.randrange(len(TREE_OPS))]
    if not _paths(doc):   # a document emptied by an earlier mutation: only keys can be added
        op = _op_extra_key
    return f"{op.__name__[4:]}: {op(doc, rng, toml)}"


# --------------------------------------------------------------------------------------------------
# Mutators of bytes
# --------------------------------------------------------------------------------------------------

def _random_bytes(rng, n: int) -> bytes:
    return bytes(rng.randrange(256) for _ in range(n))


def mutate_bytes(data: bytes, rng) -> tuple[bytes, str]:
    """One byte-level mutation of a file's content; returns the new bytes and a description."""
    n = len(data)
    op = rng.choice(("truncate", "bitflip", "noise", "insert", "empty", "random", "encoding"))
    if op == "truncate" and n:
        at = rng.randrange(n)
        return data[:at], f"truncated at byte {at} of {n}"
    if op == "bitflip" and n:
        out = bytearray(data)
        flips = rng.randint(1, 8)
        for _ in range(flips):
            out[rng.randrange(n)] ^= 1 << rng.randrange(8)
        return bytes(out), f"{flips} random bit(s) flipped"
    if op == "noise" and n:
        at, size = rng.randrange(n), rng.randint(1, 16)
        return data[:at] + _random_bytes(rng, size) + data[at + size:], f"{size} random bytes written at {at}"
    if op == "insert":
        at, size = rng.randrange(n + 1), rng.randint(1, 16)
        return data[:at] + _random_bytes(rng, size) + data[at:], f"{size} random bytes inserted at {at}"
    if op == "empty":
        return b"", "empty file"
    if op == "encoding":
        how = rng.choice(("utf-16", "bom", "latin-1 byte", "nul"))
        if how == "utf-16":
            return data.decode("utf-8", "replace").encode("utf-16"), "re-encoded as UTF-16"
        if how == "bom":
            return b"\xef\xbb\xbf" + data, "UTF-8 byte order mark prepended"
        if how == "nul":
            return data + b"\x00" * 4, "NUL bytes appended"
        at = rng.randrange(n + 1)
        return data[:at] + b"\xff\xfe" + data[at:], f"invalid UTF-8 bytes inserted at {at}"
    size = rng.randint(1, 200)
    return _random_bytes(rng, size), f"{size} random bytes"


# --------------------------------------------------------------------------------------------------
# Mutators of .npz archives: the arrays, then the zip
# --------------------------------------------------------------------------------------------------

NPZ_DTYPES = ("int8", "uint8", "int64", "float16", "float64", "complex64", "bool", "U8", "S8", "object", "struct")


def _retype(a: np.ndarray, name: str) -> np.ndarray:
    if name == "struct":
        return np.zeros(a.shape, dtype=[("a", "f4"), ("b", "i4")])
    if name == "object":
        return np.array(a.tolist() if a.ndim else a.item(), dtype=object) if a.size else np.zeros(a.shape, object)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return a.astype(name)
    except (TypeError, ValueError):
        return np.zeros(a.shape, dtype=name)


def _reshape(a: np.ndarray, rng) -> tuple[np.ndarray, str]:
    how = rng.choice(("flatten", "add axis", "transpose", "empty", "scalar", "tile", "column"))
    if how == "flatten":
        return a.reshape(-1), "flattened"
    if how == "add axis":
        return a[None, ...], "an axis added"
    if how == "transpose" and a.ndim >= 2:
        return a.T[:, :-1], "transposed and cut"
    if how == "empty":
        return a.reshape(-1)[:0] if a.ndim < 2 else a[:0], "emptied"
    if how == "scalar" and a.size:
        return np.array(a.reshape(-1)[0]), "made 0-d"
    if how == "column":
        return a.reshape(-1, 1), "made a column"
    return np.stack([a, a]), "tiled 2x"


def _values(a: np.ndarray, key: str, rng) -> tuple[np.ndarray, str]:
    if a.dtype.kind in "US" or key in ("target_wkt", "name"):
        if key == "target_wkt" and rng.random() < 0.8:
            s = WKT_VARIANTS[rng.randrange(len(WKT_VARIANTS))]
        else:
            s = STRING_VARIANTS[rng.randrange(len(STRING_VARIANTS))]
        return np.str_(s), f"-> {s[:60]!r}"
    if key == "format_version":
        v = rng.choice((0, 2, -1, 2**62))
        return np.int64(v), f"-> {v}"
    v = rng.choice((NAN, INF, -INF, -1.0, 0.0, 1e300, 3.5e38, 1e-45, 5e-324))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = np.array(a, dtype=np.float64)
    except (TypeError, ValueError):   # a struct or object array from an earlier mutation
        out = np.zeros(max(a.size, 1))
    if out.size == 0:
        return out, "left empty"
    flat = out.reshape(-1)
    i = rng.randrange(flat.size) if rng.random() < 0.7 else None
    if i is None:
        flat[:] = v
    else:
        flat[i] = v
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # 1e300 to float32 overflows to inf: kept as it comes
        out = out.astype(a.dtype if rng.random() < 0.5 and a.dtype.kind == "f" else np.float64)
    return out, f"{'element ' + str(i) if i is not None else 'all'} -> {v!r}"


def mutate_arrays(arrays: dict, rng) -> str:
    """One array-level mutation of an ``.npz``'s arrays (in place); returns its description."""
    keys = sorted(arrays)
    op = rng.choice(("dtype", "shape", "values", "values", "missing", "extra", "rename"))
    if not keys:
        op = "extra"
    if op == "extra":
        name = rng.choice(("extra", "obj2", "OBJ", "target"))
        arrays[name] = np.arange(rng.randint(0, 4), dtype=np.float32)
        return f"npz: extra array {name!r}"
    key = keys[rng.randrange(len(keys))]
    if op == "dtype":
        dt = NPZ_DTYPES[rng.randrange(len(NPZ_DTYPES))]
        arrays[key] = _retype(arrays[key], dt)
        return f"npz: {key} dtype -> {dt}"
    if op == "shape":
        arrays[key], how = _reshape(arrays[key], rng)
        return f"npz: {key} {how} (shape {arrays[key].shape})"
    if op == "values":
        arrays[key], how = _values(arrays[key], key, rng)
        return f"npz: {key} {how}"
    if op == "missing":
        del arrays[key]
        return f"npz: {key} missing"
    new = rng.choice((key.upper(), key + "_", "x" + key))
    arrays[new] = arrays.pop(key)
    return f"npz: {key} renamed to {new!r}"


def _members(data: bytes) -> list[tuple[zipfile.ZipInfo, bytes]]:
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        return [(info, zf.read(info)) for info in zf.infolist()]


def _zip(members) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, payload in members:
            zf.writestr(name, payload)
    return buf.getvalue()


def _data_offset(data: bytes, info: zipfile.ZipInfo) -> int:
    h = info.header_offset
    name_len = int.from_bytes(data[h + 26:h + 28], "little")
    extra_len = int.from_bytes(data[h + 28:h + 30], "little")
    return h + 30 + name_len + extra_len


def _bad_npy_header(payload: bytes, rng) -> tuple[bytes, str]:
    end = payload.index(b"\n") + 1 if b"\n" in payload[:512] else 128
    header = payload[:end].decode("latin-1")
    how = rng.choice(("descr", "shape big", "shape negative", "fortran", "garbage", "magic", "version"))
    if how == "descr":
        header = re.sub(r"'descr': '[^']*'", "'descr': '<zz'", header)
    elif how == "shape big":
        header = re.sub(r"'shape': \([^)]*\)", "'shape': (600, 600)", header)
    elif how == "shape negative":
        header = re.sub(r"'shape': \([^)]*\)", "'shape': (-1, 6)", header)
    elif how == "fortran":
        header = header.replace("'fortran_order': False", "'fortran_order': 7")
    elif how == "garbage":
        header = header[:10] + "{'descr': " + " " * (len(header) - 21) + "\n"
    elif how == "magic":
        header = "\x93NUMPX" + header[6:]
    else:
        header = header[:6] + "\x09\x09" + header[8:]
    return header.encode("latin-1") + payload[end:], how


def mutate_zip(data: bytes, rng) -> tuple[bytes, str]:
    """One zip-level corruption of ``.npz`` bytes; returns the new bytes and a description."""
    members = _members(data)
    if not members:
        return mutate_bytes(data, rng)
    op = rng.choice(("truncate tail", "flip header", "flip directory", "flip data", "npy header", "plain npy",
                     "pickle", "duplicate member", "foreign member", "empty zip", "compressed"))
    out = bytearray(data)
    if op == "truncate tail":
        cut = rng.randint(1, 120)
        return data[:-cut], f"zip: last {cut} bytes cut (end of central directory)"
    if op == "flip header":
        info = members[rng.randrange(len(members))][0]
        at = info.header_offset + rng.randrange(30)
        out[at] ^= 1 << rng.randrange(8)
        return bytes(out), f"zip: a bit flipped in the local header of {info.filename} (byte {at})"
    if op == "flip directory":
        start = max(data.find(b"PK\x01\x02"), 0)
        at = rng.randrange(start, len(data))
        out[at] ^= 1 << rng.randrange(8)
        return bytes(out), f"zip: a bit flipped in the central directory (byte {at})"
    if op == "flip data":
        info = members[rng.randrange(len(members))][0]
        begin = _data_offset(data, info)
        at = begin + rng.randrange(max(info.compress_size, 1))
        out[at] ^= 1 << rng.randrange(8)
        return bytes(out), f"zip: a bit flipped in the data of {info.filename} (bad CRC)"
    if op == "npy header":
        i = rng.randrange(len(members))
        payload, how = _bad_npy_header(members[i][1], rng)
        new = [(info.filename, payload if k == i else p) for k, (info, p) in enumerate(members)]
        return _zip(new), f"zip: bad .npy header of {members[i][0].filename} ({how})"
    if op == "plain npy":
        buf = io.BytesIO()
        np.save(buf, np.ones((6, 6), np.float32))
        return buf.getvalue(), "a plain .npy file instead of an .npz"
    if op == "pickle":
        buf = io.BytesIO()
        np.save(buf, np.array([{"obj": 1}], dtype=object), allow_pickle=True)
        return buf.getvalue(), "a pickled object .npy instead of an .npz"
    if op == "duplicate member":
        info, payload = members[rng.randrange(len(members))]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")   # zipfile warns about the duplicate name: that is the point
            new = _zip([(i.filename, p) for i, p in members] + [(info.filename, payload[: len(payload) // 2])])
        return new, f"zip: {info.filename} twice, the second one cut in half"
    if op == "foreign member":
        return _zip([(i.filename, p) for i, p in members] + [("notes.txt", b"hello")]), "zip: a non-.npy member"
    if op == "empty zip":
        return _zip([]), "zip: no members"
    buf = io.BytesIO()
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        np.savez_compressed(buf, **{k: npz[k] for k in npz.files})
    return buf.getvalue(), "zip: compressed archive (np.savez_compressed)"


# --------------------------------------------------------------------------------------------------
# Class "archive": .npz members that declare, or inflate to, more than a reader may take
# --------------------------------------------------------------------------------------------------

BOMB_BYTES = 65 * 2**20   # over MAX_MEMBER_BYTES (64 MiB): deflates to about 64 KiB
# (key, descr, shape) of .npy headers that declare far more data than the few bytes that follow them
HUGE_DECLARATIONS = (("target_wkt", "<U100000000", ()), ("name", "<U2000000000", ()), ("obj", "<f8", (100000, 100000)),
                     ("obj", "<c16", (4096, 4096)), ("obj", "<f4", (4096, 4096)), ("cell_size", "<f8", (2**40,)),
                     ("origin", "<f8", (2**62,)), ("origin", "<f8", (2**31, 2**31, 2**31)),
                     ("target", "<f8", (10**9, 4)), ("format_version", "<i8", (2**40,)), ("obj", "|O", (6, 6)))
BOMBS = ("target_wkt", "cell_size trailing zeros", "obj", "extra.npy", "target_wkt lying size")


def npy_header(descr: str, shape: tuple, fortran: bool = False) -> bytes:
    """A version 1.0 ``.npy`` header declaring ``descr`` and ``shape`` (no check that they are sane)."""
    text = f"{{'descr': {descr!r}, 'fortran_order': {fortran}, 'shape': {tuple(shape)!r}, }}"
    text += " " * ((-(10 + len(text) + 1)) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + len(text).to_bytes(2, "little") + text.encode("latin-1")


def _zip_members(members, compression=zipfile.ZIP_STORED) -> bytes:
    """A zip of ``(name, payload)`` pairs, duplicates kept (zipfile warns about them)."""
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with zipfile.ZipFile(buf, "w") as zf:
            for name, payload, *how in members:
                zf.writestr(name, payload, compress_type=how[0] if how else compression)
    return buf.getvalue()


def _base_members() -> list[tuple[str, bytes]]:
    return [(info.filename, payload) for info, payload in _members(_base_scene_files()[0])]


def _set_stated_size(data: bytes, name: str, size: int) -> bytes:
    """``data`` with the uncompressed size of member ``name`` set to ``size`` in its local header and
    in the central directory (a zip that lies about how much the member inflates to)."""
    out = bytearray(data)
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        info = zf.getinfo(name)
    out[info.header_offset + 22:info.header_offset + 26] = size.to_bytes(4, "little")
    at = data.find(b"PK\x01\x02")
    while at >= 0:
        n = int.from_bytes(data[at + 28:at + 30], "little")
        if data[at + 46:at + 46 + n] == name.encode():
            out[at + 24:at + 28] = size.to_bytes(4, "little")
        at = data.find(b"PK\x01\x02", at + 4)
    return bytes(out)


@functools.cache
def bomb_archive(which: str) -> bytes:
    """A scene ``.npz`` with one highly compressible member over its bound (built once, then cached)."""
    base = _base_members()
    zeros = bytes(BOMB_BYTES)
    deflate = zipfile.ZIP_DEFLATED
    if which.startswith("target_wkt"):
        member = ("target_wkt.npy", npy_header(f"<U{BOMB_BYTES // 4}", ()) + zeros, deflate)
    elif which == "cell_size trailing zeros":   # an honest 8-byte header, then 65 MiB nobody declared
        member = ("cell_size.npy", npy_header("<f8", ()) + np.float64(1.0).tobytes() + zeros, deflate)
    elif which == "obj":   # over obj's own bound (4096 * 4096 * 8 bytes + 64 KiB), within its side limit
        member = ("obj.npy", npy_header("<c16", (3000, 3000)) + bytes(3000 * 3000 * 16), deflate)
    else:
        member = ("extra.npy", npy_header("|u1", (BOMB_BYTES,)) + zeros, deflate)
    members = [m for m in base if m[0] != member[0]] + [member]
    data = _zip_members(members)
    if which.endswith("lying size"):
        data = _set_stated_size(data, member[0], 1000)
    return data


def mutate_archive(rng) -> tuple[bytes, str]:
    """One archive-member attack on the valid ``.npz`` scene: a header that declares a huge array over a
    few bytes, a member that inflates past its bound, a duplicated member, an extra large member."""
    base = _base_members()
    op = rng.choice(("huge header", "huge header", "bomb", "bomb", "duplicate", "large member"))
    if op == "huge header":
        key, descr, shape = HUGE_DECLARATIONS[rng.randrange(len(HUGE_DECLARATIONS))]
        tail = bytes(rng.choice((0, 8, 64)))
        members = [m for m in base if m[0] != f"{key}.npy"] + [(f"{key}.npy", npy_header(descr, shape) + tail)]
        if rng.random() < 0.5:
            members.sort()
        return _zip_members(members, rng.choice((zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED))), (
            f"archive: {key}.npy declares {descr} {shape} over {len(tail)} bytes")
    if op == "bomb":
        which = BOMBS[rng.randrange(len(BOMBS))]
        return bomb_archive(which), f"archive: a deflated member over its bound ({which})"
    if op == "duplicate":
        name, payload = base[rng.randrange(len(base))]
        how = rng.choice(("same", "other array", "first differs"))
        if how == "same":
            second = payload
        else:
            buf = io.BytesIO()
            np.save(buf, np.full((3, 3), 7.0, np.float32) if name == "obj.npy" else np.str_("POLYGON EMPTY"))
            second = buf.getvalue()
        members = base + [(name, second)]
        if how == "first differs":
            members = [(name, second)] + base
        return _zip_members(members), f"archive: {name} twice ({how})"
    size = rng.choice((2**20, 8 * 2**20))
    name = rng.choice(("extra.npy", "obj2.npy", "notes.txt", "obj.npy.npy"))
    payload = npy_header("|u1", (size,)) + bytes(size)
    return (_zip_members(base + [(name, payload)], rng.choice((zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED))),
            f"archive: an extra member {name} of {size // 2**20} MiB")


# --------------------------------------------------------------------------------------------------
# Class "nesting": one value wrapped in thousands of lists or objects
# --------------------------------------------------------------------------------------------------

NEST_DEPTHS = (2000, 3000, 5000)
NEST_MARK = "JAXPLAN_FUZZ_NEST_MARK"


def nest_deeply(doc: dict, rng, dump) -> tuple[bytes, str]:
    """The text of ``doc`` (JSON, or TOML when ``dump`` is ``to_toml``) with one value (or, in JSON,
    the whole document) wrapped in 2,000-5,000 lists or objects; the text is written directly, as
    neither ``json.dumps`` nor ``to_toml`` recurses that deep."""
    toml = dump is to_toml
    depth = NEST_DEPTHS[rng.randrange(len(NEST_DEPTHS))]
    how = rng.choice(("lists", "objects"))
    path = None if not toml and rng.random() < 0.15 else _pick(rng, doc)
    old = doc if path is None else _get(doc, path)
    inner = toml_value(old) if toml else json.dumps(old)
    if how == "lists":
        opening, closing = "[" * depth, "]" * depth
    else:
        opening, closing = ("{a = " if toml else '{"a": ') * depth, "}" * depth
    nested = opening + inner + closing
    if path is None:
        return nested.encode(), f"nesting: the document wrapped in {depth} {how}"
    _set(doc, path, NEST_MARK)
    text = dump(doc)
    mark = toml_value(NEST_MARK) if toml else json.dumps(NEST_MARK)
    return text.replace(mark, nested, 1).encode(), f"nesting: {label(path)} wrapped in {depth} {how}"


# --------------------------------------------------------------------------------------------------
# Class "fs": the --out folder prepared before the run (symbolic links out of it, a manifest that is
# not jaxplan's, a lock held by another run, a stale lock)
# --------------------------------------------------------------------------------------------------

FS_MODES = ("symlinked folder", "symlinked file", "foreign run.json", "busy", "stale lock")
DEAD_PID = 4_194_305   # above Linux's largest pid_max (2**22): no process has it


def _plant_manifest(out: Path, command: str, files: list[str]) -> None:
    doc = {"format": "jaxplan.run", "version": 1, "command": command, "arguments": {}, "status": "complete",
           "started": "2026-01-01T00:00:00+00:00", "finished": "2026-01-01T00:00:01+00:00", "files": files,
           "error": None}
    (out / "run.json").write_text(json.dumps(doc))


def prepare_out(case, rng) -> None:
    """Create ``case.out`` (a folder) in one of ``FS_MODES``, with victim files outside it whose content
    the run must leave alone (``case.victims``) and files in it that a refused run must not change
    (``case.planted``)."""
    out, outside = case.out, case.folder / "outside"
    out.mkdir(parents=True)
    outside.mkdir()
    mode = FS_MODES[rng.randrange(len(FS_MODES))]
    victim = outside / "victim.txt"
    victim.write_bytes(b"a file outside --out: no run may touch it\n")
    case.victims[victim] = victim.read_bytes()
    detail = ""
    if mode == "symlinked folder":
        (out / "sub").symlink_to(outside, target_is_directory=True)
        files = ["sub/victim.txt", "sub", "../outside/victim.txt", str(victim), "sub/../sub/victim.txt"]
        files = [f for f in files if rng.random() < 0.7] or ["sub/victim.txt"]
        _plant_manifest(out, case.command, files)
        detail = f"listing {files}"
    elif mode == "symlinked file":
        name = rng.choice(("summary.json", "fabric.png", "victim.txt", "plan.json", "scene.npz"))
        (out / name).symlink_to(victim)
        nested = out / "deep"
        nested.mkdir()
        (nested / "link.txt").symlink_to(os.path.relpath(victim, nested))
        _plant_manifest(out, case.command, [name, "deep/link.txt"])
        detail = f"{name} and deep/link.txt link to the victim"
    elif mode == "foreign run.json":
        how = rng.choice(("text", "other json", "list", "empty", "symlink to a victim", "folder"))
        manifest = out / "run.json"
        if how == "text":
            manifest.write_text("my own notes\n")
        elif how == "other json":
            manifest.write_text(json.dumps({"format": "someone.else", "files": ["victim.txt"]}))
        elif how == "list":
            manifest.write_text('["sub/victim.txt"]')
        elif how == "empty":
            manifest.write_bytes(b"")
        elif how == "symlink to a victim":
            manifest.symlink_to(victim)
        else:
            manifest.mkdir()
            (manifest / "keep.txt").write_text("keep")
        detail = how
        if how != "symlink to a victim":
            case.planted.update(_snapshot(out))
    elif mode == "busy":
        case.holder = {"pid": rng.choice((os.getpid(), 1, DEAD_PID)), "command": "x"}
        (out / ".jaxplan.lock").write_text(json.dumps(case.holder))
        case.planted.update(_snapshot(out))
        detail = f"held by pid {case.holder['pid']}"
    else:
        (out / ".jaxplan.lock").write_text(json.dumps({"pid": DEAD_PID, "command": "episode"})
                                           if rng.random() < 0.8 else "garbage")
        detail = f"pid {DEAD_PID}"
    case.fs = mode
    case.mutations.append(f"fs: {mode}" + (f" ({detail})" if detail else ""))


def _snapshot(folder: Path) -> dict:
    """Every file under ``folder`` (links not followed) and its bytes (None for a link or a folder)."""
    out = {}
    for p in sorted(folder.rglob("*")):
        out[p] = p.read_bytes() if p.is_file() and not p.is_symlink() else None
    return out


# --------------------------------------------------------------------------------------------------
# Cases
# --------------------------------------------------------------------------------------------------

@dataclass
class Case:
    """One fuzz case: a mutated input file in ``folder`` and the CLI call that reads it."""

    kind: str
    command: str
    mutations: list[str]
    folder: Path
    input: Path
    out: Path
    argv: list[str] = field(default_factory=list)
    cls: str = "inputs"   # one of CLASSES
    fs: str | None = None   # class "fs": one of FS_MODES, how --out was prepared
    victims: dict = field(default_factory=dict)   # files outside --out -> their bytes: never to change
    planted: dict = field(default_factory=dict)   # files in --out -> bytes: a refused run leaves them
    holder: dict | None = None   # mode "busy": what the held lock file says

    def describe(self) -> str:
        return f"{self.kind} via {self.command}: " + ("; ".join(self.mutations) or "unmutated (valid)")

    @contextlib.contextmanager
    def running(self):
        """The context a case runs in: for mode ``busy``, an exclusive ``flock`` on ``--out``'s lock file,
        held by this process (two separate opens conflict, even within one process) until the run ends."""
        if self.fs != "busy":
            yield
            return
        fd = os.open(self.out / ".jaxplan.lock", os.O_RDWR)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            yield
        finally:
            os.close(fd)


def _mutated_doc(doc: dict, rng, dump) -> tuple[bytes, list[str]]:
    """Tree mutations, byte mutations, both, or none (a valid control case)."""
    r = rng.random()
    notes = []
    if r < 0.04:
        return dump(doc).encode(), []
    if r < 0.72 or r >= 0.95:
        for _ in range(rng.choice((1, 1, 1, 2, 3))):
            notes.append(mutate_tree(doc, rng, toml=dump is to_toml))
    data = dump(doc).encode("utf-8", "surrogatepass")
    if r >= 0.72:
        data, note = mutate_bytes(data, rng)
        notes.append(f"bytes: {note}")
    return data, notes


def _mutated_npz(rng) -> tuple[bytes, list[str]]:
    arrays = base_npz_arrays()
    r = rng.random()
    notes = []
    if r < 0.04:
        return npz_bytes(arrays), []
    if r < 0.5 or r >= 0.95:
        for _ in range(rng.choice((1, 1, 2))):
            notes.append(mutate_arrays(arrays, rng))
    data = npz_bytes(arrays)
    if 0.5 <= r < 0.8 or r >= 0.95:
        data, note = mutate_zip(data, rng)
        notes.append(note)
    elif r >= 0.8:
        data, note = mutate_bytes(data, rng)
        notes.append(f"bytes: {note}")
    return data, notes


def _base_doc(kind: str) -> dict:
    return {"scene.json": base_scene_doc, "sweep.toml": lambda: copy.deepcopy(SWEEP_SPEC),
            "pusharound.json": lambda: copy.deepcopy(PUSH_SCENE)}[kind]()


def _mutated_input(kind: str, rng) -> tuple[bytes, list[str]]:
    if kind == "scene.npz":
        return _mutated_npz(rng)
    return _mutated_doc(_base_doc(kind), rng, to_toml if kind == "sweep.toml" else json.dumps)


def make_case(rng, folder: Path, kind: str | None = None, cls: str = "inputs") -> Case:
    """Write one mutated input file into the (new, empty) ``folder`` and return the case.

    rng: ``random.Random`` (or hypothesis's ``st.randoms()``); kind: one of ``KINDS`` or None (drawn:
    with ``KIND_WEIGHTS`` for class ``inputs``, evenly among ``CLASS_KINDS[cls]`` otherwise); cls: one
    of ``CLASSES``.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if cls not in CLASSES:
        raise ValueError(f"cls: {cls!r} is not one of {CLASSES}.")
    if kind is None:
        kinds = CLASS_KINDS[cls]
        kind = KINDS[_weighted(rng, KIND_WEIGHTS)] if cls == "inputs" else kinds[rng.randrange(len(kinds))]
    if kind not in CLASS_KINDS[cls]:
        raise ValueError(f"kind: {kind!r} is not one of class {cls!r}'s kinds {CLASS_KINDS[cls]}.")
    out_dir = folder / "out"
    if kind == "sweep.toml":
        (folder / "site.json").write_text(_base_scene_files()[1])
    if cls == "archive":
        data, note = mutate_archive(rng)
        notes = [note]
    elif cls == "nesting":
        data, note = nest_deeply(_base_doc(kind), rng, to_toml if kind == "sweep.toml" else json.dumps)
        notes = [note]
    elif cls == "fs" and rng.random() < FS_VALID_SHARE:   # mostly valid input: the run reaches --out
        data, notes = (_base_scene_files()[0] if kind == "scene.npz" else
                       json.dumps(_base_doc(kind)).encode()), []
    else:
        data, notes = _mutated_input(kind, rng)
    name = {"scene.npz": "scene.npz", "scene.json": "scene.json", "sweep.toml": "spec.toml",
            "pusharound.json": "scene.json"}[kind]
    path = folder / name
    path.write_bytes(data)
    if kind.startswith("scene."):
        if cls == "fs" or rng.random() < EPISODE_SHARE:   # fs: a command that writes an output folder
            command, out = "episode", out_dir
            argv = ["episode", "--scene", str(path), "--out", str(out), "--no-animation", "--max-pushes", "2"]
        else:
            command, out = "fabric", out_dir / "f.npz"
            argv = ["fabric", "--scene", str(path), "--out", str(out)]
    elif kind == "sweep.toml":
        command, out = "sweep", out_dir / "s.csv"
        argv = ["sweep", str(path), "--out", str(out), "--no-progress"]
    else:
        command, out = "pusharound", out_dir
        argv = ["pusharound", "--scene", str(path), "--out", str(out), "--no-execute", "--time-limit",
                str(PUSH_TIME_LIMIT_S), "--backend", "c", "--max-frames", "2", "--fps", "1"]
    case = Case(kind, command, notes, folder, path, out, argv, cls=cls)
    if cls == "fs":
        prepare_out(case, rng)
    return case


def _weighted(rng, weights) -> int:
    x, acc = rng.random() * sum(weights), 0.0
    for i, w in enumerate(weights):
        acc += w
        if x < acc:
            return i
    return len(weights) - 1


# --------------------------------------------------------------------------------------------------
# Running and checking
# --------------------------------------------------------------------------------------------------

def _innermost(tb, package: str | None = None) -> str | None:
    """``path:function`` of the innermost frame (of ``package``'s files if given)."""
    frames = traceback.extract_tb(tb)
    for frame in reversed(frames):
        parts = Path(frame.filename).parts
        if package is None or package in parts:
            if package is not None:
                parts = parts[len(parts) - 1 - parts[::-1].index(package):]
            return f"{'/'.join(parts[-3:]) if package is None else '/'.join(parts)}:{frame.name}"
    return None


def execute(argv: list[str]) -> dict:
    """Run ``jaxplan.cli.app.main(argv)`` in this process, capturing stdout, stderr and warnings.

    Returns a dict: ``code`` (the return value or SystemExit code; None when it raised), ``exception``
    (the traceback's last line), ``where`` (innermost jaxplan frame), ``frame`` (innermost frame),
    ``stdout``, ``stderr``, ``warnings`` (categories), ``seconds``.
    """
    from jaxplan.cli import main

    out, err = io.StringIO(), io.StringIO()
    result = {"code": None, "exception": None, "where": None, "frame": None}
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught, redirect_stdout(out), redirect_stderr(err):
        warnings.simplefilter("always")
        try:
            result["code"] = main(list(argv))
        except SystemExit as exc:
            result["code"] = 0 if exc.code is None else exc.code if isinstance(exc.code, int) else 1
        except Exception as exc:   # every other exception is a finding
            result["exception"] = traceback.format_exception_only(exc)[-1].strip()
            result["where"] = _innermost(exc.__traceback__, "jaxplan")
            result["frame"] = _innermost(exc.__traceback__)
    result.update(stdout=out.getvalue(), stderr=err.getvalue(), seconds=time.perf_counter() - start,
                  warnings=sorted({w.category.__name__ for w in caught}))
    return result


def visible_lines(text: str) -> list[str]:
    """The non-blank lines a terminal shows for ``text``: of each line, what follows its last ``\\r``
    (tqdm erases a closed bar that way)."""
    return [s for s in (line.split("\r")[-1].strip() for line in text.split("\n")) if s]


@functools.cache
def field_words(kind: str) -> tuple[str, ...]:
    """The names an error message may use to point at the bad part of a ``kind`` input."""
    if kind.startswith("scene."):
        return SCENE_FIELDS
    if kind == "pusharound.json":
        return PUSH_FIELDS
    from jaxplan.sweep import spec

    return (("sweep spec", "scenes", "random_scenes", "fabric", "spill", "static", "metrics", "seeds", "shape",
             "density", "top_sources", "max_steps") + spec.FABRIC_TRACED + spec.FABRIC_STATIC + spec.SPILL_TRACED
            + spec.SPILL_STATIC + SCENE_FIELDS)


def line_problems(case: Case, stderr: str) -> list[str]:
    """What is wrong with an exit-2 stderr: not one line, no ``error:``, names no file, flag or field."""
    lines = visible_lines(stderr)
    if len(lines) != 1:
        return [f"{len(lines)} lines on stderr"]
    line = lines[0]
    if not line.startswith("error: "):
        return ["the line does not start with 'error: '"]
    names_file = str(case.input) in line or case.input.name in line or (case.fs is not None and str(case.out) in line)
    names_flag = re.search(r"(?<![\w-])--[a-z][a-z-]+", line) is not None
    names_field = any(re.search(rf"(?<![A-Za-z_]){re.escape(w)}(?![A-Za-z_])", line) for w in field_words(case.kind))
    if not (names_file or names_flag or names_field):
        return ["the line names neither the file nor a flag or field"]
    return []


def output_problems(case: Case, code) -> list[str]:
    """Half-written outputs: an --out left by a failure, a missing or incomplete output, temp files."""
    problems = []
    out = case.out
    top = case.folder / "out"   # every case's --out is this folder or a file in it
    if code == 2 and top.exists() and case.fs is None:   # an fs case's --out existed before the run
        problems.append("exit 2 but the --out path was created")
    if code == 0:
        if not out.exists():
            problems.append("exit 0 but no output at --out")
        manifest = out / "run.json" if out.is_dir() else None
        if manifest is not None and manifest.exists():
            try:
                doc = json.loads(manifest.read_text())
            except (OSError, ValueError) as exc:
                problems.append(f"run.json unreadable ({type(exc).__name__})")
            else:
                if doc.get("status") != "complete":
                    problems.append(f"exit 0 but run.json status is {doc.get('status')!r}")
                missing = [f for f in doc.get("files", []) if not (out / f).exists()]
                if missing:
                    problems.append(f"run.json lists missing file(s) {missing}")
    temps = [str(p.relative_to(case.folder)) for p in case.folder.rglob(".*") if ".tmp" in p.name]
    if temps:
        problems.append(f"temp file(s) left: {temps}")
    return problems


def outside_problems(case: Case) -> list[str]:
    """Victim files outside ``--out`` that are gone, replaced or changed."""
    problems = []
    for path, content in case.victims.items():
        if path.is_symlink() or not path.is_file():
            problems.append(f"touched outside --out: {path.relative_to(case.folder)} removed or replaced")
        elif path.read_bytes() != content:
            problems.append(f"touched outside --out: {path.relative_to(case.folder)} changed")
    return problems


def fs_problems(case: Case, code) -> list[str]:
    """For a folder held by another run or holding a foreign manifest: the run was refused and left the
    folder's files as they were."""
    if case.fs not in ("busy", "foreign run.json") or not case.planted:
        return []
    problems = []
    if code == 0:
        problems.append(f"exit 0 into a folder with {'a held lock' if case.fs == 'busy' else 'a foreign run.json'}")
    now = _snapshot(case.out) if case.out.is_dir() else {}
    changed = [str(p.relative_to(case.folder)) for p, b in case.planted.items() if p not in now or now[p] != b]
    if changed:
        problems.append(f"planted file(s) changed or removed: {changed}")
    return problems


def check_case(case: Case, run: dict) -> tuple[str, list[str]]:
    """The outcome of a run (one of ``OUTCOMES``) and its problems (empty for a passing outcome)."""
    outside = outside_problems(case)
    if outside:   # before all else: a file outside --out changed, whatever the run did
        return "touched_outside", outside + ([f"timeout ({run['timeout']} s)"] if run.get("timeout") else [])
    if run.get("timeout"):
        return "timeout", [f"no result within {run['timeout']} s"]
    if run.get("crash"):
        return "crash", [run["crash"]]
    outputs = output_problems(case, run["code"]) + fs_problems(case, run["code"])
    if run["exception"] is not None:
        return "traceback", [run["exception"]] + outputs
    if run["code"] not in (0, 2):
        return "other_exit", [f"exit code {run['code']}"] + outputs
    if outputs:
        return "half_written", outputs + (line_problems(case, run["stderr"]) if run["code"] == 2 else [])
    if run["code"] == 2:
        bad = line_problems(case, run["stderr"])
        return ("exit2_bad_line", bad) if bad else ("exit2_good", [])
    return "exit0", []


def _normalise(text: str, case: Case) -> str:
    """``text`` with the case's folder, numbers, long quoted values and byte positions masked."""
    text = text.replace(str(case.folder), "D")
    text = re.sub(r"'utf-8' codec can't decode .*", "<not UTF-8: a UnicodeDecodeError>", text)
    text = re.sub(r"0x[0-9a-f]+", "0x_", text)
    text = re.sub(r"(?<![A-Za-z_0-9])(?<![A-Za-z]-)-?\d+(\.\d+)?(e[-+]?\d+)?(?![A-Za-z_])", "N", text)
    text = re.sub(r"'[^'\n]*'", "'...'", text)
    return text[:140]


def finding_key(case: Case, run: dict, outcome: str, problems: list[str]) -> str:
    """Groups findings by cause: a traceback by its innermost jaxplan function and its last line, a bad
    line by the line, both with paths and numbers masked; an output problem by its first kind."""
    reader = READERS[case.kind]
    if outcome == "traceback":
        return f"{reader}: in {run['where'] or run['frame']}: {_normalise(run['exception'], case)[:100]}"
    if outcome == "exit2_bad_line":
        line = (visible_lines(run["stderr"]) or ["<nothing>"])[0]
        return f"{reader}: {problems[0]}: {_normalise(line, case)}"
    if outcome == "half_written":
        return f"{case.command}: {problems[0].split(':')[0]}"
    if outcome == "touched_outside":
        return f"{case.command}: touched outside --out ({case.fs})"
    return f"{case.command}: {outcome} ({_normalise(problems[0], case) if problems else ''})"


# --------------------------------------------------------------------------------------------------
# The standalone run: one worker process runs the cases, a new one after a timeout or a crash
# --------------------------------------------------------------------------------------------------

def _worker(conn) -> None:
    from jaxplan.cli import main  # noqa: F401 -- import once, before the first case

    while True:
        argv = conn.recv()
        if argv is None:
            return
        conn.send(execute(argv))


class Worker:
    """A spawned process that runs ``execute(argv)``; restarted after a timeout or a crash."""

    def __init__(self, timeout_s: float):
        import multiprocessing

        self._ctx = multiprocessing.get_context("spawn")
        self.timeout_s = timeout_s
        self._proc = None

    def _start(self) -> None:
        self._conn, child = self._ctx.Pipe()
        self._proc = self._ctx.Process(target=_worker, args=(child,), daemon=True)
        self._proc.start()
        child.close()

    def run(self, argv: list[str]) -> dict:
        if self._proc is None or not self._proc.is_alive():
            self._start()
        start = time.perf_counter()
        self._conn.send(argv)
        try:
            if self._conn.poll(self.timeout_s):
                return self._conn.recv()
            result = {"timeout": self.timeout_s}
        except EOFError:
            self._proc.join(5)
            result = {"crash": f"worker died (exit code {self._proc.exitcode})"}
        self._stop()
        result.update(seconds=time.perf_counter() - start, stdout="", stderr="", exception=None, where=None,
                      frame=None, code=None, warnings=[])
        return result

    def _stop(self) -> None:
        if self._proc is not None:
            if self._proc.is_alive():
                self._proc.kill()
            self._proc.join(5)
            self._proc = None

    def close(self) -> None:
        if self._proc is not None and self._proc.is_alive():
            self._conn.send(None)
            self._proc.join(10)
        self._stop()


def case_class(seed: int, index: int, kinds=None, classes=None) -> str:
    """The class of case ``index`` of ``seed``: drawn with ``CLASS_WEIGHTS`` among ``classes`` (default
    all) that have a kind in ``kinds``, from a random stream of its own."""
    import random

    pool = [c for c in (classes or CLASSES) if not kinds or set(CLASS_KINDS[c]) & set(kinds)]
    if not pool:
        raise ValueError(f"no class of {classes or CLASSES} has a kind of {kinds}.")
    if len(pool) == 1:
        return pool[0]
    rng = random.Random(f"class:{seed}:{index}")
    return pool[_weighted(rng, [CLASS_WEIGHTS[CLASSES.index(c)] for c in pool])]


def build_case(seed: int, index: int, folder: Path, kinds=None, classes=None) -> Case:
    """Case ``index`` of ``seed``: always the same input (and command) for the same seed, index, kinds
    and classes."""
    import random

    cls = case_class(seed, index, kinds, classes)
    rng = random.Random(seed * 1_000_003 + index)
    if cls == "inputs":
        kind = kinds[rng.randrange(len(kinds))] if kinds else None
    else:
        allowed = [k for k in CLASS_KINDS[cls] if not kinds or k in kinds]
        kind = allowed[rng.randrange(len(allowed))]
    return make_case(rng, folder, kind, cls)


def replay_command(seed: int, index: int, kinds=None, classes=None) -> str:
    return (f"python -m tests.fuzz.fuzz_cli --seed {seed} --replay {index}"
            + (f" --kinds {' '.join(kinds)}" if kinds else "")
            + (f" --classes {' '.join(classes)}" if classes else "") + f" --keep out/fuzz_case{index}")


def _example(case: Case, run: dict, outcome: str, problems: list[str], replay: str, index: int) -> dict:
    text = None
    if case.input.exists():
        raw = case.input.read_bytes()
        text = raw[:400].decode("utf-8", "backslashreplace") if case.kind != "scene.npz" else None
    return {"case": index, "class": case.cls, "kind": case.kind, "command": case.command, "fs": case.fs,
            "mutations": case.mutations,
            "argv": [a.replace(str(case.folder), "D") for a in case.argv], "outcome": outcome,
            "problems": [p.replace(str(case.folder), "D") for p in problems],
            "traceback_last_line": (run.get("exception") or "").replace(str(case.folder), "D")[:500] or None,
            "where": run.get("where"), "frame": run.get("frame"),
            "stderr_lines": [s.replace(str(case.folder), "D")[:300] for s in visible_lines(run.get("stderr", ""))][:5],
            "input_start": text,
            "replay": replay}


def run_cases(indices, seed: int, root: Path, timeout_s: float, kinds=None, keep: bool = False,
              progress: bool = True, classes=None) -> tuple[list[dict], dict]:
    """Make, run and check the cases ``indices`` of ``seed``; returns per-case records and findings."""
    from tqdm import tqdm

    worker = Worker(timeout_s)
    records, findings = [], {}
    counts = Counter()
    bar = tqdm(list(indices), desc="fuzz", unit="case", disable=not progress, file=sys.stderr)
    try:
        for index in bar:
            case = build_case(seed, index, root / f"case{index:05d}", kinds, classes)
            with case.running():
                run = worker.run(case.argv)
            outcome, problems = check_case(case, run)
            counts[outcome] += 1
            bar.set_postfix({k: v for k, v in counts.items()}, refresh=False)
            record = {"case": index, "class": case.cls, "kind": case.kind, "command": case.command,
                      "outcome": outcome, "seconds": round(run["seconds"], 3)}
            if case.fs:
                record["fs"] = case.fs
            if case.victims:
                record["victims"] = len(case.victims)
            if outcome not in PASSING:
                key = finding_key(case, run, outcome, problems)
                record["finding"] = key
                entry = findings.setdefault(key, {"key": key, "outcome": outcome, "count": 0, "kinds": Counter(),
                                                  "commands": Counter(), "cases": [],
                                                  "example": _example(case, run, outcome, problems,
                                                                      replay_command(seed, index, kinds, classes),
                                                                      index)})
                entry["count"] += 1
                entry["kinds"][case.kind] += 1
                entry["commands"][case.command] += 1
                entry["cases"].append(index)
            records.append(record)
            if not keep:
                shutil.rmtree(case.folder, ignore_errors=True)
    finally:
        bar.close()
        worker.close()
    return records, findings


def summarise(records: list[dict], findings: dict, meta: dict) -> dict:
    by_kind = {k: Counter() for k in KINDS}
    by_class = {c: Counter() for c in CLASSES}
    by_fs = {m: Counter() for m in FS_MODES}
    by_command = defaultdict(Counter)
    seconds = defaultdict(list)
    for r in records:
        by_kind[r["kind"]][r["outcome"]] += 1
        by_class[r.get("class", "inputs")][r["outcome"]] += 1
        if r.get("fs"):
            by_fs[r["fs"]][r["outcome"]] += 1
        by_command[r["command"]][r["outcome"]] += 1
        seconds[r["kind"]].append(r["seconds"])

    def table(counter):
        return {o: counter.get(o, 0) for o in OUTCOMES} | {"total": sum(counter.values())}

    ordered = sorted(findings.values(), key=lambda f: (OUTCOMES.index(f["outcome"]), -f["count"], f["key"]))
    return {**meta, "cases": len(records),
            "outcomes": table(Counter(r["outcome"] for r in records)),
            "kinds": {k: table(c) for k, c in by_kind.items() if c},
            "classes": {k: table(c) for k, c in by_class.items() if c},
            "fs_modes": {k: table(c) for k, c in by_fs.items() if c},
            "victims_checked": sum(r.get("victims", 0) for r in records),
            "commands": {k: table(c) for k, c in sorted(by_command.items())},
            "case_seconds": {k: {"total": round(sum(v), 1), "median": round(statistics.median(v), 3),
                                 "max": round(max(v), 2)} for k, v in seconds.items()},
            "findings": [{**f, "kinds": dict(f["kinds"]), "commands": dict(f["commands"])} for f in ordered]}


def markdown(result: dict) -> str:
    cols = [o for o in OUTCOMES if result["outcomes"][o] or o in ("exit0", "exit2_good", "exit2_bad_line",
                                                                  "traceback", "half_written", "touched_outside",
                                                                  "crash")]
    head = "| | " + " | ".join(cols) + " | total |"
    rule = "|---|" + "---:|" * (len(cols) + 1)

    def rows(table):
        return [f"| {name} | " + " | ".join(str(t[o]) for o in cols) + f" | {t['total']} |" for name, t in table]

    lines = ["# CLI input fuzzing", "",
             f"{result['date']}, {result['host']}, jax {result['jax']} ({result['backend']}), seed {result['seed']}, "
             f"{result['cases']} cases in {result['seconds']:.0f} s (per-case timeout {result['case_timeout_s']:g} s). "
             "Each case mutates a valid input file and runs the CLI on it in-process "
             "(`tests/fuzz/fuzz_cli.py`). Passing: `exit0`, `exit2_good` (one `error:` line naming the file, a "
             "flag or a field, no output left behind).", "",
             "## Cases per class", "", head, rule, *rows(result.get("classes", {}).items()), "",
             "## Cases per kind of input", "", head, rule, *rows(result["kinds"].items()),
             "| **all** | " + " | ".join(f"**{result['outcomes'][o]}**" for o in cols)
             + f" | **{result['outcomes']['total']}** |", "",
             "## Cases per command", "", head, rule, *rows(result["commands"].items()), "",
             *(["## Class fs: cases per way --out was prepared", "",
                f"{result.get('victims_checked', 0)} victim file(s) outside --out checked after the runs "
                "(`touched_outside`: one gone or changed).", "", head, rule,
                *rows(result["fs_modes"].items()), ""] if result.get("fs_modes") else []),
             f"## Distinct findings ({len(result['findings'])})", ""]
    if not result["findings"]:
        lines.append("None.")
    for i, f in enumerate(result["findings"], 1):
        ex = f["example"]
        kinds = ", ".join(f"{k} {n}" for k, n in f["kinds"].items())
        lines.append(f"{i}. **{f['outcome']}** `{f['key']}` ({f['count']} case(s): {kinds})")
        more = ", ".join(map(str, f["cases"][:12])) + (", ..." if len(f["cases"]) > 12 else "")
        lines.append(f"   - example (case {ex['case']}; cases {more}): {ex['kind']}, "
                     + ("; ".join(ex["mutations"]) or "unmutated"))
        if ex["traceback_last_line"]:
            lines.append(f"   - traceback: `{ex['traceback_last_line'][:300]}`")
        elif ex["stderr_lines"]:
            lines.append(f"   - stderr: `{ex['stderr_lines'][0][:300]}`"
                         + (f" (+{len(ex['stderr_lines']) - 1} line(s))" if len(ex["stderr_lines"]) > 1 else ""))
        if ex["problems"] and f["outcome"] != "traceback":
            lines.append(f"   - problem: {'; '.join(ex['problems'])[:300]}")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.fuzz.fuzz_cli",
                                 description=__doc__.split("\n\n")[0].replace("\n", " "),
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="examples:\n  python -m tests.fuzz.fuzz_cli --cases 1000 --seed 0\n"
                                        "  python -m tests.fuzz.fuzz_cli --cases 50 --kinds scene.npz\n"
                                        "  python -m tests.fuzz.fuzz_cli --seed 0 --replay 17 --keep out/fuzz17")
    ap.add_argument("--cases", type=int, default=1000, help="number of cases (default 1000, about 2 minutes)")
    ap.add_argument("--seed", type=int, default=0, help="seed; case I of seed S is always the same input (default 0)")
    ap.add_argument("--kinds", nargs="+", choices=KINDS, default=None, metavar="KIND",
                    help=f"only these kinds of input, of {', '.join(KINDS)} (default: all, drawn with weights "
                         f"{', '.join(map(str, KIND_WEIGHTS))})")
    ap.add_argument("--classes", nargs="+", choices=CLASSES, default=None, metavar="CLASS",
                    help=f"only these classes of case, of {', '.join(CLASSES)} (default: all, drawn with weights "
                         f"{', '.join(map(str, CLASS_WEIGHTS))})")
    ap.add_argument("--case-timeout", type=float, default=120.0, metavar="S",
                    help="seconds one case may run before its worker is killed (default 120)")
    ap.add_argument("--replay", type=int, default=None, metavar="I",
                    help="run case I of --seed only, print what happened (writes no results)")
    ap.add_argument("--keep", type=Path, default=None, metavar="DIR",
                    help="write the case folders (inputs and outputs) into DIR and keep them")
    ap.add_argument("--name", default="fuzz_cli", help="results file stem (default fuzz_cli)")
    ap.add_argument("--results-dir", type=Path, default=RESULTS_DIR, metavar="DIR",
                    help="where <name>.json and <name>.md go (default experiments/results)")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    if args.cases < 1 or args.case_timeout <= 0:
        ap.error("--cases must be >= 1 and --case-timeout > 0")
    os.environ.setdefault("XLA_FLAGS", FAST_COMPILE_FLAGS)
    root = args.keep if args.keep is not None else Path(tempfile.mkdtemp(prefix="jaxplan-fuzz-"))
    if args.keep is not None and args.keep.exists() and any(args.keep.iterdir()):
        ap.error(f"--keep: {args.keep} is not empty; give a new folder")
    try:
        if args.replay is not None:
            records, findings = run_cases([args.replay], args.seed, root, args.case_timeout, args.kinds,
                                          keep=args.keep is not None, progress=False, classes=args.classes)
            (rec,) = records
            print(json.dumps(rec))
            for f in findings.values():
                print(json.dumps(f["example"], indent=1))
            return 0
        start = time.perf_counter()
        records, findings = run_cases(range(args.cases), args.seed, root, args.case_timeout, args.kinds,
                                      keep=args.keep is not None, progress=not args.no_progress,
                                      classes=args.classes)
        import jax

        meta = {"date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"), "host": platform.platform(),
                "jax": jax.__version__, "backend": jax.default_backend(), "seed": args.seed,
                "kinds_requested": args.kinds or list(KINDS), "classes_requested": args.classes or list(CLASSES),
                "case_timeout_s": args.case_timeout,
                "xla_flags": os.environ.get("XLA_FLAGS", ""), "seconds": round(time.perf_counter() - start, 1),
                "command": "python -m tests.fuzz.fuzz_cli " + " ".join(argv if argv is not None else sys.argv[1:])}
        result = summarise(records, findings, meta)
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)
    write_results(args.results_dir, args.name, result, markdown(result))
    return 0


def write_results(results_dir: Path, stem: str, result: dict, markdown_text: str) -> None:
    """``<stem>.json`` and ``<stem>.md`` in ``results_dir``, as the benchmarks in ``experiments/`` write
    theirs (``experiments.results_io``); the table is printed too."""
    results_dir.mkdir(parents=True, exist_ok=True)
    (results_dir / f"{stem}.json").write_text(json.dumps(result, indent=1, allow_nan=False) + "\n")
    (results_dir / f"{stem}.md").write_text(markdown_text)
    print(markdown_text)


if __name__ == "__main__":
    raise SystemExit(main())
