"""The pipeline as data: the stages, their options and the options of a build, in one table.

:data:`STAGES` declares the pipeline in the order a build runs it: each :class:`Stage`
names its runner (``"module:function"``, called with a :class:`StageContext`; the runners
are :mod:`pysolver.stages.runners`), the files it reads and writes in the design folder, the
:class:`BuildOptions` fields that switch it on, the outputs a build that skips it may carry
over, and the options (:data:`OPTIONS`) its subcommand takes.  From this table

* :func:`pysolver.build.build` runs the stages (``for stage in STAGES``), checks the inputs
  of the skipped ones and starts their early checks;
* the command line (:mod:`pysolver.cli`) generates a subcommand per stage, its options and
  the ``--help`` text, beside the subcommands of its own table (:mod:`pysolver.cli.table`);
* the studio shows the plan of a *Run*;
* ``docs/for-contributors.md`` shows how adding a stage is one entry here and one module.

This module is light on purpose (the standard library and :mod:`pysolver.params`): the
command line reads it for ``--help`` without loading any stage.  Runners are named, not
imported; :func:`runner` imports one when it runs (``tests/test_architecture.py`` reads the
names and checks them as imports of :mod:`pysolver.build`).
"""

from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..params import DEFAULT_REFINE, PHYSICS_DEFAULT, PROGRAMMING, SIM, UNIT_CELL

# ------------------------------------------------------------------------------------------
# options


@dataclass(frozen=True)
class Option:
    """One command-line argument: its flags and :meth:`argparse.ArgumentParser.add_argument`
    settings.

    Attributes
    ----------
    flags : tuple of str
        ``("--t-end",)``, or ``("dir",)`` for a positional argument.
    help : str
    settings : dict
        ``type``, ``default``, ``choices``, ``metavar``, ``action``, ``nargs``, ``dest``.
    exclusive : str, optional
        Options of a command with the same name here are mutually exclusive.
    """

    flags: tuple
    help: str = ""
    settings: dict = field(default_factory=dict)
    exclusive: str | None = None

    @property
    def dest(self) -> str:
        """The attribute the parsed value lands in (a :class:`BuildOptions` field when the
        option is one)."""
        if "dest" in self.settings:
            return self.settings["dest"]
        long = next((f for f in self.flags if f.startswith("--")), self.flags[0])
        return long.lstrip("-").replace("-", "_")


def opt(*flags: str, help: str = "", exclusive: str | None = None, **settings) -> Option:
    """An :class:`Option` (keyword arguments as for ``add_argument``)."""
    return Option(tuple(flags), help, settings, exclusive)


