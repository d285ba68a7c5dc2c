"""``morphshell``: the command line, one subcommand per stage and tool.

The package, top down:

* :func:`main` (here): the entry point of the ``morphshell`` console script and of
  ``python -m pysolver.cli`` (:mod:`pysolver.cli.__main__`): parses, runs the subcommand,
  and turns what went wrong into a message and an exit code;
* :mod:`pysolver.cli.parser`: the parser and the ``--help`` text, generated from the tables;
* :mod:`pysolver.cli.table`: the subcommands (one per stage of
  :data:`pysolver.stages.STAGES`, ``build``, and the tools), their arguments and help;
* :mod:`pysolver.cli.commands`: what each subcommand does, importing its stage when it runs
  (``# lazy:``) so that ``morphshell --help`` is instant.

The stage table itself, :mod:`pysolver.stages`, stays outside the package: the build
(:mod:`pysolver.build`) and the studio read it too, and the build, which the command line
runs, never imports the command line (``tests/test_architecture.py``).

Errors the project raises on purpose (:class:`pysolver.errors.MorphshellError`) are printed
without a traceback (``--debug`` shows it) and exit with a code that tells bad input (2) from
a failed check (3) and an internal error (1); a failure of the machine (a full disk, no
memory: :func:`pysolver.errors.environment_message`) is named with its fix (2).
"""

from __future__ import annotations

import sys
import traceback
import warnings

from ..errors import (
    EXIT_BAD_INPUT,
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_OK,
    MorphshellError,
    environment_message,
)
from ..stages import runner
from .parser import make_parser


def _warning_printer(command: str):
    """``warnings.showwarning`` replacement: the project's warnings as one clean line
    (``morphshell build: warning: ...``), other libraries' warnings as usual."""
    default = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if category.__module__.split(".")[0] in ("pysolver", "sim"):
            print(f"morphshell {command}: warning: {message}", file=sys.stderr, flush=True)
        else:
            default(message, category, filename, lineno, file, line)

    return show


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``morphshell`` console script.

    Parameters
    ----------
    argv : list of str, optional
        The arguments after ``morphshell`` (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit code: 0, 2 bad input (or the machine's failure), 3 a check said FAIL, 1 a
        bug, 130 interrupted.
    """
    ap = make_parser()
    args = ap.parse_args(argv)
    if args.command is None:
        ap.print_help()
        return EXIT_OK
    shown = warnings.showwarning
    warnings.showwarning = _warning_printer(args.command)
    try:
        return runner(args.run)(args)
    except MorphshellError as e:
        if getattr(args, "debug", False):
            traceback.print_exc()
        print(f"morphshell {args.command}: error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print(f"morphshell {args.command}: interrupted; previous complete results are kept.",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as e:  # a bug: say so, and how to get details
        if getattr(args, "debug", False):
            traceback.print_exc()
        env = environment_message(e, args.command)
        if env is not None:  # the machine, not the program: named, with the fix
            print(env, file=sys.stderr)
            return EXIT_BAD_INPUT
        print(f"morphshell {args.command}: internal error ({type(e).__name__}: {e}). "
              "This is a bug; re-run with --debug for the traceback and report it.",
              file=sys.stderr)
        return EXIT_INTERNAL
    finally:
        warnings.showwarning = shown


__all__ = ["main"]
