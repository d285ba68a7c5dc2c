"""Where the coupon's per-print timing bias comes from (issue #45, item 2; not a test).

On a built design (``--design``, default ``build/bench/tolerance_petal``, as
``bench/bench_tolerance.py`` builds it), for the Monte Carlo samples ``--samples`` of seed 0
(the tolerance run's own draws, :func:`pysolver.tolerance.analysis._draw`, and the coupon's
own stream), the shell is reprogrammed from the sample's coupon in several ways and
simulated with the sample's print (every factor drawn), in this process, one after another:

``two``       the coupon's fit as ``calibrate-time`` makes it (the modulus kept where the data
              separate it), the tolerance run's ``coupon-NNNNN`` perturbation;
``one``       the compliance alone fitted (the modulus kept at 1);
``two0``, ``one0``  the same with the fit before :attr:`pysolver.params.Coupon.later_layer`
              (each cell's nominal closing time fitted, not its expected one);
``oracle``    the drawn compliance and modulus themselves (a perfect coupon): what is left is
              the reprogramming's own error, the time model against the simulator.

For each: the mean signed error ``T - t*`` over the cells that complete (s; negative = early),
the RMS error, P(cell within 10 s) over all cells, and the fitted factors.  With the time
model alone (no simulation, ``--model-only``): the same for every sample of ``--model-samples``
(the shell's cells' model closing times under the drawn print, the per-bracket scatter left
out), so that the fits' effect on the time model's error is seen over many prints.

Writes ``<out>/coupon_bias.json``.  Usage::

    .venv/bin/python bench/bench_coupon_bias.py [--design build/bench/tolerance_petal]
        [--samples 2,4,20] [--variants two,one,oracle] [--model-samples 64] [--model-only]
        [--coupon-sim] [--reach] [--out build/bench]

``--reach`` (only): per compliance 0.5-2, the share of the design's cells that the
reprogramming puts at the thinnest printable bracket, and the share whose thinnest brackets
close more than 10 s after t* (what no coupon can correct).

``--coupon-sim``: the coupon itself, designed as ``morphshell coupon`` makes it, simulated at
the nominal print to 300 s (could the simulator's closing times ship with the coupon?).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _fit(variant: str, setup: dict, mat, draw: dict, seed: int, i: int, unc):
    """The factors a variant reprograms with (``{"compliance": {"value"}, ...}``) or None."""
    from pysolver.params import COUPON
    from pysolver.tolerance import coupon as cp

    if variant == "oracle":
        return {"compliance": {"value": draw["material"]},
                "modulus": {"value": draw["modulus"] * draw["relaxation"]}}
    from pysolver.errors import InputError
    from pysolver.temporal import coupon as tc

    rng = np.random.default_rng([seed, i, cp.COUPON_STREAM])
    coupon = dataclasses.replace(COUPON, later_layer=not variant.endswith("0"))
    if variant.startswith("one"):
        coupon = dataclasses.replace(coupon, max_correlation=-1.0)  # never separable: s alone
    d = cp.simulated_coupon(setup, mat, draw, rng, unc.thickness_sd)
    try:
        return tc.fit_coupon(d, mat, coupon)
    except InputError:
        return None


def _errors(T, t_star, tol: float = 10.0) -> dict:
    """Signed mean and RMS error over completing cells (s), P(within tol) over all."""
    T = np.asarray(T, float)
    ok = np.isfinite(T)
    e = T[ok] - t_star[ok]
    return {"mean_error_s": float(e.mean()) if ok.any() else None,
            "rms_error_s": float(np.sqrt(np.mean(e ** 2))) if ok.any() else None,
            "p_within_10s": float(np.mean(ok & (np.abs(np.where(ok, T, 0) - t_star) <= tol))),
            "completed": int(ok.sum())}


def _model_times(shell: dict, mat, h, draw: dict):
    from pysolver.temporal import coupon as tc
    return tc.closing_times(mat, shell["b0"], shell["x"], shell["f_bracket"], h,
                            draw["material"], draw["modulus"] * draw["relaxation"])


def _context(design: Path):
    from pysolver.tables import read_table
    from pysolver.temporal.program import load_material
    from pysolver.tolerance import analysis as an
    from pysolver.tolerance import coupon as cp

    mat = load_material(None)
    unc, _ = an._uncertainty(an.UNCERTAINTY, None)
    cells = read_table(design, "cells")
    h = np.c_[cells["thickness_top_mm"], cells["thickness_bottom_mm"]].astype(float)
    return {"mat": mat, "unc": unc, "cells": cells, "h": h, "setup": cp.coupon_setup(mat),
            "shell": cp.shell_geometry(design),
            "t_star": np.asarray(cells["t_star_s"], float),
            "t_model_nominal": _model_times(cp.shell_geometry(design), mat, h,
                                            {"material": 1.0, "modulus": 1.0,
                                             "relaxation": 1.0})}


def model_only(ctx: dict, n: int, variants) -> dict:
    """Per variant: the time model's per-print error of the reprogrammed shell (no thickness
    scatter on the shell), over the nominal model times, for samples 0..n-1."""
    from pysolver.tolerance import analysis as an
    from pysolver.tolerance import coupon as cp

    nc = len(ctx["t_star"])
    out = {v: [] for v in variants}
    for i in range(n):
        d = an._draw(0, i, nc, ctx["unc"], ctx["unc"].material_sd)
        for v in variants:
            fit = _fit(v, ctx["setup"], ctx["mat"], d, 0, i, ctx["unc"])
            h2 = ctx["h"] if fit is None else cp.reprogrammed_thickness(
                ctx["shell"], ctx["h"], ctx["mat"], fit)
            t = _model_times(ctx["shell"], ctx["mat"], h2, d)
            ok = np.isfinite(t) & np.isfinite(ctx["t_model_nominal"])
            e = t[ok] - ctx["t_model_nominal"][ok]
            out[v].append({"sample": i, "rms_s": float(np.sqrt(np.mean(e ** 2))),
                           "mean_s": float(e.mean())})
    return {v: {"median_rms_s": float(np.median([r["rms_s"] for r in rows])),
                "p90_rms_s": float(np.percentile([r["rms_s"] for r in rows], 90)),
                "mean_signed_s": float(np.mean([r["mean_s"] for r in rows])),
                "samples": rows} for v, rows in out.items()}


def simulate(ctx: dict, design: Path, samples, variants) -> list:
    """Simulate each (sample, variant) with the sample's whole print (in this process)."""
    from pysolver.params import SIM
    from pysolver.tolerance import analysis as an
    from pysolver.tolerance import coupon as cp

    payload = an.read_payload(design)
    nc = len(ctx["t_star"])
    rows = []
    for i in samples:
        d = an._draw(0, i, nc, ctx["unc"], ctx["unc"].material_sd)
        for v in variants:
            t0 = time.perf_counter()
            fit = _fit(v, ctx["setup"], ctx["mat"], d, 0, i, ctx["unc"])
            h2 = ctx["h"] if fit is None else cp.reprogrammed_thickness(
                ctx["shell"], ctx["h"], ctx["mat"], fit)
            pert = an.make_perturbation(f"{v}-{i:05d}", dict(d, thickness=d["thickness"]
                                                             + (h2 - ctx["h"])), nc)
            r = an.run_sample(payload, pert, {"t_end": SIM.t_end, "dt": SIM.dt,
                                              "thresholds": None})
            T = [np.nan if x is None else x for x in r["t_done"]]
            row = {"sample": i, "variant": v, "drawn_compliance": d["material"],
                   "drawn_modulus": d["modulus"] * d["relaxation"],
                   "fit_compliance": None if fit is None else fit["compliance"]["value"],
                   "fit_modulus": None if fit is None else fit["modulus"]["value"],
                   **_errors(T, ctx["t_star"]), "wall_s": round(time.perf_counter() - t0, 1)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def coupon_in_the_simulator(out: Path, t_end: float = 300.0) -> dict:
    """The coupon itself (``morphshell coupon``, not rendered, into ``out``) simulated at the
    nominal print: could its simulated closing times ship with it?"""
    from pysolver.coupon import make_coupon
    from pysolver.params import SIM
    from pysolver.tolerance import analysis as an

    if not (out / "coupon.csv").exists():
        make_coupon(out, render=False, progress=False)
    n = len(an.read_table(out, "cells")["cell_id"])
    r = an.run_sample(an.read_payload(out), an.nominal_perturbation(n),
                      {"t_end": t_end, "dt": SIM.dt, "thresholds": None})
    return {"cells": n, "completed": r["n_completed"], "t_end_s": t_end,
            "verdict": r["verdict"], "reasons": r["reasons"][:4]}


def reach(design: Path, compliances=(0.5, 0.6, 0.8, 1.0, 1.5, 2.0)) -> list:
    """Can the reprogramming reach a print of compliance ``s``?  Per ``s``: the share of the
    design's cells reprogrammed (exact factors) with a bracket at the thinnest printable
    thickness, and the share whose thinnest brackets close more than 10 s after t* (the
    time model's)."""
    from pysolver.params import UNIT_CELL
    from pysolver.temporal import coupon as tc

    ctx = _context(design)
    sh, h, h_min = ctx["shell"], ctx["h"], UNIT_CELL.thickness_min
    from pysolver.tolerance import coupon as cp
    rows = []
    for s in compliances:
        h2 = cp.reprogrammed_thickness(sh, h, ctx["mat"], {"compliance": {"value": s},
                                                           "modulus": {"value": 1.0}})
        t = tc.closing_times(ctx["mat"], sh["b0"], sh["x"], sh["f_bracket"],
                             np.full_like(h, h_min), s, 1.0)
        rows.append({"compliance": s,
                     "at_thinnest": float(np.mean(np.any(h2 <= h_min + 1e-6, axis=1))),
                     "late_by_10s_at_thinnest": float(np.mean(t > ctx["t_star"] + 10.0))})
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--design", default=str(ROOT / "build" / "bench" / "tolerance_petal"))
    ap.add_argument("--samples", default="2,4,20")
    ap.add_argument("--variants", default="two0,one0,two,one,oracle")
    ap.add_argument("--model-samples", type=int, default=64)
    ap.add_argument("--model-only", action="store_true")
    ap.add_argument("--reach", action="store_true",
                    help="only: how much of the design the reprogramming can reach per compliance")
    ap.add_argument("--coupon-sim", action="store_true",
                    help="also simulate the coupon itself at the nominal print")
    ap.add_argument("--out", default=str(ROOT / "build" / "bench"))
    a = ap.parse_args()
    from pysolver.core.writes import atomic_write_text

    design = Path(a.design)
    if a.reach:
        for r in reach(design):
            print(json.dumps(r), flush=True)
        return 0
    variants = a.variants.split(",")
    ctx = _context(design)
    res = {"design": str(design),
           "model": model_only(ctx, a.model_samples, variants) if a.model_samples else {}}
    for v, m in res["model"].items():
        print(f"time model, {v}: per-print RMS median {m['median_rms_s']:.2f} s, p90 "
              f"{m['p90_rms_s']:.2f} s, mean signed {m['mean_signed_s']:+.2f} s", flush=True)
    if not a.model_only:
        res["simulated"] = simulate(ctx, design, [int(x) for x in a.samples.split(",")],
                                    variants)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if a.coupon_sim:
        res["coupon_simulated"] = coupon_in_the_simulator(out / "coupon")
        print(json.dumps(res["coupon_simulated"]), flush=True)
    atomic_write_text(out / "coupon_bias.json", json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
