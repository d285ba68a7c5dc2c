"""One exception type for the whole project, the CLI exit codes, and the messages of the
machine's failures.

Every public boundary (CLI, file and table readers, API functions) raises
:class:`MorphshellError` (or its subclass :class:`InputError`) with a message
that names *what* is wrong (file, row, value), the rule broken, and the fix.
The CLI prints the message without a traceback and exits with
:data:`EXIT_BAD_INPUT` for bad input, :data:`EXIT_INTERNAL` for a bug, and
:data:`EXIT_CHECK_FAILED` when a design or simulation check says FAIL.
"""

from __future__ import annotations

import errno

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


# OSError numbers that describe the machine (the user can fix them), not a bug:
# errno -> (what happened, the fix)
_ENVIRONMENT_ERRNOS = {
    errno.ENOSPC: ("no space left on the device (the disk is full)",
                   "free some space or write elsewhere (--out), then re-run"),
    errno.EDQUOT: ("the disk quota is exceeded", "free some space or write elsewhere (--out), "
                                                 "then re-run"),
    errno.EFBIG: ("the file is too large for its file system or for this process's file-size "
                  "limit (ulimit -f)", "write to another file system (--out) or raise the "
                                       "limit, then re-run"),
    errno.EACCES: ("permission denied", "check the permissions of the folder, then re-run"),
    errno.EPERM: ("operation not permitted", "check the permissions of the folder, then "
                                             "re-run"),
    errno.EROFS: ("the file system is read-only", "write elsewhere (--out), then re-run"),
    errno.EADDRINUSE: ("the network port is already in use",
                       "choose another --port, or omit it to take any free port"),
    errno.EADDRNOTAVAIL: ("the network address is not available on this machine",
                          "check the address (the studio listens on 127.0.0.1)"),
    errno.EMFILE: ("too many open files", "raise the limit (ulimit -n), then re-run"),
    errno.ENFILE: ("too many open files on the machine", "close other programs, then re-run"),
    errno.ENAMETOOLONG: ("a file name is too long", "use a shorter --out path or file name"),
    errno.ELOOP: ("a symbolic link stands where morphshell does not follow links",
                  "replace the link by a real folder or file, then re-run"),
    errno.EIO: ("an input/output error on the device", "check the disk, then re-run"),
}


def _environment_error(e: BaseException):
    """(what happened, which file, fix) when ``e`` (or an error it came from) is the machine,
    not a bug; else None."""
    seen = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, MemoryError):
            return ("the machine ran out of memory", None,
                    "give a smaller input (e.g. decimate the mesh) or close other programs, "
                    "then re-run")
        if isinstance(e, OSError) and e.errno in _ENVIRONMENT_ERRNOS:
            what, fix = _ENVIRONMENT_ERRNOS[e.errno]
            return what, e.filename, fix
        e = e.__cause__ or e.__context__
    return None


def environment_message(e: BaseException, command: str) -> str | None:
    """The message of ``e`` when it is the machine's failure (a full disk, a quota, no
    memory, ...: :data:`_ENVIRONMENT_ERRNOS`), naming it and the fix; None for a bug.

    Parameters
    ----------
    e : BaseException
    command : str
        The command that failed, as the message names it (``"build"``, ``"studio run"``).
    """
    env = _environment_error(e)
    if env is None:
        return None
    what, filename, fix = env
    where = f" ({filename})" if filename else ""
    return (f"morphshell {command}: error: {what}{where}.\n  Fix: {fix}; previous complete "
            "results are kept.")
