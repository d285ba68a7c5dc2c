"""The command line's table: every subcommand, its arguments and its help.

One subcommand per stage of :data:`pysolver.stages.STAGES` that has one
(:func:`stage_command`: ``morphshell <stage> DIR``, the design stage ``morphshell design
SHAPE``), :data:`BUILD` for the whole pipeline, and :data:`TOOLS`, the subcommands that are
not a stage.  Each :class:`Command` names the function that runs it
(``"pysolver.cli.commands:function"``, imported when it runs); an argument is an
:class:`~pysolver.stages.Option`, or the name of one of the pipeline's
:data:`~pysolver.stages.OPTIONS`.  :mod:`pysolver.cli.parser` makes the parser and the
``--help`` text from this table.

Like :mod:`pysolver.stages`, this module is light on purpose: ``morphshell --help`` reads it
without loading any stage.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..params import TESTS, TOLERANCE_RUN, UNCERTAINTY
from ..stages import DESIGN_OPTIONS, OPTIONS, STAGES, Option, Stage, opt


@dataclass(frozen=True)
class Command:
    """A subcommand that is not one stage on a design folder.

    Attributes
    ----------
    name, help, summary : str
        The subcommand, its help, and its line in ``morphshell --help``.
    run : str
        ``"module:function"``, ``function(args: argparse.Namespace) -> int`` (exit code).
    arguments : tuple of Option or str
        Its arguments; a str names an entry of :data:`~pysolver.stages.OPTIONS`.
    """

    name: str
    help: str
    summary: str
    run: str
    arguments: tuple = ()


DASK_OPTIONS = (
    opt("--scheduler", default=None,
        help="address of a running Dask scheduler (tls://host:8786; plain tcp:// is warned "
             "about; credentials from Dask's configuration, see docs/tolerance.md); default: a "
             "local cluster sized to this machine, on 127.0.0.1 with TLS"),
    opt("--workers", type=int, default=None,
        help="worker processes of the local cluster (default: one per core)"),
    opt("--dashboard", action="store_true",
        help="serve the local cluster's Dask dashboard (on 127.0.0.1 only)"),
)
DIR = opt("dir", help="design folder (e.g. build/petal)")

BUILD = Command(
    "build", "run the whole pipeline for a shape or a mesh file",
    "the whole pipeline: " + " -> ".join(s.name for s in STAGES), "pysolver.cli.commands:build",
    (opt("shape", help="built-in shape name (see 'shapes') or a mesh/stencil file"), "out",
     *DESIGN_OPTIONS, "material", "seed", "refine", "program", "robust_timing", "render",
     "simulate", "t_end", "dt", "jobs", "renderer", "solver"))
"""``morphshell build``: every stage of :data:`STAGES` that its options ask for."""

TOOLS = (
    Command("compare-scan", "compare scanned marker dots with the simulation",
            "compare a 3D scan of the printed shell's marker dots with the simulation",
            "pysolver.cli.commands:compare_scan",
            (DIR, opt("scan", help="point set: OBJ vertices, PLY, or CSV with x y z columns "
                                   "(mm)"),
             opt("--layer", choices=("auto", "top", "bottom"), default="auto",
                 help="layer whose markers were scanned (default: the better fitting one)"),
             opt("--state", choices=("auto", "final", "rest"), default="auto",
                 help="compare the last frame in water (final) or the dry resting shape "
                      "(rest, from --physics ...,dry-rest); default: rest when simulated"),
             opt("--gate-mm", type=float, default=None, metavar="MM",
                 help="leave out matches farther than MM (outlier dots); default: every dot "
                      "is matched, the printed shells' procedure"),
             opt("--out", default=None,
                 help="folder of scan_<name>.json and .png (default DIR/scan_report)"))),
    Command("mechtest", "virtual mechanical tests of the morphed, dried shell (SI Note 6)",
            "stretch, bend, shear, compress the morphed shell as SI Note 6's tester did",
            "pysolver.cli.commands:mechtest",
            (DIR, opt("--test", action="append", choices=TESTS, default=None,
                      help="a test to run (repeat for several; default: all four)"),
             opt("--axis-deg", type=float, default=90.0, metavar="DEG",
                 help="in-plane direction of the load, degrees from the flat x axis "
                      "(default 90: along y, the mechtest shape's length)"),
             opt("--material", default=None,
                 help="bracket model file (default: the committed one)"))),
    Command("fit-material", "fit the bracket model from measurements",
            "fit the bracket material model from tensile-test measurements",
            "pysolver.cli.commands:fit_material",
            (opt("--data", default=None,
                 help="measurement folder (default: data/material-measurements, the paper's "
                      "tests shipped with the project)"),
             opt("--out", default=None,
                 help="model file to write (default: the committed model when fitting the "
                      "shipped data, else build/material/<data folder>.json)"),
             opt("--report", default=None,
                 help="fit report folder (default: build/material[/<data folder>])"),
             opt("--compare-to", default=None,
                 help="plot the new model against this one (default: the committed model)"))),
    Command("fit-membrane", "fit the linearised membrane model (F_mem)",
            "fit the linearised membrane model from FEM samples",
            "pysolver.cli.commands:fit_membrane",
            (opt("--out", default=None, help="model file to write"),
             opt("--report", default=None, help="fit report folder"))),
    Command("specimens", "printable unit-cell test specimens",
            "printable unit-cell test specimens from the same SCAD modules",
            "pysolver.cli.commands:specimens",
            (opt("--out", default="build/specimens", help="output folder"), "jobs")),
    Command("coupon", "printable timing coupon: unit cells to time in the bath",
            "printable timing coupon (a strip of labelled unit cells from the same SCAD "
            "modules) and its coupon.csv; see docs/coupon.md",
            "pysolver.cli.commands:coupon",
            (opt("--out", default="build/coupon", help="output folder"),
             opt("--material", default=None, help="bracket model file (default: the "
                                                   "committed one)"), "jobs", "renderer")),
    Command("calibrate-time", "fit the print's factors to a timed coupon",
            "fit the bracket compliance (and membrane modulus) to a timed coupon.csv and "
            "write a material file for --material / MATERIAL=",
            "pysolver.cli.commands:calibrate_time",
            (opt("coupon_csv", metavar="COUPON_CSV", help="coupon.csv with closing_time_s "
                                                          "filled in (docs/coupon.md)"),
             opt("--out", default=None, help="material file to write (default "
                                             "build/material/coupon-calibrated.json)"),
             opt("--material", default=None, help="bracket model the coupon is fitted "
                                                   "against (default: the committed one)"))),
    Command("shapes", "list the built-in shapes", "list the built-in shapes",
            "pysolver.cli.commands:shapes"),
    Command("studio", "browser front end: paint the time landscape, build it again, compare",
            "browser front end: paint the time landscape, build it again, compare builds",
            "pysolver.cli.commands:studio",
            (opt("dirs", nargs="*", metavar="DIR",
                 help="build folders, shown side by side (default: every build/<name>)"),
             opt("--port", type=int, default=0, help="port on 127.0.0.1 (default: any free)"),
             opt("--no-browser", action="store_true", help="do not open a browser"))),
    Command("tolerance", "Monte Carlo tolerance analysis of a design folder (Dask)",
            "Monte Carlo over print and material scatter: P(PASS), spreads (on Dask)",
            "pysolver.cli.commands:tolerance",
            (opt("dir", help="programmed design folder (e.g. build/petal)"),
             opt("--samples", type=int, default=TOLERANCE_RUN.samples,
                 help=f"Monte Carlo samples (default {TOLERANCE_RUN.samples})"),
             opt("--seed", type=int, default=TOLERANCE_RUN.seed,
                 help="seed of the draws (fixed: a rerun gives the same numbers)"),
             opt("--thickness-sd", type=float, default=UNCERTAINTY.thickness_sd,
                 help=f"bracket thickness sd, mm (default {UNCERTAINTY.thickness_sd})"),
             opt("--stretch", type=float, default=UNCERTAINTY.stretch_mean,
                 help=f"membrane pre-stretch mean (default {UNCERTAINTY.stretch_mean})"),
             opt("--stretch-sd", type=float, default=UNCERTAINTY.stretch_sd,
                 help=f"pre-stretch sd (default {UNCERTAINTY.stretch_sd})"),
             opt("--modulus-sd", type=float, default=UNCERTAINTY.modulus_rel_sd,
                 help="relative sd of the membrane modulus (default "
                      f"{UNCERTAINTY.modulus_rel_sd})"),
             opt("--material-sd", type=float, default=UNCERTAINTY.material_sd,
                 help="sd of ln(bracket compliance factor) (default: from the material fit "
                      "residuals; 0 = off)"),
             opt("--relaxation", action="store_true",
                 help="also draw membrane stress relaxation from the measured curve"),
             opt("--coupon", action="store_true",
                 help="also simulate the timing coupon workflow: each sample's coupon fitted, "
                      "its shell programmed again and simulated (docs/coupon.md)"),
             opt("--time-tol", type=float, default=TOLERANCE_RUN.time_tol_s,
                 help="a cell is on time within this of t*, s (default "
                      f"{TOLERANCE_RUN.time_tol_s:g})"),
             opt("--sensitivity", type=int, default=None,
                 help="one-at-a-time runs per factor (default "
                      f"min({TOLERANCE_RUN.sensitivity_samples}, samples); 0 = none)"),
             "t_end", "dt", opt("--material", default=None, help="bracket model file"),
             opt("--out", default=None, help="output folder (default DIR/tolerance)"),
             *DASK_OPTIONS)),
    Command("sweep", "build the design variants of a TOML spec and tabulate them (Dask)",
            "build a grid or list of design variants from a TOML spec (on Dask)",
            "pysolver.cli.commands:sweep",
            (opt("spec", help="sweep spec (TOML; see docs/tolerance.md)"),
             opt("--out", default=None, help="output folder (default build/sweep-<name>)"),
             *DASK_OPTIONS)),
)
"""The subcommands besides ``build`` and the stages."""


def stage_command(s: Stage) -> Command:
    """The subcommand of a stage: ``morphshell <stage> DIR [options]`` (the design stage
    makes a new folder from a shape: ``morphshell design SHAPE [--out DIR]``)."""
    if s.name == "design":
        return Command("design", "design the flat layout only", s.help,
                       "pysolver.cli.commands:design",
                       (opt("shape", help="built-in shape name (see 'shapes') or a "
                                          "mesh/stencil file"), *s.options))
    return Command(s.name, s.help, s.help, "pysolver.cli.commands:stage", (DIR, *s.options))


def commands() -> tuple[Command, ...]:
    """Every subcommand, in the order of ``morphshell --help``."""
    return (BUILD, *(stage_command(s) for s in STAGES if s.command), *TOOLS)


def argument(a) -> Option:
    """An argument of a :class:`Command` as an :class:`Option`."""
    return OPTIONS[a] if isinstance(a, str) else a


__all__ = ["Command", "DASK_OPTIONS", "DIR", "BUILD", "TOOLS", "stage_command", "commands",
           "argument"]
