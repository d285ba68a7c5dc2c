"""Whole folders: made in a private temporary folder, sealed (every file recorded) and
renamed into place; a build's staging folder; clean-up after a killed run."""

from __future__ import annotations

import contextlib
import os
import stat
import time
import warnings
from pathlib import Path

from ..errors import InputError
from .locks import LOCK_SUFFIX, lock_path, stale_lock
from .manifest import (
    STAGING_SUFFIX,
    STAMP_NAME,
    TEMP_NAME,
    entry_state,
    file_digest,
    folder_lock,
    is_private,
    make_private,
    new_token,
    pid_alive,
    public_mode,
    read_stamp,
    remove_private,
    stamp_owner,
    store_stamp,
    temporary_of,
)
from .ownership import claim_output
from .writes import make_dirs

STALE_STAGING_S = 7 * 24 * 3600.0
"""Staging folders of other outputs, left by killed builds, are removed after a week (when
their stamp says they are morphshell's and this user's, and no build holds their lock)."""


class _Warning(UserWarning):
    """A file of the user's was found where morphshell cleans up; it was kept."""


def _walk_files(folder: Path):
    """(relative path, kind) of every entry under ``folder``, never following links;
    ``kind`` is "dir", "file" or "other"."""
    for root, dirs, files in os.walk(folder):
        r = Path(root)
        for n in sorted(dirs):
            p = r / n
            if p.is_symlink():
                yield p, "other"
            else:
                yield p, "dir"
        for n in sorted(files):
            p = r / n
            st = os.lstat(p)
            yield p, ("file" if stat.S_ISREG(st.st_mode) else "other")
        dirs[:] = [d for d in dirs if not (r / d).is_symlink()]


def seal(folder) -> None:
    """Record every file and folder of ``folder``, a private folder morphshell has just made
    whole (:func:`atomic_dir`, a build's staging folder), in its manifest.

    Nested folders with a sealed stamp of their own (``stl/`` made by :func:`atomic_dir`)
    keep it; temporary folders of killed steps inside are removed; links and special files
    are not recorded (they stay foreign)."""
    folder = Path(folder)
    old = read_stamp(folder) or {}
    files, dirs = {}, []
    skip: list[Path] = []
    for p, kind in _walk_files(folder):
        if any(s in p.parents for s in skip):
            continue
        rel = p.relative_to(folder).as_posix()
        if kind == "dir":
            sub = read_stamp(p)
            if sub is not None and temporary_of(p) is not None:
                remove_private(p)
                skip.append(p)
                continue
            dirs.append(rel)
            if sub is not None and not is_private(sub):
                skip.append(p)  # its own manifest lists its files
            elif sub is not None:
                (p / STAMP_NAME).unlink()
        elif kind == "file" and p.parent == folder and p.name.startswith(STAMP_NAME + "."):
            p.unlink()  # a temporary stamp of a killed step, in this private folder
        elif kind == "file" and p.name != STAMP_NAME:
            files[rel] = list(file_digest(p))
    keep = {k: old[k] for k in ("for", "token", "pid") if k in old}
    with folder_lock(folder):
        store_stamp(folder, {"files": files, "dirs": sorted(dirs), "prev": {}, "pending": {},
                        **keep}, read_stamp(folder))


def _remove_ours(folder: Path) -> list[Path]:
    """Delete from ``folder`` what its manifests vouch for (each file checked right before
    it goes) and the folders left empty; returns what was kept (the user's)."""
    kept: list[Path] = []
    m = read_stamp(folder)
    if m is None:
        return [folder]

    def rm(d: Path, owner: Path, man: dict) -> bool:
        empty = True
        for e in sorted(os.scandir(d), key=lambda e: e.name):
            p = Path(e.path)
            rel = p.relative_to(owner).as_posix()
            if e.is_dir(follow_symlinks=False):
                if rel in man["dirs"]:
                    sub = read_stamp(p)
                    ok = (rm(p, p, sub) if sub is not None and not is_private(sub)
                          else rm(p, owner, man))
                elif temporary_of(p) is not None:
                    remove_private(p)
                    ok = True
                else:
                    ok = False
                    kept.append(p)
                empty &= ok
            elif e.is_file(follow_symlinks=False) and d == owner and (
                    e.name == STAMP_NAME or e.name == f"{STAMP_NAME}.{man.get('next')}.tmp"):
                continue
            elif e.is_file(follow_symlinks=False) and (entry_state(p, rel, man) is None
                                                       or stale_lock(p)):
                p.unlink()
            else:
                kept.append(p)
                empty = False
        if empty and d == owner:
            for n in os.listdir(d):  # the stamp (and its temporary) go last
                if n.startswith(STAMP_NAME):
                    os.unlink(d / n)
        if empty:
            try:
                os.rmdir(d)
            except OSError:  # something appeared meanwhile: it stays
                kept.append(d)
                return False
        return empty

    rm(folder, folder, m)
    return kept


