"""The stamp of a folder morphshell writes: its manifest, read, checked and stored.

A folder's stamp (:data:`STAMP_NAME`) records each file morphshell wrote there (SHA-256 and
size) and each subfolder it made; :func:`entry_state` says whether a file is still the one
recorded.  Private folders being made (temporary, moved-aside, staging) carry a stamp
saying what they are (:func:`temporary_of`).  A stamp of an older morphshell, which
recorded no contents, is refused here and only here (:class:`OlderStamp`).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import os
import re
import secrets
import shutil
import stat
import time
from pathlib import Path

from ..errors import InputError

STAMP_NAME = ".morphshell-build"
"""Stamp file of every folder morphshell writes: its manifest (module docstring)."""
STAMP_VERSION = 2
STAGING_SUFFIX = ".morphshell-staging"
_PRIVATE_ROLES = ("tmp", "work", "old", "staging")


def _umask() -> int:
    # os.umask can only be read by setting it; set it straight back
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def public_mode(path, *, recursive: bool = False) -> None:
    """Give ``path`` the mode an ordinary ``open``/``mkdir`` would have under the current
    umask (temporary files and folders are private, 0600/0700).  Symbolic links are never
    followed."""
    mask = _umask()
    path = Path(path)
    paths = [path]
    if recursive and path.is_dir() and not path.is_symlink():
        paths += [Path(r) / n for r, ds, fs in os.walk(path) for n in ds + fs]
    for p in paths:
        try:
            fd = os.open(p, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
        except OSError:
            continue  # a symbolic link (ELOOP), or gone
        try:
            st = os.fstat(fd)
            if stat.S_ISDIR(st.st_mode) or stat.S_ISREG(st.st_mode):
                os.fchmod(fd, (0o777 if stat.S_ISDIR(st.st_mode) else 0o666) & ~mask)
        finally:
            os.close(fd)


def file_digest(path) -> tuple[str, int]:
    """SHA-256 (hex) and size in bytes of the regular file ``path`` (never through a link).

    Raises
    ------
    OSError
        ``path`` is a link, not a regular file, or cannot be read.
    """
    fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
            raise OSError(errno.EINVAL, "not a regular file", str(path))
        h, n = hashlib.sha256(), 0
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
            n += len(chunk)
    return h.hexdigest(), n


def new_token() -> str:
    return secrets.token_hex(8)


class DamagedFolder(InputError):
    """A stamp or record that morphshell reads paths from is damaged, or names a path
    outside its folder: the folder is refused as a whole and nothing in it is touched."""
_DAMAGED_FIX = ("morphshell changes nothing in this folder: check its files yourself, then "
                "build into a new folder (e.g. --out build/NAME-2), or delete the stamp "
                f"{STAMP_NAME} so that every file there counts as yours")
_TMP_FILE = re.compile(r"^\..+\.tmp-[0-9a-f]{16}")
"""Names of :func:`atomic_file`'s temporary files (the only names a ``pending`` entry
may have)."""


class OlderStamp(DamagedFolder):
    """The stamp of a folder made by an older morphshell (a bare list of names, without
    the hashes and sizes of :data:`STAMP_VERSION` 2): its files cannot be told from the
    user's, so the folder is refused as a whole wherever it is met (the one place old
    builds are explained)."""

    def __init__(self, folder):
        super().__init__(f"{folder} was made by an older morphshell that did not record file "
                         "contents: morphshell cannot tell its files from yours there, so it "
                         "deletes, replaces and writes nothing in it.",
                         fix="build into a new folder (e.g. --out build/NAME-2), or remove the "
                             "old one yourself after checking it holds nothing of yours.")


def contained_path(folder, rel, *, source) -> Path:
    """``folder / rel`` for a relative path ``rel`` read from a file (a stamp, a manifest, a
    staging record): the one check of every such path before it is used.

    Parameters
    ----------
    folder : path-like
        The folder the path must stay in.
    rel : str
        The path as read: relative, ``/``-separated, without ``.``, ``..`` or empty parts.
    source : path-like
        The file it was read from (named in the error).

    Returns
    -------
    pathlib.Path
        ``folder / rel``; the folders on the way, links resolved, lie inside ``folder``.

    Raises
    ------
    DamagedFolder
        ``rel`` is not such a path, or reaches outside ``folder`` through a link.
    """
    folder = Path(folder)
    why = None
    if not isinstance(rel, str) or not rel or "\0" in rel or "\\" in rel:
        why = "is not a path"
    elif rel.startswith("/"):
        why = "is an absolute path"
    elif any(part in ("", ".", "..") for part in rel.split("/")):
        why = "has a '..', '.' or empty part"
    else:
        base = folder.resolve()
        parent = (folder / rel).parent.resolve()
        if parent != base and base not in parent.parents:
            why = f"leads outside the folder (to {parent})"
    if why is not None:
        raise DamagedFolder(f"{source}: the path {str(rel)[:200]!r} it names {why}; the "
                            f"folder {folder} is damaged or its record was not written by "
                            "morphshell, so nothing in it is deleted or replaced.",
                            fix=_DAMAGED_FIX)
    return folder / rel


def _damaged(p: Path, why: str) -> DamagedFolder:
    return DamagedFolder(f"{p} is damaged ({why}): morphshell cannot tell its files from "
                         "yours in that folder, so it deletes and replaces nothing there.",
                         fix=_DAMAGED_FIX)


def _another_users(p: Path) -> bool:
    """Whether the stamp ``p`` (a file, a link or anything else) or its folder belongs to
    another user than this process's effective one: their record, not this user's, which
    morphshell reads as no stamp (never honoured, never called damaged, never written)."""
    uid = os.geteuid()
    try:
        return os.lstat(p).st_uid != uid or os.stat(p.parent).st_uid != uid
    except OSError:   # none there, or unreadable: the open that follows tells which
        return False


def _load_stamp(p: Path):
    """The JSON value of the stamp file ``p``; None when there is none, or when it or its
    folder belongs to another user (:func:`_another_users`).

    Raises
    ------
    DamagedFolder
        Something of this user's is there that is not a readable regular JSON file."""
    if _another_users(p):
        return None
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except FileNotFoundError:
        return None
    except OSError as e:
        raise _damaged(p, "a symbolic link" if e.errno == errno.ELOOP
                       else f"cannot be read: {e.strerror}") from None
    try:
        with os.fdopen(fd, "rb") as f:
            st = os.fstat(f.fileno())
            if st.st_uid != os.geteuid():   # (given to another user since the check above)
                return None
            if not stat.S_ISREG(st.st_mode):
                raise _damaged(p, "not a regular file")
            return json.loads(f.read(64 << 20))
    except OSError as e:
        raise _damaged(p, f"cannot be read: {e.strerror}") from None
    except ValueError as e:
        raise _damaged(p, f"not JSON: {e}") from None


