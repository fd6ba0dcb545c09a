"""Output files that are never half-written and output folders that say what belongs to which run.

- :func:`atomic_write` writes one file through a temp file and a rename: a reader sees the old file or
  the new one, never a part.
- :class:`RunFolder` owns an output folder for one run. Opening it removes the previous run's files
  (those its manifest lists, and the names this command writes), then keeps a manifest,
  ``DIR/run.json``, current after every file::

      {"format": "jaxplan.run", "version": 1, "command": "demo", "arguments": {...},
       "status": "running" | "complete" | "interrupted" | "failed",
       "started": "2026-01-01T12:00:00+00:00", "finished": null | "...",
       "files": ["fabric.png", "summary.json"], "error": null | "..."}

  ``files`` are paths relative to ``DIR`` of the files this run wrote, each complete. Files in ``DIR``
  that neither the old manifest nor the command names (a user's notes) are left alone.
"""
from __future__ import annotations

import contextlib
import datetime
import json
import os
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import BinaryIO

from jaxplan.core.files import path_kind, shown_path

__all__ = ["MANIFEST", "RunFolder", "RunInterrupted", "atomic_write", "read_manifest", "write_json"]

MANIFEST = "run.json"
MANIFEST_FORMAT = "jaxplan.run"
STATUSES = ("running", "complete", "interrupted", "failed")


