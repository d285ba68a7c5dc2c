"""Build locks: one run at a time writes an output folder (``.<name>.morphshell-lock``)."""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import stat
from pathlib import Path

from ..errors import InputError
from .writes import make_dirs

LOCK_SUFFIX = ".morphshell-lock"
_LOCK_TEXT = re.compile(r"^(pid \d+)?$")


def is_lock_file(p: Path) -> bool:
    """A lock file of :func:`build_lock`: named so, a regular file of this user's holding only
    ``pid N`` (another user's lock file is theirs, never removed)."""
    if not p.name.endswith(LOCK_SUFFIX):
        return False
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError:
        return False
    with os.fdopen(fd, "rb") as f:
        st = os.fstat(f.fileno())
        return (stat.S_ISREG(st.st_mode) and st.st_size <= 64 and st.st_uid == os.geteuid()
                and _LOCK_TEXT.match(f.read(64).decode("ascii", "replace").strip()) is not None)


def stale_lock(p: Path) -> bool:
    """A lock file of ours that no live process holds."""
    if not is_lock_file(p):
        return False
    try:
        with open(p, "rb") as f:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
    except OSError:
        return False


def lock_path(target) -> Path:
    """The lock file of the output folder ``target``: ``.<name>.morphshell-lock`` beside it."""
    target = Path(target)
    return target.parent / f".{target.name}{LOCK_SUFFIX}"


@contextlib.contextmanager
def build_lock(target):
    """Hold an exclusive, non-blocking lock for the output folder ``target``; the lock
    file is removed when the lock is released.

    Raises
    ------
    InputError
        If another process holds the lock (another build of the same shape).
    """
    path = lock_path(target)
    make_dirs(path.parent)
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
        except OSError as e:
            raise InputError(f"cannot open the lock file {path} ({e.strerror}).",
                             fix=f"remove {path} if it is a link or a folder, then re-run."
                             ) from None
        f = os.fdopen(fd, "r+")
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            f.seek(0)
            holder = f.read(64).strip() or "another process"
            f.close()
            raise InputError(
                f"{target} is being built by {holder}: two builds of the same shape "
                "would overwrite each other.",
                fix="wait for the other build to finish (builds of other shapes may run "
                "concurrently), or remove the stale lock " + str(path)
                + " if no build is running.",
            ) from None
        # the file may have been removed by the previous holder between open and flock
        try:
            same = os.fstat(f.fileno()).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        f.close()
    try:
        f.seek(0)
        f.truncate()
        f.write(f"pid {os.getpid()}")
        f.flush()
        yield path
    finally:
        with contextlib.suppress(OSError):
            path.unlink()
        with contextlib.suppress(OSError):
            fcntl.flock(f, fcntl.LOCK_UN)
        f.close()