OPTIONS = {o.dest: o for o in (
    opt("--out", default=None, help="output folder (default: build/<name>)"),
    opt("--vertices", type=int, default=None,
        help="number of stencil vertices N (default: estimated from the area, then searched "
             "to minimise stencil scaling)"),
    opt("--time", default=None, exclusive="landscape",
        help="time landscape: a constant in s, or a Python expression of the target "
             "coordinates x, y, z in mm (e.g. '30 + 0.5*z'); default: the shape's own"),
    opt("--time-file", default=None, metavar="FILE", exclusive="landscape",
        help="time landscape as a CSV of one time (s) per vertex of the input mesh, in file "
             "order (one column, optional header); carried onto the stencil by interpolation, "
             "used as given for a stencil OBJ"),
    opt("--scale", type=float, default=1.0, exclusive="size",
        help="multiply the input mesh coordinates by this factor (e.g. 1000 for metres)"),
    opt("--size", type=float, default=None, metavar="MM", exclusive="size",
        help="scale the input so that its largest bounding-box extent is MM mm (for unitless "
             "meshes)"),
    opt("--flattening", choices=("cetm", "lscm"), default="cetm",
        help="conformal flattening method (default: cetm)"),
    opt("--stencil", "--stencil-order", dest="stencil", action="store_true",
        help="the mesh is a finished stencil: its own triangles are the bases (no remeshing), "
             "its vt (OBJ) the flat layout (else it is flattened); without it a mesh with a "
             "UV map is a target surface, and only morphshell's own stencil.obj is read as a "
             "stencil (a built-in shape is refused)"),
    opt("--min-bumper", type=float, default=None, metavar="MM",
        help="minimal bumper length beyond the base rim, mm (default 0.3, the paper's; 3D "
             "scaling rule)"),
    opt("--min-gap", type=float, default=None, metavar="MM",
        help="minimal flat gap between facing bumper tips, mm (default 0.1; 2D scaling rule)"),
    opt("--max-cell-length", type=float, default=None, metavar="MM",
        help="longest printable unit cell (flat centre distance), mm (default "
             f"{UNIT_CELL.max_cell_length:g})"),
    opt("--material", default=None, help="bracket model file (default: the committed one)"),
    opt("--seed", type=int, default=None, help="CVT remeshing seed (default: searched)"),
    opt("--refine", type=int, default=DEFAULT_REFINE,
        help="K rounds of closing the timing loop: correct t* from the simulation (default "
             f"{DEFAULT_REFINE}, as make's REFINE; 0 = off); up to "
             f"{PROGRAMMING.refine_extra_rounds} more while cells never close"),
    opt("--robust-timing", action="store_true",
        help="program each cell's layers against the per-bracket thickness scatter: the "
             "layer less sensitive to its thickness times the cell, the other closes up to "
             f"{PROGRAMMING.robust_max_lead_s:g} s earlier (lower predicted spread, slightly "
             "larger nominal timing error: "
             "docs/results.md)"),
    opt("--no-program", dest="program", action="store_false",
        help="keep uniform thickness"),
    opt("--no-render", dest="render", action="store_false", help="skip STL rendering"),
    opt("--no-sim", dest="simulate", action="store_false", help="skip simulation and report"),
    opt("--t-end", type=float, default=None,
        help=f"simulated time in water, s (default {SIM.t_end:g})"),
    opt("--dt", type=float, default=None,
        help=f"simulation time step, s (default {SIM.dt:g})"),
    opt("--jobs", type=int, default=None, help="parallel OpenSCAD processes"),
    opt("--renderer", choices=("auto", "openscad", "fast"), default=None,
        help="part renderer: auto (the default: fast once its self-check against OpenSCAD "
             "passes on your scad/, else openscad), openscad (Debian OpenSCAD for every part) "
             "or fast (openscad-evaluator, ~15x faster, no self-check; a part it fails on is "
             "rendered by OpenSCAD)"),
    opt("--solver", choices=("fast", "reference"), default="fast",
        help="simulation linear algebra: fast (default) or reference (the path before the "
             "speed work, kept for comparisons; same results)"),
    opt("--no-resume", dest="resume", action="store_false",
        help="start over, ignore a checkpoint"),
    opt("--physics", default=None, metavar="EFFECTS",
        help="effects beyond the reference simulator, comma-separated: clearance, "
             "bumper-compliance, relaxation, membrane-temperature, gravity, dry-rest, rim, "
             "contact, bracket-bending; 'default' stands for the default set "
             f"({','.join(PHYSICS_DEFAULT.switched_on()).replace('_', '-')}), 'none' for the "
             "reference model, 'all' for every effect (default: default; docs/physics.md)"),
    opt("--thickness-file", default=None, metavar="FILE",
        help="bracket thicknesses the stencil was printed with: CSV, one row per unit cell "
             "(base_a, base_b or face_a, face_b; thickness_top_mm, thickness_bottom_mm or "
             "thickness_plus_normal_mm, thickness_minus_normal_mm); written to cells.csv, so "
             "the folder can be simulated without 'program'"),
)}
"""The options of the pipeline's commands, by :attr:`Option.dest`."""

DESIGN_OPTIONS = ("vertices", "time", "time_file", "scale", "size", "flattening", "stencil",
                  "min_bumper", "min_gap", "max_cell_length")
"""The design stage's options (``--min-bumper``, ``--min-gap``, ``--max-cell-length`` make
:attr:`BuildOptions.params`)."""

PHYSICS_PARAMETERS = (("stretch-to-glue-min", "min"), ("glue-to-water-min", "min"),
                      ("drying-min", "min"), ("water-temp-c", "deg C"), ("lab-temp-c", "deg C"),
                      ("print-density", "g/cm^3"), ("water-density", "g/cm^3"),
                      ("latex-density", "g/cm^3"), ("rim-margin-mm", "mm"), ("rim-stretch", ""))
"""Parameters of ``--physics`` (:class:`pysolver.params.PhysicsOptions`, docs/physics.md)."""

for _name, _unit in PHYSICS_PARAMETERS:
    _o = opt(f"--{_name}", type=float, default=None, help=f"physics parameter ({_unit})")
    OPTIONS[_o.dest] = _o
OPTIONS["face_down"] = opt("--face-down", choices=("bottom", "top"), default=None,
                           help="layer on the tank floor / table (gravity, dry-rest)")
PHYSICS_OPTIONS = ("physics", *(n.replace("-", "_") for n, _ in PHYSICS_PARAMETERS),
                   "face_down")
"""``--physics`` and its parameters; together they make :attr:`BuildOptions.physics`."""


