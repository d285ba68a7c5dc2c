"""Audits and claims: what in a folder is not morphshell's, and whether a command may
write (and later replace) an output folder or file."""

from __future__ import annotations

import json
import os
from pathlib import Path

from ..errors import InputError
from .locks import LOCK_SUFFIX, is_lock_file
from .manifest import (
    STAGING_SUFFIX,
    STAMP_NAME,
    entry_state,
    is_private,
    read_stamp,
    stamp_owner,
    start_stamp,
    temporary_of,
)
from .writes import make_dirs


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
                if sub is not None and not is_private(sub):
                    _audit_in(p, p, sub, out)  # a folder with its own manifest
                else:
                    _audit_in(p, owner, m, out)
            elif temporary_of(p) is None:
                out.append((p, "a folder morphshell did not make"))
        elif e.is_file(follow_symlinks=False):
            if d == owner and (e.name == STAMP_NAME
                               or e.name == f"{STAMP_NAME}.{m.get('next')}.tmp"):
                continue
            if is_lock_file(p):
                continue  # the lock of a subfolder's build (removed when released)
            why = entry_state(p, rel, m)
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
                    "holds files that morphshell did not write")
            raise InputError(f"{what} {dst} {kind} ({_listing(bad, dst)}); replacing it "
                             "would delete them.", fix=fix)
        owner = stamp_owner(dst.parent)
        if owner is not None:
            om = read_stamp(owner)
            if om is not None and not is_private(om) and \
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
    if m is None or is_private(m):
        raise InputError(f"{what} {folder} has no {STAMP_NAME} stamp: morphshell cannot "
                         "tell its files from yours there, so it writes nothing into it.",
                         fix="make the design folder with 'morphshell build' or 'morphshell "
                             "design' (e.g. --out build/NAME) and run the stage on that.")
    return folder


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
