"""What every subcommand shares: the error type, the parser, checked argument types, scene loading,
parameter dicts, atomic files."""
from __future__ import annotations

import argparse
import math
import os
import sys
import textwrap
from pathlib import Path

import numpy as np

from jaxplan.core import RunFolder, path_kind
from jaxplan.transport import BUILTIN_SCENES

EXIT_BAD_INPUT = 2
_WARN_BUILD_BYTES = 10**9   # a fabric build estimated above this gets a warning line


class CLIError(Exception):
    """Bad command-line input; the message is printed as ``error: <message>``."""


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line, as every other CLI error:
    ``error: --fps: must be an int in [1, 50] ...; got 0; see 'jaxplan demo --help'`` on stderr, exit
    code 2, without argparse's usage block. Subparsers inherit the class."""

    def error(self, message):
        text = " ".join(str(message).split())
        if text.startswith("argument "):     # argparse's "argument --fps: ..." -> "--fps: ..."
            text = text[len("argument "):]
        self.exit(EXIT_BAD_INPUT, f"error: {text}; see '{self.prog} --help'\n")


def _num(x) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


def _range_text(kind, lo, hi, lo_open: bool, hi_open: bool, inf_ok: bool, unit: str) -> str:
    noun = "an int" if kind is int else "a number"
    if math.isinf(hi):
        text = f"{noun} {'>' if lo_open else '>='} {_num(lo)}" + (" (inf allowed)" if inf_ok else "")
    else:
        text = f"{noun} in {'(' if lo_open else '['}{_num(lo)}, {_num(hi)}{')' if hi_open else ']'}"
    return text + (f" {unit}" if unit else "")


def ranged(kind, lo, hi=math.inf, *, lo_open: bool = False, hi_open: bool = False, inf_ok: bool = False,
           unit: str = "", why: str = ""):
    """An argparse ``type=`` that parses ``kind`` (``int`` or ``float``) and requires it in the range
    ``lo``..``hi`` (``lo_open`` / ``hi_open``: exclude the end). NaN is always refused, and so is
    infinity unless ``inf_ok`` (with ``hi`` = inf). A refusal reads ``--flag: must be a number in
    (0, 180) degrees; <why>; got nan``; ``Parser`` prints it as one line, exit code 2, before any work."""
    what = _range_text(kind, lo, hi, lo_open, hi_open, inf_ok, unit)

    def parse(text: str):
        try:
            value = kind(text)
        except (TypeError, ValueError):
            value = None
        if value is not None and kind is float:
            if math.isnan(value) or (math.isinf(value) and not (inf_ok and value > 0)):
                value = None
        if value is not None and not math.isinf(value):
            too_low = value <= lo if lo_open else value < lo
            too_high = value >= hi if hi_open else value > hi
            if too_low or too_high:
                value = None
        if value is None:
            raise argparse.ArgumentTypeError(f"must be {what}{'; ' + why if why else ''}; got {text}")
        return value

    parse.__name__ = kind.__name__   # argparse names the type in some messages
    return parse


# shared flags
FPS = ranged(int, 1, 50, why="GIF frame delays are whole 1/100 s and viewers slow delays under 0.02 s down")
SEED = ranged(int, 0, 2**32 - 1, why="a 32-bit unsigned seed")


MAP_SUFFIX = ".map"
MAP_SCENE_HELP = ("; or a MovingAI benchmark map (FILE.map, https://movingai.com/benchmarks/): a site on its free "
                  "cells, targets and material drawn from --site-seed (docs/scene-files.md)")


def add_site_seed_option(p) -> None:
    """``--site-seed N``: the seed of the site ``load_scene`` builds on a ``.map`` ``--scene``."""
    p.add_argument("--site-seed", type=SEED, default=None, metavar="N",
                   help="with a MovingAI FILE.map --scene: the seed that places the targets and the material "
                        "piles (jaxplan.transport.site_from_map), an int in [0, 4294967295]; default 0")


def load_scene(spec: str, site_seed: int | None = None):
    """A built-in scene by name, a scene file (.npz / .json) by path, or a site on a MovingAI map
    (``.map``, ``jaxplan.transport.site_from_map`` with seed ``site_seed``, default 0).

    A bad file -- missing, a directory, unreadable, damaged, wrong keys or values -- is one
    ``CLIError("--scene: Scene file <path>: ...")`` (``Scene.load`` names what is wrong), or
    ``CLIError("--scene: Map file <path>: ...")``. A ``site_seed`` with a scene that is not a map is a
    ``CLIError`` naming ``--site-seed``.
    """
    from jaxplan.transport import Scene, builtin_scene, site_from_map

    path = Path(spec)
    is_map = path.suffix.lower() == MAP_SUFFIX
    if site_seed is not None and not is_map:
        raise CLIError(f"--site-seed: {site_seed} is only used with a MovingAI .map --scene, and {spec!r} is not "
                       "one; drop --site-seed or give a FILE.map.")
    if spec in BUILTIN_SCENES:
        return builtin_scene(spec)
    kind = cli_path_kind(spec, "--scene")
    if kind == "dir":
        raise CLIError(f"--scene: {spec!r} is a directory; give a .npz/.json scene file, a .map file or a "
                       f"built-in scene ({', '.join(BUILTIN_SCENES)}).")
    if kind != "missing":
        try:
            return site_from_map(path, 0 if site_seed is None else site_seed) if is_map else Scene.load(path)
        except ValueError as exc:
            raise CLIError(f"--scene: {exc}") from None
    if path.suffix.lower() in (".npz", ".json", MAP_SUFFIX) or os.sep in spec:
        raise CLIError(f"--scene: no such scene file {spec!r}.")
    raise CLIError(f"--scene: {spec!r} is neither a built-in scene ({', '.join(BUILTIN_SCENES)}) "
                   "nor an existing .npz/.json scene file or .map file.")