@dataclass(frozen=True)
class BuildOptions:
    """Everything a build (or one stage) is asked to do, besides its source.

    The command line fills it from its options (:data:`OPTIONS`, same names);
    :func:`pysolver.build.build` takes it (or these fields as keywords) and
    :func:`pysolver.build.check_build_options` refuses bad values before any stage runs.

    Attributes
    ----------
    out : path-like, optional
        Output folder (default ``build/<name>``).
    vertices, time, time_file, scale, size, flattening, stencil, seed
        Design options, see :func:`pysolver.design.run_design`.
    thickness_file : path-like, optional
        Bracket thicknesses the stencil was printed with (``morphshell design
        --thickness-file``, :mod:`pysolver.design.thickness_file`).
    params : UnitCell, optional
        Unit cell with the user's tolerances (:func:`pysolver.design.unit_cell_options`);
        default :data:`pysolver.params.UNIT_CELL`.  Later stages read it from ``design.json``.
    material : path-like, optional
        Bracket model file (default: the committed model).
    refine : int
        Rounds of timing correction from the simulation (0 = none).
    robust_timing : bool
        Program the layers against the per-bracket thickness scatter
        (:func:`pysolver.temporal.program.robust_layers`).
    program, render, simulate : bool
        Run the temporal programming, the rendering, and the simulation and report.
    t_end, dt : float, s, optional
        Simulated time in water and time step (default :data:`pysolver.params.SIM`).
    solver : {"fast", "reference"}
        Linear-algebra path of the simulations (same results).
    resume : bool
        A simulation continues from its checkpoint when it matches.
    physics : PhysicsOptions, optional
        Effects beyond the reference simulator (the simulate and program subcommands; a
        build switches contact on by itself when parts pass through each other).
    jobs : int, optional
        Parallel part renderers.
    renderer : {"openscad", "fast", "auto"}, optional
        Part renderer (default :data:`pysolver.render.DEFAULT_RENDERER`).
    progress : bool
        Progress lines on stderr (:mod:`pysolver.core.progress`).
    keep_failed : bool
        Keep the staging folder of a build whose stage fails (``--debug``).
    """

    out: Any = None
    vertices: int | None = None
    time: Any = None
    time_file: Any = None
    scale: float = 1.0
    size: float | None = None
    flattening: str = "cetm"
    stencil: bool = False
    seed: int | None = None
    thickness_file: Any = None
    params: Any = None
    material: Any = None
    refine: int = DEFAULT_REFINE
    robust_timing: bool = False
    program: bool = True
    render: bool = True
    simulate: bool = True
    t_end: float | None = None
    dt: float | None = None
    solver: str = "fast"
    resume: bool = True
    physics: Any = None
    jobs: int | None = None
    renderer: str | None = None
    progress: bool = True
    keep_failed: bool = False

    def given(self, *names: str) -> dict:
        """``{name: value}`` of the named fields that are not None (a stage's keyword
        arguments whose defaults are the stage's own)."""
        return {n: getattr(self, n) for n in names if getattr(self, n) is not None}

    def replace(self, **changes) -> BuildOptions:
        """A copy with ``changes`` (unknown names: ``TypeError``)."""
        return dataclasses.replace(self, **changes)


# ------------------------------------------------------------------------------------------
# stages


@dataclass
class StageContext:
    """What a stage runner gets: where to work and what it was asked.

    Attributes
    ----------
    folder : Path
        The design folder the stage works in (a build's staging folder).
    options : BuildOptions
    name : str
        The design's name (progress lines).
    source : str, optional
        The build's input (the design stage).
    build : dict, optional
        The build's ``summary.json`` being filled; None when the stage runs alone (its
        subcommand).
    substage : callable, optional
        ``substage(key, fn, *a, **kw)``: run a step of the stage as its own entry of the
        build's summary (timing, progress line); None outside a build.
    fit_landscape : bool
        The program stage maps the landscape onto the achievable times when it clamps
        more than ``Programming.fit_clamped_fraction`` of the cells, or stretches it when
        its order would not survive a print's timing scatter
        (``Programming.fit_order_spearman``; a shape's own landscape in a build; a user's
        landscape is only checked).
    physics : PhysicsOptions, optional
        Physics the build switched on along the way (contact), for the later stages.
    """

    folder: Path
    options: BuildOptions
    name: str = ""
    source: str | None = None
    build: dict | None = None
    substage: Any = None
    fit_landscape: bool = False
    physics: Any = None

    @property
    def progress(self) -> bool:
        return self.options.progress


