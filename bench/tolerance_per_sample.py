"""Per print of a coupon tolerance run: on time without and with the coupon (issue #45; not a
test).

Reads a tolerance folder written with ``--coupon`` (``summary.json``, ``samples/*.json``) and
its design's ``cells.csv``; prints, per sample, the drawn and fitted compliance, P(cell within
``time_tol_s``) without and with the coupon, and the mean signed error ``T - t*`` over the
cells that complete (s; negative = early); then the means over all samples and without the
prints where nothing completes.  ``--same OTHER``: the largest difference between the
results both folders hold under the same name (every number but the wall time), e.g. two
runs from scratch: a rerun check (``--skip-coupon``: all but the coupon runs, for two codes
whose coupon fit differs).

Usage::

    .venv/bin/python bench/tolerance_per_sample.py build/bench/tolerance_petal_w1
        [--design build/bench/tolerance_petal] [--same OTHER_TOLERANCE_FOLDER]
        [--skip-coupon] [--plot PNG] [--other LABEL=OTHER_TOLERANCE_FOLDER]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _result(folder: Path, name: str) -> dict:
    """A stored task result (``samples/NAME.json``, its ``result``)."""
    return json.loads((folder / "samples" / name).read_text())["result"]


def _times(rec: dict) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in rec["t_done"]], float)


def per_sample(folder: Path, t_star, tol: float) -> list:
    s = json.loads((folder / "summary.json").read_text())
    fits = s["options"]["coupon"]["fits"]
    rows = []
    for i in range(s["options"]["samples"]):
        row = {"sample": i}
        for kind in ("sample", "coupon"):
            T = _times(_result(folder, f"{kind}-{i:05d}.json"))
            ok = np.isfinite(T)
            row[f"p_{kind}"] = float(np.mean(ok & (np.abs(np.where(ok, T, 0) - t_star) <= tol)))
            row[f"mean_error_{kind}_s"] = float(np.mean(T[ok] - t_star[ok])) if ok.any() else None
        f = fits[i] or {}
        row.update({"drawn_compliance": f.get("drawn_compliance"),
                    "fit_compliance": f.get("compliance"), "fit_modulus": f.get("modulus")})
        rows.append(row)
    return rows


def _diff(a, b) -> float:
    if isinstance(a, dict) and isinstance(b, dict):
        return max([_diff(a[k], b.get(k)) for k in a if k != "wall_s"], default=0.0)
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return max([_diff(x, y) for x, y in zip(a, b, strict=True)], default=0.0)
    if isinstance(a, bool | str | type(None)) or isinstance(b, bool | str | type(None)):
        return 0.0 if a == b else float("inf")
    return abs(float(a) - float(b))


def same(a: Path, b: Path, skip_coupon: bool = False) -> dict:
    names = sorted({p.name for p in (a / "samples").glob("*.json")}
                   & {p.name for p in (b / "samples").glob("*.json")})
    if skip_coupon:
        names = [n for n in names if not n.startswith("coupon-")]
    d = [_diff(_result(a, n), _result(b, n)) for n in names]
    return {"shared_results": len(names), "largest_difference": max(d, default=None)}


def plot(rows: list, others: dict, png: Path) -> None:
    """Each print's mean signed error (s) against its drawn compliance: without the coupon,
    with it, and with the coupon of each ``others`` folder (label -> rows)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.2), dpi=110)
    s = [r["drawn_compliance"] for r in rows]
    ax.scatter(s, [r["mean_error_sample_s"] for r in rows], c="0.6", s=18, label="no coupon")
    ax.scatter(s, [r["mean_error_coupon_s"] for r in rows], c="C0", s=22,
               label="coupon (this run)")
    for k, (label, rr) in enumerate(others.items()):
        ax.scatter([r["drawn_compliance"] for r in rr], [r["mean_error_coupon_s"] for r in rr],
                   marker="x", c=f"C{k + 1}", s=22, label=f"coupon ({label})")
    ax.axhspan(-10, 10, color="C2", alpha=0.08, lw=0)
    ax.axhline(0, c="k", lw=0.6)
    ax.set_xscale("log")
    ax.set_ylim(-30, 35)
    ax.set_xlabel("drawn bracket compliance s (per print)")
    ax.set_ylabel("mean of T - t* over completed cells (s)")
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder")
    ap.add_argument("--design", default=str(ROOT / "build" / "bench" / "tolerance_petal"))
    ap.add_argument("--same", default=None)
    ap.add_argument("--tol", type=float, default=10.0)
    ap.add_argument("--plot", default=None, help="PNG of each print's mean error")
    ap.add_argument("--other", default=None,
                    help="LABEL=FOLDER: another coupon run's prints on the plot")
    ap.add_argument("--skip-coupon", action="store_true",
                    help="--same compares all but the coupon runs (two codes whose coupon fit "
                         "differs)")
    a = ap.parse_args()
    from pysolver.tables import read_table

    t_star = np.asarray(read_table(Path(a.design), "cells")["t_star_s"], float)
    rows = per_sample(Path(a.folder), t_star, a.tol)
    for r in rows:
        print(json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in r.items()}))
    live = [r for r in rows if r["mean_error_sample_s"] is not None]
    out = {k: {"all": float(np.mean([r[k] for r in rows])),
               "without_prints_where_nothing_completes": float(np.mean([r[k] for r in live]))}
           for k in ("p_sample", "p_coupon")}
    out["mean_abs_error_coupon_s"] = float(np.mean([abs(r["mean_error_coupon_s"]) for r in live
                                                    if r["mean_error_coupon_s"] is not None]))
    out["mean_error_coupon_s"] = float(np.mean([r["mean_error_coupon_s"] for r in live
                                               if r["mean_error_coupon_s"] is not None]))
    if a.plot:
        others = {}
        if a.other:
            label, folder = a.other.split("=", 1)
            others[label] = per_sample(Path(folder), t_star, a.tol)
        plot(rows, others, Path(a.plot))
    if a.same:
        out["same"] = same(Path(a.folder), Path(a.same), a.skip_coupon)
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
