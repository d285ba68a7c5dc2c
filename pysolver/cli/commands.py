"""What each ``morphshell`` subcommand does once its arguments are parsed.

:func:`pysolver.cli.main` parses (:mod:`pysolver.cli.parser`) and calls the function a
:class:`~pysolver.cli.table.Command` names here, ``function(args) -> exit code``.  Like the
command line itself, this module imports each stage inside the function that runs it
(``# lazy:``), so that a subcommand loads only what it needs.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from ..core.locks import build_lock
from ..core.ownership import (
    check_design_folder,
    claim_output,
    claim_output_file,
    claim_result_folder,
)
from ..errors import EXIT_BAD_INPUT, EXIT_CHECK_FAILED, EXIT_INTERNAL, EXIT_OK
from ..params import UNCERTAINTY
from ..stages import (
    PHYSICS_OPTIONS,
    BuildOptions,
    StageContext,
    runner,
)
from ..stages import stage as stage_named

_FIELDS = {f.name for f in dataclasses.fields(BuildOptions)}


def _progress(args: argparse.Namespace) -> bool:
    return not getattr(args, "quiet", False)


def build_options(args: argparse.Namespace) -> BuildOptions:
    """The :class:`BuildOptions` of parsed arguments: the fields of the same names, the
    unit cell from ``--min-bumper``, ``--min-gap``, ``--max-cell-length``, the physics from
    ``--physics`` and its parameters, ``progress`` from ``--quiet`` and ``keep_failed``
    from ``--debug``."""
    kw = {k: v for k, v in vars(args).items() if k in _FIELDS}
    if hasattr(args, "max_cell_length"):
        from ..design import unit_cell_options  # lazy: the stage loads when its subcommand runs

        kw["params"] = unit_cell_options(min_bumper=args.min_bumper, min_gap=args.min_gap,
                                         max_cell_length=args.max_cell_length)
    if hasattr(args, "physics"):
        from ..simulator import parse_physics  # lazy: the stage loads when its subcommand runs

        kw["physics"] = parse_physics(args.physics, **{k: getattr(args, k)
                                                       for k in PHYSICS_OPTIONS[1:]})
    return BuildOptions(**kw, progress=_progress(args), keep_failed=getattr(args, "debug", False))


def build(args: argparse.Namespace) -> int:
    """``morphshell build``: every stage the options ask for (:func:`pysolver.build.build`)."""
    from ..build import build as run_build  # lazy: the stage loads when its subcommand runs

    return run_build(args.shape, build_options(args)).get("exit_code", EXIT_OK)


def design(args: argparse.Namespace) -> int:
    """``morphshell design``: the design stage into a new folder."""
    from ..build import design_only  # lazy: the stage loads when its subcommand runs

    design_only(args.shape, build_options(args))
    return EXIT_OK


def stage(args: argparse.Namespace) -> int:
    """``morphshell <stage> DIR``: one stage of :data:`pysolver.stages.STAGES` on a design
    folder, in place: only into a folder morphshell made (its stamp records what it wrote),
    one stage or build at a time.  Exit code 3 when the stage's verdict is FAIL."""
    from ..build import check_build_options  # lazy: the stage loads when its subcommand runs

    s = stage_named(args.command)
    opts = build_options(args)
    check_build_options(opts.replace(render=False, simulate=s.name == "simulate"))
    folder = Path(args.dir).absolute()
    check_design_folder(folder)
    with build_lock(folder):
        res = runner(s.run)(StageContext(folder, opts, name=folder.name))
    return EXIT_CHECK_FAILED if (res or {}).get("verdict") == "FAIL" else EXIT_OK


def compare_scan(args: argparse.Namespace) -> int:
    """``morphshell compare-scan DIR SCAN``: into ``DIR/scan_report``, or a folder of its own
    (``--out``, claimed like any output folder)."""
    from ..simulator import compare_scan as run  # lazy: the stage loads when its subcommand runs

    folder = Path(args.dir).absolute()
    check_design_folder(folder)
    # checked before any work; made (and stamped) by the stage once it has a result
    out = None if args.out is None else claim_output(args.out, what="--out folder",
                                                     inputs=[args.scan])
    with build_lock(folder):
        run(folder, Path(args.scan), layer=args.layer, state=args.state, gate_mm=args.gate_mm,
            out_dir=out, progress=_progress(args))
    return EXIT_OK


def mechtest(args: argparse.Namespace) -> int:
    """``morphshell mechtest DIR --test ...``: into ``DIR/mechtest`` (SI Note 6)."""
    from ..simulator import TESTS, check_mechtest_targets  # lazy: loads with its subcommand
    from ..simulator import mechtest as run  # lazy: the stage loads when its subcommand runs

    folder = Path(args.dir).absolute()
    check_design_folder(folder)
    tests = list(dict.fromkeys(args.test)) if args.test else None
    with build_lock(folder):
        check_mechtest_targets(folder, tests or TESTS)  # every target before any test runs
        run(folder, **({"tests": tests} if tests else {}), axis_deg=args.axis_deg,
            material=args.material, progress=_progress(args))
    return EXIT_OK


