"""Atomic outputs and build locks.

Every stage writes into a temporary folder beside its destination and moves it
into place only when it has finished, so an interrupted run (Ctrl-C, kill)
leaves either the previous complete result or nothing, never a mix.  A lock
file per output folder keeps two builds of the same shape from clobbering each
other; builds of different shapes lock different files and run concurrently.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import tempfile
from pathlib import Path

from .errors import InputError


def replace_dir(src: Path, dst: Path) -> None:
    """Move the finished folder ``src`` to ``dst``, replacing any previous ``dst``.

    The old folder is first renamed aside, then ``src`` renamed into place, then
    the old one deleted: at every instant ``dst`` is absent or complete.
    """
    src, dst = Path(src), Path(dst)
    old = None
    if dst.exists():
        old = dst.with_name(f".{dst.name}.old-{os.getpid()}")
        if old.exists():
            shutil.rmtree(old)
        os.replace(dst, old)
    os.replace(src, dst)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def recover_stale(dst) -> list[Path]:
    """Clean up after a run of ``dst`` that was killed (SIGKILL, power loss); call it while
    holding :func:`build_lock` for ``dst``.

    * a killed :func:`atomic_dir` leaves its temporary ``.<name>.tmp-*`` folder: removed;
    * a :func:`replace_dir` killed between its two renames leaves ``dst`` absent and the
      previous complete result in ``.<name>.old-<pid>``: renamed back to ``dst``;
      otherwise old folders are removed.

    Returns
    -------
    list of Path
        The folders removed or restored.
    """
    dst = Path(dst)
    if not dst.parent.is_dir():
        return []
    done = []
    for tmp in sorted(dst.parent.glob(f".{dst.name}.tmp-*")):
        shutil.rmtree(tmp, ignore_errors=True)
        done.append(tmp)
    olds = sorted(dst.parent.glob(f".{dst.name}.old-*"), key=lambda q: q.stat().st_mtime)
    if olds and not dst.exists():
        os.replace(olds.pop(), dst)
        done.append(dst)
    for old in olds:
        shutil.rmtree(old, ignore_errors=True)
        done.append(old)
    return done


@contextlib.contextmanager
def atomic_dir(dst, *, keep_on_error: bool = False):
    """Context manager yielding a temporary folder that becomes ``dst`` on success.

    Parameters
    ----------
    dst : path-like
        Final folder.  Its parent is created if needed.
    keep_on_error : bool
        Keep the temporary folder when the block raises (for debugging).

    Yields
    ------
    tmp : pathlib.Path
        Empty folder on the same file system as ``dst``.
    """
    dst = Path(dst)
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dst.name}.tmp-", dir=dst.parent))
    try:
        yield tmp
    except BaseException:
        if not keep_on_error:
            shutil.rmtree(tmp, ignore_errors=True)
        raise
    replace_dir(tmp, dst)


def atomic_write_text(path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and an atomic rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", newline="\n") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def build_lock(target):
    """Hold an exclusive, non-blocking lock for the output folder ``target``.

    Raises
    ------
    InputError
        If another process holds the lock (another build of the same shape).
    """
    target = Path(target)
    lock_dir = target.parent / ".locks"
    lock_dir.mkdir(parents=True, exist_ok=True)
    lock_path = lock_dir / f"{target.name}.lock"
    f = open(lock_path, "a+")
    try:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            f.seek(0)
            holder = f.read().strip() or "another process"
            raise InputError(
                f"{target} is being built by {holder}: two builds of the same shape "
                "would overwrite each other.",
                fix="wait for the other build to finish (builds of other shapes may run "
                "concurrently), or remove the stale lock " + str(lock_path)
                + " if no build is running.",
            ) from None
        f.seek(0)
        f.truncate()
        f.write(f"pid {os.getpid()}")
        f.flush()
        yield lock_path
    finally:
        with contextlib.suppress(OSError):
            fcntl.flock(f, fcntl.LOCK_UN)
        f.close()
