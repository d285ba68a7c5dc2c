"""The longest flat cell of one target's candidates over a range of vertex counts, with the
stencil's rim held or sliding (``StencilSearch.opt_slide_rim``).

Each count is made and optimised as the count search makes a candidate (first rim inset,
one seed), then laid out; the table says whether the longest flat cell is a rim cell.

Usage::

    .venv/bin/python bench/scan_counts.py TARGET.obj --size 171 --counts 256,260,264,268,272
        [--min-bumper 0.1] [--seed 0] [--out build/bench]

Writes ``build/bench/scan_counts.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pysolver.design import unit_cell_options  # noqa: E402
from pysolver.design.flatten import cetm  # noqa: E402
from pysolver.design.layout import build_layout  # noqa: E402
from pysolver.design.mesh_input import load_input  # noqa: E402
from pysolver.design.stencil.count_search import CountSearch  # noqa: E402
from pysolver.design.stencil.remesh import needs_dense, resample_dense  # noqa: E402
from pysolver.params import STENCIL  # noqa: E402


def scan(V, F, counts, params, settings, seed: int = 0) -> list:
    """One row per count: 3D scaling, longest flat cell (mm), whether it is a rim cell, and
    the longest interior cell (mm)."""
    if needs_dense(V, F, settings):
        V, F = resample_dense(V, F, settings.dense_faces)
    search = CountSearch(V, F, None, params=params, settings=settings, method="cvt",
                         optimize=True, graded=False)
    inset = search.insets[0]
    rows = []
    for n in counts:
        n = search.trial(n, seed, inset, given=True)  # (the count asked for, off the ladder)
        V2, F2, _ = search.meshes[(n, seed, float(inset))]
        UV, _, _ = cetm(V2, F2)
        lay = build_layout(V2, UV, F2, params)
        L, rim = lay.central_length, lay.cells.boundary
        i = int(np.argmax(L))
        rows.append({"vertices": n, "scale3d": round(float(lay.scale3d), 4),
                     "longest_mm": round(float(L[i]), 3), "longest_on_rim": bool(rim[i]),
                     "longest_interior_mm": round(float(L[~rim].max()), 3)})
        print(json.dumps(rows[-1]), flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("target", type=Path)
    ap.add_argument("--size", type=float, required=True, help="largest extent, mm")
    ap.add_argument("--counts", required=True, help="comma-separated vertex counts")
    ap.add_argument("--min-bumper", type=float, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=ROOT / "build" / "bench")
    a = ap.parse_args()
    surf = load_input(a.target, size=a.size)
    params = unit_cell_options(min_bumper=a.min_bumper)
    counts = [int(x) for x in a.counts.split(",")]
    out = {"target": str(a.target), "size_mm": a.size, "min_bumper": a.min_bumper}
    for mode, slide in (("held", False), ("sliding", True)):
        print(f"rim {mode}:", flush=True)
        out[mode] = scan(surf.V, surf.F, counts, params,
                         replace(STENCIL, opt_slide_rim=slide), a.seed)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "scan_counts.json").write_text(json.dumps(out, indent=1))
    print(f"-> {a.out / 'scan_counts.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