def _check_manifest(folder: Path, data: dict, p: Path) -> dict:
    """``data`` (a stamp of this version) with its keys' types and every path it names
    checked (:func:`contained_path`)."""
    for key, kind in (("files", dict), ("dirs", list), ("prev", dict), ("pending", dict)):
        data.setdefault(key, kind())
        if not isinstance(data[key], kind):
            raise _damaged(p, f"'{key}' is not a {kind.__name__}")
    for key in ("files", "prev"):
        for rel, rec in data[key].items():
            contained_path(folder, rel, source=p)
            if not (isinstance(rec, list) and len(rec) == 2 and isinstance(rec[0], str)
                    and isinstance(rec[1], int)):
                raise _damaged(p, f"the record of {str(rel)[:200]!r} is not [sha256, size]")
    for rel in data["dirs"]:
        contained_path(folder, rel, source=p)
    for rel in data["pending"]:
        contained_path(folder, rel, source=p)
        if not _TMP_FILE.match(rel.rsplit("/", 1)[-1]):
            raise _damaged(p, f"the pending entry {rel[:200]!r} is not a temporary file's "
                              "name")
    return data


def read_stamp(folder) -> dict | None:
    """The manifest of ``folder`` (module docstring), or None when it has no stamp, a
    stamp of another program, or a stamp that another user owns (or in a folder another
    user owns: :func:`_another_users`).

    Raises
    ------
    OlderStamp
        The stamp was written by an older morphshell (:class:`OlderStamp`).
    DamagedFolder
        The stamp is not a readable JSON object, its fields have the wrong types, or a path
        it names is not a plain relative path inside ``folder`` (:func:`contained_path`).
    """
    p = Path(folder) / STAMP_NAME
    data = _load_stamp(p)
    if data is None:
        return None
    if not isinstance(data, dict):
        raise _damaged(p, "not a JSON object")
    if data.get("made_by") not in ("morphshell", "morphshell studio"):
        return None
    if data.get("version") != STAMP_VERSION or not isinstance(data.get("files"), dict):
        raise OlderStamp(folder)
    return _check_manifest(Path(folder), data, p)


def _read_stamp_or_none(folder) -> dict | None:
    """:func:`read_stamp`, with a damaged stamp read as none (a folder that is then not
    recognised as one of morphshell's private folders, so it is left alone)."""
    try:
        return read_stamp(folder)
    except DamagedFolder:
        return None


def is_private(m: dict | None) -> bool:
    """A stamp of a folder that is still being made (its files are not recorded yet)."""
    return m is not None and m.get("role") in _PRIVATE_ROLES


