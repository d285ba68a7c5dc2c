"""Output folders: ownership, atomic replacement, permissions and build locks.

morphshell never deletes or overwrites a file it did not make.  Every folder it
writes carries a stamp file, :data:`STAMP_NAME`, listing the files it wrote
there (its manifest).  An output path is accepted (:func:`claim_output`) only when
it does not exist, is an empty folder, or is a stamped folder holding nothing but
the files its manifests list; a file, a symbolic link, a foreign folder or a
folder that contains the build's own input is refused with the fix.

Every stage writes into a temporary folder beside its destination and moves it
into place only when it has finished, so an interrupted run (Ctrl-C, kill)
leaves either the previous complete result or nothing, never a mix.  A lock file
beside each output folder keeps two builds of the same shape from clobbering each
other; builds of different shapes lock different files and run concurrently.
Locks and staging folders left by killed processes are cleaned by the next run.

Outputs follow the umask like ordinary files (0644 files and 0755 folders under the
usual umask 022), although they are written through ``tempfile``, whose files are
private (0600/0700) by design.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

from .errors import InputError

STAMP_NAME = ".morphshell-build"
"""Stamp file of every folder morphshell writes: JSON with the relative paths of the
files it wrote (``files``)."""

LOCK_SUFFIX = ".morphshell-lock"
STAGING_SUFFIX = ".morphshell-staging"
STALE_STAGING_S = 24 * 3600.0
"""Staging folders of other shapes, left by killed builds, are removed after this long."""


# ---------------------------------------------------------------- permissions


def _umask() -> int:
    # os.umask can only be read by setting it; set it straight back
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def public_mode(path, *, recursive: bool = False) -> None:
    """Give ``path`` the mode an ordinary ``open``/``mkdir`` would have under the current
    umask (``tempfile`` makes private 0600 files and 0700 folders)."""
    mask = _umask()
    path = Path(path)
    paths = [path]
    if recursive and path.is_dir():
        paths += list(path.rglob("*"))
    for p in paths:
        if p.is_symlink():
            continue
        os.chmod(p, (0o777 if p.is_dir() else 0o666) & ~mask)


# ---------------------------------------------------------------- ownership


def _manifest(folder: Path) -> set[str] | None:
    """Files listed by ``folder``'s stamp (relative POSIX paths), None when unstamped."""
    stamp = folder / STAMP_NAME
    if not stamp.is_file() or stamp.is_symlink():
        return None
    try:
        data = json.loads(stamp.read_text())
        return {str(f) for f in data["files"]}
    except (OSError, ValueError, KeyError, TypeError):
        return None


def write_stamp(folder, *, since: float | None = None) -> None:
    """Record the files of ``folder`` as morphshell's.

    Parameters
    ----------
    folder : path-like
        A folder morphshell has written.
    since : float, optional
        Epoch seconds.  When given, only files modified since then are added to the
        existing manifest (a stage run on an existing design folder); otherwise every
        file of the folder is listed (a folder morphshell has just made whole).
    """
    folder = Path(folder)
    files = set() if since is None else (_manifest(folder) or set())
    for p in folder.rglob("*"):
        if p.is_file() and p.name != STAMP_NAME and (since is None
                                                     or p.lstat().st_mtime >= since):
            files.add(p.relative_to(folder).as_posix())
    files = {f for f in files if (folder / f).exists()}
    text = json.dumps({"made_by": "morphshell", "files": sorted(files)}, indent=0) + "\n"
    atomic_write_text(folder / STAMP_NAME, text)


