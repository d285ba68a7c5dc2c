"""Cross-check of the fast renderer (openscad-evaluator) against Debian OpenSCAD (not a test).

For each shape: the design tables (``run_design``, no programming stage; ``--vary-thickness``
sets per-cell thicknesses 0.30-0.65 mm as ``tests/test_render.py`` does), every part file,
rendered with cold caches by both backends (``render_parts(renderer="openscad")`` and
``renderer="fast"``, no fallback hidden: fallbacks are counted), then per part:

* both part STLs closed 2-manifolds (manifold3d),
* relative volume difference ``|V_fast - V_openscad| / V_openscad`` (limit 1e-4),
* symmetric-difference volume via manifold3d booleans, relative to V_openscad (limit 1e-3),

and per layer (``render_design`` with each cache, all parts cached by then): watertight, one
body, volume.  Writes ``<out>/render_fast.json`` with per-part timings (mean, median, p90 of
the per-part renderer wall time, pool wall time per part, CPU per part) and agreement figures.

Usage::

    .venv/bin/python bench/bench_render_fast.py [--shapes regular dome petal] [--out /tmp/x]
        [--jobs 2] [--vary-thickness]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pysolver import tables  # noqa: E402
from pysolver.design import run_design  # noqa: E402
from pysolver.render import load_stl, render_design, render_parts, to_manifold  # noqa: E402
from pysolver.render import parts as render  # noqa: E402
from pysolver.render.scad_io import write_part_files  # noqa: E402

VOLUME_RTOL = 1e-4
SYMDIFF_RTOL = 1e-3


def _stats(x) -> dict:
    x = np.asarray(list(x), float)
    if x.size == 0:
        return {}
    return {"n": int(x.size), "mean": float(x.mean()), "median": float(np.median(x)),
            "p90": float(np.percentile(x, 90)), "max": float(x.max()), "min": float(x.min())}


def bench_shape(shape: str, root: Path, jobs: int, vary: bool) -> dict:
    design = root / shape
    if not (design / "bases.csv").is_file():
        run_design(shape, design, progress=False, plots=False)
    if vary:
        cells = tables.read_table(design, "cells")
        k = np.arange(len(cells["cell_id"]))
        cells["thickness_top_mm"] = 0.30 + 0.05 * (k % 8)
        cells["thickness_bottom_mm"] = 0.65 - 0.05 * (k % 8)
        tables.write_table(design, "cells", cells)
    tag = "vary" if vary else "plain"
    parts = write_part_files(design, design / "scad")
    out = {"shape": shape, "parts": len(parts), "bases": int(sum(p.kind == "node"
                                                                 for p in parts) // 2)}
    res = {}
    for name in ("openscad", "fast"):
        cache = root / f"cache_{shape}_{name}_{tag}"
        shutil.rmtree(cache, ignore_errors=True)
        print(f"[bench] {shape}: {len(parts)} parts with {name} ...", file=sys.stderr, flush=True)
        r = render_parts(parts, cache_dir=cache, jobs=jobs, renderer=name, progress=True)
        res[name] = r
        out[name] = {"version": r["renderer_version"], "rendered": r["rendered"],
                     "wall_s": r["wall_s"], "wall_s_per_part": r["wall_s"] / len(parts),
                     "cpu_s_per_part": r["cpu_s"] / len(parts),
                     "seconds_per_part": _stats(r["seconds"].values()),
                     "fallback": r["fallback"]}
    t0 = time.perf_counter()
    rows = []
    for p in parts:
        a = to_manifold(load_stl(res["openscad"]["stl"][p.name]), f"{p.name} openscad")
        b = to_manifold(load_stl(res["fast"]["stl"][p.name]), f"{p.name} fast")
        va, vb = a.volume(), b.volume()
        sym = (a - b).volume() + (b - a).volume()
        rows.append({"part": p.name, "kind": p.kind, "volume_openscad": va, "volume_fast": vb,
                     "volume_rel": abs(vb - va) / va, "symdiff_rel": sym / va,
                     "genus_equal": a.genus() == b.genus(),
                     "seconds_openscad": res["openscad"]["seconds"].get(p.name),
                     "seconds_fast": res["fast"]["seconds"].get(p.name)})
    out["compare_s"] = time.perf_counter() - t0
    vr = np.array([r["volume_rel"] for r in rows])
    sr = np.array([r["symdiff_rel"] for r in rows])
    out["agreement"] = {
        "volume_rel": _stats(vr), "symdiff_rel": _stats(sr),
        "parts_over_volume_limit": [r["part"] for r in rows if r["volume_rel"] > VOLUME_RTOL],
        "parts_over_symdiff_limit": [r["part"] for r in rows if r["symdiff_rel"] > SYMDIFF_RTOL],
        "genus_differs": [r["part"] for r in rows if not r["genus_equal"]],
        "worst": sorted(rows, key=lambda r: -r["symdiff_rel"])[:5],
        "by_kind": {k: {"volume_rel_max": float(max(r["volume_rel"] for r in rows
                                                    if r["kind"] == k)),
                        "symdiff_rel_max": float(max(r["symdiff_rel"] for r in rows
                                                     if r["kind"] == k))}
                    for k in sorted({r["kind"] for r in rows})},
    }
    layers = {}
    for name in ("openscad", "fast"):
        copy = root / f"{shape}_{name}_{tag}"
        shutil.rmtree(copy, ignore_errors=True)
        shutil.copytree(design, copy, ignore=shutil.ignore_patterns("scad", "stl"))
        s = render_design(copy, cache_dir=root / f"cache_{shape}_{name}_{tag}", jobs=jobs,
                          renderer=name, progress=False)
        layers[name] = {k: {"watertight": s["watertight"][k], "bodies": s["bodies"][k],
                            "volume_mm3": s["volumes_mm3"][k]} for k in s["volumes_mm3"]}
        layers[name]["union_s"] = s["timings_s"]["union"]
    out["layers"] = layers
    out["layer_volume_rel"] = {
        k: abs(layers["fast"][k]["volume_mm3"] - layers["openscad"][k]["volume_mm3"])
        / layers["openscad"][k]["volume_mm3"] for k in layers["openscad"] if k != "union_s"}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shapes", nargs="+", default=["regular", "dome", "petal"])
    ap.add_argument("--out", default="/tmp/x")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--vary-thickness", action="store_true")
    args = ap.parse_args(argv)
    root = Path(args.out)
    root.mkdir(parents=True, exist_ok=True)
    report = {"jobs": args.jobs, "vary_thickness": args.vary_thickness,
              "loadavg_start": os.getloadavg(),
              "openscad": render.openscad_version(render.find_openscad()),
              "limits": {"volume_rel": VOLUME_RTOL, "symdiff_rel": SYMDIFF_RTOL}, "shapes": {}}
    for shape in args.shapes:
        report["shapes"][shape] = bench_shape(shape, root, args.jobs, args.vary_thickness)
        r = report["shapes"][shape]
        print(f"[bench] {shape}: {r['parts']} parts; openscad "
              f"{r['openscad']['wall_s_per_part']:.3f} s/part wall, fast "
              f"{r['fast']['wall_s_per_part']:.3f} s/part wall; volume_rel max "
              f"{r['agreement']['volume_rel']['max']:.2e}, symdiff_rel max "
              f"{r['agreement']['symdiff_rel']['max']:.2e}; fallbacks "
              f"{len(r['fast']['fallback'])}", file=sys.stderr, flush=True)
    report["loadavg_end"] = os.getloadavg()
    name = "render_fast_vary.json" if args.vary_thickness else "render_fast.json"
    (root / name).write_text(json.dumps(report, indent=1, default=float) + "\n")
    print(f"[bench] wrote {root / name}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
