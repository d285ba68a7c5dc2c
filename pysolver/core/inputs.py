"""Reading the user's input files: regular files only, opened without blocking.

A FIFO, a device or a socket given as a mesh, scan, time file, model or table would block
its reader for ever: :func:`read_input` refuses it, naming what it is and the fix.
"""

from __future__ import annotations

import os
import stat

from ..errors import InputError

_KINDS = ((0o140000, "a socket"), (0o120000, "a symbolic link"), (0o060000, "a block device"),
          (0o040000, "a folder"), (0o020000, "a character device"), (0o010000, "a FIFO (named "
                                                                          "pipe)"))


def read_input(path, what: str = "input file", max_bytes: int | None = None) -> bytes:
    """The bytes of the input file ``path``, which must be a regular file.

    A FIFO, a device or a socket given as a mesh, scan, time file, model or table would
    block the reader for ever (or never end): it is refused.  The file is opened without
    blocking and checked on the open descriptor, so it cannot be swapped in between.

    Parameters
    ----------
    path : path-like
    what : str
        How the message names the file (``"mesh file"``).
    max_bytes : int, optional
        Refuse larger files.

    Raises
    ------
    InputError
        Missing, unreadable, not a regular file, or too large.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise InputError(f"{what} {path} does not exist.", fix="check the path.") from None
    except OSError as e:
        raise InputError(f"cannot open the {what} {path} ({e.strerror}).",
                         fix="check the path and its permissions.") from None
    with os.fdopen(fd, "rb") as f:
        st = os.fstat(f.fileno())
        if not stat.S_ISREG(st.st_mode):
            kind = next((k for bits, k in _KINDS if stat.S_IFMT(st.st_mode) == bits),
                        "not a regular file")
            raise InputError(f"{what} {path} is {kind}, not a file: morphshell reads only "
                             "regular files (reading a pipe or a device could block for ever).",
                             fix="give the path of an ordinary file (copy the data into one "
                                 "first).")
        if max_bytes is not None and st.st_size > max_bytes:
            raise InputError(f"{what} {path} has {st.st_size} bytes, more than the "
                             f"{max_bytes} allowed.", fix="give a smaller file.")
        return f.read()


def check_input_file(path, what: str = "input file") -> None:
    """Refuse ``path`` unless it is a regular file (:func:`read_input`, without reading).

    Raises
    ------
    InputError
    """
    try:
        st = os.stat(path)
    except OSError:
        return  # the reader names a missing file in its own words
    if not stat.S_ISREG(st.st_mode) and not stat.S_ISDIR(st.st_mode):
        read_input(path, what)  # (raises, naming the kind)
