"""Output folders: ownership by content, atomic replacement, permissions and build locks.

morphshell never deletes or overwrites a file it did not make.  "Made" is decided by
content, recorded when the file is written, never after the fact:

* Every folder morphshell writes carries a stamp file, :data:`STAMP_NAME` (JSON), its
  manifest: for each file it wrote, the path relative to the folder, the SHA-256 and the
  size of what it wrote (``files``), and the subfolders it made (``dirs``).
* A file is morphshell's only when the manifest lists it with the hash and size it has now.
  A file the manifest does not list, or whose content changed since (a user's edit, a copy
  dropped in under the same name), is the user's: it is never deleted or overwritten, and
  the run that would do so is refused naming the file and the fix.  The same holds for
  folders: an unlisted folder (even an empty one), a symbolic link, a FIFO or a device.
* Writing into a folder in place (a stage command on a design folder, the studio's Save,
  a sweep's results) goes through :func:`atomic_file`, the one writer of the project: a
  unique temporary file beside the destination (``O_EXCL``, never following a link),
  its hash recorded in the manifest, then one atomic rename.  The manifest is updated
  under a lock on the folder, so concurrent writers never lose each other's records.
* Whole folders (a build, ``stl/``, ``report/``) are made in a private temporary folder
  (mode 0700) beside the destination, sealed (every file hashed into its manifest) and
  renamed into place (:func:`atomic_dir`, :func:`replace_dir`); the previous folder is
  moved aside and only the files its manifest vouches for are deleted.
* The temporary, moved-aside and staging folders morphshell leaves after a kill are
  recognised by the stamp inside them (what they were made for, a random token that is
  also in their name, their owner), never by their name alone; a user's
  ``.petal.tmp-notes`` or ``.petal.old-2023`` is left alone.

Only the private temporary folders are trusted as a whole: they are made with mode 0700
under a random name, and nothing but the running command writes into them.

Outputs follow the umask like ordinary files (0644 files and 0755 folders under the
usual umask 022), although the temporary files and folders are private.
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
import warnings
from pathlib import Path

from .errors import InputError

STAMP_NAME = ".morphshell-build"
"""Stamp file of every folder morphshell writes: its manifest (module docstring)."""

STAMP_VERSION = 2
LOCK_SUFFIX = ".morphshell-lock"
STAGING_SUFFIX = ".morphshell-staging"
STALE_STAGING_S = 7 * 24 * 3600.0
"""Staging folders of other outputs, left by killed builds, are removed after a week (when
their stamp says they are morphshell's and this user's, and no build holds their lock)."""

_PRIVATE_ROLES = ("tmp", "work", "old", "staging")
_NEVER_OURS = "move it out of the folder (or give another --out), then re-run; " \
              "morphshell never deletes or overwrites files it did not make"


class _Warning(UserWarning):
    """A file of the user's was found where morphshell cleans up; it was kept."""


# ---------------------------------------------------------------- permissions


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


# ---------------------------------------------------------------- hashes and stamps


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


def _token() -> str:
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

    A stamp of an older morphshell (a bare list of names, no hashes) is returned with
    ``legacy`` set: its files cannot be told from the user's.

    Raises
    ------
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
        return {"legacy": True, "files": {}, "dirs": [], "prev": {}, "pending": {}}
    return _check_manifest(Path(folder), data, p)


def _read_stamp_or_none(folder) -> dict | None:
    """:func:`read_stamp`, with a damaged stamp read as none (a folder that is then not
    recognised as one of morphshell's private folders, so it is left alone)."""
    try:
        return read_stamp(folder)
    except DamagedFolder:
        return None


def _is_private(m: dict | None) -> bool:
    """A stamp of a folder that is still being made (its files are not recorded yet)."""
    return m is not None and m.get("role") in _PRIVATE_ROLES


