"""``morphshell``: the command line, one subcommand per stage.

Each subcommand is a thin wrapper around one stage function; the heavy imports
happen inside the subcommand so ``morphshell --help`` is instant.  Errors the
project raises on purpose (:class:`pysolver.errors.MorphshellError`) are printed
without a traceback (``--debug`` shows it) and exit with a code that tells bad
input (2) from a failed check (3) and an internal error (1).
"""

from __future__ import annotations

import argparse
import dataclasses
import errno
import functools
import sys
import time
import traceback
import warnings
from pathlib import Path

from .atomic import STAMP_NAME, claim_output, claim_output_file, write_stamp
from .errors import (
    EXIT_BAD_INPUT,
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_OK,
    MorphshellError,
)
from .params import (
    DEFAULT_REFINE,
    MODEL_LIMITS,
    PHYSICS_DEFAULT,
    TOLERANCE_RUN,
    UNCERTAINTY,
    UNIT_CELL,
)

STAGES_HELP = """\
stages (each reads and writes plain files in a design folder, build/<shape>/):
  build         the whole pipeline: design -> program -> simulate -> render -> report
  design        target surface -> stencil -> flat layout -> bases.csv, cells.csv, bumpers.csv
  program       bracket thicknesses from the time landscape (temporal programming)
  render        per-part OpenSCAD rendering and union -> stl/*.stl
  simulate      quasi-static morphing simulation -> sim/frames.npz
  report        simulation check report (verdict, pictures, animation) -> report/
  compare-scan  compare a 3D scan of the printed shell's marker dots with the simulation
  fit-material  fit the bracket material model from tensile-test measurements
  fit-membrane  fit the linearised membrane model from FEM samples
  specimens     printable unit-cell test specimens from the same SCAD modules
  shapes        list the built-in shapes
  studio        browser front end: morph viewer, time-landscape editor, builds side by side
  tolerance     Monte Carlo over print and material scatter: P(PASS), spreads (on Dask)
  sweep         build a grid or list of design variants from a TOML spec (on Dask)
"""


def _add_design_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--vertices", type=int, default=None,
                   help="number of stencil vertices N (default: estimated from the area, then "
                        "searched to minimise stencil scaling)")
    tl = p.add_mutually_exclusive_group()
    tl.add_argument("--time", default=None,
                    help="time landscape: a constant in s, or a Python expression of the "
                         "target coordinates x, y, z in mm (e.g. '30 + 0.5*z'); default: the "
                         "shape's own")
    tl.add_argument("--time-file", default=None, metavar="FILE",
                    help="time landscape as a CSV of one time (s) per vertex of the input mesh, "
                         "in file order (one column, optional header); carried onto the "
                         "stencil by interpolation, used as given for a stencil OBJ")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--scale", type=float, default=1.0,
                      help="multiply the input mesh coordinates by this factor (e.g. 1000 for "
                           "metres)")
    size.add_argument("--size", type=float, default=None, metavar="MM",
                      help="scale the input so that its largest bounding-box extent is MM mm "
                           "(for unitless meshes)")
    p.add_argument("--flattening", choices=("cetm", "lscm"), default="cetm",
                   help="conformal flattening method (default: cetm)")
    p.add_argument("--stencil", action="store_true",
                   help="the input is a finished stencil OBJ (v = target positions, vt = flat "
                        "layout, one vt per v): used as given, vertex and face order kept "
                        "(refused if it is not one)")
    p.add_argument("--stencil-order", action="store_true",
                   help="treat an OBJ with vt as a finished stencil: keep vertex/face order")
    p.add_argument("--min-bumper", type=float, default=None, metavar="MM",
                   help="minimal bumper length beyond the base rim, mm (default 0.3, the "
                        "paper's; 3D scaling rule)")
    p.add_argument("--min-gap", type=float, default=None, metavar="MM",
                   help="minimal flat gap between facing bumper tips, mm (default 0.1; 2D "
                        "scaling rule)")
    p.add_argument("--max-cell-length", type=float, default=None, metavar="MM",
                   help="longest printable unit cell (flat centre distance), mm (default "
                        f"{UNIT_CELL.max_cell_length:g})")