def foreign_files(folder) -> list[Path]:
    """Files under ``folder`` that no stamp lists (all of them when it is unstamped).

    A file belongs to the nearest stamped folder above it: ``stl/top.stl`` is checked
    against ``stl/``'s stamp when there is one, else against ``folder``'s.
    """
    folder = Path(folder)
    cache: dict[Path, set[str] | None] = {}
    foreign = []
    for p in sorted(folder.rglob("*")):
        if p.is_dir() and not p.is_symlink():
            continue
        if p.name == STAMP_NAME:
            continue
        owner = p.parent
        while True:
            if owner not in cache:
                cache[owner] = _manifest(owner)
            if cache[owner] is not None or owner == folder:
                break
            owner = owner.parent
        listed = cache[owner]
        if listed is None or p.relative_to(owner).as_posix() not in listed:
            foreign.append(p)
    return foreign


def claim_output(dst, *, what: str = "output folder", inputs=()) -> Path:
    """Check that morphshell may write (and later replace) the folder ``dst``.

    Parameters
    ----------
    dst : path-like
        The output folder.
    what : str
        How the message names it (e.g. ``"--out folder"``).
    inputs : iterable of path-like
        Input files of the run; none may lie inside ``dst``.

    Returns
    -------
    Path
        ``dst``, absolute.

    Raises
    ------
    InputError
        ``dst`` is a file or a symbolic link, a non-empty folder morphshell did not
        make (or holding files it did not write), or contains one of ``inputs``.
    """
    dst = Path(dst).absolute()
    fix = ("choose a new or empty folder (e.g. --out build/NAME), or move your files out "
           f"of {dst} first; morphshell never deletes files it did not make.")
    for src in inputs:
        if src is None or not Path(src).exists():
            continue
        s, d = Path(src).resolve(), dst.resolve()
        if s == d or d in s.parents:
            raise InputError(f"{what} {dst} contains the input {src}: writing the build "
                             "there would delete it.", fix=fix)
    if dst.is_symlink():
        raise InputError(f"{what} {dst} is a symbolic link.",
                         fix="give the real folder it points to, or a new folder.")
    if dst.exists() and not dst.is_dir():
        raise InputError(f"{what} {dst} is a file, not a folder: morphshell would "
                         "replace it.", fix="give a folder path that does not exist yet "
                         "(e.g. --out build/NAME); morphshell never deletes files it did "
                         "not make.")
    if dst.is_dir():
        foreign = foreign_files(dst)
        if foreign:
            names = ", ".join(str(p.relative_to(dst)) for p in foreign[:3])
            more = f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
            kind = ("is not a morphshell build folder" if _manifest(dst) is None
                    else "holds files that morphshell did not write")
            raise InputError(f"{what} {dst} {kind} ({names}{more}); replacing it would "
                             "delete them.", fix=fix)
    return dst


# ---------------------------------------------------------------- atomic moves


def replace_dir(src: Path, dst: Path) -> None:
    """Move the finished folder ``src`` to ``dst``, replacing any previous ``dst``.

    The old folder is first renamed aside, then ``src`` renamed into place, then
    the old one deleted: at every instant ``dst`` is absent or complete.  ``dst``
    must pass :func:`claim_output` (checked again here, just before the move).
    """
    src, dst = Path(src), Path(dst)
    claim_output(dst)
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
      otherwise old folders are removed;
    * lock files and staging folders of other outputs in the same parent, left by killed
      runs, are removed (:func:`clean_stale_siblings`).

    Returns
    -------
    list of Path
        The folders and files removed or restored.
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
    return done + clean_stale_siblings(dst)


def clean_stale_siblings(dst) -> list[Path]:
    """Remove the lock files no live process holds, and other outputs' staging folders that
    are unlocked and older than :data:`STALE_STAGING_S`, in ``dst``'s parent folder."""
    parent = Path(dst).parent
    done = []
    for lock in sorted(parent.glob(f".*{LOCK_SUFFIX}")):
        if lock == lock_path(dst):
            continue
        with contextlib.suppress(OSError), open(lock, "a+") as f:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                continue  # a live build
            lock.unlink()
            done.append(lock)
    now = time.time()
    for staging in sorted(parent.glob(f".*{STAGING_SUFFIX}")):
        name = staging.name[1:-len(STAGING_SUFFIX)]
        if name == Path(dst).name or lock_path(parent / name).exists():
            continue
        if now - staging.stat().st_mtime > STALE_STAGING_S:
            shutil.rmtree(staging, ignore_errors=True)
            done.append(staging)
    return done


