"""Writing one file: the project's one writer, :func:`atomic_file`, and its helpers.

Inside a stamped folder each write is recorded in the manifest (:mod:`.manifest`) before
its rename, and a file that is not morphshell's is never overwritten.
"""

from __future__ import annotations

import contextlib
import os
import stat
from pathlib import Path

from ..errors import InputError
from .manifest import (
    STAMP_NAME,
    contained_path,
    entry_state,
    file_digest,
    folder_lock,
    is_private,
    new_token,
    pid_alive,
    public_mode,
    read_stamp,
    stamp_owner,
    store_stamp,
    temporary_of,
    write_new,
)

_NEVER_OURS = "move it out of the folder (or give another --out), then re-run; " \
              "morphshell never deletes or overwrites files it did not make"


def make_dirs(folder) -> Path:
    """``mkdir -p folder``, recording each folder it makes in the manifest of the stamped
    folder above it; never through a symbolic link inside a stamped folder.

    Raises
    ------
    InputError
        A folder on the way inside a stamped folder is a link, a file, or a folder
        morphshell did not make.
    """
    folder = Path(folder).absolute()
    missing = []
    d = folder
    while not os.path.lexists(d):
        missing.append(d)
        d = d.parent
    owner = stamp_owner(d)
    if owner is not None:
        m = read_stamp(owner)
        if m is not None and not is_private(m):
            for p in [d, *d.parents]:
                if p == owner or owner not in p.parents:
                    break
                rel = p.relative_to(owner).as_posix()
                if p.is_symlink() or not p.is_dir() or (rel not in m["dirs"]
                                                        and temporary_of(p) is None):
                    what = ("a symbolic link" if p.is_symlink() else "not a folder"
                            if not p.is_dir() else "a folder morphshell did not make")
                    raise InputError(f"{p} is {what}: morphshell writes nothing through it.",
                                     fix=_NEVER_OURS)
    if not d.is_dir():
        raise InputError(f"{d} is not a folder.", fix="give a folder path.")
    for p in reversed(missing):
        with contextlib.suppress(FileExistsError):
            os.mkdir(p)
        if p.is_symlink() or not p.is_dir():
            raise InputError(f"{p} appeared as a link or a file while morphshell made it.",
                             fix=_NEVER_OURS)
        own = stamp_owner(p.parent)
        if own is not None:
            with folder_lock(own):
                m = read_stamp(own)
                if m is not None and not is_private(m):
                    rel = p.relative_to(own).as_posix()
                    if rel not in m["dirs"]:
                        store_stamp(own, dict(m, dirs=sorted({*m["dirs"], rel})), m)
    return folder


def _drop_dead_temporaries(owner: Path, m: dict) -> dict:
    """Remove the temporary files that writers killed before their rename left in ``owner``
    (recorded as pending by a process that is gone); returns the manifest without them."""
    dead = {k for k, pid in m["pending"].items()
            if pid != os.getpid() and not pid_alive(pid)}
    for k in dead:
        p = contained_path(owner, k, source=owner / STAMP_NAME)
        with contextlib.suppress(OSError):
            if stat.S_ISREG(os.lstat(p).st_mode):
                p.unlink()
    return dict(m, pending={k: v for k, v in m["pending"].items() if k not in dead})


def _check_replaceable(path: Path, owner: Path, m: dict) -> None:
    """Refuse to write ``path`` when something not morphshell's is there."""
    rel = path.relative_to(owner).as_posix()
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if stat.S_ISLNK(st.st_mode):
        why = "is a symbolic link"
    elif not stat.S_ISREG(st.st_mode):
        why = "is not a regular file"
    else:
        why = entry_state(path, rel, m)
        if why is None:
            return
        why = "is " + why if why.startswith(("not", "made")) else why
    raise InputError(f"{path} {why}: morphshell will not overwrite it.", fix=_NEVER_OURS)