@dataclass(frozen=True)
class Stage:
    """One stage of the pipeline.

    Attributes
    ----------
    name : str
        Its key in ``summary.json`` and its subcommand.
    run : str
        ``"module:function"``; ``function(ctx: StageContext) -> dict`` (its summary).
    help : str
        One line: the subcommand's help and its line in ``morphshell --help``.
    reads, writes : tuple of str
        Files and folders of the design folder (``docs/design-folder.md``).
    options : tuple of str
        :data:`OPTIONS` its subcommand takes.
    needs : tuple of str
        :class:`BuildOptions` fields that must all be true for a build to run it.
    keeps : tuple of str
        Folders it writes that a build which skips it carries over while what they were
        computed from (the tables and ``depends``) is unchanged.
    depends : tuple of str
        Besides the tables, what its outputs depend on: :class:`BuildOptions` fields, or
        ``"scad"`` (the SCAD library) and ``"material"`` (the model file's content).
    prepare : str, optional
        ``"module:function"``, ``function(folder, options)``, started when a build begins
        (early checks that run while the first stages work).
    command : bool
        Has a subcommand on a design folder (``morphshell <name> DIR``).
    """

    name: str
    run: str
    help: str
    reads: tuple = ()
    writes: tuple = ()
    options: tuple = ()
    needs: tuple = ()
    keeps: tuple = ()
    depends: tuple = ()
    prepare: str | None = None
    command: bool = True

    def wanted(self, options: BuildOptions) -> bool:
        """Whether a build with ``options`` runs this stage."""
        return all(getattr(options, n) for n in self.needs)


TABLES = ("stencil.obj", "bases.csv", "cells.csv", "bumpers.csv", "time_landscape.csv",
          "support_frame.csv", "model.npz", "design.json")
"""The design stage's tables: the contract every later stage reads."""

STAGES = (
    Stage("design", "pysolver.stages.runners:design",
          "target surface -> stencil -> flat layout -> the design tables",
          reads=("<input mesh or built-in shape>",), writes=TABLES + ("design_*.png",),
          options=("out",) + DESIGN_OPTIONS + ("thickness_file",)),
    Stage("program", "pysolver.stages.runners:program",
          "bracket thicknesses from the time landscape (temporal programming)",
          reads=TABLES, writes=("cells.csv", "time_landscape.csv", "temporal.json",
                                "temporal_feasibility.png"),
          options=("material", "robust_timing") + PHYSICS_OPTIONS, needs=("program",)),
    Stage("simulate", "pysolver.stages.runners:simulate",
          "quasi-static morphing simulation (in a build, again with barrier contact when "
          "far parts pass through each other)",
          reads=TABLES, writes=("sim/frames.npz", "sim/summary.json"),
          options=("t_end", "dt", "material", "resume", "solver") + PHYSICS_OPTIONS,
          needs=("simulate",), keeps=("sim",), depends=("material", "t_end", "dt")),
    Stage("refine", "pysolver.stages.runners:refine",
          "close the timing loop: correct the thicknesses from the simulated completion "
          "times and simulate again",
          reads=TABLES + ("temporal.json", "sim/frames.npz"),
          writes=("cells.csv", "sim/frames.npz", "sim/refine.json"),
          needs=("simulate", "program", "refine"), command=False),
    Stage("render", "pysolver.stages.runners:render",
          "per-part rendering (OpenSCAD or its fast evaluator) and union into the STLs",
          reads=TABLES + ("scad/*.scad (the library)",), writes=("scad/", "stl/"),
          options=("jobs", "renderer"), needs=("render",), keeps=("scad", "stl"),
          depends=("scad",), prepare="pysolver.stages.runners:start_render_check"),
    Stage("report", "pysolver.stages.runners:report",
          "simulation check report: verdict, pictures, 3D viewer, fabrication sheet",
          reads=TABLES + ("sim/frames.npz", "stl/"), writes=("report/",),
          needs=("simulate",), keeps=("report",), depends=("material", "t_end", "dt"),
          prepare="pysolver.stages.runners:start_report_probe"),
)
"""The pipeline, in the order a build runs it."""


def stage(name: str) -> Stage:
    """The stage called ``name``."""
    for s in STAGES:
        if s.name == name:
            return s
    raise KeyError(name)


def runner(ref: str):
    """The function a ``"module:function"`` reference names (imported now)."""
    module, _, name = ref.partition(":")
    return getattr(importlib.import_module(module), name)


__all__ = ["Option", "opt", "OPTIONS", "DESIGN_OPTIONS", "PHYSICS_OPTIONS", "BuildOptions",
           "StageContext", "Stage", "STAGES", "TABLES", "stage", "runner"]