def atomic_write(path: Path, write: Callable[[BinaryIO], object]) -> None:
    """Call ``write(binary_file)`` on a temp file next to ``path``, then rename it into place.

    Nothing is left at ``path`` (or beside it) when ``write`` fails. The file gets the usual
    permissions (0666 minus the umask), not mkstemp's 0600.
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def write_json(path: Path, data) -> None:
    """``data`` as indented JSON, atomically."""
    text = json.dumps(data, indent=2) + "\n"
    atomic_write(path, lambda fh: fh.write(text.encode()))


def read_manifest(folder) -> dict | None:
    """The manifest of ``folder`` (a dict), or None when it has none or it is not a jaxplan manifest."""
    try:
        data = json.loads((Path(folder) / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("format") != MANIFEST_FORMAT:
        return None
    return data


class RunInterrupted(KeyboardInterrupt):
    """A run stopped by Ctrl-C; the message says where its partial output is."""


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def _jsonable(value):
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    return str(value)


class RunFolder:
    """The output folder of one run, used as a context manager (module docstring).

    path: the folder (created with its parents if missing). command: the command's name, for the
    manifest. arguments: the run's options (JSON-able values; others are written as strings).
    outputs: the file names this command may write, removed on opening even where no manifest lists
    them (a folder from before manifests, or a file this run will not write again).

    Leaving the ``with`` block sets the status: ``complete`` without an exception, ``interrupted`` on
    ``KeyboardInterrupt`` (re-raised as :class:`RunInterrupted`, whose message names the folder), and
    ``failed`` with the error's text otherwise (the exception propagates unchanged).
    """

    def __init__(self, path, command: str, arguments: dict | None = None, outputs: Iterable[str] = ()):
        self.path = Path(path)
        self.command = command
        self.arguments = _jsonable(dict(arguments or {}))
        self.outputs = tuple(outputs)
        self.files: list[str] = []
        self.status = "running"
        self._started = None

    # ---------------------------------------------------------------------------------------------
    def __enter__(self) -> RunFolder:
        kind = path_kind(self.path)   # a ValueError naming the path when it cannot be looked up
        if kind not in ("dir", "missing"):
            raise ValueError(f"output folder {shown_path(self.path)} exists and is not a directory; "
                             "give a folder path.")
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            self._remove_previous_run()
            self._started = _now()
            self._write_manifest(finished=None, error=None)
        except OSError as exc:
            raise ValueError(f"output folder {str(self.path)!r}: could not prepare it "
                             f"({exc.strerror or exc}).") from None
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.status, error = "complete", None
        elif issubclass(exc_type, KeyboardInterrupt):
            self.status, error = "interrupted", "interrupted (Ctrl-C)"
        else:
            self.status, error = "failed", " ".join(f"{exc_type.__name__}: {exc}".split())
        try:
            self._write_manifest(finished=_now(), error=error)
        except OSError:
            pass   # the original exception (or none) matters more than a manifest we cannot write
        if self.status == "interrupted":
            raise RunInterrupted(f"{str(self.path)!r} holds this run's partial output ({len(self.files)} "
                                 f"file(s)); {MANIFEST} there says status 'interrupted'.") from None
        return False

    # ---------------------------------------------------------------------------------------------
    def file(self, name: str) -> Path:
        """The path of output ``name`` (relative to the folder) for a writer that cannot take a file
        object; call :meth:`add` once it is complete."""
        return self.path / name

    def add(self, name) -> Path:
        """Record the complete file ``name`` (relative, or a path inside the folder) as this run's."""
        rel = self._relative(name)
        if rel not in self.files:
            self.files.append(rel)
        self._write_manifest(finished=None, error=None)
        return self.path / rel

    def write(self, name, write: Callable[[BinaryIO], object]) -> Path:
        """Write output ``name`` atomically with ``write(binary_file)`` and record it."""
        target = self.path / self._relative(name)
        target.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(target, write)
        return self.add(name)

    @contextlib.contextmanager
    def staged(self, name):
        """A temp path beside output ``name`` (same suffix) for writers that need a file name; renamed
        to ``name`` and recorded when the block ends without an exception, removed otherwise."""
        rel = self._relative(name)
        target = self.path / rel
        tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp{target.suffix}")
        try:
            yield tmp
            os.replace(tmp, target)
        finally:
            if tmp.exists():
                tmp.unlink()
        self.add(rel)

    def write_json(self, name, data) -> Path:
        """Write ``data`` as JSON to output ``name`` and record it."""
        text = json.dumps(data, indent=2) + "\n"
        return self.write(name, lambda fh: fh.write(text.encode()))

    # ---------------------------------------------------------------------------------------------
    def _relative(self, name) -> str:
        p = Path(name)
        for base in (self.path, self.path.resolve()):
            if p.parts[:len(base.parts)] == base.parts:
                p = p.relative_to(base)
                break
        if p.is_absolute() or ".." in p.parts or not p.parts or p.name == MANIFEST:
            raise ValueError(f"RunFolder: {str(name)!r} is not a file name inside {str(self.path)!r}.")
        return p.as_posix()

    def _owned(self, rel) -> Path | None:
        """``self.path / rel`` if ``rel`` is a plain relative file name inside the folder, else None."""
        if not isinstance(rel, str) or not rel:
            return None
        p = Path(rel)
        if p.is_absolute() or ".." in p.parts:
            return None
        return self.path / p

    def _remove_previous_run(self) -> None:
        old = read_manifest(self.path) or {}
        listed = old.get("files") if isinstance(old.get("files"), list) else []
        names = dict.fromkeys([*listed, *self.outputs])
        manifest = self.path / MANIFEST
        if manifest.is_file():
            manifest.unlink()
        for rel in names:
            target = self._owned(rel)
            if target is not None and (target.is_file() or target.is_symlink()):
                target.unlink()
                self._remove_empty_parents(target)
        for stale in self.path.glob(".*.tmp*"):   # temp files of a killed writer
            if stale.is_file() and any(stale.name.startswith(f".{Path(n).name}.") for n in names):
                stale.unlink()

    def _remove_empty_parents(self, removed: Path) -> None:
        parent = removed.parent
        while parent != self.path and self.path in parent.parents:
            try:
                parent.rmdir()
            except OSError:   # not empty: someone else's files live there
                return
            parent = parent.parent

    def _write_manifest(self, *, finished, error) -> None:
        write_json(self.path / MANIFEST, {
            "format": MANIFEST_FORMAT, "version": 1, "command": self.command, "arguments": self.arguments,
            "status": self.status, "started": self._started, "finished": finished,
            "files": list(self.files), "error": error,
        })
