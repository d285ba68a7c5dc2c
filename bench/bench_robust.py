"""Programming robust to the per-bracket thickness scatter (issue #45, item 3; not a test).

On a built design (``--design``, default ``build/bench/tolerance_petal``, as
``bench/bench_tolerance.py`` builds it), compares the default programming with
``Programming.robust`` (:func:`pysolver.temporal.program.robust_layers`):

1. **Time model** (seconds): every cell programmed for its t* both ways
   (:func:`pysolver.temporal.program.program_cells`); per cell, with the per-bracket
   thickness sd of :data:`pysolver.params.UNCERTAINTY`, the predicted sd of its completion
   time, its mean lateness and its RMS error about the programmed time (Clark's moments of
   the later layer, :func:`pysolver.temporal.program.later_layer_moments`); the cells whose
   other layer moved, and by how much.
2. ``--simulate`` (minutes): a copy of the design folder programmed robustly, simulated and
   refined as a build does (one round), so that its nominal timing (cells complete, Spearman,
   RMS over programmable cells, as the report computes them: ``sim/refine.json``) compares
   with the built design's; then ``--thickness-samples N`` tolerance runs with only the
   thickness scatter (every per-print factor nominal) on both folders: the simulator's
   timing error under the scatter, each way.

Writes ``<out>/robust.json``.  Usage::

    .venv/bin/python bench/bench_robust.py [--design build/bench/tolerance_petal]
        [--out build/bench/robust_petal] [--simulate] [--thickness-samples 6] [--workers 2]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def time_model(design: Path) -> dict:
    """Step 1: both programmings of the design's cells in the time model."""
    from pysolver import tables
    from pysolver.params import UNCERTAINTY
    from pysolver.temporal import program as tp
    from pysolver.temporal.membrane_model import load_membrane_model

    mat, mem = tp.load_material(None), load_membrane_model(None)
    cells = tables.read_table(design, "cells")
    land = tables.read_table(design, "time_landscape")["time_s"]
    models, _ = tp._models(design, cells, mat, mem, tp.DEFAULT_CORRECTION, None)
    out = {}
    for name, robust in (("default", False), ("robust", True)):
        p = tp.Programme.solve(cells, land, models, None, 0.0)
        if robust:
            res = tp.program_cells(cells["bracket_length_mm"], models[3][:, 0],
                                   models[3][:, 1], cells["boundary"], p.t_star, material=mat,
                                   membrane=mem, factor=models[2], robust=True)
        else:
            res = p.res
        t, dtdh = tp.layer_sensitivity(mat, res["thickness"], cells["bracket_length_mm"],
                                       res["x"], res["f_bracket"])
        sd = np.abs(dtdh) * UNCERTAINTY.thickness_sd
        ok = ~res["clamped"] & np.all(np.isfinite(t) & np.isfinite(sd), axis=1)
        mean, second = tp.later_layer_moments(t[ok] - res["t_program"][ok, None], sd[ok])
        out[name] = {"cells": int(ok.sum()),
                     "sd_s_mean": float(np.sqrt(np.maximum(second - mean ** 2, 0)).mean()),
                     "late_s_mean": float(mean.mean()),
                     "rms_about_programmed_s": float(np.sqrt(second.mean())),
                     "layers_moved": int((res["lead"] > 0).sum()),
                     "lead_s_mean_of_moved": float(res["lead"][res["lead"] > 0].mean())
                     if (res["lead"] > 0).any() else 0.0,
                     "layer_sd_ratio_median": float(np.median(
                         sd[ok].max(axis=1) / np.maximum(sd[ok].min(axis=1), 1e-9)))}
    return out


def simulate_robust(design: Path, out: Path) -> dict:
    """Step 2a: the design programmed robustly, simulated and refined (one round)."""
    from pysolver.refine import refine_design
    from pysolver.simulator import simulate_design
    from pysolver.temporal import program as tp

    folder = out / "design"
    if folder.exists():
        shutil.rmtree(folder)
    shutil.copytree(design, folder, ignore=shutil.ignore_patterns("tolerance*", "report"))
    tp.PROGRAMMING = dataclasses.replace(tp.PROGRAMMING, robust=True)
    t0 = time.perf_counter()
    tp.program_design(folder, progress=False)
    simulate_design(folder, progress=False)
    ref = refine_design(folder, iterations=1, progress=False)
    base = json.loads((design / "sim" / "refine.json").read_text())
    keys = ("rms_s", "spearman", "n_never_due", "n_used", "max_abs_s")
    return {"wall_s": round(time.perf_counter() - t0, 1),
            "default": {k: base["after"].get(k) for k in keys},
            "robust": {k: ref["after"].get(k) for k in keys}, "folder": str(folder)}


def thickness_only(folders: dict, samples: int, workers: int, out: Path) -> dict:
    """Step 2b: tolerance runs with only the per-bracket thickness scatter."""
    from pysolver.params import UNCERTAINTY
    from pysolver.tolerance import tolerance_analysis

    unc = dataclasses.replace(UNCERTAINTY, stretch_sd=0.0, modulus_rel_sd=0.0,
                              material_sd=0.0)
    res = {}
    for name, folder in folders.items():
        s = tolerance_analysis(folder, samples=samples, sensitivity=0, uncertainty=unc,
                               workers=workers, out=out / f"thickness_{name}", report=False)
        f = s["figures"]
        sd = [c["t_sd_s"] for c in s["cells"]]
        res[name] = {"p_on_time_cell_mean": f["p_on_time_cell_mean"],
                     "timing_rms_s_mean": f["timing_rms_s"]["mean"],
                     "completion_sd_s_mean": float(np.mean(sd)),
                     "predicted_sd_s_mean": f["predicted_timing_sd"]["mean_s"]}
    return res


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--design", default=str(ROOT / "build" / "bench" / "tolerance_petal"))
    ap.add_argument("--out", default=str(ROOT / "build" / "bench" / "robust_petal"))
    ap.add_argument("--simulate", action="store_true")
    ap.add_argument("--thickness-samples", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    from pysolver.core.writes import atomic_write_text

    design, out = Path(a.design), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    res = {"design": str(design), "time_model": time_model(design)}
    print(json.dumps(res["time_model"], indent=1), flush=True)
    if a.simulate:
        res["nominal"] = simulate_robust(design, out)
        print(json.dumps(res["nominal"], indent=1), flush=True)
        if a.thickness_samples:
            res["thickness_only"] = thickness_only(
                {"default": design, "robust": Path(res["nominal"]["folder"])},
                a.thickness_samples, a.workers, out)
            print(json.dumps(res["thickness_only"], indent=1), flush=True)
    atomic_write_text(out / "robust.json", json.dumps(res, indent=2, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