@contextlib.contextmanager
def atomic_file(path):
    """Write ``path`` atomically: the project's one way to write a file.

    Yields a new temporary path beside ``path`` (a unique name made with ``O_EXCL``, never a
    link, mode 0600, same suffix so that libraries pick the right format); when the block
    succeeds it gets the umask's permissions and is renamed to ``path`` in one step, when
    it fails it is removed.  Readers see the old file or the new one, never a part.

    In a stamped folder (see the module docstring) ``path`` must be absent or a file
    morphshell wrote and nobody changed since; the new file's SHA-256 and size are recorded
    in the manifest before the rename (with the previous ones, so that a kill between the
    two leaves a folder morphshell still recognises).

    Raises
    ------
    InputError
        ``path`` (or a folder on the way) is not morphshell's: a user's file, a file
        changed since morphshell wrote it, a symbolic link, a FIFO or a device.
    """
    path = Path(path).absolute()
    make_dirs(path.parent)
    owner = stamp_owner(path.parent)
    m = read_stamp(owner) if owner is not None else None
    tracked = m is not None and not is_private(m)
    base = path.name[:120]
    while True:
        tmp = path.with_name(f".{base}.tmp-{new_token()}{path.suffix[:16]}")
        if os.path.lexists(tmp):
            continue
        if not tracked:
            with contextlib.suppress(FileExistsError):
                write_new(tmp, b"")
                break
            continue
        with folder_lock(owner):
            m = _drop_dead_temporaries(owner, read_stamp(owner))
            _check_replaceable(path, owner, m)
            rel_tmp = tmp.relative_to(owner).as_posix()
            # recorded before it exists: a kill right after leaves a file morphshell knows
            store_stamp(owner, dict(m, pending={**m["pending"], rel_tmp: os.getpid()}), m,
                   keep=rel_tmp)
            try:
                write_new(tmp, b"")
                break
            except FileExistsError:  # someone else's file appeared under the name
                m = read_stamp(owner)
                store_stamp(owner, dict(m, pending={k: v for k, v in m["pending"].items()
                                               if k != rel_tmp}), m)
    try:
        yield tmp
        if tracked:
            digest = list(file_digest(tmp))
            with folder_lock(owner):
                m = read_stamp(owner)
                _check_replaceable(path, owner, m)
                rel = path.relative_to(owner).as_posix()
                prev = dict(m["prev"])
                if rel in m["files"] and os.path.lexists(path):
                    prev[rel] = m["files"][rel]
                store_stamp(owner, dict(m, files={**m["files"], rel: digest}, prev=prev), m)
                public_mode(tmp)
                os.replace(tmp, path)
        else:
            public_mode(tmp)
            os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def atomic_write_bytes(path, data: bytes) -> None:
    """Write ``data`` to ``path`` through :func:`atomic_file`."""
    with atomic_file(path) as tmp, open(tmp, "wb") as f:
        f.write(data)


def atomic_write_text(path, text: str) -> None:
    """Write ``text`` to ``path`` through :func:`atomic_file` (``\\n`` line ends)."""
    with atomic_file(path) as tmp, open(tmp, "w", newline="\n") as f:
        f.write(text)


def remove_file(path) -> None:
    """Delete the file ``path`` if morphshell wrote it (and nobody changed it since); a
    user's file is kept.  Missing files are fine."""
    path = Path(path).absolute()
    owner = stamp_owner(path.parent)
    if owner is None:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
        return
    with folder_lock(owner):
        m = read_stamp(owner)
        if m is None or is_private(m):
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
            return
        if not os.path.lexists(path):
            return
        try:
            _check_replaceable(path, owner, m)
        except InputError:
            return  # the user's: kept
        path.unlink()
        rel = path.relative_to(owner).as_posix()
        store_stamp(owner, dict(m, files={k: v for k, v in m["files"].items() if k != rel},
                           prev={k: v for k, v in m["prev"].items() if k != rel}), m)
