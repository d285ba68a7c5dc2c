"""One verdict: the report and the tolerance analysis judge the same frames alike.

Both call :func:`sim.report.verdict.check_morph`, which reads the design's own unit cell.  The
case that used to split them: a design built with ``--max-cell-length 8``.  Its membrane
check counts a membrane vertex as *far* from a base beyond ``base_r + 8`` = 10 mm of flat
distance (the default unit cell says 11.5 mm).  A vertex 10.5-11 mm from a base that ends
inside it is a collision for the design's own rule and was none for the default one, which
the tolerance analysis used: on the same frames the report said WARN, the analysis PASS.

Small on purpose: a 12-base regular patch (its whole simulation takes seconds), no render,
no refinement.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from pysolver.params import SIM, UNIT_CELL

SHAPE = "regular:rows=2,cols=3"
MAX_CELL = 8.0


@pytest.fixture(scope="module")
def judged(tmp_path_factory):
    """A ``--max-cell-length 8`` build whose last frame pushes one membrane vertex into a
    base 10.5-11 mm away in the flat layout; its report, and the frames."""
    from pysolver.build import build
    from pysolver.design import unit_cell_options

    root = tmp_path_factory.mktemp("verdict")
    build(SHAPE, out=root / "built", params=unit_cell_options(max_cell_length=MAX_CELL),
          render=False, refine=0, progress=False)
    folder = root / "design"   # a plain copy: the frames are edited below
    shutil.copytree(root / "built", folder, ignore=shutil.ignore_patterns(".morphshell-*"))
    path = folder / "sim" / "frames.npz"
    frames = dict(np.load(path, allow_pickle=False))
    fv, fc = frames["flat_membrane_vertices"], frames["flat_base_center"]
    d = np.linalg.norm(fv[:, None, :2] - fc[None, :, :2], axis=2)       # (vertex, base)
    v, b = np.argwhere((d > UNIT_CELL.base_r + MAX_CELL + 0.5)
                       & (d < UNIT_CELL.base_r + UNIT_CELL.max_cell_length - 0.5))[0]
    frames["membrane_vertices"][-1, v] = frames["base_center"][-1, b]  # in the base's middle
    np.savez(path, **frames)
    from sim.report import make_report

    report = make_report(folder, out_dir=root / "report", progress=False, image_px=64,
                         viewer_frames=2)
    return folder, frames, report, (int(v), int(b))


def test_the_report_uses_the_designs_own_cell_length(judged):
    _, _, report, (v, b) = judged
    mc = report["metrics"]["collisions"]["membrane_base"]
    assert mc["local_radius_mm"] == pytest.approx(UNIT_CELL.base_r + MAX_CELL)
    assert mc["count"] >= 1 and [v, b] in [e["pair"] for e in mc["events"]]
    assert any(r["check"] == "collisions" and "membrane" in r["message"]
               for r in report["reasons"])


def test_the_tolerance_analysis_gives_the_reports_verdict(judged, monkeypatch):
    """The analysis's own worker code (:func:`pysolver.tolerance.analysis.run_sample`) on
    the same frames (the simulation stands in) gives the report's verdict and reasons."""
    from pysolver import simulator
    from pysolver.tolerance.analysis import nominal_perturbation, read_payload, run_sample

    folder, frames, report, _ = judged
    monkeypatch.setattr(simulator, "simulate_model",
                        lambda *a, **k: dict(frames, summary={}))
    sample = run_sample(read_payload(folder), nominal_perturbation(report["metrics"]["n_cells"]),
                        {"t_end": SIM.t_end, "dt": SIM.dt, "thresholds": None})
    assert report["verdict"] == "WARN"      # the shell is fine, but for the collision
    assert sample["verdict"] == report["verdict"]
    assert sample["reasons"] == [f"{r['level']} {r['check']}: {r['message']}"
                                 for r in report["reasons"]]
    assert sample["n_never_due"] == report["metrics"]["timing"]["n_never_due"]
    assert sample["shape_rms_mm"] == pytest.approx(report["metrics"]["shape"]["rms_mm"],
                                                   rel=1e-12)