def tolerance(args: argparse.Namespace) -> int:
    """``morphshell tolerance DIR``: reads the design folder, writes its own result folder."""
    from ..build import check_build_options  # lazy: the stage loads when its subcommand runs
    from ..tolerance import tolerance_analysis  # lazy: the stage loads when its subcommand runs

    check_build_options(BuildOptions(t_end=args.t_end, dt=args.dt, render=False))
    kw = {k: v for k, v in (("t_end", args.t_end), ("dt", args.dt)) if v is not None}
    unc = dataclasses.replace(UNCERTAINTY, thickness_sd=args.thickness_sd,
                              stretch_mean=args.stretch, stretch_sd=args.stretch_sd,
                              modulus_rel_sd=args.modulus_sd, material_sd=args.material_sd,
                              relaxation=args.relaxation)
    tolerance_analysis(Path(args.dir).absolute(), samples=args.samples, uncertainty=unc,
                       seed=args.seed, time_tol_s=args.time_tol, sensitivity=args.sensitivity,
                       material=args.material, out=args.out, scheduler=args.scheduler,
                       workers=args.workers, progress=_progress(args),
                       dashboard=args.dashboard, coupon=args.coupon, **kw)
    return EXIT_OK


def fit_material(args: argparse.Namespace) -> int:
    """``morphshell fit-material``: a user's data never overwrites the committed model."""
    from ..fitting.material_fit import fit_material as fit  # lazy: loads with its subcommand

    out, report = args.out, args.report
    if args.data is not None:
        stem = Path(args.data).resolve().name or "material"
        out = out or str(Path("build/material") / f"{stem}.json")
        report = report or str(Path("build/material") / stem)
    if out is not None:
        claim_output_file(out, what="--out model file")
    if report is not None:
        claim_result_folder(report, what="--report folder")
    res = fit(data_dir=args.data, out_path=out, report_dir=report, compare_to=args.compare_to,
              progress=_progress(args))
    missing = {k: v for k, v in (res.get("missing_specimens") or {}).items() if v}
    if missing:
        print(f"note: missing from the standard design (h mm, l mm[, F N]): {missing}")
    print(f"material model: {res['model_file']} (use it with MATERIAL={res['model_file']})")
    return EXIT_OK


def fit_membrane(args: argparse.Namespace) -> int:
    """``morphshell fit-membrane``."""
    from ..fitting.membrane_fit import fit_membrane_model  # lazy: loads with its subcommand

    if args.out is not None:
        claim_output_file(args.out, what="--out model file")
    if args.report is not None:
        claim_result_folder(args.report, what="--report folder")
    fit_membrane_model(out_path=args.out, report_dir=args.report)
    return EXIT_OK


def specimens(args: argparse.Namespace) -> int:
    """``morphshell specimens``."""
    from ..render.specimens import make_specimens  # lazy: the stage loads when its subcommand runs

    make_specimens(claim_result_folder(args.out, what="--out folder"), jobs=args.jobs)
    return EXIT_OK


def coupon(args: argparse.Namespace) -> int:
    """``morphshell coupon``: the timing coupon into its own folder (docs/coupon.md)."""
    from ..coupon import make_coupon  # lazy: the stage loads when its subcommand runs

    make_coupon(claim_output(args.out, what="--out folder"), material=args.material,
                jobs=args.jobs, progress=_progress(args), renderer=args.renderer)
    return EXIT_OK


def calibrate_time(args: argparse.Namespace) -> int:
    """``morphshell calibrate-time COUPON_CSV``: the fit printed, the material file written."""
    from ..temporal.coupon import calibrate  # lazy: the stage loads when its subcommand runs

    out = claim_output_file(args.out or "build/material/coupon-calibrated.json",
                            what="--out material file")
    print(calibrate(args.coupon_csv, out, material=args.material))
    print(f"material model: {out} (use it with MATERIAL={out})")
    return EXIT_OK


def studio(args: argparse.Namespace) -> int:
    """``morphshell studio``."""
    from ..studio import serve  # lazy: the stage loads when its subcommand runs

    serve(args.dirs, port=args.port, open_browser=not args.no_browser)
    return EXIT_OK


def sweep(args: argparse.Namespace) -> int:
    """``morphshell sweep SPEC``: exit code of the worst variant that was not built."""
    from ..sweep import run_sweep  # lazy: the stage loads when its subcommand runs

    res = run_sweep(args.spec, out=args.out, scheduler=args.scheduler, workers=args.workers,
                    progress=_progress(args), dashboard=args.dashboard)
    bad = [r for r in res["rows"] if r.get("verdict") == "ERROR"]
    if not bad:
        return EXIT_OK
    print(f"morphshell sweep: error: {len(bad)} of {len(res['rows'])} variant(s) were not "
          f"built (first: {bad[0]['variant']}: {bad[0].get('error') or '?'}); see "
          f"{Path(res['out']) / 'table.csv'}", file=sys.stderr)
    if res["run"]["failed"]:
        return EXIT_INTERNAL
    return max(int(r.get("exit_code") or EXIT_BAD_INPUT) for r in bad)


def shapes(args: argparse.Namespace) -> int:
    """``morphshell shapes``: the built-in shapes, one per line."""
    from ..design.surfaces import BUILTIN_SHAPES  # lazy: loads with its subcommand

    for name in BUILTIN_SHAPES:
        print(name)
    return EXIT_OK


__all__ = ["build_options", "build", "design", "stage", "compare_scan", "mechtest",
           "tolerance", "fit_material", "fit_membrane", "specimens", "coupon", "calibrate_time",
           "studio", "sweep", "shapes"]