def staging_dir(dst) -> Path:
    """Where a build of ``dst`` runs: ``<parent>/.<name>.morphshell-staging/<name>`` (same
    file system as ``dst``, same folder name, so logs name the shape)."""
    dst = Path(dst)
    return dst.parent / f".{dst.name}{STAGING_SUFFIX}" / dst.name


def remove_staging(staging) -> None:
    """Remove a staging folder made by :func:`staging_dir` and its wrapper."""
    staging = Path(staging)
    if staging.parent.name.endswith(STAGING_SUFFIX):
        shutil.rmtree(staging.parent, ignore_errors=True)


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
        Empty folder on the same file system as ``dst``; stamped and given the umask's
        permissions when the block ends.
    """
    dst = claim_output(dst)
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dst.name}.tmp-", dir=dst.parent))
    try:
        yield tmp
    except BaseException:
        if not keep_on_error:
            shutil.rmtree(tmp, ignore_errors=True)
        raise
    write_stamp(tmp)
    public_mode(tmp, recursive=True)
    replace_dir(tmp, dst)


def atomic_write_text(path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and an atomic rename."""
    with atomic_file(path) as tmp, open(tmp, "w", newline="\n") as f:
        f.write(text)


@contextlib.contextmanager
def atomic_file(path):
    """Context manager yielding a temporary path beside ``path``; renamed to ``path``
    (with the umask's permissions) when the block succeeds, removed when it fails."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        public_mode(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


# ---------------------------------------------------------------- locks


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
    path.parent.mkdir(parents=True, exist_ok=True)
    while True:
        f = open(path, "a+")
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            f.seek(0)
            holder = f.read().strip() or "another process"
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


def claim_result_folder(folder, is_ours, *, what: str) -> Path:
    """Claim an output folder that may already hold this command's own results, so that a
    rerun resumes there: new, stamped by morphshell, or holding only files ``is_ours``
    accepts.

    Parameters
    ----------
    folder : path-like
    is_ours : callable(Path) -> bool
        Whether a file under ``folder`` that no stamp lists is one of our results.
    what : str
        How the message names the folder.

    Returns
    -------
    Path
        ``folder``, absolute.

    Raises
    ------
    InputError
        The folder holds files morphshell did not write (see :func:`claim_output`).
    """
    folder = Path(folder)
    if folder.is_dir() and not folder.is_symlink():
        foreign = [p for p in foreign_files(folder) if not is_ours(p)]
        if foreign:
            raise InputError(f"{what} {folder} holds files morphshell did not write "
                             f"({', '.join(str(p.relative_to(folder)) for p in foreign[:3])})",
                             fix="move them away or give another --out folder; morphshell "
                                 "never deletes files it did not make")
        return folder.absolute()
    return claim_output(folder, what=what)


def claim_output_file(path, *, what: str = "output file") -> Path:
    """Check that morphshell may write (and replace) the model file ``path``: it does not
    exist, or it is a JSON model file morphshell wrote (an object with ``provenance``).

    Raises
    ------
    InputError
        ``path`` is a folder, a symbolic link, or a file morphshell did not write.
    """
    path = Path(path).absolute()
    fix = "give a new file name (e.g. --out build/material/my_model.json)."
    if path.is_symlink() or path.is_dir():
        raise InputError(f"{what} {path} is a {'link' if path.is_symlink() else 'folder'}, "
                         "not a model file.", fix=fix)
    if path.exists():
        try:
            ours = "provenance" in json.loads(path.read_text())
        except (OSError, ValueError, TypeError):
            ours = False
        if not ours:
            raise InputError(f"{what} {path} exists and is not a model file morphshell "
                             "wrote: writing would overwrite it.", fix=fix)
    return path
