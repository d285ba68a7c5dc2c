"""Printed shells against their 3D scans, for every physics option (issue #32; not a test).

Reads a folder of ``../shared/printed-shells/`` (beside the clone in CI; not project data, so
this is a benchmark, and a clone without it skips with a message): the authors' stencil
(``stencil.obj``), time landscape and bracket thicknesses (``cells.csv``), the 3D scan of the
printed, morphed and dried shell (``scan_markers.obj``) and the authors' simulated markers
(``reference_simulated_markers.csv``).  For each shell:

1. **Design** through the command line, the supported path for a stencil printed elsewhere::

       morphshell design stencil.obj --stencil --time-file time_landscape.csv \\
           --thickness-file cells.csv --out <out>/printed/<shell>/design

2. **Simulate** a copy of it with each physics option and the useful combinations
   (:data:`VARIANTS`; ``morphshell simulate DIR --physics SPEC``), on Dask
   (:mod:`pysolver.distributed`, one simulation per task).
3. **Score** each against the scan with ``morphshell compare-scan DIR scan_markers.obj
   --layer bottom`` (the scan shows the -normal layer, which is morphshell's bottom): the
   printed shells' procedure, rigid registration and the mean matched distance, on the dry
   resting shape when the simulation has one.  The authors' simulated markers are scored by
   the same registration (:func:`sim.report.scan.register`).
4. **Timing** (the scan has none): per option, the simulated completion order against the
   programmed t* (Spearman), the median lateness and the cells completed.

Writes ``<out>/printed.json`` (every option's figures per shell) and
``<out>/printed_<shell>.png`` (the error of every option, and the error on the shell for the
default physics and for the reference model).

Usage::

    .venv/bin/python bench/bench_printed.py [SHELL_DIR ...] [--variants SPEC;SPEC]
        [--out build/bench] [--workers 2] [--layer bottom]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_THREAD_LIMIT", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pysolver import cli  # noqa: E402
from pysolver.core.child import python_argv  # noqa: E402
from pysolver.core.writes import atomic_write_text  # noqa: E402
from pysolver.distributed import ResultStore, Task, run_tasks  # noqa: E402
from pysolver.params import PHYSICS_DEFAULT  # noqa: E402
from pysolver.tables import read_table  # noqa: E402
from sim.model.collisions import completion_times, read_completion_frames  # noqa: E402
from sim.report.scan import plot_error_on_shell, read_points, register  # noqa: E402

SHELLS = ROOT.parent / "shared" / "printed-shells"
VARIANTS = (
    "none",
    "clearance", "bumper-compliance", "relaxation", "membrane-temperature", "gravity",
    "dry-rest", "rim", "bracket-bending", "contact",
    "relaxation,membrane-temperature",
    "clearance,bumper-compliance", "clearance,relaxation", "clearance,membrane-temperature",
    "clearance,relaxation,membrane-temperature", "clearance,gravity", "clearance,dry-rest",
    "clearance,gravity,dry-rest", "clearance,rim", "clearance,bracket-bending",
    "clearance,relaxation,membrane-temperature,gravity,dry-rest",
    "clearance,relaxation,membrane-temperature,gravity,dry-rest,rim",
    "relaxation,gravity,rim",
    "default",
)
"""Physics options simulated per shell (``--physics`` spellings): the reference model, each
effect alone, the printing clearance with each, the membrane's state in water (relaxation and
temperature together), the physical set, today's issue's worst combination and the default."""
LAYER = "bottom"
"""The scanned layer: the README of the printed shells says the -normal layer."""


def _label(spec: str) -> str:
    return spec.replace(",", "+")


def _key(spec: str) -> str:
    return spec.replace(",", "_").replace("-", "")


def _morphshell(*argv) -> None:
    cmd = [*python_argv("pysolver.cli"), *map(str, argv)]   # isolated (child.python_argv)
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stderr[-2000:]}")


def _completion(folder: Path) -> dict:
    """Simulated completion against the programmed t* (the scan has no times)."""
    from scipy.stats import spearmanr  # heavy: scipy.stats only for this summary

    t_sim = completion_times(read_completion_frames(folder))
    t_star = read_table(folder, "cells")["t_star_s"]
    ok = np.isfinite(t_sim)
    out = {"completed": int(ok.sum()), "cells": int(len(t_sim))}
    if ok.sum() > 2:
        late = t_sim[ok] - t_star[ok]
        out.update({"spearman": round(float(spearmanr(t_sim[ok], t_star[ok])[0]), 3),
                    "median_late_s": round(float(np.median(late)), 1),
                    "rms_s": round(float(np.sqrt(np.mean(late ** 2))), 1)})
        # order: mean completion of the earliest and latest third of the programmed times
        q = np.quantile(t_star, [1 / 3, 2 / 3])
        early, lateq = ok & (t_star <= q[0]), ok & (t_star >= q[1])
        if early.any() and lateq.any():
            out["first_third_s"] = round(float(np.mean(t_sim[early])), 1)
            out["last_third_s"] = round(float(np.mean(t_sim[lateq])), 1)
    return out


def _picture(path: Path, name: str, rows: dict, ref_mean: float, default: str,
             flat_xy, errors: dict) -> None:
    import matplotlib  # heavy: matplotlib only for the picture

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: matplotlib only for the picture

    specs = [s for s in rows if rows[s].get("mean_mm") is not None]
    fig = plt.figure(figsize=(16, 7))
    gs = fig.add_gridspec(1, 3, width_ratios=[1.6, 0.5, 0.5])
    ax = fig.add_subplot(gs[0])
    y = np.arange(len(specs))
    vals = [rows[s]["mean_mm"] for s in specs]
    colors = ["tab:green" if s == default else ("tab:gray" if s == "none" else "tab:blue")
              for s in specs]
    ax.barh(y, vals, color=colors)
    for yi, v in zip(y, vals, strict=True):
        ax.text(v + 0.01, yi, f"{v:.3f}", va="center", fontsize=7)
    ax.set_yticks(y, [_label(s) for s in specs], fontsize=7)
    ax.invert_yaxis()
    ax.axvline(ref_mean, color="k", ls="--", label=f"authors' simulator {ref_mean:.2f} mm")
    ax.axvline(rows["none"]["mean_mm"], color="tab:gray", ls=":",
               label=f"reference model (none) {rows['none']['mean_mm']:.2f} mm")
    lo = min(vals + [ref_mean]) - 0.15
    ax.set_xlim(max(0.0, lo), max(vals + [ref_mean]) + 0.15)
    ax.set_xlabel("mean distance scan dot - simulated marker (mm)")
    ax.set_title(f"{name}: every physics option against the scan (green: the default)",
                 fontsize=10)
    ax.legend(fontsize=8, loc="lower right")
    vmax = max(float(np.max(e)) for _, e in errors.values())
    sc = None
    for k, (spec, (ids, err)) in enumerate(errors.items()):
        a = fig.add_subplot(gs[1 + k])
        sc = plot_error_on_shell(a, flat_xy, ids, err, vmax=vmax,
                                 title=f"{_label(spec)}: mean {np.mean(err):.2f} mm")
    fig.subplots_adjust(left=0.27, right=0.9, wspace=0.3)
    fig.colorbar(sc, ax=fig.axes[1:], label="scan dot - simulated marker (mm)", shrink=0.8)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def bench_shell(src: Path, out: Path, variants, workers, layer: str) -> dict:
    name = src.name
    files = {k: src / k for k in ("stencil.obj", "cells.csv", "scan_markers.obj")}
    missing = [str(p) for p in files.values() if not p.is_file()]
    if missing:
        raise FileNotFoundError(f"{src}: missing {missing}")
    base = out / "printed" / name
    design = base / "design"
    t0 = time.perf_counter()
    argv = ["design", files["stencil.obj"], "--stencil", "--thickness-file",
            files["cells.csv"], "--out", design, "--quiet"]
    if (src / "time_landscape.csv").is_file():
        argv[3:3] = ["--time-file", src / "time_landscape.csv"]
    _morphshell(*argv)
    design_s = time.perf_counter() - t0
    folders = {}
    tasks = []
    for spec in variants:
        d = base / _key(spec)
        if d.exists():
            shutil.rmtree(d)  # a benchmark measures from scratch
        shutil.copytree(design, d, ignore=shutil.ignore_patterns("*.png"))
        folders[spec] = d
        tasks.append(Task(key=_key(spec), fn=cli.main,
                          args=(["simulate", str(d), "--physics", spec, "--quiet",
                                 "--no-resume"],),
                          fingerprint=f"{time.time_ns()}"))
    store = base / "tasks"
    if store.exists():
        shutil.rmtree(store)
    t1 = time.perf_counter()
    results, stats = run_tasks(tasks, ResultStore(store), workers=workers,
                               label=f"printed {name}")
    sim_s = time.perf_counter() - t1
    P = read_points(files["scan_markers.obj"])
    rows = {}
    errors = {}
    bases = read_table(design, "bases")
    flat = np.c_[bases["flat_x_mm"], bases["flat_y_mm"]]
    for spec, d in folders.items():
        code = results.get(_key(spec))
        if code != 0:
            rows[spec] = {"failed": stats.failed.get(_key(spec), f"exit code {code}")}
            continue
        _morphshell("compare-scan", d, files["scan_markers.obj"], "--layer", layer, "--quiet")
        r = json.loads((d / "scan_report" / f"scan_{files['scan_markers.obj'].stem}.json")
                       .read_text())
        summ = json.loads((d / "sim" / "summary.json").read_text())
        rows[spec] = {k: r[k] for k in ("mean_mm", "median_mm", "max_mm", "rms_mm", "matched",
                                        "n_scan", "n_markers", "state", "layer")}
        rows[spec]["mean_over_diameter"] = r["mean_over_diameter"]
        rows[spec]["physics"] = summ.get("physics")
        rows[spec]["sim_wall_s"] = summ.get("wall_s")
        rows[spec]["timing"] = _completion(d)
        if spec in ("none", "default"):
            pr = np.array(r["pairs"])
            errors[spec] = (pr[:, 1].astype(int), pr[:, 2])
    ref = {}
    ref_path = src / "reference_simulated_markers.csv"
    if ref_path.is_file():
        reg = register(P, read_points(ref_path))
        ref = {"mean_mm": float(reg["dist"].mean()), "median_mm": float(np.median(reg["dist"])),
               "max_mm": float(reg["dist"].max()), "matched": int(len(reg["dist"]))}
    ok = {s: v for s, v in rows.items() if "mean_mm" in v}
    best = min(ok, key=lambda s: ok[s]["mean_mm"]) if ok else None
    png = out / f"printed_{name}.png"
    if "none" in ok and errors:
        _picture(png, name, ok, ref.get("mean_mm", float("nan")), "default", flat, errors)
    return {"source": str(src), "design_folder": str(design),
            "design_command": "morphshell " + " ".join(str(a) for a in argv),
            "scored_layer": layer, "scan_points": int(len(P)),
            "reference_simulator": ref, "variants": rows, "best": best,
            "default": "default", "default_physics": PHYSICS_DEFAULT.switched_on(),
            "picture": str(png), "seconds": {"design": round(design_s, 1),
                                             "simulations": round(sim_s, 1)},
            "dask": stats.to_dict()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("shells", nargs="*", type=Path,
                    help=f"folders of printed shells (default: every folder of {SHELLS})")
    ap.add_argument("--variants", default=None,
                    help="';'-separated --physics specs (default: bench_printed.VARIANTS)")
    ap.add_argument("--out", type=Path, default=ROOT / "build" / "bench")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--layer", default=LAYER, choices=("top", "bottom", "auto"))
    a = ap.parse_args()
    shells = a.shells or (sorted(p for p in SHELLS.iterdir() if p.is_dir())
                          if SHELLS.is_dir() else [])
    if not shells:
        print(f"bench_printed: skipped, no printed shells in {SHELLS} (../shared is beside "
              "the clone in CI only)", file=sys.stderr)
        return 0
    variants = VARIANTS if a.variants is None else tuple(
        v.strip() for v in a.variants.split(";") if v.strip())
    if "none" not in variants:
        variants = ("none", *variants)
    a.out.mkdir(parents=True, exist_ok=True)
    res = {"shells": {}, "variants": list(variants), "cpu_count": os.cpu_count(),
           "load_avg": list(os.getloadavg())}
    for src in shells:
        r = bench_shell(Path(src).resolve(), a.out.resolve(), variants, a.workers, a.layer)
        res["shells"][Path(src).name] = r
        print(f"{Path(src).name}: authors' simulator "
              f"{r['reference_simulator'].get('mean_mm', float('nan')):.3f} mm", flush=True)
        for spec, v in r["variants"].items():
            print(f"  {_label(spec):<62s} " + (f"{v['mean_mm']:.3f} mm" if "mean_mm" in v
                                               else f"FAILED {v['failed'][:60]}"), flush=True)
    atomic_write_text(a.out / "printed.json", json.dumps(res, indent=1, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