def cli_path_kind(path, flag: str) -> str:
    """``jaxplan.core.files.path_kind`` of a flag's path; a path the system cannot look up is a
    ``CLIError`` naming the flag."""
    try:
        return path_kind(path)
    except ValueError as exc:
        raise CLIError(f"{flag}: {exc}") from None


def check_fabric_memory(args, scene, params) -> None:
    """Refuse, before any work, a fabric whose estimated build memory
    (``jaxplan.transport.fabric.estimate_build_bytes``) exceeds the memory available; the message
    names ``--k`` where the command has it, else ``--scene`` (the grid is what is too large)."""
    from jaxplan.transport import check_build_memory

    flag = "--k" if hasattr(args, "k") else "--scene"
    try:
        need = check_build_memory(scene.shape, params)
    except ValueError as exc:
        text = str(exc).removeprefix("FabricParams.k: ")
        raise CLIError(f"{flag}: {text}") from None
    if need >= _WARN_BUILD_BYTES:   # it fits, but the user should know what is coming
        print(f"warning: {flag}: K = {params.k} needs about {need / 1e9:.1f} GB for the first build, whose "
              "compilation takes minutes (about 45 s at K = 12, 140 s at K = 16 on 2 cores); K = 4 to 8 "
              "covers most scenes.", file=sys.stderr)


def check_out_dir(path: str, flag: str = "--out") -> None:
    """Refuse a folder that neither exists nor can be created (an existing file, a file on the way,
    no write permission), without creating anything: commands check this before any work."""
    target = Path(path)
    kind = cli_path_kind(path, flag)
    if kind != "missing":
        if kind != "dir":
            raise CLIError(f"{flag}: {path!r} exists and is not a folder; give a folder path.")
        if not os.access(target, os.W_OK | os.X_OK):
            raise CLIError(f"{flag}: {path!r} is not writable; give a folder you can write to.")
        return
    _check_creatable(path, flag, "create")


def check_out_file(path: str, flag: str = "--out") -> None:
    """Refuse an output file path that is a folder or whose folder cannot be created (nothing is created)."""
    if cli_path_kind(path, flag) == "dir":
        raise CLIError(f"{flag}: {path!r} is a folder; give a file path.")
    _check_creatable(path, flag, "write")


def _check_creatable(path: str, flag: str, verb: str) -> None:
    """The nearest existing folder above ``path`` must be a writable folder (not a file)."""
    parent = Path(path).absolute().parent
    while cli_path_kind(parent, flag) == "missing":
        parent = parent.parent
    if not parent.is_dir():
        raise CLIError(f"{flag}: cannot {verb} {path!r}: {str(parent)!r} is a file, not a folder.")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise CLIError(f"{flag}: cannot {verb} {path!r}: {str(parent)!r} is not writable.")


def fabric_params(args):
    from jaxplan.transport import FabricParams, validate_params

    params = FabricParams(theta_tol_deg=args.theta_tol, tau_h=getattr(args, "tau_h", 0.5),
                          k=getattr(args, "k", 4), monotone=not getattr(args, "no_monotone", False))
    validate_params(params)  # before any expensive work; raises ValueError naming the field
    return params


def params_dict(params) -> dict:
    out = {}
    for key in ("theta_tol_deg", "tau_h", "anchor_lambda", "slack_tau", "monotone", "k",
                "max_hops", "highway_relative", "highway_smoothing", "highway_nms"):
        value = getattr(params, key)
        if isinstance(value, (bool, np.bool_)) or value is None:
            out[key] = None if value is None else bool(value)
        elif isinstance(value, (int, np.integer)):
            out[key] = int(value)
        else:
            out[key] = float(np.asarray(value))
    return out


def run_folder(args) -> RunFolder:
    """The ``RunFolder`` of ``--out`` for this command (``with run_folder(args) as run: ...``): it
    takes the folder's lock and removes the previous run's files on entry. Open it after every input
    is validated, so that bad input leaves the folder as it was."""
    arguments = {k: v for k, v in vars(args).items() if not callable(v)}
    return _OutFlagFolder(args.out, command=args.command, arguments=arguments)


class _OutFlagFolder(RunFolder):
    """A ``RunFolder`` whose errors on opening name the ``--out`` flag."""

    def __enter__(self):
        try:
            return super().__enter__()
        except ValueError as exc:
            raise CLIError(f"--out: {exc}") from None


def csv_text(columns: dict) -> str:
    """Columns (name -> equal-length sequences) as CSV text with a header line."""
    names = list(columns)
    lines = [",".join(names)] + [",".join(str(v) for v in row) for row in zip(*columns.values())]
    return "\n".join(lines) + "\n"


angle = ranged(float, 0.0, 180.0, lo_open=True, hi_open=True, unit="degrees",
               why="the cone half-angle of the visibility rule (Eq. 1)")


def wrap(text: str) -> str:
    return textwrap.fill(" ".join(text.split()), width=79)


def add_theta_option(p) -> None:
    p.add_argument("--theta-tol", type=angle, default=60.0, metavar="DEG",
                   help="cone half-angle of the visibility rule (Eq. 1), degrees in (0, 180); default 60")
