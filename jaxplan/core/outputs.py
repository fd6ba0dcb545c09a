"""Output files that are never half-written and output folders that say what belongs to which run.

- :func:`atomic_write` writes one file through a temp file and a rename: a reader sees the old file or
  the new one, never a part.
- :class:`RunFolder` owns an output folder for one run. Opening it takes the folder's lock (one run
  per folder), removes the previous run's files (exactly those its manifest lists), then keeps a
  manifest, ``DIR/run.json``, current after every file::

      {"format": "jaxplan.run", "version": 1, "command": "demo", "arguments": {...},
       "status": "running" | "complete" | "interrupted" | "failed",
       "started": "2026-01-01T12:00:00+00:00", "finished": null | "...",
       "files": ["fabric.png", "summary.json"], "error": null | "..."}

  ``files`` are paths relative to ``DIR`` of the files this run wrote, each complete. Cleanup never
  leaves the folder: a listed path is removed only if it resolves inside the folder's real path
  through no symbolic link, and is a regular file. Files no manifest lists (a user's notes, a
  folder from before manifests) are left alone, and a ``run.json`` that jaxplan did not write is
  refused rather than replaced.
- The lock, ``DIR/.jaxplan.lock``, is created atomically and holds the running process's pid and
  command; a second run into the folder is refused, naming that pid. A lock whose process is gone
  (a killed run) is taken over with a warning.
"""
from __future__ import annotations

import contextlib
import datetime
import fcntl
import json
import os
import re
import signal
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

from jaxplan.core.files import path_kind, shown_path
from jaxplan.core.signals import signal_name, signal_number

__all__ = ["LOCK", "MANIFEST", "RunFolder", "RunInterrupted", "atomic_write", "read_manifest", "write_json"]

