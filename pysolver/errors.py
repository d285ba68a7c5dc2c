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