def _write_new(path: Path, data: bytes) -> None:
    """Create ``path`` (which must not exist, not even as a link) holding ``data``."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC,
                 0o600)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
    finally:
        os.close(fd)


def _store(folder: Path, data: dict, old: dict | None, *, keep: str | None = None) -> None:
    """Replace ``folder``'s stamp by ``data``; call it holding :func:`_folder_lock`.

    The stamp's own temporary file is named by a token the previous stamp chose
    (``next``), so a temporary stamp left by a kill is recognised as morphshell's."""
    tok = (old or {}).get("next") or _token()
    data = dict(data, made_by="morphshell", version=STAMP_VERSION, next=_token())
    # pending temporary files that are gone need no record any more
    data["pending"] = {k: v for k, v in data.get("pending", {}).items()
                       if k == keep or os.path.lexists(folder / k)}
    text = json.dumps(data, indent=0, sort_keys=True) + "\n"
    tmp = folder / f"{STAMP_NAME}.{tok}.tmp"
    try:
        _write_new(tmp, text.encode())
    except FileExistsError:  # the temporary stamp of a killed run: ours (its name was secret)
        os.unlink(tmp)
        _write_new(tmp, text.encode())
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
    with _folder_lock(folder):
        _store(folder, data, read_stamp(folder))


@contextlib.contextmanager
def _folder_lock(folder: Path):
    """Exclusive lock on the folder itself (``flock`` on its descriptor): one manifest update
    at a time, across processes."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    try:
        with contextlib.suppress(OSError):  # a file system without flock: no lock
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


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
            if sub is not None and _temporary_of(p) is not None:
                _remove_private(p)
                skip.append(p)
                continue
            dirs.append(rel)
            if sub is not None and not sub.get("legacy") and not _is_private(sub):
                skip.append(p)  # its own manifest lists its files
            elif sub is not None:
                (p / STAMP_NAME).unlink()
        elif kind == "file" and p.parent == folder and p.name.startswith(STAMP_NAME + "."):
            p.unlink()  # a temporary stamp of a killed step, in this private folder
        elif kind == "file" and p.name != STAMP_NAME:
            files[rel] = list(file_digest(p))
    keep = {k: old[k] for k in ("for", "token", "pid") if k in old}
    with _folder_lock(folder):
        _store(folder, {"files": files, "dirs": sorted(dirs), "prev": {}, "pending": {},
                        **keep}, read_stamp(folder))


# ---------------------------------------------------------------- temporary folders


_TEMP_NAME = re.compile(r"^\.(?P<for>.+)\.(?P<kind>tmp|old)-(?P<token>[0-9a-f]{16})$")


def _temporary_of(p: Path) -> str | None:
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
    if m is None or m.get("legacy"):
        return None
    name = p.name
    if name.endswith(STAGING_SUFFIX) and name.startswith("."):
        target = name[1:-len(STAGING_SUFFIX)]
        return target if m.get("role") == "staging" and m.get("for") == target else None
    g = _TEMP_NAME.match(name)
    if g and m.get("for") == g["for"] and m.get("token") == g["token"]:
        return g["for"]
    return None


def _pid_alive(pid) -> bool:
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except (PermissionError, ValueError, TypeError, OverflowError):
        return True
    return True


def _remove_private(p: Path) -> None:
    """Remove a private folder of morphshell's (recognised by :func:`_temporary_of`) with
    everything in it; links inside are removed, never followed."""
    shutil.rmtree(p, ignore_errors=True)


def _make_private(parent: Path, name: str, **fields) -> Path:
    """A new private folder ``parent/name`` (mode 0700) with a stamp saying what it is."""
    path = parent / name
    os.mkdir(path, 0o700)
    start_stamp(path, **fields)
    return path


# ---------------------------------------------------------------- ownership


def _owner(folder: Path) -> Path | None:
    """The nearest folder at or above ``folder`` with a stamp (which records what is
    written in ``folder``), or None."""
    for d in (folder, *folder.parents):
        if os.path.lexists(d / STAMP_NAME) and read_stamp(d) is not None:
            return d
    return None


def _entry_state(p: Path, rel: str, m: dict) -> str | None:
    """None when the file ``p`` (``rel`` in the manifest ``m``) is morphshell's, else why
    not."""
    if rel in m["pending"]:
        return None  # a temporary file of a write in progress or killed
    rec = m["files"].get(rel)
    if rec is None:
        if m.get("legacy"):
            return "made by an older morphshell that did not record file contents"
        return "not written by morphshell"
    known = [list(rec), list(m["prev"].get(rel) or [None, None])]
    try:
        if os.lstat(p).st_size not in (known[0][1], known[1][1]):
            return "changed since morphshell wrote it"  # (no need to read it)
        got = list(file_digest(p))
    except OSError as e:
        return f"cannot be read ({e.strerror})"
    return None if got in known else "changed since morphshell wrote it"


def audit(folder) -> list[tuple[Path, str]]:
    """Everything under the stamped folder ``folder`` that is not morphshell's, with why.

    A file belongs to the nearest folder above it whose stamp its parent's manifest
    vouches for (``stl/top.stl`` is checked against ``stl/``'s stamp when the build folder
    lists ``stl``).  An unstamped ``folder`` is foreign as a whole unless it is empty.

    Returns
    -------
    list of (Path, str)
        The foreign entries (files, folders, links, special files) and the reason.
    """
    folder = Path(folder)
    m = read_stamp(folder)
    if m is None:
        return [(p, "not made by morphshell") for p in sorted(folder.iterdir())]
    out: list[tuple[Path, str]] = []
    _audit_in(folder, folder, m, out)
    return out


def _audit_in(d: Path, owner: Path, m: dict, out: list) -> None:
    try:
        entries = sorted(os.scandir(d), key=lambda e: e.name)
    except OSError as e:
        out.append((d, f"cannot be read ({e.strerror})"))
        return
    for e in entries:
        p = Path(e.path)
        rel = p.relative_to(owner).as_posix()
        if e.is_symlink():
            out.append((p, "a symbolic link"))
        elif e.is_dir(follow_symlinks=False):
            if rel in m["dirs"]:
                sub = read_stamp(p)
                if sub is not None and not _is_private(sub):
                    _audit_in(p, p, sub, out)  # a folder with its own manifest
                else:
                    _audit_in(p, owner, m, out)
            elif _temporary_of(p) is None:
                out.append((p, "a folder morphshell did not make"))
        elif e.is_file(follow_symlinks=False):
            if d == owner and (e.name == STAMP_NAME
                               or e.name == f"{STAMP_NAME}.{m.get('next')}.tmp"):
                continue
            if _is_lock_file(p):
                continue  # the lock of a subfolder's build (removed when released)
            why = _entry_state(p, rel, m)
            if why:
                out.append((p, why))
        else:
            out.append((p, "not a regular file"))


def foreign_files(folder) -> list[Path]:
    """Paths under ``folder`` that are not morphshell's (:func:`audit`)."""
    return [p for p, _ in audit(folder)]


