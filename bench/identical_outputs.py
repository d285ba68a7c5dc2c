"""Check that a code change leaves the outputs of every built-in shape unchanged.

    python bench/identical_outputs.py record DIR [--shapes dome,saddle]
    python bench/identical_outputs.py compare BASELINE_DIR NEW_DIR

``record`` builds every built-in shape (design + program + simulate + refine, no render,
no report) into ``DIR/<shape>/`` and writes ``DIR/hashes.json``: the sha256 of every file
of the design folder (tables, stencil, pictures, JSON records; not ``summary.json`` and the
simulation outputs) and of ``sim/frames.npz``.  ``compare`` reports, per shape, the files
that are not byte-identical and the largest absolute difference of any array in the
simulation frames; it exits 1 unless every CSV/OBJ table is byte-identical, every JSON
record is equal once its wall-clock timings and the repository path are left out, and
every frame difference is at most 1e-9.  Files only in the new folder are listed as new.
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
# wall-clock fields: they differ between any two runs
TIMING_KEYS = {"timings_s", "seconds", "wall_s"}
# frames.npz's hash of the tables it was simulated from: design.json is one of them and holds
# wall-clock timings, so it differs between any two runs; the tables themselves are compared
# file by file above
DERIVED_KEYS = {"tables_sha256"}


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
    for mod_name in ("sim.report", "pysolver.build", "pysolver.simulator",
                     "pysolver.stages.runners"):
        try:
            mod = importlib.import_module(mod_name)
        except ModuleNotFoundError:  # an older layout of the orchestrator
            continue
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
        if k in TIMING_KEYS or k in DERIVED_KEYS:
            continue
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


def _json_norm(x, root: str, path: str = ""):
    """A JSON record without wall-clock timings, with the repository path replaced."""
    if isinstance(x, dict):
        return {k: _json_norm(v, root, f"{path}.{k}") for k, v in x.items()
                if k not in TIMING_KEYS and not (k == "time_s" and ".comparison." in path)}
    if isinstance(x, list):
        return [_json_norm(v, root, path) for v in x]
    if isinstance(x, str) and x.startswith(root):
        return "<repo>" + x[len(root):]
    return x


def _json_equal(a: Path, b: Path) -> bool:
    ra = json.loads(a.read_text())
    rb = json.loads(b.read_text())
    root_a = str(Path(ra.get("summary", {}).get("material_model", "/")).parents[2]) \
        if isinstance(ra.get("summary", {}).get("material_model"), str) else "\0"
    root_b = str(Path(rb.get("summary", {}).get("material_model", "/")).parents[2]) \
        if isinstance(rb.get("summary", {}).get("material_model"), str) else "\0"
    return _json_norm(ra, root_a) == _json_norm(rb, root_b)


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
        added = sorted(set(tn) - set(tb))
        differ = sorted(k for k in tb if tn.get(k) != tb[k])
        json_eq = [k for k in differ if k.endswith(".json") and k in tn
                   and _json_equal(base / s / k, new / s / k)]
        differ = [k for k in differ if k not in json_eq]
        same = len([k for k in tb if tn.get(k) == tb[k]])
        d = _frame_diff(base / s / "sim" / "frames.npz", new / s / "sim" / "frames.npz")
        ok &= not differ and d <= FRAME_TOL
        print(f"{s}: {same}/{len(tb)} files byte-identical"
              + (f", {len(json_eq)} JSON equal but for timings/paths ({', '.join(json_eq)})"
                 if json_eq else "")
              + (f", DIFFER: {', '.join(differ)}" if differ else "")
              + (f", new: {', '.join(added)}" if added else "")
              + f"; frames sha256 {'equal' if hb[s]['frames'] == hn[s]['frames'] else 'differ'}"
              f", max |frame difference| = {d:.3g} (wall-clock 'wall_s' and 'tables_sha256' "
              "left out)")
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
