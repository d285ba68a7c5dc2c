"""Every command that takes ``--out`` (or ``--report``) can be run twice into the same place.

A command that claims an output folder must also record what it writes there, or its own
files look like the user's on the next run and the rerun is refused (issue 46: the second
``morphshell compare-scan DIR scan.csv --out X`` failed with "scan_scan.json: not made by
morphshell").  :data:`RUNS` holds one rerun per such command, and
:func:`test_every_command_with_an_output_is_covered` fails when a new command with ``--out``
has none.

``design``, ``build``, ``compare-scan``, ``coupon`` (without its renders) and
``calibrate-time`` run for real on tiny inputs (a few seconds each).
The others would take minutes (a material fit, a membrane fit, OpenSCAD renders, Monte Carlo
on Dask), so their computation is replaced by a stub that claims the folder the way the
real code does (the command's own claim, then the stage's ``claim_result_folder``) and
writes one file through the project's writer: what is tested is the claim and the record,
which is where the bug was.  The real writers of the fit reports are checked too
(:func:`test_fit_report_writers_record_their_files`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _shared import run_cli
from test_report import make_synthetic_design

from pysolver.cli.table import argument, commands
from pysolver.core import manifest, ownership, writes
from pysolver.coupon import make_coupon

SHAPE = "regular:rows=2,cols=2"


def _stub_writer(name):
    """A stand-in for a slow stage: writes ``name`` into its folder through the writer."""
    def write(folder):
        writes.atomic_write_text(Path(folder) / name, "stub\n")
    return write


def _fit_material_stub(*, data_dir, out_path, report_dir, compare_to, progress):
    writes.atomic_write_text(out_path, '{"provenance": {}}\n')
    writes.make_dirs(report_dir)
    _stub_writer("fit_report.json")(report_dir)
    return {"model_file": str(out_path)}


def _fit_membrane_stub(*, out_path, report_dir):
    writes.atomic_write_text(out_path, '{"provenance": {}}\n')
    writes.make_dirs(report_dir)
    _stub_writer("membrane_fit.png")(report_dir)


def _tolerance_stub(design_dir, *, out, **_):
    from pysolver.tolerance import analysis

    _stub_writer("summary.json")(analysis._claim(Path(out)))


def _sweep_stub(spec, *, out, **_):
    from pysolver import sweep

    folder = sweep._claim(Path(out))
    _stub_writer("table.csv")(folder)
    return {"rows": [], "out": str(folder), "run": {"failed": {}}}


def _specimens_stub(folder, *, jobs):
    _stub_writer("specimens.csv")(folder)


def _coupon_unrendered(out, **kw):
    """The real coupon (design, tables, sheet) without its OpenSCAD renders."""
    return make_coupon(out, material=kw.get("material"), progress=False, render=False)


def _timed_coupon(tmp_path) -> Path:
    """A coupon's CSV with closing times the shipped model predicts for brackets 1.2 times
    as compliant (what a maker would type in after timing the coupon)."""
    from pysolver.temporal import coupon as tc
    from pysolver.temporal.program import load_material

    out = tmp_path / "coupon"
    if not out.exists():
        make_coupon(out, progress=False, render=False)
    d = tc.read_coupon_csv(out / tc.CSV_NAME)
    t = tc.closing_times(load_material(None), d["b0"], d["x"], d["f_bracket"], d["thickness"],
                         1.2, 1.0)
    lines = (out / tc.CSV_NAME).read_text().splitlines()
    rows = [ln + (f"{x:.3f}" if np.isfinite(x) else tc.NEVER)
            for ln, x in zip(lines[1:], t, strict=True)]
    timed = tmp_path / "timed.csv"
    timed.write_text("\n".join([lines[0], *rows]) + "\n")
    return timed


@pytest.fixture
def synthetic(tmp_path):
    """A small design folder with a simulation, stamped like one morphshell made, and a scan
    of its top markers."""
    d = tmp_path / "design"
    d.mkdir()
    manifest.start_stamp(d)
    make_synthetic_design(d, n=5, membrane=False)
    with np.load(d / "sim" / "frames.npz") as z:
        M = z["marker_top"][-1]
    scan = tmp_path / "scan.csv"
    np.savetxt(scan, M + 0.1, delimiter=",")
    return d, scan


RUNS = {
    # command: (arguments before the output option, the output option(s), stubs)
    "build": (lambda t, s: [SHAPE, "--no-render", "--no-sim", "--no-program"],
              ["--out", "X"], {}),
    "design": (lambda t, s: [SHAPE], ["--out", "X"], {}),
    "compare-scan": (lambda t, s: [s[0], s[1]], ["--out", "X"], {}),
    "fit-material": (lambda t, s: [], ["--out", "m.json", "--report", "R"],
                     {"pysolver.fitting.material_fit.fit_material": _fit_material_stub}),
    "fit-membrane": (lambda t, s: [], ["--out", "m.json", "--report", "R"],
                     {"pysolver.fitting.membrane_fit.fit_membrane_model": _fit_membrane_stub}),
    "specimens": (lambda t, s: [], ["--out", "X"],
                  {"pysolver.render.specimens.make_specimens": _specimens_stub}),
    "tolerance": (lambda t, s: [s[0]], ["--out", "X"],
                  {"pysolver.tolerance.tolerance_analysis": _tolerance_stub}),
    "sweep": (lambda t, s: [t / "spec.toml"], ["--out", "X"],
              {"pysolver.sweep.run_sweep": _sweep_stub}),
    "coupon": (lambda t, s: [], ["--out", "X"],
               {"pysolver.coupon.make_coupon": _coupon_unrendered}),
    "calibrate-time": (lambda t, s: [str(_timed_coupon(t))], ["--out", "m.json"], {}),
}


def test_every_command_with_an_output_is_covered():
    with_out = {c.name for c in commands()
                if any(argument(a).dest == "out" for a in c.arguments)}
    assert with_out == set(RUNS), "add a rerun to RUNS for " + str(with_out ^ set(RUNS))


@pytest.mark.parametrize("name", sorted(RUNS))
def test_a_second_run_into_the_same_output_is_accepted(name, synthetic, tmp_path, capsys,
                                                       monkeypatch):
    head, out, stubs = RUNS[name]
    for target, stub in stubs.items():
        monkeypatch.setattr(target, stub)
    monkeypatch.chdir(tmp_path)
    argv = [name, *head(tmp_path, synthetic), *out]
    for run in (1, 2):
        rc, msg = run_cli(argv, capsys)
        assert rc == 0, f"run {run} of {' '.join(map(str, argv))}:\n{msg}"
    folders = [tmp_path / v for k, v in zip(out, out[1:], strict=False)
               if k in ("--out", "--report") and not v.endswith(".json")]
    for f in folders:
        assert manifest.read_stamp(f) is not None, f
        assert ownership.audit(f) == [], f


def test_a_users_file_in_the_scan_output_is_still_refused(synthetic, tmp_path, capsys,
                                                          monkeypatch):
    """The rerun is accepted because the files are recorded, not because nothing is
    checked: a file of the user's dropped into the folder between the runs stops the rerun."""
    monkeypatch.chdir(tmp_path)
    argv = ["compare-scan", *synthetic, "--out", "X"]
    assert run_cli(argv, capsys)[0] == 0
    (tmp_path / "X" / "notes.txt").write_text("mine")
    rc, msg = run_cli(argv, capsys)
    assert rc == 2 and "notes.txt: not written by morphshell" in msg, msg
    assert (tmp_path / "X" / "notes.txt").read_text() == "mine"


def test_fit_report_writers_record_their_files(tmp_path):
    """The fit reports' figures go through the project's writer (a claimed report folder
    then audits clean): checked on the membrane fit's picture, drawn from a tiny model."""
    from pysolver.fitting.membrane_fit import plot_membrane_fit

    folder = ownership.claim_result_folder(tmp_path / "R", what="--report folder")
    b = np.array([2.0, 2.0, 3.0, 3.0])
    d = np.array([0.1, 0.2, 0.1, 0.2])
    model = {"form": "c0", "terms": ["1"], "coefficients": [1.0], "boundary_factor": 0.6,
             "fit": {"residual_rms_N": 0.0, "residual_max_N": 0.0, "n_samples": 4},
             "samples": {"b0_mm": b.tolist(), "d_mm": d.tolist(), "force_N": [1.0] * 4},
             "boundary": {"rows_b0_d_faces_ratio": [[2.0, 0.1, 3, 0.6]]}}
    plot_membrane_fit(model, folder / "membrane_fit.png")
    assert "membrane_fit.png" in manifest.read_stamp(folder)["files"]
    assert ownership.audit(folder) == []