def replace_dir(src: Path, dst: Path) -> None:
    """Move the finished, sealed folder ``src`` to ``dst``, replacing any previous ``dst``.

    The old folder is first moved into a private folder beside it, then ``src`` renamed into
    place, then the old one's files that its manifest vouches for are deleted (anything
    else is kept and named in a warning): at every instant ``dst`` is absent or complete.
    ``dst`` must pass :func:`claim_output` (checked again here, just before the move).
    """
    src, dst = Path(src), Path(dst).absolute()
    claim_output(dst)
    aside = None
    if os.path.lexists(dst):
        tok = new_token()
        aside = make_private(dst.parent, f".{dst.name}.old-{tok}", role="old", token=tok,
                              **{"for": dst.name})
        os.replace(dst, aside / dst.name)
    try:
        os.rename(src, dst)
    except OSError:
        if aside is not None and not os.path.lexists(dst):
            os.replace(aside / dst.name, dst)
            _remove_ours_private(aside)
        raise
    own = stamp_owner(dst.parent)
    if own is not None:
        with folder_lock(own):
            m = read_stamp(own)
            rel = dst.relative_to(own).as_posix()
            if m is not None and not is_private(m) and rel not in m["dirs"]:
                store_stamp(own, dict(m, dirs=sorted({*m["dirs"], rel})), m)
    if aside is not None:
        _remove_ours_private(aside)


def _remove_ours_private(aside: Path) -> None:
    """Remove a moved-aside folder: the old folder's own files, then the private wrapper;
    a user's file found inside is kept there and named in a warning."""
    kept = []
    for p in aside.iterdir():
        if p.name.startswith(STAMP_NAME):
            continue
        kept += _remove_ours(p) if p.is_dir() and not p.is_symlink() else [p]
    if kept:
        warnings.warn(f"kept {len(kept)} file(s) that morphshell did not write, found in the "
                      f"replaced folder: {', '.join(map(str, kept[:3]))} (in {aside})",
                      _Warning, stacklevel=3)
        return
    remove_private(aside)


def recover_stale(dst) -> list[Path]:
    """Clean up after a run of ``dst`` that was killed (SIGKILL, power loss); call it while
    holding :func:`build_lock` for ``dst``.

    * a killed :func:`atomic_dir` leaves its temporary ``.<name>.tmp-<token>`` folder:
      removed;
    * a :func:`replace_dir` killed between its two renames leaves ``dst`` absent and the
      previous complete result in ``.<name>.old-<token>/<name>``: moved back to ``dst``;
      otherwise old folders are removed (their own files only);
    * lock files and staging folders of other outputs in the same parent, left by killed
      runs, are removed (:func:`clean_stale_siblings`).

    Only folders whose stamp says they are morphshell's, made for ``dst`` by this user and
    by a process that is gone, are touched.

    Returns
    -------
    list of Path
        The folders and files removed or restored.
    """
    dst = Path(dst).absolute()
    if not dst.parent.is_dir():
        return []
    done = []
    olds = []
    for p in sorted(dst.parent.iterdir()):
        if not TEMP_NAME.match(p.name) or temporary_of(p) != dst.name:
            continue
        m = read_stamp(p) or {}
        if m.get("pid") != os.getpid() and pid_alive(m.get("pid")):
            continue  # another process's, still at work
        if ".old-" in p.name:
            olds.append((m.get("created", 0.0), p))
        else:
            remove_private(p)
            done.append(p)
    olds.sort()
    if olds and not os.path.lexists(dst) and os.path.isdir(olds[-1][1] / dst.name):
        os.replace(olds[-1][1] / dst.name, dst)
        done.append(dst)
    for _, old in olds:
        _remove_ours_private(old) if (old / dst.name).exists() else remove_private(old)
        done.append(old)
    return done + clean_stale_siblings(dst)


