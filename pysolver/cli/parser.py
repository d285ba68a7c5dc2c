"""The parser of ``morphshell``, generated from the tables.

Every subcommand, its options and the ``--help`` epilog come from
:data:`pysolver.stages.STAGES` (one subcommand per stage on a design folder) and the command
line's own table (:mod:`pysolver.cli.table`: ``build`` and the tools); a parsed
subcommand carries the ``"module:function"`` name of what runs it (``args.run``).
"""

from __future__ import annotations

import argparse

from ..stages import STAGES
from .table import TOOLS, argument, commands


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


def make_parser() -> argparse.ArgumentParser:
    """The parser of ``morphshell``: ``--debug`` and ``--quiet`` (before or after the
    subcommand) and one subparser per subcommand of :func:`pysolver.cli.table.commands`,
    whose ``run`` default names the function that runs it."""
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


__all__ = ["stages_help", "make_parser"]