def _unit_cell(args: argparse.Namespace):
    """The design's unit cell from --min-bumper, --min-gap, --max-cell-length (checked)."""
    from .design import unit_cell_options  # lazy: the stage loads when its subcommand runs

    return unit_cell_options(min_bumper=args.min_bumper, min_gap=args.min_gap,
                             max_cell_length=args.max_cell_length)


def _add_renderer_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--renderer", choices=("auto", "openscad", "fast"), default=None,
                   help="part renderer: auto (the default: fast once its self-check "
                        "against OpenSCAD passes on your scad/, else openscad), openscad "
                        "(Debian OpenSCAD for every part) or fast (openscad-evaluator, ~15x "
                        "faster, no self-check; a part it fails on is rendered by OpenSCAD)")


def _add_solver_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--solver", choices=("fast", "reference"), default="fast",
                   help="simulation linear algebra: fast (default) or reference (the path "
                        "before the speed work, kept for comparisons; same results)")


def _add_dask_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scheduler", default=None,
                   help="address of a running Dask scheduler (tcp://host:8786); default: a "
                        "local cluster sized to this machine")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes of the local cluster (default: one per core)")


def _add_physics_options(p: argparse.ArgumentParser) -> None:
    """``--physics`` and its parameters (pysolver.params.PhysicsOptions, docs/physics.md)."""
    p.add_argument("--physics", default=None, metavar="EFFECTS",
                   help="effects beyond the reference simulator, comma-separated: clearance, "
                        "relaxation, membrane-temperature, gravity, dry-rest, rim, contact, "
                        "bracket-bending; 'default' stands for the default set "
                        f"({','.join(PHYSICS_DEFAULT.switched_on()).replace('_', '-')}), "
                        "'none' for the reference model, 'all' for every effect "
                        "(default: default; docs/physics.md)")
    for name, unit in (("stretch-to-glue-min", "min"), ("glue-to-water-min", "min"),
                       ("drying-min", "min"), ("water-temp-c", "deg C"),
                       ("lab-temp-c", "deg C"),
                       ("print-density", "g/cm^3"), ("water-density", "g/cm^3"),
                       ("latex-density", "g/cm^3"), ("rim-margin-mm", "mm"),
                       ("rim-stretch", "")):
        p.add_argument(f"--{name}", type=float, default=None, help=f"physics parameter ({unit})")
    p.add_argument("--face-down", choices=("bottom", "top"), default=None,
                   help="layer on the tank floor / table (gravity, dry-rest)")


