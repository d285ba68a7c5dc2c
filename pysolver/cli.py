"""``morphshell``: the command line, one subcommand per stage and tool.

The subcommands, their options and the ``--help`` text are generated from the tables of
:mod:`pysolver.stages` (:data:`~pysolver.stages.STAGES`: one subcommand per stage on a
design folder; ``build``; :data:`~pysolver.stages.TOOLS`); what a subcommand does is the
function its table entry names (:mod:`pysolver.commands`), imported when it runs so that
``morphshell --help`` is instant.  Errors the project raises on purpose
(:class:`pysolver.errors.MorphshellError`) are printed without a traceback (``--debug``
shows it) and exit with a code that tells bad input (2) from a failed check (3) and an
internal error (1).
"""

from __future__ import annotations

import argparse
import errno
import sys
import traceback
import warnings

from .errors import (
    EXIT_BAD_INPUT,
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_OK,
    MorphshellError,
)
from .stages import STAGES, TOOLS, argument, commands, runner


def stages_help() -> str:
    """The epilog of ``morphshell --help``, from the tables: the pipeline's stages in the
    order ``build`` runs them, with the files each writes, then the tools."""
    lines = ["pipeline: 'morphshell build' runs these stages in order; each reads and writes "
             "plain files",
             "in a design folder (build/<shape>/), and each but refine is also a subcommand:"]
    for s in STAGES:
        lines.append(f"  {s.name:<13s} {s.help}" + ("" if s.command else " (build only)"))
        lines.append(f"  {'':<13s}   writes {', '.join(s.writes)}")
    lines += ["tools:"] + [f"  {c.name:<13s} {c.summary}" for c in TOOLS]
    return "\n".join(lines) + "\n"


def _add_arguments(p: argparse.ArgumentParser, arguments) -> None:
    """The arguments of one subcommand (mutually exclusive ones in their group)."""
    groups: dict = {}
    for a in arguments:
        o = argument(a)
        target = p
        if o.exclusive:
            if o.exclusive not in groups:
                groups[o.exclusive] = p.add_mutually_exclusive_group()
            target = groups[o.exclusive]
        target.add_argument(*o.flags, help=o.help or None, **o.settings)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="morphshell",
        description="Design flat-printed shells that morph in hot water into a chosen 3D shape "
                    "at chosen times, and check the morph by simulation before printing.",
        epilog=stages_help(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    ap.add_argument("--quiet", action="store_true", help="no progress output")
    # the same flags after the subcommand ('morphshell build petal --debug'); SUPPRESS keeps
    # a flag given before the subcommand from being reset by the subparser's default
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                        help="show tracebacks of errors")
    common.add_argument("--quiet", action="store_true", default=argparse.SUPPRESS,
                        help="no progress output")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    for c in commands():
        p = sub.add_parser(c.name, parents=[common], help=c.help)
        p.set_defaults(run=c.run)
        _add_arguments(p, c.arguments)
    return ap


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


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``morphshell`` console script."""
    ap = _parser()
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


if __name__ == "__main__":
    sys.exit(main())
