"""What a user-given path names, asked without letting the operating system's errors escape."""
from __future__ import annotations

import errno
import os
import stat

__all__ = ["path_kind", "shown_path"]

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
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return "missing"
    except OSError as exc:
        reason = exc.strerror or errno.errorcode.get(exc.errno, str(exc))
        raise ValueError(f"{shown_path(path)} is not a usable path ({reason}); check it.") from None
    except ValueError:   # an embedded NUL byte
        raise ValueError(f"{shown_path(path)} is not a usable path (it holds a NUL byte); check it.") from None
    if stat.S_ISREG(mode):
        return "file"
    if stat.S_ISDIR(mode):
        return "dir"
    return "other"