def _physics_from_args(args: argparse.Namespace):
    from sim.model.physics import parse_physics  # lazy: the stage loads when its subcommand runs

    keys = ("stretch_to_glue_min", "glue_to_water_min", "drying_min", "water_temp_c",
            "lab_temp_c", "print_density", "water_density", "latex_density", "rim_margin_mm",
            "rim_stretch", "face_down")
    return parse_physics(args.physics, **{k: getattr(args, k) for k in keys})


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="morphshell",
        description="Design flat-printed shells that morph in hot water into a chosen 3D shape "
                    "at chosen times, and check the morph by simulation before printing.",
        epilog=STAGES_HELP,
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
    add = functools.partial(sub.add_parser, parents=[common])

    p = add("build", help="run the whole pipeline for a shape or a mesh file")
    p.add_argument("shape", help="built-in shape name (see 'shapes') or a mesh/stencil file")
    p.add_argument("--out", default=None, help="output folder (default: build/<name>)")
    _add_design_options(p)
    p.add_argument("--material", default=None, help="bracket model file (default: committed one)")
    p.add_argument("--seed", type=int, default=None,
                   help="CVT remeshing seed (default: searched)")
    p.add_argument("--refine", type=int, default=DEFAULT_REFINE,
                   help="K rounds of closing the timing loop: correct t* from the simulation "
                        f"(default {DEFAULT_REFINE}, as make's REFINE; 0 = off); up to "
                        f"{MODEL_LIMITS.refine_extra_rounds} more while cells never close")
    p.add_argument("--no-program", action="store_true", help="keep uniform thickness")
    p.add_argument("--no-render", action="store_true", help="skip STL rendering")
    p.add_argument("--no-sim", action="store_true", help="skip simulation and report")
    p.add_argument("--t-end", type=float, default=None, help="simulated time in water, s")
    p.add_argument("--dt", type=float, default=None, help="simulation time step, s")
    p.add_argument("--jobs", type=int, default=None, help="parallel OpenSCAD processes")
    _add_renderer_option(p)
    _add_solver_option(p)

    p = add("design", help="design the flat layout only")
    p.add_argument("shape")
    p.add_argument("--out", default=None)
    _add_design_options(p)
    p.add_argument("--thickness-file", default=None, metavar="FILE",
                   help="bracket thicknesses the stencil was printed with: CSV, one row per "
                        "unit cell (base_a, base_b or face_a, face_b; thickness_top_mm, "
                        "thickness_bottom_mm or thickness_plus_normal_mm, "
                        "thickness_minus_normal_mm); written to cells.csv, so the folder "
                        "can be simulated without 'program'")

    p = add("program", help="bracket thicknesses from the time landscape")
    p.add_argument("dir", help="design folder")
    p.add_argument("--material", default=None)
    _add_physics_options(p)

    p = add("render", help="render the STLs of a design folder")
    p.add_argument("dir")
    p.add_argument("--jobs", type=int, default=None)
    _add_renderer_option(p)

    p = add("simulate", help="simulate the morph of a design folder")
    p.add_argument("dir")
    p.add_argument("--t-end", type=float, default=None)
    p.add_argument("--dt", type=float, default=None, help="time step, s (default 0.5)")
    p.add_argument("--material", default=None)
    p.add_argument("--no-resume", action="store_true", help="start over, ignore a checkpoint")
    _add_physics_options(p)
    _add_solver_option(p)

    p = add("report", help="simulation check report of a design folder")
    p.add_argument("dir")

    p = add("compare-scan", help="compare scanned marker dots with the simulation")
    p.add_argument("dir")
    p.add_argument("scan", help="point set: OBJ vertices, PLY, or CSV with x y z columns (mm)")
    p.add_argument("--layer", choices=("auto", "top", "bottom"), default="auto",
                   help="layer whose markers were scanned (default: the better fitting one)")
    p.add_argument("--state", choices=("auto", "final", "rest"), default="auto",
                   help="compare the last frame in water (final) or the dry resting shape "
                        "(rest, from --physics ...,dry-rest); default: rest when simulated")
    p.add_argument("--gate-mm", type=float, default=None, metavar="MM",
                   help="leave out matches farther than MM (outlier dots); default: every "
                        "dot is matched, the printed shells' procedure")
    p.add_argument("--out", default=None,
                   help="folder of scan_<name>.json and .png (default DIR/scan_report)")

    p = add("fit-material", help="fit the bracket model from measurements")
    p.add_argument("--data", default=None,
                   help="measurement folder (default: data/material-measurements, the "
                        "paper's tests shipped with the project)")
    p.add_argument("--out", default=None,
                   help="model file to write (default: the committed model when fitting the "
                        "shipped data, else build/material/<data folder>.json)")
    p.add_argument("--report", default=None,
                   help="fit report folder (default: build/material[/<data folder>])")
    p.add_argument("--compare-to", default=None,
                   help="plot the new model against this one (default: the committed model)")

    p = add("fit-membrane", help="fit the linearised membrane model (F_mem)")
    p.add_argument("--out", default=None)
    p.add_argument("--report", default=None)

    p = add("specimens", help="printable unit-cell test specimens")
    p.add_argument("--out", default="build/specimens")
    p.add_argument("--jobs", type=int, default=None)

    add("shapes", help="list the built-in shapes")

    p = add("studio", help="browser front end: morph viewer, time-landscape editor")
    p.add_argument("dirs", nargs="*", metavar="DIR",
                   help="build folders, shown side by side (default: every build/<name>)")
    p.add_argument("--port", type=int, default=0, help="port on 127.0.0.1 (default: any free)")
    p.add_argument("--no-browser", action="store_true", help="do not open a browser")
    p = add("tolerance", help="Monte Carlo tolerance analysis of a design folder (Dask)")
    p.add_argument("dir", help="programmed design folder (e.g. build/petal)")
    p.add_argument("--samples", type=int, default=TOLERANCE_RUN.samples,
                   help=f"Monte Carlo samples (default {TOLERANCE_RUN.samples})")
    p.add_argument("--seed", type=int, default=TOLERANCE_RUN.seed,
                   help="seed of the draws (fixed: a rerun gives the same numbers)")
    p.add_argument("--thickness-sd", type=float, default=UNCERTAINTY.thickness_sd,
                   help=f"bracket thickness sd, mm (default {UNCERTAINTY.thickness_sd})")
    p.add_argument("--stretch", type=float, default=UNCERTAINTY.stretch_mean,
                   help=f"membrane pre-stretch mean (default {UNCERTAINTY.stretch_mean})")
    p.add_argument("--stretch-sd", type=float, default=UNCERTAINTY.stretch_sd,
                   help=f"pre-stretch sd (default {UNCERTAINTY.stretch_sd})")
    p.add_argument("--modulus-sd", type=float, default=UNCERTAINTY.modulus_rel_sd,
                   help="relative sd of the membrane modulus (default "
                        f"{UNCERTAINTY.modulus_rel_sd})")
    p.add_argument("--material-sd", type=float, default=UNCERTAINTY.material_sd,
                   help="sd of ln(bracket compliance factor) (default: from the material "
                        "fit residuals; 0 = off)")
    p.add_argument("--relaxation", action="store_true",
                   help="also draw membrane stress relaxation from the measured curve")
    p.add_argument("--time-tol", type=float, default=TOLERANCE_RUN.time_tol_s,
                   help="a cell is on time within this of t*, s (default "
                        f"{TOLERANCE_RUN.time_tol_s:g})")
    p.add_argument("--sensitivity", type=int, default=None,
                   help="one-at-a-time runs per factor (default "
                        f"min({TOLERANCE_RUN.sensitivity_samples}, samples); 0 = none)")
    p.add_argument("--t-end", type=float, default=None, help="simulated time in water, s")
    p.add_argument("--dt", type=float, default=None, help="time step, s (default 0.5)")
    p.add_argument("--material", default=None, help="bracket model file")
    p.add_argument("--out", default=None, help="output folder (default DIR/tolerance)")
    _add_dask_options(p)

    p = add("sweep", help="build the design variants of a TOML spec and tabulate them (Dask)")
    p.add_argument("spec", help="sweep spec (TOML; see docs/tolerance.md)")
    p.add_argument("--out", default=None, help="output folder (default build/sweep-<name>)")
    _add_dask_options(p)
    return ap


