"""Why the predicted initial slopes miss the printed shell's (issue #44, item 2; not a test).

    .venv/bin/python bench/mechtest_slopes.py [DIR] [--shell-tests ../shared/shell-tests]

Reads a ``mechtest`` specimen that ``bench/bench_mechtest.py`` built and tested (``DIR``,
default ``build/bench-mechtest-a0``) and the measured curves of ``../shared/shell-tests``
(never committed), and measures three things that are not the model's constants:

1. **The slope's estimator on both curves.**  The tester's README gives no window for the
   initial slope; morphshell reads the least-squares line over the first 2 % of strain
   (``MechTest.slope_window``).  Every 2 %-wide window's slope along both curves, and the
   steepest one before the peak: the slope of the linear part after a seating toe (the toe
   compensation of the flexural and tensile test standards, ASTM D790 / D638: the toe is
   take-up of slack and seating of the specimen, not the material).
2. **The prediction's sampling.**  30 equal steps put 2 (stretching) and 3 (bending) points
   in the first 2 %; the same test with 16 steps over the first 4 % (``--fine``).
3. **The dry brackets' stiffness source.**  The dry bracket law is fitted to the unit-cell
   tests' crosshead travel, which includes the test rig's compliance (0.032 mm/N over a
   specimen's 4 brackets, :func:`pysolver.material.bumper.rig_compliance`, measured on the
   shortest cells).  The same test with the rig taken off the dry law, to first order:
   ``x_meas = x + 4 c_rig F`` gives ``F_true(x) = F_fit(s x)``, ``s = 1 / (1 - 4 c_rig c1)``
   (``--rig-off``; an experiment, not the model).

Prints the tables of ``docs/results.md`` ("Why the initial slopes miss").  Predicted curves
go through the tester's formulas with its a0, b0 (:func:`bench_mechtest.to_tester`).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import bench_mechtest as bm  # noqa: E402

from pysolver.material.bumper import rig_compliance  # noqa: E402
from pysolver.material.measurements import load_measurements  # noqa: E402
from pysolver.material.model import load_bracket_model  # noqa: E402
from pysolver.params import MECHTEST  # noqa: E402
from sim.model.mechtest import dried_shell, initial_slope, readings, run_test  # noqa: E402

WINDOW = 2.0
"""Width of the slope windows, % of strain (``MechTest.slope_window``)."""


def window_slopes(x, y, upto: float, step: float = 0.5):
    """Least-squares slope of every ``WINDOW``-wide window starting at 0, ``step``, ... up to
    ``upto - WINDOW`` (%): ``(starts, slopes)``, MPa per %."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    starts, slopes = [], []
    for x0 in np.arange(0.0, max(upto - WINDOW, 0.0) + 1e-9, step):
        s = (x >= x0 - 1e-9) & (x <= x0 + WINDOW + 1e-9)
        if s.sum() >= 2:
            starts.append(float(x0))
            slopes.append(float(np.polyfit(x[s], y[s], 1)[0]))
    return np.array(starts), np.array(slopes)


def toe_free_slope(x, y, upto: float) -> tuple[float, float]:
    """The steepest window slope before the peak and where its window starts (%)."""
    starts, slopes = window_slopes(x, y, upto)
    k = int(np.argmax(slopes))
    return float(slopes[k]), float(starts[k])


class RigOff:
    """A bracket model whose dry law (t = 0) has the test rig's compliance taken off."""

    def __init__(self, model, c_rig: float, brackets: int = 4):
        self.model, self.c_rig, self.n = model, c_rig, brackets

    def __getattr__(self, name):
        return getattr(self.model, name)

    def coefficients(self, h, b, t, eta: float = 0.0):
        """Force coefficients (n, 4); at t = 0 each ``c_k`` times ``s^k``."""
        c = np.asarray(self.model.coefficients(h, b, t, eta=eta), float)
        if np.ndim(t) or float(t) != 0.0:
            return c
        c = c.reshape(-1, 4)
        s = 1.0 / (1.0 - self.n * self.c_rig * c[:, 0])
        if np.any(s <= 0):
            raise SystemExit("a dry bracket as stiff as the rig: the first-order removal fails")
        return c * s[:, None] ** np.arange(1, 5)


