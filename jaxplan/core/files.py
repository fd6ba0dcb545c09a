"""What a user-given path names, asked without letting the operating system's errors escape."""
from __future__ import annotations

import errno
import os
import stat

__all__ = ["path_kind", "read_text", "shown_path"]

_SHOWN_CHARS = 80


def shown_path(path) -> str:
    """``path`` quoted for a message, shortened in the middle when it is longer than 80 characters."""
    text = str(path)
    if len(text) > _SHOWN_CHARS:
        half = _SHOWN_CHARS // 2 - 2
        text = f"{text[:half]}...{text[-half:]}"
    return repr(text)


def path_kind(path) -> str:
    """``"file"``, ``"dir"``, ``"missing"`` or ``"other"`` (a device, a socket) for ``path``.

    Raises ``ValueError`` naming the path when the system cannot even look it up (a name too long,
    a loop of symbolic links, no permission to search a folder on the way).
    """
    try:
        return _kind(path)
    except _Unusable as exc:
        raise ValueError(f"{shown_path(path)} is not a usable path ({exc}); check it.") from None


class _Unusable(Exception):
    """The system cannot look the path up; the message is the reason."""


def _kind(path) -> str:
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return "missing"
    except OSError as exc:
        raise _Unusable(exc.strerror or errno.errorcode.get(exc.errno, str(exc))) from None
    except ValueError:   # an embedded NUL byte
        raise _Unusable("it holds a NUL byte") from None
    if stat.S_ISREG(mode):
        return "file"
    if stat.S_ISDIR(mode):
        return "dir"
    return "other"


def read_text(path, what: str, *, max_bytes: int | None = None) -> str:
    """The UTF-8 text of the user's file ``path``; ``what`` names the kind of file for messages
    (``"a TOML spec file"``).

    Raises ``ValueError`` with what is wrong and the fix, without the path (callers prefix their own
    context): a path the system cannot look up, a folder, a missing, unreadable, empty (blank) or
    non-UTF-8 file, and with ``max_bytes`` a file longer than that (at most ``max_bytes + 1`` bytes are
    read, so a huge file or a device never fills the memory).
    """
    try:
        kind = _kind(path)
    except _Unusable as exc:
        raise ValueError(f"is not a usable path ({exc}); check it.") from None
    if kind == "dir":
        raise ValueError(f"is a directory; give the path of {what}.")
    if kind == "missing":
        raise ValueError("no such file; check the path.")
    try:
        with open(path, "rb") as fh:
            raw = fh.read() if max_bytes is None else fh.read(int(max_bytes) + 1)
    except OSError as exc:
        raise ValueError(f"could not be read ({exc.strerror or exc}); check the file's permissions.") from None
    if max_bytes is not None and len(raw) > max_bytes:
        raise ValueError(f"is longer than {int(max_bytes):,} bytes, too long for {what}; check the path.")
    if not raw.strip():
        raise ValueError(f"is empty; expected {what}.")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"is not UTF-8 text (byte {exc.start}: {exc.reason}), so not {what}.") from None
