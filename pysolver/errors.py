"""One exception type for the whole project, and the CLI exit codes.

Every public boundary (CLI, file and table readers, API functions) raises
:class:`MorphshellError` (or its subclass :class:`InputError`) with a message
that names *what* is wrong (file, row, value), the rule broken, and the fix.
The CLI prints the message without a traceback and exits with
:data:`EXIT_BAD_INPUT` for bad input, :data:`EXIT_INTERNAL` for a bug, and
:data:`EXIT_CHECK_FAILED` when a design or simulation check says FAIL.
"""

from __future__ import annotations

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
