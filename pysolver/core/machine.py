"""What this process may still take of the machine: memory, within every limit set on it.

The machine's free memory (``MemAvailable``) is not what a process may allocate when it
runs under ``ulimit -v`` (``RLIMIT_AS``) or in a container or a systemd slice (a cgroup's
``memory.max``): an estimate that ignores them lets a dense input start and then die of
``MemoryError`` (or be killed) instead of being refused with its fix.
"""

from __future__ import annotations

import os
import resource
from pathlib import Path


def _meminfo(proc: Path) -> int | None:
    """``MemAvailable`` of ``<proc>/meminfo``, bytes."""
    try:
        for line in (proc / "meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _address_space_left(proc: Path) -> int | None:
    """The soft ``RLIMIT_AS`` (``ulimit -v``) less this process's mapped size
    (``VmSize`` of ``<proc>/self/status``), bytes; None without a limit."""
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return None
    used = 0
    try:
        for line in (proc / "self" / "status").read_text().splitlines():
            if line.startswith("VmSize:"):
                used = int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return max(soft - used, 0)


def _read_bytes(path: Path) -> int | None:
    """A cgroup file holding a byte count; None when absent or ``max`` (no limit)."""
    try:
        text = path.read_text().strip()
    except OSError:
        return None
    return int(text) if text.isascii() and text.isdigit() else None


def _cgroup_left(proc: Path, cgroup_root: Path) -> int | None:
    """The least room left under this process's cgroup and its ancestors (v2:
    ``memory.max - memory.current``; v1: ``memory.limit_in_bytes - memory.usage_in_bytes``),
    bytes; None without a limit."""
    try:
        lines = (proc / "self" / "cgroup").read_text().splitlines()
    except OSError:
        return None
    left = None
    for line in lines:
        _, controllers, path = (line.split(":", 2) + ["", ""])[:3]
        if controllers == "":
            base, files = cgroup_root, ("memory.max", "memory.current")
        elif "memory" in controllers.split(","):
            base, files = cgroup_root / "memory", ("memory.limit_in_bytes",
                                                   "memory.usage_in_bytes")
        else:
            continue
        d = base / path.strip("/")
        for folder in (d, *d.parents):
            limit = _read_bytes(folder / files[0])
            if limit is not None and limit < 1 << 60:   # v1 writes "no limit" as ~2^63
                room = max(limit - (_read_bytes(folder / files[1]) or 0), 0)
                left = room if left is None else min(left, room)
            if folder == base:
                break
    return left


def available_memory(*, proc="/proc", cgroup_root="/sys/fs/cgroup") -> int:
    """Bytes of memory this process can still allocate: the least of the machine's
    available memory, the room its address-space limit leaves and the room its cgroups
    leave.

    Parameters
    ----------
    proc, cgroup_root : path-like
        Where ``/proc`` and the cgroup file system are (tests give fake ones).

    Returns
    -------
    int, bytes
    """
    proc, cgroup_root = Path(proc), Path(cgroup_root)
    free = _meminfo(proc)
    if free is None:
        free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    limits = [x for x in (_address_space_left(proc), _cgroup_left(proc, cgroup_root))
              if x is not None]
    return min([free, *limits])


__all__ = ["available_memory"]
