"""What every subcommand shares: the error type, scene loading, parameter dicts, atomic files."""
from __future__ import annotations

import argparse
import os
import textwrap
from pathlib import Path

import numpy as np

from jaxplan.core.outputs import RunFolder
from jaxplan.transport.scenes import BUILTIN_SCENES

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130   # 128 + SIGINT, as shells report a Ctrl-C


class CLIError(Exception):
    """Bad command-line input; the message is printed as ``error: <message>``."""


def load_scene(spec: str):
    """A built-in scene by name, or a scene file (.npz / .json) by path.

    A bad file -- missing, a directory, unreadable, damaged, wrong keys or values -- is one
    ``CLIError("--scene: Scene file <path>: ...")`` (``Scene.load`` names what is wrong).
    """
    from jaxplan.transport.scene import Scene
    from jaxplan.transport.scenes import builtin_scene

    if spec in BUILTIN_SCENES:
        return builtin_scene(spec)
    path = Path(spec)
    if path.is_dir():
        raise CLIError(f"--scene: {spec!r} is a directory; give a .npz/.json scene file or a built-in "
                       f"scene ({', '.join(BUILTIN_SCENES)}).")
    if path.exists():
        try:
            return Scene.load(path)
        except ValueError as exc:
            raise CLIError(f"--scene: {exc}") from None
    if path.suffix.lower() in (".npz", ".json") or os.sep in spec:
        raise CLIError(f"--scene: no such scene file {spec!r}.")
    raise CLIError(f"--scene: {spec!r} is neither a built-in scene ({', '.join(BUILTIN_SCENES)}) "
                   "nor an existing .npz/.json scene file.")


def fabric_params(args):
    from jaxplan.transport.params import FabricParams, validate_params

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


def run_folder(args, outputs) -> RunFolder:
    """The ``RunFolder`` of ``--out`` for this command (``with run_folder(args, NAMES) as run: ...``).

    outputs: the file names the command may write; a previous run's files are removed on entry.
    Open it after every input is validated, so that bad input leaves the folder as it was.
    """
    arguments = {k: v for k, v in vars(args).items() if not callable(v)}
    return _OutFlagFolder(args.out, command=args.command, arguments=arguments, outputs=outputs)


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


def angle(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an angle in degrees, got {text!r}") from None


def wrap(text: str) -> str:
    return textwrap.fill(" ".join(text.split()), width=79)


def add_theta_option(p) -> None:
    p.add_argument("--theta-tol", type=angle, default=60.0, metavar="DEG",
                   help="cone half-angle of the visibility rule (Eq. 1), degrees in (0, 180); default 60")
