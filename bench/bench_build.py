"""Benchmark of a whole build from scratch (not a test): ``make shape=petal`` with an empty part
cache, as a new user's first build after installing.

Each solver path (``--solver fast``, the default, and ``reference``, the path before the speed
work) builds ``petal`` in its own fresh working folder, so no part cache or staging folder
carries over, and the stage split comes from the build's own ``summary.json``.  Writes
``build/bench/build_petal.json``: ``wall_s`` (the fast path, target 60 s), ``cpu_s`` (CPU time
of the build and its child processes), ``stages_s`` (design,
program, simulate, refine, render, report), ``render_split_s`` (the render stage's write_scad,
self_check, part renderer, union, export), the same under ``solvers`` for each path, and
``speedup_vs_reference``.  With ``--rounds N`` each path builds N times, the paths taking
turns in A B B A order; each keeps its fastest round and lists all of them in
``rounds_wall_s``.

Usage::

    .venv/bin/python bench/bench_build.py [--shape petal] [--solver both|fast|reference]
                                          [--rounds N]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # this checkout's pysolver, also in the child (PACKAGE_ROOT)

from pysolver.core.child import python_argv  # noqa: E402


def _build(shape: str, solver: str, log) -> dict:
    """Build ``shape`` in a fresh folder through the CLI; wall time and the stage split."""
    with tempfile.TemporaryDirectory(prefix="morphshell-bench-") as tmp:
        env = dict(os.environ, XDG_CACHE_HOME=str(Path(tmp) / "cache"))
        ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        # an isolated child (child.python_argv): nothing from its working directory runs
        r = subprocess.run([*python_argv("pysolver.cli"), "--quiet", "build", shape,
                            "--solver", solver], cwd=tmp, env=env, capture_output=True,
                           text=True)
        wall = time.perf_counter() - t0
        ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        # CPU time of the build and its children (renderers): beside the wall time, it shows
        # how much other work on the machine delayed the build
        cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
        if r.returncode not in (0, 3):
            raise SystemExit(f"build {shape} --solver {solver} failed:\n{r.stderr}")
        name = shape.split(":")[0]
        summary = json.loads((Path(tmp) / "build" / name / "summary.json").read_text())
    stages = {k: v for k, v in summary["timings_s"].items() if k != "total"}
    # the render's own split: part files, the self-check (the wait for the background check
    # started with the build), the part renderer, union, export
    render_split = summary.get("stages", {}).get("render", {}).get("timings_s", {})
    log(f"{shape} --solver {solver}: {wall:.1f} s (cpu {cpu:.1f} s)  "
        + "  ".join(f"{k} {v:.1f}" for k, v in stages.items()))
    return {"wall_s": round(wall, 2), "cpu_s": round(cpu, 2),
            "build_total_s": summary["timings_s"]["total"],
            "stages_s": stages, "render_split_s": render_split,
            "verdict": summary.get("figures", {}).get("verdict"),
            "bases": summary.get("figures", {}).get("n_bases"),
            "loadavg_end": [round(v, 2) for v in os.getloadavg()]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--shape", default="petal")
    ap.add_argument("--solver", choices=("both", "fast", "reference"), default="both")
    ap.add_argument("--out", default=str(ROOT / "build" / "bench"))
    ap.add_argument("--rounds", type=int, default=1,
                    help="builds per path, in A B B A order (the fastest is kept)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    def log(msg):
        print(f"[bench_build] {msg}", file=sys.stderr, flush=True)

    solvers = ["fast", "reference"] if args.solver == "both" else [args.solver]
    # rounds in A B B A order, so neither path always runs first (the first build of a run
    # also warms the page cache for the executables and libraries); each path keeps its
    # fastest round, the one least disturbed by other work on a shared machine
    rounds: dict[str, list] = {s: [] for s in solvers}
    for r in range(args.rounds):
        for s in (solvers if r % 2 == 0 else solvers[::-1]):
            rounds[s].append(_build(args.shape, s, log))
    runs = {s: dict(min(rs, key=lambda x: x["wall_s"]), rounds_wall_s=[x["wall_s"] for x in rs])
            for s, rs in rounds.items()}
    res = dict(runs[solvers[0]], shape=args.shape, solvers=runs, target_wall_s=60.0,
               cpu_count=os.cpu_count(), rounds=args.rounds)
    if len(runs) == 2:
        res["speedup_vs_reference"] = round(runs["reference"]["wall_s"]
                                            / runs["fast"]["wall_s"], 2)
    name = args.shape.split(":")[0]
    (out / f"build_{name}.json").write_text(json.dumps(res, indent=2) + "\n")
    log(f"-> {out / f'build_{name}.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
