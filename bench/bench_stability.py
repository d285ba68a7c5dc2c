"""Design stability: the same surface gives the same shell, however it is labelled, placed or
computed (issues #28 and #42).

For each built-in shape, each of ``../shared/reference-shapes`` (cover at ``--size 106
--min-bumper 0.1``, stand at ``--size 171``) and each of ``../shared/peer-shapes`` (at the
sizes its README gives, and at ``--min-bumper 0.1``), the design stage runs in a fresh
process under these conditions:

* ``base``: as installed (2 BLAS threads on the 2-core machine);
* ``relabel``: the same surface with its vertices and faces listed in another order and each
  face's corners rotated, five times (an exact symmetry of the problem);
* ``rotate``: the same surface moved by a random rigid motion (an exact symmetry too; its
  landscape, if any, moved with it);
* ``jitter``: the input coordinates moved by 1e-7 of the size (seeded normal noise);
* ``cpu``: ``NPY_DISABLE_CPU_FEATURES="AVX2 FMA3"``, ``OPENBLAS_CORETYPE=Sandybridge``;
* ``threads1``: one BLAS / OpenMP thread.

A shape is *stable* when every run gives the base's verdict (printable, unprintable,
refused), and, printable, its bases within 3 %, 3D scaling within 1 % and longest flat cell
within 0.15 mm.  Figures: ``build/bench/stability.json`` (per shape and run: bases, 3D
scaling, longest flat cell, verdict, design seconds; per shape: stable, and the largest
deviations).  A shape missing from ``../shared`` is reported as missing, not skipped
silently.

Usage::

    .venv/bin/python bench/bench_stability.py [--shapes petal,cover,...]
        [--conditions base,relabel,rotate,jitter,cpu] [--shared ../shared] [--out build/bench]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pysolver.design import run_design, surfaces, unit_cell_options  # noqa: E402
from pysolver.design.mesh_input import size_factor  # noqa: E402
from pysolver.errors import InputError  # noqa: E402

VERTEX_RTOL, SCALE_RTOL, CELL_ATOL_MM = 0.03, 0.01, 0.15
JITTER = 1e-7
RELABELLINGS = 5
TWO = {"OPENBLAS_NUM_THREADS": "2", "OMP_NUM_THREADS": "2"}
CONDITIONS = {
    "base": TWO, "relabel": TWO, "rotate": TWO, "jitter": TWO,
    "cpu": {"NPY_DISABLE_CPU_FEATURES": "AVX2 FMA3", "OPENBLAS_CORETYPE": "Sandybridge"},
    "threads1": {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"},
}
RUNS = {"relabel": RELABELLINGS}  # runs of a condition (its seeds 1..k); one otherwise
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


def perturb(V, F, condition: str, k: int):
    """The surface ``V`` (n, 3), ``F`` (m, c) under a condition's perturbation, seeded by
    ``k``: relabelled (vertex order, face order, corners rotated), moved rigidly, or
    jittered by ``JITTER`` of its largest extent; unchanged otherwise.

    Returns
    -------
    V, F : the perturbed surface
    moved : callable or None -- maps points of the perturbed frame back to the original
        (for a landscape given as a function of the target's coordinates)
    order : (n,) int -- the original index of each perturbed vertex (for per-vertex data,
        a stencil's flat layout)
    """
    V, F = np.asarray(V, float), np.asarray(F)
    rng = np.random.default_rng(20261207 + k)
    if condition == "relabel":
        p = rng.permutation(len(V))
        inv = np.empty_like(p)
        inv[p] = np.arange(len(p))
        F = np.roll(inv[F][rng.permutation(len(F))], int(rng.integers(F.shape[1])), axis=1)
        return V[p], F, None, p
    if condition == "rotate":
        R = Rotation.random(random_state=rng).as_matrix()
        c = rng.normal(size=3) * np.ptp(V, axis=0).max()
        return V @ R.T + c, F, (lambda X: (np.asarray(X) - c) @ R), np.arange(len(V))
    if condition == "jitter":
        return (V + JITTER * np.ptp(V, axis=0).max() * rng.standard_normal(V.shape), F, None,
                np.arange(len(V)))
    return V, F, None, np.arange(len(V))


def perturbed_obj(src: Path, dst: Path, condition: str, k: int, size=None) -> Path:
    """A copy of an OBJ's surface (its ``v`` and ``f`` rows; texture and normal indices
    dropped, since the design stage reads only the positions of a target) under
    :func:`perturb`, first scaled to ``size`` (mm, largest bounding-box extent) when given:
    ``--size`` measures an axis-aligned box, which a rigid motion changes, so the rotated
    copy is written at the base's scale and designed without ``--size``."""
    V, F = [], []
    for ln in src.read_text(errors="replace").splitlines():
        w = ln.split()
        if w[:1] == ["v"]:
            V.append([float(x) for x in w[1:4]])
        elif w[:1] == ["f"]:
            F.append([int(t.split("/")[0]) for t in w[1:]])
    n = len(V)
    F = [[i - 1 if i > 0 else n + i for i in f] for f in F]
    if len({len(f) for f in F}) != 1:
        raise SystemExit(f"{src}: faces of mixed sizes; give a triangle mesh")
    V = np.array(V)
    if size is not None:
        V = V * size_factor(V, size, src.name)
    V, F, _, _ = perturb(V, np.array(F), condition, k)
    rows = ["v {:.17g} {:.17g} {:.17g}".format(*v) for v in V]
    rows += ["f " + " ".join(str(int(i) + 1) for i in f) for f in F]
    dst.write_text("\n".join(rows) + "\n")
    return dst


def probe(source: str, size, min_bumper, condition: str, k: int, out: Path) -> dict:
    """Design one case in this process; its figures (run by :func:`run_case` in a child)."""
    params = unit_cell_options(min_bumper=min_bumper)
    if surfaces.is_builtin(source) and not Path(source).exists():
        src = surfaces.builtin(source)
        V, F, back, order = perturb(src.V, src.F, condition, k)
        time_fn = src.time if back is None or src.time is None else (
            lambda X, t=src.time: t(back(X)))
        src = replace(src, V=V, F=F, time=time_fn,
                      UV=None if src.UV is None else src.UV[order])
    else:
        src = Path(source)
        if condition == "rotate" and size is not None:
            src, size = perturbed_obj(src, out.parent / f"{out.name}.obj", condition, k,
                                      size), None
        elif condition in ("relabel", "rotate", "jitter"):
            src = perturbed_obj(src, out.parent / f"{out.name}.obj", condition, k)
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


def run_case(name: str, case: tuple, condition: str, k: int, work: Path) -> dict:
    """One case under one condition (its run ``k``), in a fresh process (the environment
    variables act when numpy and OpenBLAS load)."""
    source, size, mb = case
    env = {**os.environ, **CONDITIONS[condition]}
    args = [sys.executable, "-I", __file__, "--probe", source, str(size), str(mb), condition,
            str(k), str(work / f"{name}-{condition}{k}")]
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


def runs(conds) -> list:
    """(condition, k) of every run: ``RUNS`` of a condition (seeded 1..k), else one (0)."""
    return [(c, k) for c in conds for k in (range(1, RUNS[c] + 1) if c in RUNS else [0])]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--shapes", default=None, help="comma-separated case names (default: all)")
    ap.add_argument("--conditions", default="base,relabel,rotate,jitter,cpu,threads1")
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--out", type=Path, default=ROOT / "build" / "bench")
    ap.add_argument("--jobs", type=int, default=2, help="designs at a time (default 2)")
    ap.add_argument("--resume", action="store_true",
                    help="reuse the runs a former call of the same code left in --out")
    ap.add_argument("--cached", action="store_true",
                    help="with --resume: tabulate the runs already made, run none")
    ap.add_argument("--probe", nargs=6, default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.probe:
        src, size, mb, cond, k, out = a.probe
        f = probe(src, None if size == "None" else float(size),
                  None if mb == "None" else float(mb), cond, int(k), Path(out))
        print(json.dumps(f))
        return 0
    all_cases = cases(a.shared)
    names = a.shapes.split(",") if a.shapes else list(all_cases)
    conds = a.conditions.split(",")
    unknown = [c for c in conds if c not in CONDITIONS] + [n for n in names if n not in all_cases]
    if unknown or conds[0] != "base":
        print(f"unknown condition or shape: {unknown}; the first condition must be base",
              file=sys.stderr)
        return 2
    work = a.out / "stability-work"
    work.mkdir(parents=True, exist_ok=True)
    todo = [(n, c, k) for n in names for c, k in runs(conds)
            if surfaces.is_builtin(all_cases[n][0]) or Path(all_cases[n][0]).exists()]
    # the relabellings last: they give the base's design to the last bit by construction
    # (pysolver.geometry.canonical_order), the other conditions are the informative ones
    todo.sort(key=lambda j: j[1] == "relabel")
    if a.cached:
        todo = [j for j in todo if (work / f"{j[0]}-{j[1]}{j[2]}.json").exists()]
    t_all, rows = time.perf_counter(), {}

    def one(job):
        name, c, k = job
        cache = work / f"{name}-{c}{k}.json"
        if a.resume and cache.exists():
            return job, json.loads(cache.read_text())
        r = run_case(name, all_cases[name], c, k, work)
        cache.write_text(json.dumps(r))
        return job, r
    with ThreadPoolExecutor(max_workers=max(1, a.jobs)) as pool:
        for i, (job, r) in enumerate(pool.map(one, todo)):
            rows[job] = r
            eta = (time.perf_counter() - t_all) / (i + 1) * (len(todo) - i - 1)
            print(f"[{i + 1}/{len(todo)}] {job[0]} {job[1]}{job[2] or ''}: {r.get('verdict')} "
                  f"{r.get('bases', '')} bases, scale3d {r.get('scale3d', '')}, longest cell "
                  f"{r.get('max_cell_mm', '')} mm (ETA {eta / 60:.0f} min)", flush=True)
    results = {}
    for name in names:
        if not any(j[0] == name for j in rows):
            results[name] = {"missing": all_cases[name][0]}
            print(f"{name}: no run ({all_cases[name][0]}; ../shared beside the clone?)")
            continue
        mine = {f"{c}{k or ''}": rows[(name, c, k)] for c, k in runs(conds)
                if (name, c, k) in rows}
        if "base" not in mine:
            results[name] = {"missing": "no base run"}
            continue
        base = mine["base"]
        dev = {key: compare(base, r) for key, r in mine.items() if key != "base"}
        results[name] = {"conditions": mine, "deviations": dev,
                         "stable": all(d["stable"] for d in dev.values())}
    a.out.mkdir(parents=True, exist_ok=True)
    summary = {"tolerances": {"bases_rel": VERTEX_RTOL, "scale3d_rel": SCALE_RTOL,
                              "max_cell_mm": CELL_ATOL_MM, "jitter": JITTER,
                              "relabellings": RELABELLINGS},
               "conditions": {c: CONDITIONS[c] for c in conds}, "shapes": results,
               "all_stable": all(r.get("stable", False) for r in results.values())}
    (a.out / "stability.json").write_text(json.dumps(summary, indent=1))
    print(table(results, conds))
    print(f"-> {a.out / 'stability.json'}: all stable {summary['all_stable']}")
    return 0


def table(results: dict, conds) -> str:
    """The summary as a Markdown table: per shape the base's figures and, per condition, the
    largest deviation (bases %, 3D scaling %, longest cell mm) or the verdict that changed."""
    head = ["shape", "verdict", "bases", "3D scaling", "longest cell (mm)"] + \
        [c for c in conds if c != "base"] + ["stable"]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, r in results.items():
        if "missing" in r:
            out.append(f"| {name} | missing |" + " |" * (len(head) - 2))
            continue
        b = r["conditions"]["base"]
        row = [name, b["verdict"], str(b.get("bases", "–")), str(b.get("scale3d", "–")),
               str(b.get("max_cell_mm", "–"))]
        for c in conds[1:]:
            ds = [r["deviations"][f"{c}{k or ''}"] for c2, k in runs([c])
                  if f"{c}{k or ''}" in r["deviations"]]
            if not ds:
                row.append("not run")
                continue
            if any("why" in d for d in ds):
                row.append(next(d["why"] for d in ds if "why" in d))
            elif all("bases_rel" not in d for d in ds):
                row.append("same verdict")
            else:
                row.append("{:.1f} % / {:.2f} % / {:.3f}".format(
                    100 * max(d["bases_rel"] for d in ds),
                    100 * max(d["scale3d_rel"] for d in ds), max(d["max_cell_mm"] for d in ds)))
        row.append("yes" if r["stable"] else "**no**")
        out.append("| " + " | ".join(row) + " |")
    return "\n".join(out)


if __name__ == "__main__":
    sys.exit(main())
