"""Check that a code change leaves the outputs of every built-in shape unchanged.

    python bench/identical_outputs.py record DIR [--shapes dome,saddle]
    python bench/identical_outputs.py compare BASELINE_DIR NEW_DIR

``record`` builds every built-in shape (design + program + simulate + refine, no render,
no report) into ``DIR/<shape>/`` and writes ``DIR/hashes.json``: the sha256 of every table
file of the design folder (everything but ``summary.json`` and the simulation outputs) and
of ``sim/frames.npz``.  ``compare`` reports, per shape, the tables that are not
byte-identical and the largest absolute difference of any array in the simulation frames;
it exits 1 unless every table is identical and every frame difference is at most 1e-9.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

SHAPES = ("dome", "saddle", "petal", "spiral", "regular", "weave")
FRAME_TOL = 1e-9
# outputs that are not design tables: timings and versions, the simulation, the report
SKIP = {"summary.json", "design.log"}
SKIP_DIRS = {"sim", "report", "stl", "scad"}


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def _tables(folder: Path) -> dict:
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder)
        if not p.is_file() or rel.parts[0] in SKIP_DIRS or rel.name in SKIP \
                or rel.name.startswith("."):
            continue
        out[str(rel)] = _sha(p)
    return out


def _build(shape: str, out: Path) -> None:
    import pysolver.build as b

    # no report: stub it wherever the orchestrator finds it
    def no_report(*a, **k):
        return {}

    def no_verdict(*a, **k):
        return None

    import importlib
    for mod_name in ("sim.report", "pysolver.build"):
        mod = importlib.import_module(mod_name)
        for name, stub in (("make_report", no_report), ("print_verdict", no_verdict)):
            if hasattr(mod, name):
                setattr(mod, name, stub)
    b.build(shape, out=out, render=False, simulate=True, progress=False)


def record(folder: Path, shapes) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    result = {}
    for s in shapes:
        d = folder / s
        print(f"{s} ...", file=sys.stderr, flush=True)
        _build(s, d.resolve())
        result[s] = {"tables": _tables(d), "frames": _sha(d / "sim" / "frames.npz")}
    (folder / "hashes.json").write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")


def _frame_diff(a: Path, b: Path) -> float:
    fa, fb = np.load(a, allow_pickle=False), np.load(b, allow_pickle=False)
    if set(fa.files) != set(fb.files):
        return float("inf")
    worst = 0.0
    for k in fa.files:
        x, y = fa[k], fb[k]
        if x.shape != y.shape:
            return float("inf")
        if x.dtype.kind in "fiub" and y.dtype.kind in "fiub":
            if x.size:
                with np.errstate(invalid="ignore"):
                    d = np.abs(x.astype(float) - y.astype(float))
                same_nan = np.isnan(x.astype(float)) & np.isnan(y.astype(float))
                d = np.where(same_nan, 0.0, d)
                worst = max(worst, float(np.max(d)) if not np.isnan(d).any() else float("inf"))
        elif not np.array_equal(x, y):
            return float("inf")
    return worst


def compare(base: Path, new: Path) -> int:
    hb = json.loads((base / "hashes.json").read_text())
    hn = json.loads((new / "hashes.json").read_text())
    ok = True
    for s in hb:
        if s not in hn:
            print(f"{s}: missing in {new}")
            ok = False
            continue
        tb, tn = hb[s]["tables"], hn[s]["tables"]
        differ = sorted(k for k in set(tb) | set(tn) if tb.get(k) != tn.get(k))
        same = len([k for k in tb if tn.get(k) == tb[k]])
        d = _frame_diff(base / s / "sim" / "frames.npz", new / s / "sim" / "frames.npz")
        ok &= not differ and d <= FRAME_TOL
        print(f"{s}: {same}/{len(tb)} tables byte-identical"
              + (f" (differ: {', '.join(differ)})" if differ else "")
              + f"; frames sha256 {'equal' if hb[s]['frames'] == hn[s]['frames'] else 'differ'}"
              f", max |frame difference| = {d:.3g}")
    print("IDENTICAL" if ok else "DIFFERENT")
    return 0 if ok else 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("dir", type=Path)
    r.add_argument("--shapes", default=",".join(SHAPES))
    c = sub.add_parser("compare")
    c.add_argument("base", type=Path)
    c.add_argument("new", type=Path)
    a = ap.parse_args(argv)
    if a.cmd == "record":
        record(a.dir, [s for s in a.shapes.split(",") if s])
        return 0
    return compare(a.base, a.new)


if __name__ == "__main__":
    sys.exit(main())