def _design_dir(arg: str) -> Path:
    """A stage's design folder argument, absolute (stages run external tools elsewhere)."""
    return Path(arg).absolute()


def _run(args: argparse.Namespace) -> int:
    progress = not getattr(args, "quiet", False)
    if hasattr(args, "dir"):
        args.dir = _design_dir(args.dir)
        t0 = time.time()
        try:
            return _run_stage(args, progress)
        finally:  # files this stage wrote into a stamped design folder are morphshell's
            if (args.dir / STAMP_NAME).is_file():
                write_stamp(args.dir, since=t0 - 1.0)
    return _run_command(args, progress)


def _run_command(args: argparse.Namespace, progress: bool) -> int:
    """The subcommands that make new outputs (no design-folder argument)."""
    cmd = args.command
    if cmd == "build":
        from .build import build  # lazy: the stage loads when its subcommand runs
        result = build(args.shape, out=args.out, vertices=args.vertices, time=args.time,
                       scale=args.scale, size=args.size, flattening=args.flattening,
                       time_file=args.time_file,
                       stencil_order=args.stencil_order, material=args.material,
                       refine=args.refine, program=not args.no_program,
                       render=not args.no_render, simulate=not args.no_sim,
                       t_end=args.t_end, dt=args.dt, jobs=args.jobs, progress=progress,
                       renderer=args.renderer, keep_failed=getattr(args, "debug", False),
                       solver=args.solver, params=_unit_cell(args), seed=args.seed,
                       stencil=args.stencil)
        return result.get("exit_code", EXIT_OK)
    if cmd == "design":
        from .build import design_only  # lazy: the stage loads when its subcommand runs
        design_only(args.shape, out=args.out, vertices=args.vertices, time=args.time,
                    scale=args.scale, size=args.size, flattening=args.flattening,
                    time_file=args.time_file,
                    stencil_order=args.stencil_order, progress=progress,
                    params=_unit_cell(args), stencil=args.stencil,
                    thickness_file=args.thickness_file)
        return EXIT_OK
    return _run_other(args, progress)