def write_new(path: Path, data: bytes) -> None:
    """Create ``path`` (which must not exist, not even as a link) holding ``data``."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC,
                 0o600)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
    finally:
        os.close(fd)


def store_stamp(folder: Path, data: dict, old: dict | None, *, keep: str | None = None) -> None:
    """Replace ``folder``'s stamp by ``data``; call it holding :func:`folder_lock`.

    The stamp's own temporary file is named by a token the previous stamp chose
    (``next``), so a temporary stamp left by a kill is recognised as morphshell's."""
    tok = (old or {}).get("next") or new_token()
    data = dict(data, made_by="morphshell", version=STAMP_VERSION, next=new_token())
    # pending temporary files that are gone need no record any more
    data["pending"] = {k: v for k, v in data.get("pending", {}).items()
                       if k == keep or os.path.lexists(folder / k)}
    text = json.dumps(data, indent=0, sort_keys=True) + "\n"
    tmp = folder / f"{STAMP_NAME}.{tok}.tmp"
    try:
        write_new(tmp, text.encode())
    except FileExistsError:  # the temporary stamp of a killed run: ours (its name was secret)
        os.unlink(tmp)
        write_new(tmp, text.encode())
    try:
        public_mode(tmp)
        os.replace(tmp, folder / STAMP_NAME)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def start_stamp(folder, **fields) -> None:
    """Give the new (or empty) folder ``folder`` an empty manifest, so that the files written
    into it from now on are recorded.  ``fields`` (``role``, ``for``, ``token``, ...) mark
    a private folder being made."""
    folder = Path(folder)
    data = {"files": {}, "dirs": [], "prev": {}, "pending": {}, "uid": os.geteuid(),
            "pid": os.getpid(), "created": time.time(), **fields}
    with folder_lock(folder):
        store_stamp(folder, data, read_stamp(folder))


@contextlib.contextmanager
def folder_lock(folder: Path):
    """Exclusive lock on the folder itself (``flock`` on its descriptor): one manifest update
    at a time, across processes."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    try:
        with contextlib.suppress(OSError):  # a file system without flock: no lock
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)
TEMP_NAME = re.compile(r"^\.(?P<for>.+)\.(?P<kind>tmp|old)-(?P<token>[0-9a-f]{16})$")


def temporary_of(p: Path) -> str | None:
    """If ``p`` is a temporary, moved-aside or staging folder morphshell made, the name of
    the folder it was made for; else None.  Recognised by the stamp inside (what it was
    made for, its token, its owner) matching the name, never by the name alone."""
    try:
        st = os.lstat(p)
    except OSError:
        return None
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.geteuid():
        return None
    m = _read_stamp_or_none(p)
    if m is None:
        return None
    name = p.name
    if name.endswith(STAGING_SUFFIX) and name.startswith("."):
        target = name[1:-len(STAGING_SUFFIX)]
        return target if m.get("role") == "staging" and m.get("for") == target else None
    g = TEMP_NAME.match(name)
    if g and m.get("for") == g["for"] and m.get("token") == g["token"]:
        return g["for"]
    return None


def pid_alive(pid) -> bool:
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except (PermissionError, ValueError, TypeError, OverflowError):
        return True
    return True


def remove_private(p: Path) -> None:
    """Remove a private folder of morphshell's (recognised by :func:`temporary_of`) with
    everything in it; links inside are removed, never followed."""
    shutil.rmtree(p, ignore_errors=True)


def make_private(parent: Path, name: str, **fields) -> Path:
    """A new private folder ``parent/name`` (mode 0700) with a stamp saying what it is."""
    path = parent / name
    os.mkdir(path, 0o700)
    start_stamp(path, **fields)
    return path


def stamp_owner(folder: Path) -> Path | None:
    """The nearest folder at or above ``folder`` with a stamp (which records what is
    written in ``folder``), or None."""
    for d in (folder, *folder.parents):
        if os.path.lexists(d / STAMP_NAME) and read_stamp(d) is not None:
            return d
    return None


def entry_state(p: Path, rel: str, m: dict) -> str | None:
    """None when the file ``p`` (``rel`` in the manifest ``m``) is morphshell's, else why
    not."""
    if rel in m["pending"]:
        return None  # a temporary file of a write in progress or killed
    rec = m["files"].get(rel)
    if rec is None:
        return "not written by morphshell"
    known = [list(rec), list(m["prev"].get(rel) or [None, None])]
    try:
        if os.lstat(p).st_size not in (known[0][1], known[1][1]):
            return "changed since morphshell wrote it"  # (no need to read it)
        got = list(file_digest(p))
    except OSError as e:
        return f"cannot be read ({e.strerror})"
    return None if got in known else "changed since morphshell wrote it"