def _listing(bad: list[tuple[Path, str]], base: Path) -> str:
    def name(p):
        try:
            return str(p.relative_to(base)) or p.name
        except ValueError:
            return str(p)
    text = ", ".join(f"{name(p)}: {why}" for p, why in bad[:3])
    return text + (f" and {len(bad) - 3} more" if len(bad) > 3 else "")


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
        make (an empty subfolder counts), a folder holding files it did not write or
        that changed since, or contains one of ``inputs``.
    """
    dst = Path(dst).absolute()
    check_name_length(dst, what=what)
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
        bad = audit(dst)
        if bad:
            m = read_stamp(dst)
            kind = ("is not a morphshell build folder" if m is None else
                    "was made by an older morphshell that did not record file contents"
                    if m.get("legacy") else "holds files that morphshell did not write")
            raise InputError(f"{what} {dst} {kind} ({_listing(bad, dst)}); replacing it "
                             "would delete them.", fix=fix)
        owner = _owner(dst.parent)
        if owner is not None:
            om = read_stamp(owner)
            if om is not None and not _is_private(om) and \
                    dst.relative_to(owner).as_posix() not in om["dirs"]:
                raise InputError(f"{what} {dst} is a folder morphshell did not make inside "
                                 f"{owner}; replacing it would delete it.", fix=fix)
    return dst


SIBLING_EXTRA = len(f"..tmp-{'0' * 16}")
"""Characters the longest name morphshell makes beside an output folder adds to its name
(``.<name>.tmp-<token>``; ``.<name>.morphshell-staging`` and the lock file are shorter)."""


def check_name_length(dst: Path, *, what: str = "output folder") -> None:
    """Refuse an output folder whose name leaves no room for the temporary, staging and lock
    names morphshell makes beside it (the file system's longest name, ``NAME_MAX``, is
    usually 255 bytes).

    Raises
    ------
    InputError
        Naming the length, the longest name that works and the fix.
    """
    parent = next((d for d in Path(dst).parents if d.is_dir()), Path("/"))
    try:
        name_max = os.pathconf(parent, "PC_NAME_MAX")
    except (OSError, ValueError):
        name_max = 255
    longest = name_max - SIBLING_EXTRA
    n = len(os.fsencode(Path(dst).name))
    if n > longest:
        raise InputError(f"{what} {dst}: its name is {n} bytes long, and morphshell needs at "
                         f"most {longest} (it makes .<name>.tmp-<token>, "
                         f".<name>{STAGING_SUFFIX} and .<name>{LOCK_SUFFIX} beside it, and "
                         f"this file system allows names of {name_max} bytes).",
                         fix=f"give a shorter folder name (at most {longest} characters), "
                             "e.g. --out build/NAME.")


def check_design_folder(folder, *, what: str = "design folder") -> Path:
    """Check that a stage may write into the existing folder ``folder`` in place: a real
    folder (not a link) with a morphshell stamp of this version.

    Raises
    ------
    InputError
        Naming the folder and the fix.
    """
    folder = Path(folder).absolute()
    if folder.is_symlink() or not folder.is_dir():
        raise InputError(f"{what} {folder} is "
                         f"{'a symbolic link' if folder.is_symlink() else 'not a folder'}.",
                         fix="give the design folder itself (e.g. build/petal).")
    m = read_stamp(folder)
    if m is None or m.get("legacy") or _is_private(m):
        why = ("was made by an older morphshell that did not record file contents"
               if m and m.get("legacy") else f"has no {STAMP_NAME} stamp")
        raise InputError(f"{what} {folder} {why}: morphshell cannot tell its files from "
                         "yours there, so it writes nothing into it.",
                         fix="make the design folder with 'morphshell build' or 'morphshell "
                             "design' (e.g. --out build/NAME) and run the stage on that.")
    return folder


# ---------------------------------------------------------------- writing one file


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
    owner = _owner(d)
    if owner is not None:
        m = read_stamp(owner)
        if m is not None and not _is_private(m):
            for p in [d, *d.parents]:
                if p == owner or owner not in p.parents:
                    break
                rel = p.relative_to(owner).as_posix()
                if p.is_symlink() or not p.is_dir() or (rel not in m["dirs"]
                                                        and _temporary_of(p) is None):
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
        own = _owner(p.parent)
        if own is not None:
            with _folder_lock(own):
                m = read_stamp(own)
                if m is not None and not _is_private(m) and not m.get("legacy"):
                    rel = p.relative_to(own).as_posix()
                    if rel not in m["dirs"]:
                        _store(own, dict(m, dirs=sorted({*m["dirs"], rel})), m)
    return folder


def _drop_dead_temporaries(owner: Path, m: dict) -> dict:
    """Remove the temporary files that writers killed before their rename left in ``owner``
    (recorded as pending by a process that is gone); returns the manifest without them."""
    dead = {k for k, pid in m["pending"].items()
            if pid != os.getpid() and not _pid_alive(pid)}
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
        why = _entry_state(path, rel, m)
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
    owner = _owner(path.parent)
    m = read_stamp(owner) if owner is not None else None
    tracked = m is not None and not _is_private(m)
    if m is not None and m.get("legacy"):
        raise InputError(f"{owner} was made by an older morphshell that did not record file "
                         f"contents: morphshell will not write {path.name} into it.",
                         fix="rebuild into a new folder (e.g. --out build/NAME-2), or remove "
                             "the old one yourself after checking it holds nothing of yours.")
    base = path.name[:120]
    while True:
        tmp = path.with_name(f".{base}.tmp-{_token()}{path.suffix[:16]}")
        if os.path.lexists(tmp):
            continue
        if not tracked:
            with contextlib.suppress(FileExistsError):
                _write_new(tmp, b"")
                break
            continue
        with _folder_lock(owner):
            m = _drop_dead_temporaries(owner, read_stamp(owner))
            _check_replaceable(path, owner, m)
            rel_tmp = tmp.relative_to(owner).as_posix()
            # recorded before it exists: a kill right after leaves a file morphshell knows
            _store(owner, dict(m, pending={**m["pending"], rel_tmp: os.getpid()}), m,
                   keep=rel_tmp)
            try:
                _write_new(tmp, b"")
                break
            except FileExistsError:  # someone else's file appeared under the name
                m = read_stamp(owner)
                _store(owner, dict(m, pending={k: v for k, v in m["pending"].items()
                                               if k != rel_tmp}), m)
    try:
        yield tmp
        if tracked:
            digest = list(file_digest(tmp))
            with _folder_lock(owner):
                m = read_stamp(owner)
                _check_replaceable(path, owner, m)
                rel = path.relative_to(owner).as_posix()
                prev = dict(m["prev"])
                if rel in m["files"] and os.path.lexists(path):
                    prev[rel] = m["files"][rel]
                _store(owner, dict(m, files={**m["files"], rel: digest}, prev=prev), m)
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
    owner = _owner(path.parent)
    if owner is None:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
        return
    with _folder_lock(owner):
        m = read_stamp(owner)
        if m is None or _is_private(m):
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
        _store(owner, dict(m, files={k: v for k, v in m["files"].items() if k != rel},
                           prev={k: v for k, v in m["prev"].items() if k != rel}), m)


# ---------------------------------------------------------------- whole folders


def _remove_ours(folder: Path) -> list[Path]:
    """Delete from ``folder`` what its manifests vouch for (each file checked right before
    it goes) and the folders left empty; returns what was kept (the user's)."""
    kept: list[Path] = []
    m = read_stamp(folder)
    if m is None or m.get("legacy"):
        return [folder]

    def rm(d: Path, owner: Path, man: dict) -> bool:
        empty = True
        for e in sorted(os.scandir(d), key=lambda e: e.name):
            p = Path(e.path)
            rel = p.relative_to(owner).as_posix()
            if e.is_dir(follow_symlinks=False):
                if rel in man["dirs"]:
                    sub = read_stamp(p)
                    ok = (rm(p, p, sub) if sub is not None and not _is_private(sub)
                          and not sub.get("legacy") else rm(p, owner, man))
                elif _temporary_of(p) is not None:
                    _remove_private(p)
                    ok = True
                else:
                    ok = False
                    kept.append(p)
                empty &= ok
            elif e.is_file(follow_symlinks=False) and d == owner and (
                    e.name == STAMP_NAME or e.name == f"{STAMP_NAME}.{man.get('next')}.tmp"):
                continue
            elif e.is_file(follow_symlinks=False) and (_entry_state(p, rel, man) is None
                                                       or _stale_lock(p)):
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
        tok = _token()
        aside = _make_private(dst.parent, f".{dst.name}.old-{tok}", role="old", token=tok,
                              **{"for": dst.name})
        os.replace(dst, aside / dst.name)
    try:
        os.rename(src, dst)
    except OSError:
        if aside is not None and not os.path.lexists(dst):
            os.replace(aside / dst.name, dst)
            _remove_ours_private(aside)
        raise
    own = _owner(dst.parent)
    if own is not None:
        with _folder_lock(own):
            m = read_stamp(own)
            rel = dst.relative_to(own).as_posix()
            if m is not None and not _is_private(m) and not m.get("legacy") \
                    and rel not in m["dirs"]:
                _store(own, dict(m, dirs=sorted({*m["dirs"], rel})), m)
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
    _remove_private(aside)


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
        if not _TEMP_NAME.match(p.name) or _temporary_of(p) != dst.name:
            continue
        m = read_stamp(p) or {}
        if m.get("pid") != os.getpid() and _pid_alive(m.get("pid")):
            continue  # another process's, still at work
        if ".old-" in p.name:
            olds.append((m.get("created", 0.0), p))
        else:
            _remove_private(p)
            done.append(p)
    olds.sort()
    if olds and not os.path.lexists(dst) and os.path.isdir(olds[-1][1] / dst.name):
        os.replace(olds[-1][1] / dst.name, dst)
        done.append(dst)
    for _, old in olds:
        _remove_ours_private(old) if (old / dst.name).exists() else _remove_private(old)
        done.append(old)
    return done + clean_stale_siblings(dst)


_LOCK_TEXT = re.compile(r"^(pid \d+)?$")


def _is_lock_file(p: Path) -> bool:
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


def _stale_lock(p: Path) -> bool:
    """A lock file of ours that no live process holds."""
    if not _is_lock_file(p):
        return False
    try:
        with open(p, "rb") as f:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
    except OSError:
        return False


def clean_stale_siblings(dst) -> list[Path]:
    """Remove the lock files no live process holds, and other outputs' staging folders that
    are unlocked and older than :data:`STALE_STAGING_S`, in ``dst``'s parent folder.  Both
    are recognised by content (a lock file holds only ``pid N``; a staging folder's stamp
    says what it is and that it is this user's), not by name alone."""
    dst = Path(dst)
    parent = dst.parent
    done = []
    for lock in sorted(q for q in parent.iterdir() if q.name.endswith(LOCK_SUFFIX)):
        if lock != lock_path(dst) and _stale_lock(lock):  # (a live build holds its lock)
            lock.unlink()
            done.append(lock)
    now = time.time()
    for staging in sorted(q for q in parent.iterdir() if q.name.endswith(STAGING_SUFFIX)):
        name = _temporary_of(staging)
        if name is None or name == dst.name or lock_path(parent / name).exists():
            continue
        m = read_stamp(staging) or {}
        if now - float(m.get("created", now)) > STALE_STAGING_S:
            _remove_private(staging)
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
        if _temporary_of(wrapper) != staging.name:
            raise InputError(f"{wrapper} exists and is not a staging folder of morphshell's "
                             "(no stamp of ours inside): it is kept.",
                             fix="move or rename it, then build again.")
        m = read_stamp(wrapper) or {}
        if m.get("inputs_sha256") == inputs_sha256 and staging.is_dir() \
                and _is_private(read_stamp(staging)):
            return True
        _remove_private(wrapper)
    _make_private(wrapper.parent, wrapper.name, role="staging", inputs_sha256=inputs_sha256,
                  **{"for": staging.name})
    _make_private(wrapper, staging.name, role="work", **{"for": staging.name})
    return False


def remove_staging(staging) -> None:
    """Remove a staging folder made by :func:`open_staging` and its wrapper."""
    wrapper = Path(staging).parent
    if _temporary_of(wrapper) is not None:
        _remove_private(wrapper)


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
    tok = _token()
    tmp = _make_private(dst.parent, f".{dst.name}.tmp-{tok}", role="tmp", token=tok,
                        **{"for": dst.name})
    try:
        yield tmp
    except BaseException:
        if not keep_on_error:
            _remove_private(tmp)
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
    if dst.is_dir() and not dst.is_symlink() and _is_private(read_stamp(dst)):
        yield dst
    else:
        with atomic_dir(dst) as tmp:
            yield tmp


def write_stamp(folder, *, since: float | None = None) -> None:
    """Kept for callers of the former API, which stamped files after the fact.  Files are
    now recorded when they are written (:func:`atomic_file`), so this only seals a private
    folder being made (:func:`seal`) and does nothing to any other folder: it never adopts
    a file.  ``since`` is ignored."""
    del since
    if _is_private(read_stamp(folder)):
        seal(folder)


def _manifest(folder) -> set[str] | None:
    """Names the manifest of ``folder`` records (former API), None when unstamped."""
    m = read_stamp(folder)
    return None if m is None or m.get("legacy") else set(m["files"])


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


def claim_result_folder(folder, *, what: str, inputs=()) -> Path:
    """Claim an output folder that may already hold this command's own results, so that a
    rerun resumes there: new, empty, or stamped by morphshell with nothing of the user's
    in it.  A new or empty folder gets an empty manifest, so that each result written into
    it (:func:`atomic_file`) is recorded as it is written.

    The arguments are :func:`claim_output`'s (``inputs``: the run's input files, none of
    which may lie inside ``folder``).  Returns ``folder``, absolute.

    Raises
    ------
    InputError
        The folder holds files morphshell did not write, or one of ``inputs`` (see
        :func:`claim_output`).
    """
    folder = claim_output(folder, what=what, inputs=inputs)
    make_dirs(folder)
    if read_stamp(folder) is None:
        start_stamp(folder)
    return folder


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
            if not path.is_file():
                raise OSError
            ours = "provenance" in json.loads(path.read_text())
        except (OSError, ValueError, TypeError):
            ours = False
        if not ours:
            raise InputError(f"{what} {path} exists and is not a model file morphshell "
                             "wrote: writing would overwrite it.", fix=fix)
    return path