MANIFEST = "run.json"
LOCK = ".jaxplan.lock"
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
    """A run stopped by Ctrl-C, SIGTERM or SIGHUP; the message says where its partial output is, and
    ``signum`` which signal stopped it."""

    def __init__(self, message: str, signum: int = signal.SIGINT):
        super().__init__(message)
        self.signum = int(signum)


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
    manifest and the lock. arguments: the run's options (JSON-able values; others are written as
    strings).

    Leaving the ``with`` block sets the status: ``complete`` without an exception, ``interrupted`` on
    ``KeyboardInterrupt`` (Ctrl-C, or SIGTERM / SIGHUP under ``core.signals.stop_signals_interrupt``;
    re-raised as :class:`RunInterrupted`, whose message names the folder), and ``failed`` with the
    error's text otherwise (the exception propagates unchanged). The lock is released either way.
    """

    def __init__(self, path, command: str, arguments: dict | None = None):
        self.path = Path(path)
        self.command = command
        self.arguments = _jsonable(dict(arguments or {}))
        self.files: list[str] = []
        self.status = "running"
        self._started = None
        self._lock_fd: int | None = None

    # ---------------------------------------------------------------------------------------------
    def __enter__(self) -> RunFolder:
        kind = path_kind(self.path)   # a ValueError naming the path when it cannot be looked up
        if kind not in ("dir", "missing"):
            raise ValueError(f"output folder {shown_path(self.path)} exists and is not a directory; "
                             "give a folder path.")
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            self._take_lock()
        except OSError as exc:
            raise ValueError(f"output folder {str(self.path)!r}: could not prepare it "
                             f"({exc.strerror or exc}).") from None
        try:
            self._remove_previous_run()
            self._started = _now()
            self._write_manifest(finished=None, error=None)
        except BaseException as exc:
            self._release_lock()
            if isinstance(exc, OSError):
                raise ValueError(f"output folder {str(self.path)!r}: could not prepare it "
                                 f"({exc.strerror or exc}).") from None
            raise
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.status, error = "complete", None
        elif issubclass(exc_type, KeyboardInterrupt):
            signum = signal_number(exc)
            how = "Ctrl-C, SIGINT" if signum == signal.SIGINT else signal_name(signum)
            self.status, error = "interrupted", f"interrupted ({how})"
        else:
            self.status, error = "failed", " ".join(f"{exc_type.__name__}: {exc}".split())
        try:
            self._write_manifest(finished=_now(), error=error)
        except OSError:
            pass   # the original exception (or none) matters more than a manifest we cannot write
        finally:
            self._release_lock()
        if self.status == "interrupted":
            raise RunInterrupted(f"{str(self.path)!r} holds this run's partial output ({len(self.files)} "
                                 f"file(s)); {MANIFEST} there says status 'interrupted'.", signum) from None
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
        """``self.path / rel`` if ``rel`` names a regular file inside the folder, reached through no
        symbolic link (the file itself included) and resolving inside the folder's real path; else None."""
        if not isinstance(rel, str) or not rel:
            return None
        p = Path(rel)
        if p.is_absolute() or ".." in p.parts or not p.parts:
            return None
        target, step = self.path / p, self.path
        for part in p.parts:
            step = step / part
            if step.is_symlink():
                return None
        root = os.path.realpath(self.path)
        if os.path.commonpath([root, os.path.realpath(target)]) != root or not target.is_file():
            return None
        return target

    def _remove_previous_run(self) -> None:
        manifest = self.path / MANIFEST
        if manifest.is_symlink() or (manifest.exists() and read_manifest(self.path) is None):
            raise ValueError(f"output folder {shown_path(self.path)} holds a {MANIFEST} that jaxplan did not "
                             "write; give another folder, or move that file away.")
        old = read_manifest(self.path) or {}
        listed = [rel for rel in (old.get("files") if isinstance(old.get("files"), list) else [])
                  if isinstance(rel, str)]
        if manifest.is_file():
            manifest.unlink()
        for rel in dict.fromkeys(listed):
            target = self._owned(rel)
            if target is not None:
                target.unlink()
                self._remove_empty_parents(target)
        for rel in listed:   # temp files that a killed writer of a listed file left beside it
            name = Path(rel)
            if name.is_absolute() or ".." in name.parts or not name.parts:
                continue
            temp = re.compile(rf"\.{re.escape(name.name)}\.([A-Za-z0-9_]{{8}}\.tmp|\d+\.tmp.*)")
            for stale in (self.path / name).parent.glob(f".{name.name}.*"):
                if temp.fullmatch(stale.name) and self._owned(stale.relative_to(self.path).as_posix()):
                    stale.unlink()

    # ---------------------------------------------------------------------------------------------
    def _take_lock(self) -> None:
        """Hold an exclusive ``flock`` on ``DIR/.jaxplan.lock`` for the run. The kernel releases it
        when the process ends however it ends, so a lock file left by a killed run is only stale."""
        lock = self.path / LOCK
        for _ in range(8):
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _lock_holder(fd)
                os.close(fd)
                raise ValueError(f"output folder {shown_path(self.path)} is in use by another run "
                                 f"({holder.get('command', 'jaxplan')}, pid {holder.get('pid', 'unknown')}); "
                                 "wait for it to end, or give another folder.") from None
            try:
                same = os.fstat(fd).st_ino == os.stat(lock).st_ino
            except FileNotFoundError:
                same = False
            if not same:   # the run before us removed the file as we opened it: open the new one
                os.close(fd)
                continue
            stale = _lock_holder(fd)
            if stale:
                print(f"warning: output folder {shown_path(self.path)}: taking over the lock of a run that "
                      f"ended without releasing it (pid {stale.get('pid', 'unknown')}).", file=sys.stderr)
            os.ftruncate(fd, 0)
            os.pwrite(fd, json.dumps({"pid": os.getpid(), "command": self.command}).encode(), 0)
            self._lock_fd = fd
            return
        raise ValueError(f"output folder {shown_path(self.path)}: could not take its lock; give another folder.")

    def _release_lock(self) -> None:
        fd = self._lock_fd
        if fd is not None:
            with contextlib.suppress(FileNotFoundError):
                (self.path / LOCK).unlink()
            os.close(fd)
            self._lock_fd = None

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


def _lock_holder(fd: int) -> dict:
    """The ``{"pid", "command"}`` a lock file holds; {} when it is empty or unreadable."""
    try:
        data = json.loads(os.pread(fd, 4096, 0) or b"{}")
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}
