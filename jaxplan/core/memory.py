"""How much memory this process may still take: ``available_memory_bytes``.

Used to refuse, before any work, a setting whose estimated cost (e.g.
``jaxplan.transport.fabric.estimate_build_bytes``) cannot fit.
"""
from __future__ import annotations

import os
from pathlib import Path

__all__ = ["available_memory_bytes"]

_MEMINFO = Path("/proc/meminfo")
# cgroup v2 and v1: a container's limit can be far below the machine's free memory
_CGROUP_LIMITS = ((Path("/sys/fs/cgroup/memory.max"), Path("/sys/fs/cgroup/memory.current")),
                  (Path("/sys/fs/cgroup/memory/memory.limit_in_bytes"),
                   Path("/sys/fs/cgroup/memory/memory.usage_in_bytes")))


def _meminfo_available() -> int | None:
    """``MemAvailable`` of /proc/meminfo in bytes (Linux), else free physical pages; None if unknown."""
    try:
        for line in _MEMINFO.read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024   # the file says kB and means KiB
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _cgroup_room() -> int | None:
    """Bytes left under this process's cgroup memory limit; None without a (finite) limit."""
    for limit_path, usage_path in _CGROUP_LIMITS:
        try:
            limit_text = limit_path.read_text().strip()
            usage = int(usage_path.read_text().strip())
        except (OSError, ValueError):
            continue
        if limit_text == "max" or not limit_text.isdigit() or int(limit_text) >= 1 << 60:
            return None   # v1 reports "no limit" as a huge number
        return max(0, int(limit_text) - usage)
    return None


def available_memory_bytes() -> int | None:
    """Memory this process can still take, bytes: the smaller of the kernel's ``MemAvailable`` and the
    room under a cgroup (container) limit. None when neither can be read (a check should then pass)."""
    known = [x for x in (_meminfo_available(), _cgroup_room()) if x is not None]
    return min(known) if known else None
