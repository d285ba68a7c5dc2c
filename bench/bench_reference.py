"""The reference's own cover stencil through morphshell (issue #19 bar; not a test).

Reads ``../shared/reference-shapes`` (beside the clone in CI, not project data, so this is a
benchmark and not a test; a clone on its own skips it with a message):

1. ``design cover_reference_stencil.obj --stencil --min-bumper 0.1 --time-file
   cover_reference_time_landscape.csv`` (the landscape is per stencil vertex: used as
   given), figures: 3D and flat scaling (bar: both <= 1.001), smallest printed flat gap;
2. ``program`` (the landscape is only checked, not remapped), then the Pearson correlation
   of the bracket thicknesses with ``cover_reference_cells.csv`` (bar: >= 0.9), cells
   matched by face pair, +normal layer = top (:mod:`pysolver.temporal.reference_compare`).

Writes ``<out>/reference.json`` (default ``build/bench``).

Usage::

    .venv/bin/python bench/bench_reference.py [--shared ../shared/reference-shapes]
        [--out build/bench]
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _reference import reference_options  # noqa: E402  (bench/, beside this script)

from pysolver.design import run_design, unit_cell_options  # noqa: E402
from pysolver.tables import read_cells  # noqa: E402
from pysolver.temporal import program_design  # noqa: E402
from pysolver.temporal.reference_compare import read_reference_cells, thickness_correlation  # noqa: E402

SCALE_BAR = 1.001
PEARSON_BAR = 0.9


def main() -> int:
    args = reference_options(__doc__, ROOT)
    src = Path(args.shared)
    files = {k: src / f"cover_reference_{k}" for k in
             ("stencil.obj", "time_landscape.csv", "cells.csv")}
    missing = [str(p) for p in files.values() if not p.is_file()]
    if missing:
        print(f"bench_reference: skipped, missing {missing} (../shared is beside the clone "
              "in CI only)", file=sys.stderr)
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="bench_reference_"))
    try:
        t0 = time.perf_counter()
        params = unit_cell_options(min_bumper=0.1)
        summary = run_design(files["stencil.obj"], tmp / "cover", params=params,
                             time_file=files["time_landscape.csv"], stencil=True,
                             progress=False, plots=False)
        t_design = time.perf_counter() - t0
        program_design(tmp / "cover", progress=False, picture=False)
        t_program = time.perf_counter() - t0 - t_design
        cells = read_cells(tmp / "cover" / "cells.csv")
        corr = thickness_correlation(cells, read_reference_cells(files["cells.csv"]))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    sc = summary["scale"]
    res = {
        "stencil": str(files["stencil.obj"]), "min_bumper_mm": params.min_bumper,
        "scale3d": sc["scale3d"], "scale2d": sc["scale2d"], "scale2d_rule": sc["scale2d_rule"],
        "min_printed_flat_gap_mm": summary["checks"]["figures"].get("min_flat_gap_mm"),
        "scale_bar": SCALE_BAR,
        "scales_pass": bool(sc["scale3d"] <= SCALE_BAR and sc["scale2d"] <= SCALE_BAR),
        "thickness": corr, "pearson_bar": PEARSON_BAR,
        "pearson_pass": bool(corr["pearson"] >= PEARSON_BAR),
        "seconds": {"design": round(t_design, 2), "program": round(t_program, 2)},
    }
    (out / "reference.json").write_text(json.dumps(res, indent=2) + "\n")
    print(f"reference cover: scale3d {sc['scale3d']:.6f}, scale2d {sc['scale2d']:.6f} "
          f"(bar {SCALE_BAR}); thickness Pearson {corr['pearson']:.3f} (top "
          f"{corr['pearson_top']:.3f}, bottom {corr['pearson_bottom']:.3f}; bar {PEARSON_BAR})"
          f" -> {out / 'reference.json'}")
    return 0 if res["scales_pass"] and res["pearson_pass"] else 1


if __name__ == "__main__":
    sys.exit(main())
