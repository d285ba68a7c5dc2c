"""Benchmark of the morphing simulator (not a test).

A shell the size of the paper's largest example (549 rigid bodies, 7942 membrane elements):
by default ``petal:size=1.6``, 582 bases with the automatic stencil search (until issue #19,
with hand-tuned counts, ``petal:size=1.7`` had 588 bases and 9139 membrane triangles), programmed
with the fitted bracket model, simulated for 240 steps of 0.5 s (plus the dry step).
(``--shape weave:large`` matches the paper's body count, 551 bases, but not its membrane:
its lattice cells are 5.9 mm, so only 4138 triangles.)  Writes

* ``build/bench/sim.json`` -- ``wall_s`` (total simulation wall time of the default ``fast``
  solver path), its split (factorisation, linear solves, assembly + line search + other), CPU
  time, per-step wall and Newton iterations (mean / median / max), peak memory, model sizes,
  machine load; under ``solvers`` the same for each path timed, and with both paths (the
  default) ``speedup_vs_reference`` and the largest difference of their final base centres
  (mm) and completion times (s);
* ``build/bench/sim_profile_<solver>.txt`` -- cProfile, top entries by internal time;
* under ``physics`` in ``sim.json``: the cost of each physics option (issues #18, #32,
  ``docs/physics.md``), each switched on in addition to the default physics
  (:data:`~pysolver.params.PHYSICS_DEFAULT`) on the default (``fast``) path after the runs
  above: its wall time, Newton iterations and ``wall_ratio`` to the default run
  (``--effects none`` skips them).

Usage::

    .venv/bin/python bench/bench_sim.py [--shape petal:size=1.6] [--t-end 120] [--out build/bench]
                                        [--solver both|fast|reference]
                                        [--effects relaxation,gravity,...|none]

Fallbacks: if the design stage cannot build the shape, a synthetic 546-base regular patch on a
spherical cap is used; if the fitted bracket model is missing, a stand-in force law (recorded
in the JSON).  The machine may be shared: the JSON records the load average and CPU time.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import pstats
import resource
import shutil
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_THREAD_LIMIT", "1")  # before anything loads CHOLMOD / OpenMP

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # test fixtures: synthetic shells, stand-in material


def _design_key(shape: str) -> str:
    """Cache key of a design: the shape spec and the design code that makes it."""
    import hashlib

    import pysolver

    h = hashlib.sha256(shape.encode())
    for f in sorted(Path(pysolver.__file__).parent.glob("*.py")):
        h.update(f.read_bytes())
    return h.hexdigest()


def _design(shape: str, folder: Path, log) -> str:
    """Create the design folder (cached on the shape and the design code); returns a
    description of what was built."""
    from pysolver.errors import InputError

    key = _design_key(shape)
    src, keyfile = folder / ".bench_source", folder / ".bench_key"
    if (folder / "cells.csv").exists() and src.exists() and keyfile.exists() \
            and keyfile.read_text() == key:
        return src.read_text()
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True, exist_ok=True)
    try:
        from pysolver.design import run_design

        run_design(shape, folder, progress=False, plots=False)
        desc = f"design stage: {shape}"
    except (ImportError, InputError) as e:
        log(f"design of {shape!r} failed ({e}); using a synthetic regular patch")
        from synthetic import regular_stencil, write_design

        write_design(folder, regular_stencil(22, 14, central_length=7.0, radius=90.0), 0.45)
        desc = "synthetic regular patch 22x14 on a spherical cap (R = 90 mm)"
    src.write_text(desc)
    keyfile.write_text(key)
    return desc


def _load_material(log):
    from pysolver.errors import InputError

    try:
        from pysolver.material.model import load_bracket_model

        mat = load_bracket_model()
        return mat, str(mat.path)
    except (ImportError, InputError) as e:
        from synthetic import StandInBracketModel

        log(f"no fitted bracket model ({e}); using the stand-in force law")
        return StandInBracketModel(t_soft=20.0), "stand-in (tests/synthetic.py)"


def _material(folder: Path, log):
    from pysolver.errors import InputError

    try:
        from pysolver.material.model import load_bracket_model

        mat = load_bracket_model()
    except (ImportError, InputError) as e:
        from synthetic import StandInBracketModel

        log(f"no fitted bracket model ({e}); using the stand-in force law")
        return StandInBracketModel(t_soft=20.0), "stand-in (tests/synthetic.py)", "design default"
    try:
        from pysolver.temporal import program_design

        program_design(folder, material=mat, progress=False, picture=False, fit_landscape=True)
        prog = "programmed (pysolver.temporal)"
    except (ImportError, InputError) as e:
        log(f"programming failed ({e}); keeping the design thicknesses")
        prog = "design default"
    return mat, str(getattr(mat, "path", type(mat).__name__)), prog


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--shape", default="petal:size=1.6")
    ap.add_argument("--t-end", type=float, default=120.0)
    ap.add_argument("--out", default=str(ROOT / "build" / "bench"))
    ap.add_argument("--top", type=int, default=30, help="profile entries to keep")
    ap.add_argument("--solver", choices=("both", "fast", "reference"), default="both",
                    help="solver path(s) to time (default: both, and their ratio)")
    ap.add_argument("--effects", default="relaxation,membrane_temperature,gravity,dry_rest,rim,"
                                         "contact,bracket_bending",
                    help="physics options to time one by one on the fast path (or none)")
    ap.add_argument("--prepare-only", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    def log(msg):
        print(f"[bench_sim] {msg}", file=sys.stderr, flush=True)

    folder = out / f"sim_{args.shape.replace(':', '_').replace('=', '')}"
    t0 = time.perf_counter()
    if args.prepare_only:  # child process: design + programming (their memory is not ours)
        _design(args.shape, folder, log)
        _, mat_desc, prog = _material(folder, log)
        (folder / ".bench_program").write_text(prog)
        return 0
    import subprocess

    subprocess.run([sys.executable, __file__, "--prepare-only", "--shape", args.shape,
                    "--out", str(out)], check=True)
    source = (folder / ".bench_source").read_text()
    prog = (folder / ".bench_program").read_text()
    mat, mat_desc = _load_material(log)
    t_prep = time.perf_counter() - t0

    from pysolver.mechanics import kernels, load_model

    t0 = time.perf_counter()
    kernels.warm_up()  # numba compilation (cached on disk after the first run)
    t_compile = time.perf_counter() - t0
    model = load_model(folder)
    log(f"{source}: {model.summary()}; material {mat_desc}; thickness {prog}")
    runs, finals = {}, {}
    for solver in (["fast", "reference"] if args.solver == "both" else [args.solver]):
        runs[solver], finals[solver] = _simulate(folder, mat, solver, args, out, log)
    fast = runs[next(iter(runs))]
    res = dict(fast)
    res.update({
        "solvers": runs,
        "model": model.summary(),
        "source": source,
        "material": mat_desc,
        "thickness": prog,
        "numba": kernels.HAVE_NUMBA,
        "numba_compile_s": round(t_compile, 2),
        "prepare_s": round(t_prep, 2),
        "cpu_count": os.cpu_count(),
        "omp_thread_limit": os.environ.get("OMP_THREAD_LIMIT"),
        "target_wall_s": 20.0,
    })
    if len(runs) == 2:
        res["speedup_vs_reference"] = round(runs["reference"]["wall_s"] / runs["fast"]["wall_s"],
                                            2)
        a, b = finals["fast"], finals["reference"]
        res["final_position_difference_mm"] = float(np.abs(a[0] - b[0]).max())
        res["completion_time_difference_s"] = float(np.nanmax(np.abs(a[1] - b[1]))
                                                    if np.isfinite(a[1]).any() else 0.0)
    if args.effects != "none" and "fast" in runs:
        import dataclasses

        from pysolver.params import PHYSICS_DEFAULT

        res["physics"] = {}
        for eff in args.effects.split(","):
            ph = dataclasses.replace(PHYSICS_DEFAULT, **{eff: True})
            r, _ = _simulate(folder, mat, "fast", args, out, log, physics=ph, tag=eff)
            res["physics"][eff] = {
                "wall_s": r["wall_s"], "cpu_s": r["cpu_s"],
                "wall_ratio": round(r["wall_s"] / runs["fast"]["wall_s"], 3),
                "newton_iterations": r["newton_iterations"]["total"],
                "converged_steps": r["converged_steps"], "steps": r["steps"],
                "completed_cells": r["completed_cells"],
                "dry_rest": r["summary"].get("dry_rest"),
                "loadavg_start": r["loadavg_start"]}
    (out / "sim.json").write_text(json.dumps(res, indent=2, default=float) + "\n")
    log(" | ".join(f"{k}: wall {v['wall_s']:.1f} s ({v['split_s']})" for k, v in runs.items())
        + f" -> {out / 'sim.json'}")
    return 0


def _simulate(folder: Path, mat, solver: str, args, out: Path, log, physics=None,
              tag=None) -> tuple[dict, tuple]:
    """Simulate the benchmark design with one solver path (and physics options); returns its
    figures and (final base centres (n, 3) mm, completion times (n_cells,) s)."""
    from pysolver.params import PHYSICS_DEFAULT
    from sim.model.collisions import completion_times
    from sim.model.simulate import simulate_design

    physics = PHYSICS_DEFAULT if physics is None else physics
    tag = tag or solver

    load0 = os.getloadavg()
    prof = cProfile.Profile()
    c0, w0 = time.process_time(), time.perf_counter()
    prof.enable()
    # settle_mm=0: no early stop once the shell has settled -- every run simulates all
    # 240 increments, like the paper's timing, so figures stay comparable across designs
    summary = simulate_design(folder, t_end=args.t_end, material=mat, progress=True,
                              resume=False, checkpoint_every=0, settle_mm=0.0, solver=solver,
                              physics=physics)
    prof.disable()
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    load1 = os.getloadavg()
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    with np.load(folder / "sim" / "frames.npz") as z:
        it = z["newton_iterations"]
        ws = z["wall_s"]
        conv = z["converged"]
        tc = completion_times({"t": z["t"], "collided": z["collided"]})
        final = np.array(z["base_center"][-1])
    steps = len(it) - 1
    lin = summary["linear_solver"]
    res = {
        "wall_s": round(wall, 2),
        "cpu_s": round(cpu, 2),
        "split_s": {"factorize": round(lin["factorize_s"], 2),
                    "linear_solve": round(lin["solve_s"], 2),
                    "assembly_line_search_other": round(wall - lin["factorize_s"]
                                                        - lin["solve_s"], 2)},
        "factorizations": lin["factorizations"],
        "ms_per_factorization": round(1000 * lin["factorize_s"]
                                      / max(lin["factorizations"], 1), 2),
        "steps": int(steps),
        "frames": int(len(it)),
        "t_end_s": args.t_end,
        "per_step_wall_s": {"mean": round(float(ws.mean()), 4),
                            "median": round(float(np.median(ws)), 4),
                            "max": round(float(ws.max()), 4), "dry": round(float(ws[0]), 4)},
        "newton_iterations": {"total": int(it.sum()), "mean": round(float(it.mean()), 3),
                              "median": float(np.median(it)), "max": int(it.max()),
                              "dry": int(it[0]),
                              "histogram": np.bincount(it).tolist()},
        "converged_steps": int(conv.sum()),
        "completed_cells": int(np.isfinite(tc).sum()),
        "peak_memory_mb": round(peak_mb, 1),
        "loadavg_start": [round(v, 2) for v in load0],
        "loadavg_end": [round(v, 2) for v in load1],
        "summary": summary,
    }
    s = io.StringIO()
    pstats.Stats(prof, stream=s).sort_stats("tottime").print_stats(args.top)
    (out / f"sim_profile_{tag}.txt").write_text(s.getvalue())
    log(f"{tag}: wall {wall:.1f} s (cpu {cpu:.1f} s), {steps} steps, {it.sum()} Newton "
        f"iterations, {lin['factorizations']} factorisations, peak {peak_mb:.0f} MB")
    return res, (final, tc)


if __name__ == "__main__":
    raise SystemExit(main())
