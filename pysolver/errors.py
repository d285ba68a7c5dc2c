"""One exception type for the whole project, and the CLI exit codes.

Every public boundary (CLI, file and table readers, API functions) raises
:class:`MorphshellError` (or its subclass :class:`InputError`) with a message
that names *what* is wrong (file, row, value), the rule broken, and the fix.
The CLI prints the message without a traceback and exits with
:data:`EXIT_BAD_INPUT` for bad input, :data:`EXIT_INTERNAL` for a bug, and
:data:`EXIT_CHECK_FAILED` when a design or simulation check says FAIL.
"""

from __future__ import annotations

import os
import stat

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_BAD_INPUT = 2
EXIT_CHECK_FAILED = 3
EXIT_INTERRUPTED = 130


class MorphshellError(Exception):
    """Base class of every error the project raises on purpose.

    Parameters
    ----------
    message : str
        What is wrong, naming the file/row/value concerned.
    fix : str, optional
        How to fix it; appended as ``"Fix: ..."``.
    """

    exit_code = EXIT_INTERNAL

    def __init__(self, message: str, fix: str | None = None):
        self.problem = message
        self.fix = fix
        text = message if fix is None else f"{message}\n  Fix: {fix}"
        super().__init__(text)


class InputError(MorphshellError, ValueError):
    """Bad input from the user: a file, a table, an option or an argument.

    Also a :class:`ValueError`, so numpy-style callers can catch it as such.
    """

    exit_code = EXIT_BAD_INPUT


class CheckFailed(MorphshellError):
    """A design or simulation check refused the result (verdict FAIL)."""

    exit_code = EXIT_CHECK_FAILED


class ExternalToolError(MorphshellError):
    """An external program (OpenSCAD) is missing or failed on some part."""

    exit_code = EXIT_BAD_INPUT


def refuse_first(bad, message, fix: str | None = None) -> None:
    """Raise :class:`InputError` naming the first row that breaks a rule, if any does.

    The one "check every row, name the first bad one" of the table and file readers.

    Parameters
    ----------
    bad : (n,) bool
        Rows (cells, data rows, ...) that break the rule.
    message : callable
        ``message(i, count) -> str``: what is wrong with the first bad row ``i``, given the
        ``count`` of bad rows.  Called only when some row is bad.
    fix : str, optional
        How to fix it.

    Raises
    ------
    InputError
        ``message(i, count)`` with ``fix``, when ``bad`` has a true entry.
    """
    # numpy is imported here, not at module level: the command line imports this module,
    # and `morphshell --help` stays instant without numpy
    import numpy as np

    rows = np.flatnonzero(np.asarray(bad, bool))
    if rows.size:
        raise InputError(message(int(rows[0]), int(rows.size)), fix=fix)


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