def _run_stage(args: argparse.Namespace, progress: bool) -> int:
    """The subcommands that run one stage on an existing design folder ``args.dir``."""
    cmd = args.command
    if cmd == "program":
        from .temporal import program_design  # lazy: the stage loads when its subcommand runs
        program_design(Path(args.dir), material=args.material, progress=progress,
                       physics=_physics_from_args(args))
        return EXIT_OK
    if cmd == "render":
        from .render import render_design  # lazy: the stage loads when its subcommand runs
        render_design(Path(args.dir), jobs=args.jobs, progress=progress,
                      renderer=args.renderer)
        return EXIT_OK
    if cmd == "simulate":
        from sim.model.simulate import simulate_design  # lazy: loads with its subcommand

        from .build import check_build_options  # lazy: the stage loads when its subcommand runs

        check_build_options(t_end=args.t_end, dt=args.dt, render=False)
        kw = {k: v for k, v in (("t_end", args.t_end), ("dt", args.dt)) if v is not None}
        simulate_design(Path(args.dir), material=args.material, progress=progress,
                        resume=not args.no_resume, solver=args.solver,
                        physics=_physics_from_args(args), **kw)
        return EXIT_OK
    if cmd == "report":
        from sim.report import make_report, print_verdict  # lazy: loads with its subcommand

        rep = make_report(Path(args.dir), progress=progress)
        print_verdict(rep, Path(args.dir) / "report")
        return 3 if rep.get("verdict") == "FAIL" else EXIT_OK
    if cmd == "tolerance":

        from pysolver.tolerance import tolerance_analysis  # lazy: loads with its subcommand

        from .build import check_build_options  # lazy: the stage loads when its subcommand runs

        check_build_options(t_end=args.t_end, dt=args.dt, render=False)
        kw = {k: v for k, v in (("t_end", args.t_end), ("dt", args.dt)) if v is not None}
        unc = dataclasses.replace(UNCERTAINTY, thickness_sd=args.thickness_sd,
                                  stretch_mean=args.stretch, stretch_sd=args.stretch_sd,
                                  modulus_rel_sd=args.modulus_sd, material_sd=args.material_sd,
                                  relaxation=args.relaxation)
        tolerance_analysis(Path(args.dir), samples=args.samples, uncertainty=unc,
                           seed=args.seed, time_tol_s=args.time_tol,
                           sensitivity=args.sensitivity, material=args.material,
                           out=args.out, scheduler=args.scheduler, workers=args.workers,
                           progress=progress, **kw)
        return EXIT_OK
    if cmd == "compare-scan":
        from sim.report.scan import compare_scan  # lazy: the stage loads when its subcommand runs
        out = None if args.out is None else claim_output(args.out, what="--out folder",
                                                         inputs=[args.scan])
        compare_scan(Path(args.dir), Path(args.scan), layer=args.layer, state=args.state,
                     gate_mm=args.gate_mm, out_dir=out, progress=progress)
        if out is not None:
            write_stamp(out)
        return EXIT_OK
    raise AssertionError(cmd)


