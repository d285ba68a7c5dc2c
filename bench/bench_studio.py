"""Timings of the studio on a build (not a test): the live preview and a run.

* preview: the reachable band of every cell for a painted landscape (``POST /preview`` over
  HTTP to a studio on the build, with its token), median and max of ``--previews`` requests;
  and the server's own part of it (``pysolver.studio.landscape.Feasibility.evaluate``);
* viewer: the morph viewer's data, its bytes plain and gzip-compressed (what the studio
  sends a browser that takes gzip) and the seconds to make each;
* run: *Run into a new build* (a variant beside the build, in a temporary folder beside it,
  so the render stage shares the part cache) with ``--add`` seconds added within
  ``--radius`` mm of the vertex nearest the centre: the wall time of
  ``pysolver.build.rebuild(..., out=)`` and its stages, the figures of both builds
  (``pysolver.build.report_figures``) and the painted region's cells before and after
  (``pysolver.studio.compare.compare_cells``, the studio's *Compare*).

Writes ``<out>/studio.json``.

Usage::

    .venv/bin/python bench/bench_studio.py [--build build/petal] [--out build/bench]
        [--previews 20] [--add 8] [--radius 12] [--no-run]
"""

from __future__ import annotations

import argparse
import http.client
import json
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pysolver.build import rebuild, report_figures  # noqa: E402
from pysolver.studio.compare import compare_cells  # noqa: E402
from pysolver.studio.landscape import Feasibility  # noqa: E402
from pysolver.studio.server import (  # noqa: E402
    TOKEN_HEADER,
    Build,
    StudioServer,
    resolve_folders,
)
from pysolver.tables import read_stencil, read_table  # noqa: E402


def painted(folder: Path, add: float, radius: float) -> np.ndarray:
    """The build's landscape plus ``add`` s within ``radius`` mm of its central vertex."""
    V = read_stencil(folder / "stencil.obj")[0]
    land = read_table(folder, "time_landscape")["time_s"].copy()
    c = np.argmin(np.linalg.norm(V - V.mean(axis=0), axis=1))
    land[np.linalg.norm(V - V[c], axis=1) <= radius] += add
    return land


def bench_preview(folder: Path, land: np.ndarray, n: int) -> dict:
    feas = Feasibility(folder)
    t = []
    for _ in range(n):
        t0 = time.perf_counter()
        feas.evaluate(land)
        t.append(time.perf_counter() - t0)
    srv = StudioServer(resolve_folders([folder]))
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    body = json.dumps({"landscape": land.tolist()})
    rt = []
    try:
        for _ in range(n + 1):   # the first request loads the cells and models
            c = http.client.HTTPConnection("127.0.0.1", srv.server_address[1], timeout=60)
            t0 = time.perf_counter()
            c.request("POST", "/api/build/0/preview", body=body, headers={
                "Host": f"127.0.0.1:{srv.server_address[1]}", TOKEN_HEADER: srv.token,
                "Content-Type": "application/json"})
            r = c.getresponse()
            r.read()
            rt.append(time.perf_counter() - t0)
            c.close()
            assert r.status == 200, r.status
    finally:
        srv.shutdown()
        srv.server_close()
    return {"evaluate_ms": {"median": 1e3 * float(np.median(t)), "max": 1e3 * max(t)},
            "http_ms": {"first": 1e3 * rt[0], "median": 1e3 * float(np.median(rt[1:])),
                        "max": 1e3 * max(rt[1:])},
            "n_vertices": int(len(land)),
            "n_cells": int(len(read_table(folder, "cells")["cell_id"]))}


def bench_viewer(folder: Path) -> dict:
    b = Build(folder.resolve())
    t0 = time.perf_counter()
    plain = b.viewer_body(False)
    t1 = time.perf_counter()
    packed = b.viewer_body(True)
    t2 = time.perf_counter()
    return {"plain_bytes": len(plain), "gzip_bytes": len(packed),
            "make_s": round(t1 - t0, 3), "gzip_s": round(t2 - t1, 3)}


def bench_run(folder: Path, land: np.ndarray) -> dict:
    work = Path(tempfile.mkdtemp(prefix=".bench-studio-", dir=folder.resolve().parent))
    try:
        variant = work / f"{folder.name}-2"
        t0 = time.perf_counter()
        s = rebuild(folder, land, source={"edits": [{"tool": "brush", "mode": "add"}]},
                    progress=False, out=variant)
        wall = time.perf_counter() - t0
        a, b = Build(folder.resolve()), Build(variant)
        cmp = compare_cells(b.viewer()["cells"], a.viewer()["cells"])
        figures = {"original": report_figures(folder), "variant": report_figures(variant)}
    finally:
        shutil.rmtree(work, ignore_errors=True)
    for f in figures.values():
        f.pop("reasons", None)
    return {"wall_s": round(wall, 2), "stages_s": s["timings_s"], "figures": figures,
            "region": {"n_cells": len(cmp["region"]), "variant": cmp["a"],
                       "original": cmp["b"]}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build", default="build/petal")
    ap.add_argument("--out", default="build/bench")
    ap.add_argument("--previews", type=int, default=20)
    ap.add_argument("--add", type=float, default=8.0)
    ap.add_argument("--radius", type=float, default=12.0)
    ap.add_argument("--no-run", action="store_true")
    a = ap.parse_args()
    folder = Path(a.build)
    if not (folder / "summary.json").is_file():
        print(f"[bench] {folder}: no build (make shape=petal first); skipped", file=sys.stderr)
        return 0
    land = painted(folder, a.add, a.radius)
    out = {"build": str(folder), "add_s": a.add, "radius_mm": a.radius,
           "preview": bench_preview(folder, land, a.previews)}
    print(f"[bench] preview: {out['preview']}", file=sys.stderr, flush=True)
    out["viewer"] = bench_viewer(folder)
    print(f"[bench] viewer: {out['viewer']}", file=sys.stderr, flush=True)
    if not a.no_run:
        out["run"] = bench_run(folder, land)
        print(f"[bench] run: {json.dumps(out['run'], indent=1)}", file=sys.stderr)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    (Path(a.out) / "studio.json").write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
