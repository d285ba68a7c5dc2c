"""Benchmark of the tolerance analysis on Dask (not a test): ``tolerance petal SAMPLES=32``.

Builds ``petal`` without STLs (``build/bench/tolerance_petal``, reused when present), then runs
the default tolerance analysis (32 samples, default uncertainty, the one-at-a-time
sensitivity runs) twice from scratch: on a LocalCluster of 1 worker and of 2 workers.  Writes
``build/bench/tolerance.json``: wall time of each, the speed-up 1 -> 2 workers, the number
of simulations, CPU count and load average (the machine may be shared), and the headline
figures (P(PASS) with its 95 % interval, P(not FAIL), the most influential factor, the
sensitivity table).  The two runs must give the same figures; the largest difference is
recorded.

Usage::

    .venv/bin/python bench/bench_tolerance.py [--shape petal] [--samples 32]
                                              [--workers 1,2] [--out build/bench]
                                              [--coupon] [--sensitivity N] [--resume]

``--coupon`` also simulates the coupon workflow (issue #45) and records P(cell on time) with
and without it, P(order kept) and the per-print / per-bracket variance split; ``--workers
2,2`` runs the same analysis twice (the rerun must be identical: ``max_figure_difference``).
It also records P(no collision on the way) (with and without the coupon) and where the cells'
timing error comes from (``timing_error_split``).  ``--resume`` keeps the results an earlier
run of the same code stored (its wall time then measures only what was missing: for runs cut
short on a shared machine, not for timings).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _max_diff(a, b):
    """Largest absolute difference between the numbers of two summaries (run stats aside)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return max([_max_diff(a[k], b.get(k)) for k in a if k not in ("run", "design")],
                   default=0.0)
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return max([_max_diff(x, y) for x, y in zip(a, b, strict=True)], default=0.0)
    if isinstance(a, bool | str | type(None)) or isinstance(b, bool | str | type(None)):
        return 0.0 if a == b else float("inf")
    if isinstance(a, int | float) and isinstance(b, int | float):
        return abs(a - b)
    return float("inf")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shape", default="petal")
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--workers", default="1,2")
    ap.add_argument("--out", default=str(ROOT / "build" / "bench"))
    ap.add_argument("--coupon", action="store_true")
    ap.add_argument("--sensitivity", type=int, default=None)
    ap.add_argument("--resume", action="store_true")
    a = ap.parse_args()
    from pysolver.build import build
    from pysolver.core.writes import atomic_write_text
    from pysolver.tolerance import tolerance_analysis

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    design = out / f"tolerance_{a.shape}"
    t0 = time.perf_counter()
    if not (design / "cells.csv").exists():
        build(a.shape, out=design, render=False, progress=False)
    build_s = time.perf_counter() - t0
    runs = {}
    summaries = {}
    for k, w in enumerate(int(x) for x in a.workers.split(",")):
        tol_dir = out / f"tolerance_{a.shape}_w{w}" if k == 0 else out / f"tolerance_{a.shape}_r{k}"
        if tol_dir.exists() and not a.resume:
            shutil.rmtree(tol_dir)  # a benchmark measures a run from scratch
        t0 = time.perf_counter()
        s = tolerance_analysis(design, samples=a.samples, workers=w, out=tol_dir,
                               progress=True, coupon=a.coupon, sensitivity=a.sensitivity)
        wall = time.perf_counter() - t0
        w = w if k == 0 else f"{w}-rerun{k}"
        summaries[w] = s
        runs[str(w)] = {"wall_s": round(wall, 2), "simulations": s["run"]["total"],
                        "sample_wall_s_mean": s["run"]["sample_wall_s"]["mean"]}
        print(f"{a.shape}: {a.samples} samples, {w} worker(s): {wall:.1f} s", flush=True)
    ws = list(summaries)
    f = summaries[ws[-1]]["figures"]
    res = {"shape": a.shape, "samples": a.samples, "design_build_s": round(build_s, 2),
           "runs": runs, "cpu_count": os.cpu_count(), "load_avg": list(os.getloadavg()),
           "p_pass": f["p_pass"], "p_pass_ci95": f["p_pass_ci95"],
           "p_not_fail": f["p_not_fail"], "verdicts": f["verdicts"],
           "reasons": f["reasons"], "most_influential": f.get("most_influential"),
           "sensitivity": summaries[ws[-1]]["sensitivity"],
           "material_sd": summaries[ws[-1]]["options"]["uncertainty"]["material_sd"],
           "completion_sd_s_mean": f["completion_sd_s_mean"],
           "position_sd_mm_mean": f["position_sd_mm_mean"],
           **{k: f.get(k) for k in ("p_on_time_cell_mean", "p_on_time_cell_mean_coupon",
                                    "p_order_kept", "p_order_kept_coupon", "order_pairs",
                                    "timing_variance_share", "p_all_cells_on_time",
                                    "p_all_cells_on_time_coupon", "p_no_collision",
                                    "p_no_collision_coupon", "timing_error_split")},
           "coupon_refused": (summaries[ws[-1]]["options"].get("coupon") or {}).get("refused")}
    if len(ws) >= 2:
        res["speedup"] = round(runs[str(ws[0])]["wall_s"] / runs[str(ws[-1])]["wall_s"], 3)
        # (with --workers 2,2 the 'speed-up' is the rerun's wall-time ratio)
        res["speedup_workers"] = [ws[0], ws[-1]]
        res["max_figure_difference"] = _max_diff(summaries[ws[0]], summaries[ws[-1]])
    atomic_write_text(out / "tolerance.json", json.dumps(res, indent=2, sort_keys=True) + "\n")
    print(json.dumps({k: res[k] for k in ("runs", "speedup", "p_pass", "most_influential")
                      if k in res}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
