"""Fit the stencil optimiser's timing estimates to what temporal programming computes.

The count search and the stencil optimisation steer each cell's achievable completion
times toward the landscape by a closed-form estimate (``StencilSearch.timing_fastest`` /
``timing_slowest``, :func:`pysolver.design.stencil.objective.log_time_range`)::

    log t ~ c + a log b0 + e log x + k [boundary]

This script designs and programmes the built-in shapes (the project's own, at several
sizes: no shape of ``../shared``), reads each cell's fastest time from ``cells.csv``
(``t_min_s``: thinnest brackets) and computes its slowest as the latest time both layers
reach at their thickest brackets (:func:`pysolver.temporal.both_layers_latest`; ``t_max_s``
is the later layer's, which may wait at its bumpers past that) and fits the four
coefficients of each on the terms the optimiser states
(:func:`pysolver.design.stencil.optimise.layout_timing_terms` of the stencil's layout).
Programming searches times within the bracket model's range (0-120 s), so a time at its
end is only a bound: the fit is the censored normal (Tobit) maximum likelihood, with
times under 0.5 s or over 119.5 s censored.  (Leaving them out, as a plain least squares
must, fits the slowest time on the faster cells only: under-estimated by 0.3 in log.)

Usage::

    .venv/bin/python bench/fit_timing_estimate.py [--out build/bench]
        [--designs DIRS] [--check DIRS]

``--designs DIR[,DIR]`` fits programmed design folders instead of designing the built-in
shapes; ``--check DIR[,DIR]`` adds folders scored but not fitted.  Writes
``<out>/timing_estimate.json``: both fits, their residual SD in log time and, per design,
the mean and SD of the residuals of the uncensored cells, for the fit and for the
coefficients in ``pysolver.params``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.optimize import minimize
from scipy.stats import norm

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pysolver import tables  # noqa: E402
from pysolver.design import run_design  # noqa: E402
from pysolver.design.layout import build_layout  # noqa: E402
from pysolver.design.stencil.objective import log_time_terms  # noqa: E402
from pysolver.design.stencil.optimise import layout_timing_terms  # noqa: E402
from pysolver.params import STENCIL  # noqa: E402
from pysolver.temporal import both_layers_latest, closing_lengths, program_design  # noqa: E402

SHAPES = ("petal", "petal:size=1.3", "saddle", "saddle:size=1.4", "dome",
          "dome:size=0.7", "weave", "weave:large", "spiral", "spiral:size=0.8")
CENSORED = (0.5, 119.5)
"""Times (s) at the ends of the bracket model's range are bounds, not estimates."""


def design_terms(design_dir: Path) -> dict:
    """The estimate's terms (:func:`layout_timing_terms`) and the programmed times of a
    programmed design folder: ``X`` (c, 4) [1, log b0, log x, boundary], ``t_min``,
    ``t_max`` (c,) s."""
    V, UV, F = tables.read_stencil(design_dir / "stencil.obj")
    params = tables.read_unit_cell(design_dir)
    lay = build_layout(V, UV, F, params)
    cells = tables.read_table(design_dir, "cells")
    central, contact, boundary = layout_timing_terms(lay)
    if not np.allclose(central, cells["central_length_mm"], atol=1e-6):
        # (a design laid out at a central length given, as the built-in regular lattice)
        raise SystemExit(f"{design_dir}: the stencil's layout by the scaling rules is not "
                         "its cells' table")
    log_b0, log_x = log_time_terms(central, contact, params)
    record = json.loads((design_dir / "temporal.json").read_text())
    factor = tables.record_numbers(record.get("membrane_factor"), len(central))
    if factor is None:
        raise SystemExit(f"{design_dir}: temporal.json has no per-cell membrane_factor")
    t_max = both_layers_latest(cells, factor, closing_lengths(design_dir, cells))
    return {"X": np.column_stack([np.ones_like(central), log_b0, log_x, boundary]),
            "t_min": cells["t_min_s"], "t_max": t_max}


def fit(designs: dict, key: str):
    """Censored normal maximum likelihood of ``log t`` on the terms over every design's
    cells: coefficients (4,) and the residual SD (the fitted sigma)."""
    X = np.vstack([d["X"] for d in designs.values()])
    t = np.concatenate([d[key] for d in designs.values()])
    y, low, high = np.log(np.clip(t, *CENSORED)), t <= CENSORED[0], t >= CENSORED[1]
    mid = ~(low | high)

    def nll(p):  # p = (coefficients, log sigma)
        z = (y - X @ p[:-1]) / np.exp(p[-1])
        return -(np.sum(norm.logpdf(z[mid]) - p[-1]) + np.sum(norm.logcdf(z[low]))
                 + np.sum(norm.logsf(z[high])))
    p0 = np.linalg.lstsq(X[mid], y[mid], rcond=None)[0]
    p = minimize(nll, np.r_[p0, np.log(np.std(y[mid] - X[mid] @ p0))], method="BFGS").x
    return p[:-1], float(np.exp(p[-1]))


def scores(designs: dict, key: str, coef) -> dict:
    """Per design: cells scored, mean and SD of ``log t`` minus the estimate."""
    out = {}
    for name, d in designs.items():
        ok = (d[key] > CENSORED[0]) & (d[key] < CENSORED[1])
        r = np.log(d[key][ok]) - d["X"][ok] @ np.asarray(coef)
        out[name] = {"cells": int(ok.sum()), "mean": round(float(r.mean()), 3) if ok.any()
                     else None, "sd": round(float(r.std()), 3) if ok.any() else None}
    return out


def _built_in(shape: str, d: Path, i: int) -> dict:
    print(f"[{i + 1}/{len(SHAPES)}] {shape}", flush=True)
    run_design(shape, d, progress=False, plots=False)
    program_design(d, progress=False, picture=False, fit_landscape=True)
    return design_terms(d)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "build" / "bench"))
    ap.add_argument("--designs", default="", help="programmed design folders to fit, "
                    "comma-separated (default: the built-in shapes, designed here)")
    ap.add_argument("--check", default="", help="programmed design folders, comma-separated")
    a = ap.parse_args()
    given = [Path(p) for p in filter(None, a.designs.split(","))]
    with tempfile.TemporaryDirectory() as tmp:
        designs = ({str(p): design_terms(p) for p in given} if given
                   else {shape: _built_in(shape, Path(tmp) / f"d{i}", i)
                         for i, shape in enumerate(SHAPES)})
    held = {p: design_terms(Path(p)) for p in filter(None, a.check.split(","))}
    result = {"terms": ["1", "log b0", "log x", "boundary"], "designs": list(designs)}
    for name, key, now in (("fastest", "t_min", STENCIL.timing_fastest),
                           ("slowest", "t_max", STENCIL.timing_slowest)):
        coef, sd = fit(designs, key)
        result[name] = {"fit": [round(float(c), 3) for c in coef], "sd": round(sd, 3),
                        "per_design": scores({**designs, **held}, key, coef),
                        "params": list(now),
                        "params_per_design": scores({**designs, **held}, key, now)}
        print(f"{name}: {result[name]['fit']} (sigma {sd:.3f} in log t); "
              f"pysolver.params: {list(now)}", flush=True)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "timing_estimate.json").write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {out / 'timing_estimate.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