def _run_other(args: argparse.Namespace, progress: bool) -> int:
    """Material and membrane fits, specimens, the shape list."""
    cmd = args.command
    if cmd == "fit-material":
        from .fitting.material_fit import fit_material  # lazy: loads with its subcommand
        out, report = args.out, args.report
        if args.data is not None:  # a user's data never overwrites the committed default model
            stem = Path(args.data).resolve().name or "material"
            out = out or str(Path("build/material") / f"{stem}.json")
            report = report or str(Path("build/material") / stem)
        if out is not None:
            claim_output_file(out, what="--out model file")
        if report is not None:
            claim_output(report, what="--report folder")
        res = fit_material(data_dir=args.data, out_path=out, report_dir=report,
                           compare_to=args.compare_to, progress=progress)
        missing = {k: v for k, v in (res.get("missing_specimens") or {}).items() if v}
        if missing:
            print(f"note: missing from the standard design (h mm, l mm[, F N]): {missing}")
        print(f"material model: {res['model_file']} (use it with MATERIAL={res['model_file']})")
        return EXIT_OK
    if cmd == "fit-membrane":
        from .fitting.membrane_fit import fit_membrane_model  # lazy: loads with its subcommand
        if args.out is not None:
            claim_output_file(args.out, what="--out model file")
        if args.report is not None:
            claim_output(args.report, what="--report folder")
        fit_membrane_model(out_path=args.out, report_dir=args.report)
        return EXIT_OK
    if cmd == "specimens":
        from .specimens import make_specimens  # lazy: the stage loads when its subcommand runs
        out = claim_output(args.out, what="--out folder")
        make_specimens(out, jobs=args.jobs)
        write_stamp(out)
        return EXIT_OK
    if cmd == "studio":
        from .studio import serve  # lazy: the stage loads when its subcommand runs
        serve(args.dirs, port=args.port, open_browser=not args.no_browser)
        return EXIT_OK
    if cmd == "sweep":
        from .sweep import run_sweep  # lazy: the stage loads when its subcommand runs
        res = run_sweep(args.spec, out=args.out, scheduler=args.scheduler,
                        workers=args.workers, progress=progress)
        return EXIT_OK if not res["run"]["failed"] else EXIT_INTERNAL
    if cmd == "shapes":
        from .design.surfaces import BUILTIN_SHAPES  # lazy: loads with its subcommand
        for name in BUILTIN_SHAPES:
            print(name)
        return EXIT_OK
    raise AssertionError(cmd)


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


# OSError numbers that describe the machine (the user can fix them), not a bug
_ENVIRONMENT_ERRNOS = {errno.EACCES, errno.EPERM, errno.ENOSPC, errno.EROFS, errno.EDQUOT}


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
        return _run(args)
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
        if isinstance(e, OSError) and e.errno in _ENVIRONMENT_ERRNOS:
            # the machine, not the program: no permission, disk full, read-only file system
            print(f"morphshell {args.command}: error: cannot write or read "
                  f"{e.filename or 'a file'}: {e.strerror}.\n  Fix: check the permissions and "
                  "the free space of the output folder (--out), then re-run; previous complete "
                  "results are kept.", file=sys.stderr)
            return EXIT_BAD_INPUT
        print(f"morphshell {args.command}: internal error ({type(e).__name__}: {e}). "
              "This is a bug; re-run with --debug for the traceback and report it.",
              file=sys.stderr)
        return EXIT_INTERNAL
    finally:
        warnings.showwarning = shown


if __name__ == "__main__":
    sys.exit(main())