def clean_stale_siblings(dst) -> list[Path]:
    """Remove the lock files no live process holds, and other outputs' staging folders that
    are unlocked and older than :data:`STALE_STAGING_S`, in ``dst``'s parent folder.  Both
    are recognised by content (a lock file holds only ``pid N``; a staging folder's stamp
    says what it is and that it is this user's), not by name alone."""
    dst = Path(dst)
    parent = dst.parent
    done = []
    for lock in sorted(q for q in parent.iterdir() if q.name.endswith(LOCK_SUFFIX)):
        if lock != lock_path(dst) and stale_lock(lock):  # (a live build holds its lock)
            lock.unlink()
            done.append(lock)
    now = time.time()
    for staging in sorted(q for q in parent.iterdir() if q.name.endswith(STAGING_SUFFIX)):
        name = temporary_of(staging)
        if name is None or name == dst.name or lock_path(parent / name).exists():
            continue
        m = read_stamp(staging) or {}
        if now - float(m.get("created", now)) > STALE_STAGING_S:
            remove_private(staging)
            done.append(staging)
    return done


def staging_dir(dst) -> Path:
    """Where a build of ``dst`` runs: ``<parent>/.<name>.morphshell-staging/<name>`` (same
    file system as ``dst``, same folder name, so logs name the shape)."""
    dst = Path(dst)
    return dst.parent / f".{dst.name}{STAGING_SUFFIX}" / dst.name


def open_staging(staging, *, inputs_sha256: str) -> bool:
    """Make the staging folder ``staging`` (:func:`staging_dir`) for a build whose inputs
    hash to ``inputs_sha256``, or keep the one an interrupted build with the same inputs
    left (so the simulation resumes from its checkpoint).

    Returns
    -------
    bool
        True when an interrupted build's staging folder is resumed.

    Raises
    ------
    InputError
        Something that is not morphshell's staging folder has its name.
    """
    staging = Path(staging)
    wrapper = staging.parent
    if os.path.lexists(wrapper):
        if temporary_of(wrapper) != staging.name:
            raise InputError(f"{wrapper} exists and is not a staging folder of morphshell's "
                             "(no stamp of ours inside): it is kept.",
                             fix="move or rename it, then build again.")
        m = read_stamp(wrapper) or {}
        if m.get("inputs_sha256") == inputs_sha256 and staging.is_dir() \
                and is_private(read_stamp(staging)):
            return True
        remove_private(wrapper)
    make_private(wrapper.parent, wrapper.name, role="staging", inputs_sha256=inputs_sha256,
                  **{"for": staging.name})
    make_private(wrapper, staging.name, role="work", **{"for": staging.name})
    return False


def remove_staging(staging) -> None:
    """Remove a staging folder made by :func:`open_staging` and its wrapper."""
    wrapper = Path(staging).parent
    if temporary_of(wrapper) is not None:
        remove_private(wrapper)


@contextlib.contextmanager
def atomic_dir(dst, *, keep_on_error: bool = False):
    """Context manager yielding a temporary folder that becomes ``dst`` on success.

    Parameters
    ----------
    dst : path-like
        Final folder; must pass :func:`claim_output`.  Its parent is created if needed.
    keep_on_error : bool
        Keep the temporary folder when the block raises (for debugging).

    Yields
    ------
    tmp : pathlib.Path
        Empty private folder on the same file system as ``dst``; sealed (every file
        recorded) and given the umask's permissions when the block ends.
    """
    dst = claim_output(dst)
    make_dirs(dst.parent)
    tok = new_token()
    tmp = make_private(dst.parent, f".{dst.name}.tmp-{tok}", role="tmp", token=tok,
                        **{"for": dst.name})
    try:
        yield tmp
    except BaseException:
        if not keep_on_error:
            remove_private(tmp)
        raise
    seal(tmp)
    public_mode(tmp, recursive=True)
    replace_dir(tmp, dst)


@contextlib.contextmanager
def output_folder(dst):
    """Where to write the folder ``dst``: ``dst`` itself when it is a private folder being
    made (a build's staging folder), else a private temporary that becomes ``dst`` when the
    block succeeds (:func:`atomic_dir`; ``dst`` must pass :func:`claim_output`).

    Yields
    ------
    pathlib.Path
    """
    dst = Path(dst)
    if dst.is_dir() and not dst.is_symlink() and is_private(read_stamp(dst)):
        yield dst
    else:
        with atomic_dir(dst) as tmp:
            yield tmp