def predicted(folder: Path, tester: dict, consts=MECHTEST, material=None) -> dict:
    """Stretch and bend of the dried specimen (load along y, the bench's), in the tester's
    units: per test ``x``, ``y``, ``peak``."""
    shell = dried_shell(folder, material=material, consts=consts)
    out = {}
    for test in bm.TESTS:
        r = run_test(shell, test, consts=consts, progress=False)
        pred = {"a0_mm": r["a0"], "b0_mm": r["b0"]}
        x, y = bm.to_tester(test, r["x"], r["y"], pred, tester[test])
        rd = readings(r, consts)
        px, pk = bm.to_tester(test, rd["peak_at"], rd["peak_stress_MPa"], pred, tester[test])
        out[test] = {"x": x, "y": y, "peak": float(pk), "peak_at": float(px)}
    return out


def row(name: str, test: str, meas: tuple, got: dict) -> str:
    """One table row: slopes (0-2 %, toe-free) and peak against the measured."""
    xm, ym = meas
    km = int(np.argmax(ym))
    ms, mt = initial_slope(xm, ym, test), toe_free_slope(xm[:km], ym[:km], xm[km])[0]
    ps = initial_slope(got["x"], got["y"], test)
    pt, pt0 = toe_free_slope(got["x"], got["y"], got["peak_at"])
    pk = got["peak"]
    peak = (f"{pk:.3f} ({100 * (pk / float(ym[km]) - 1):+.0f} %)" if got["x"][-1] > xm[km]
            else "(range ends before the peak)")
    return (f"| {test} | {name} | {ps:.4f} ({100 * (ps / ms - 1):+.0f} %) | "
            f"{pt:.4f} at {pt0:g} % ({100 * (pt / mt - 1):+.0f} %) | {peak} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", nargs="?", default=str(ROOT / "build" / "bench-mechtest-a0"))
    ap.add_argument("--shell-tests", default=str(ROOT.parent / "shared" / "shell-tests"))
    a = ap.parse_args(argv)
    meas_dir, folder = Path(a.shell_tests), Path(a.folder)
    tester = bm.tester_params(meas_dir)
    meas = {t: bm.read_curve(meas_dir / f"shell_{t}.csv") for t in bm.TESTS}
    c_rig = rig_compliance(load_measurements().dry)
    fine = dataclasses.replace(MECHTEST, steps=16, stretch_max=0.04, bend_max=0.04)
    runs = {"30 steps (the bench)": predicted(folder, tester),
            "16 steps over 0-4 %": predicted(folder, tester, fine),
            f"rig taken off the dry law ({c_rig:.4f} mm/N)":
                predicted(folder, tester, material=RigOff(load_bracket_model(), c_rig))}
    print("| test | measured | slope 0-2 %, MPa/% | steepest 2 % window before the peak | "
          "peak, MPa |\n|---|---|---|---|---|")
    for test, (xm, ym) in meas.items():
        km = int(np.argmax(ym))
        mt, mt0 = toe_free_slope(xm[:km], ym[:km], xm[km])
        print(f"| {test} | printed shell | {initial_slope(xm, ym, test):.4f} | {mt:.4f} at "
              f"{mt0:g} % | {ym[km]:.3f} |")
    print("\n| test | predicted | slope 0-2 % (error) | steepest window (error) | peak (error) |"
          "\n|---|---|---|---|---|")
    for test in bm.TESTS:
        for name, got in runs.items():
            print(row(name, test, meas[test], got[test]))
    for test in bm.TESTS:
        for label, (x, y) in (("measured", meas[test]),
                              ("predicted, 16 steps", (runs["16 steps over 0-4 %"][test]["x"],
                                                       runs["16 steps over 0-4 %"][test]["y"]))):
            starts, slopes = window_slopes(x, y, 6.0 + WINDOW)
            print(f"\n{test}, {label}, 2 % windows from: " + ", ".join(
                f"{s:g} % {v:.4f}" for s, v in zip(starts, slopes, strict=True)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
