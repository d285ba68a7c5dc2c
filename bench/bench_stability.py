"""Design stability: every shape gives the same shell under last-bit perturbations (issue #28).

For each built-in shape, each of ``../shared/reference-shapes`` (cover at ``--size 106
--min-bumper 0.1``, stand at ``--size 171``) and each of ``../shared/peer-shapes`` (at the
sizes its README gives, and at ``--min-bumper 0.1``), the design stage runs in a fresh
process under four conditions:

* ``base``: as installed (2 BLAS threads on the 2-core machine);
* ``jitter``: the input coordinates moved by 1e-9 of the size (seeded normal noise);
* ``cpu``: ``NPY_DISABLE_CPU_FEATURES="AVX2 FMA3"``, ``OPENBLAS_CORETYPE=Sandybridge``;
* ``threads1``: one BLAS / OpenMP thread.

A shape is *stable* when every condition gives the base's verdict (printable, unprintable,
refused), and, printable, its bases within 3 %, 3D scaling within 1 % and longest flat cell
within 0.1 mm.  Figures: ``build/bench/stability.json`` (per shape and condition: bases,
3D scaling, longest flat cell, verdict, design seconds; per shape: stable, and the largest
deviations).  A shape missing from ``../shared`` is reported as missing, not skipped
silently.

Usage::

    .venv/bin/python bench/bench_stability.py [--shapes petal,cover,...] [--conditions ...]
        [--shared ../shared] [--out build/bench]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pysolver.design import run_design, surfaces, unit_cell_options  # noqa: E402
from pysolver.errors import InputError  # noqa: E402

VERTEX_RTOL, SCALE_RTOL, CELL_ATOL_MM = 0.03, 0.01, 0.1
JITTER = 1e-9
CONDITIONS = {
    "base": {"OPENBLAS_NUM_THREADS": "2", "OMP_NUM_THREADS": "2"},
    "jitter": {"OPENBLAS_NUM_THREADS": "2", "OMP_NUM_THREADS": "2"},
    "cpu": {"NPY_DISABLE_CPU_FEATURES": "AVX2 FMA3", "OPENBLAS_CORETYPE": "Sandybridge"},
    "threads1": {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"},
}
PEERS = (("hemisphere", 100.0), ("saddle", 120.0), ("top", 120.0), ("hat", 140.0),
         ("face", 120.0), ("beetle", 150.0))


def cases(shared: Path) -> dict:
    """name -> (source, size mm or None, min bumper mm or None)."""
    out = {name: (name, None, None) for name in surfaces.BUILTIN}
    ref = shared / "reference-shapes"
    out["cover"] = (str(ref / "cover_src.obj"), 106.0, 0.1)
    out["stand"] = (str(ref / "stand_src.obj"), 171.0, None)
    for name, size in PEERS:
        out[f"peer-{name}"] = (str(shared / "peer-shapes" / f"{name}.obj"), size, None)
        out[f"peer-{name}-0.1"] = (str(shared / "peer-shapes" / f"{name}.obj"), size, 0.1)
    return out


def jittered_obj(src: Path, dst: Path, size: float) -> Path:
    """A copy of an OBJ with every ``v`` row moved by ``JITTER`` of its largest extent
    (seeded), the rest of the file unchanged."""
    lines = src.read_text(errors="replace").splitlines()
    V = np.array([[float(x) for x in ln.split()[1:4]] for ln in lines if ln.startswith("v ")])
    rng = np.random.default_rng(20261127)
    V = V + JITTER * np.ptp(V, axis=0).max() * rng.standard_normal(V.shape)
    rows = iter(V)
    out = [("v {:.17g} {:.17g} {:.17g}".format(*next(rows)) if ln.startswith("v ") else ln)
           for ln in lines]
    dst.write_text("\n".join(out) + "\n")
    return dst


def probe(source: str, size, min_bumper, jitter: bool, out: Path) -> dict:
    """Design one case in this process; its figures (run by :func:`run_case` in a child)."""
    params = unit_cell_options(min_bumper=min_bumper)
    if surfaces.is_builtin(source) and not Path(source).exists():
        src = surfaces.builtin(source)
        if jitter:
            rng = np.random.default_rng(20261127)
            src.V = src.V + JITTER * np.ptp(src.V, axis=0).max() * rng.standard_normal(
                src.V.shape)
    else:
        src = Path(source)
        if jitter:
            src = jittered_obj(src, out.parent / f"{out.name}.obj", size)
    t0 = time.perf_counter()
    try:
        s = run_design(src, out, size=size, params=params, progress=False, plots=False)
    except InputError as e:
        return {"verdict": "refused", "why": e.problem[:300],
                "design_s": round(time.perf_counter() - t0, 1)}
    return {"verdict": "printable" if s["checks"]["ok"] else "unprintable",
            "bases": s["counts"]["bases"], "scale3d": round(s["scale"]["scale3d"], 5),
            "max_cell_mm": round(s["cell_length_mm"]["max"], 4),
            "design_s": round(time.perf_counter() - t0, 1)}


def run_case(name: str, case: tuple, condition: str, work: Path) -> dict:
    """One case under one condition, in a fresh process (the environment variables act
    when numpy and OpenBLAS load)."""
    source, size, mb = case
    env = {**os.environ, **CONDITIONS[condition]}
    args = [sys.executable, __file__, "--probe", source, str(size), str(mb),
            str(condition == "jitter"), str(work / f"{name}-{condition}")]
    r = subprocess.run(args, capture_output=True, text=True, env=env, cwd=ROOT)
    if r.returncode != 0:
        return {"verdict": "error", "why": r.stderr.strip().splitlines()[-1:]}
    return json.loads(r.stdout.strip().splitlines()[-1])


def compare(base: dict, other: dict) -> dict:
    """Deviations of ``other`` from ``base`` and whether they are within the tolerances."""
    if base["verdict"] != other["verdict"]:
        return {"stable": False, "why": f"verdict {base['verdict']} -> {other['verdict']}"}
    if base["verdict"] == "refused" or "bases" not in base:
        return {"stable": True}
    d = {"bases_rel": abs(other["bases"] / base["bases"] - 1),
         "scale3d_rel": abs(other["scale3d"] / base["scale3d"] - 1),
         "max_cell_mm": abs(other["max_cell_mm"] - base["max_cell_mm"])}
    d["stable"] = (d["bases_rel"] <= VERTEX_RTOL and d["scale3d_rel"] <= SCALE_RTOL
                   and d["max_cell_mm"] <= CELL_ATOL_MM)
    return {k: (round(v, 5) if isinstance(v, float) else v) for k, v in d.items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--shapes", default=None, help="comma-separated case names (default: all)")
    ap.add_argument("--conditions", default=",".join(CONDITIONS))
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--out", type=Path, default=ROOT / "build" / "bench")
    ap.add_argument("--probe", nargs=5, default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.probe:
        src, size, mb, jit, out = a.probe
        f = probe(src, None if size == "None" else float(size),
                  None if mb == "None" else float(mb), jit == "True", Path(out))
        print(json.dumps(f))
        return 0
    all_cases = cases(a.shared)
    names = a.shapes.split(",") if a.shapes else list(all_cases)
    conds = a.conditions.split(",")
    work = a.out / "stability-work"
    work.mkdir(parents=True, exist_ok=True)
    results, t_all = {}, time.perf_counter()
    for i, name in enumerate(names):
        src = all_cases[name][0]
        if not surfaces.is_builtin(src) and not Path(src).exists():
            results[name] = {"missing": src}
            print(f"{name}: {src} missing (../shared beside the clone)", flush=True)
            continue
        rows = {c: run_case(name, all_cases[name], c, work) for c in conds}
        base = rows[conds[0]]
        dev = {c: compare(base, rows[c]) for c in conds[1:]}
        results[name] = {"conditions": rows, "deviations": dev,
                         "stable": all(d["stable"] for d in dev.values())}
        done = time.perf_counter() - t_all
        eta = done / (i + 1) * (len(names) - i - 1)
        print(f"[{i + 1}/{len(names)}] {name}: {base.get('verdict')} "
              f"{base.get('bases', '')} bases, scale3d {base.get('scale3d', '')}, longest cell "
              f"{base.get('max_cell_mm', '')} mm; stable {results[name]['stable']} "
              f"(ETA {eta / 60:.0f} min)", flush=True)
    a.out.mkdir(parents=True, exist_ok=True)
    summary = {"tolerances": {"bases_rel": VERTEX_RTOL, "scale3d_rel": SCALE_RTOL,
                              "max_cell_mm": CELL_ATOL_MM, "jitter": JITTER},
               "conditions": CONDITIONS, "shapes": results,
               "all_stable": all(r.get("stable", False) for r in results.values())}
    (a.out / "stability.json").write_text(json.dumps(summary, indent=1))
    print(f"-> {a.out / 'stability.json'}: all stable {summary['all_stable']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
