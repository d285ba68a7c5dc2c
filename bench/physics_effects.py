"""Effect of each physics option (issue #18) on the built-in shapes (not a test).

For every shape: build the design (``morphshell build SHAPE --no-render``, cached in
``build/physics/<shape>``), then simulate it in memory once with every effect off and once per
effect, and compare

* the final shape: marker tips (both layers) after the best rigid alignment (Kabsch) to the
  run with every effect off: RMS and max displacement (mm), and the RMS relative to the
  shell's size (largest extent of the target, %);
* the timing: completion time of every cell (``sim.model.simulate.completion_times``) minus the
  reference's: median and max |difference| (s), cells that complete in one and not the other;
* for ``dry_rest``: the resting shape on the table against the final frame in water (the sag).

Writes ``build/physics/effects.json``, per shape and effect a picture of the displacement
(``build/physics/<shape>_<effect>.png``: final shape seen from above and the side, markers
coloured by displacement) and its data (``<shape>_<effect>.npz``: aligned marker tips
``P`` (k, 3) mm, displacement ``d`` (k,) mm); ``--figures DIR`` then draws one picture per
effect with every shape (``DIR/<effect>.png``, used by ``docs/physics.md``).

Usage::

    .venv/bin/python bench/physics_effects.py [--shapes regular,petal,...] [--effects ...]
    .venv/bin/python bench/physics_effects.py --figures docs/physics
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_THREAD_LIMIT", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SHAPES = ("regular", "petal", "dome", "saddle", "spiral", "weave")
EFFECTS = ("clearance", "relaxation", "membrane_temperature", "gravity", "dry_rest", "rim",
           "contact", "bracket_bending")


def kabsch(P, Q):
    """Rigidly align P (n, 3) onto Q (n, 3); returns the aligned P."""
    pc, qc = P.mean(0), Q.mean(0)
    U, _, Vt = np.linalg.svd((P - pc).T @ (Q - qc))
    d = np.sign(np.linalg.det(U @ Vt))
    R = U @ np.diag([1, 1, d]) @ Vt
    return (P - pc) @ R + qc


def markers(fr, rest=False):
    k = "rest_marker_" if rest else "marker_"
    if rest:
        return np.r_[fr[k + "top"], fr[k + "bottom"]]
    return np.r_[fr[k + "top"][-1], fr[k + "bottom"][-1]]


def compare(ref, fr, size, rest=False, ref_rest=False):
    from sim.model.collisions import completion_times

    P, Q = markers(fr, rest), markers(ref, ref_rest)
    d = np.linalg.norm(kabsch(P, Q) - Q, axis=1)
    ta, tb = completion_times(ref), completion_times(fr)
    both = np.isfinite(ta) & np.isfinite(tb)
    dt = tb[both] - ta[both]
    return {"rms_mm": float(np.sqrt((d**2).mean())), "max_mm": float(d.max()),
            "rms_pct_size": float(100 * np.sqrt((d**2).mean()) / size),
            "dt_median_s": float(np.median(dt)) if len(dt) else float("nan"),
            "dt_abs_max_s": float(np.abs(dt).max()) if len(dt) else float("nan"),
            "t_done_ref_s": float(np.nanmax(ta)) if np.isfinite(ta).any() else float("nan"),
            "t_done_s": float(np.nanmax(tb)) if np.isfinite(tb).any() else float("nan"),
            "completed_ref": int(np.isfinite(ta).sum()), "completed": int(np.isfinite(tb).sum()),
            "cells": int(len(ta))}, d


def picture(fr_ref, fr, d, png, title, rest=False):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    P = markers(fr, rest)
    Q = markers(fr_ref)
    P = kabsch(P, Q)
    fig, ax = plt.subplots(1, 2, figsize=(9, 4))
    for a, (i, j, lab) in zip(ax, ((0, 1, "top view x-y"), (0, 2, "side view x-z")),
                              strict=True):
        sc = a.scatter(P[:, i], P[:, j], c=d, s=8, cmap="viridis")
        a.set_aspect("equal")
        a.set_title(lab, fontsize=9)
        a.set_xlabel("mm")
    fig.colorbar(sc, ax=ax, label="displacement, mm", shrink=0.8)
    fig.suptitle(title, fontsize=10)
    fig.savefig(png, dpi=90)
    plt.close(fig)


def figures(src: Path, dst: Path, shapes=SHAPES, effects=EFFECTS) -> None:
    """One picture per effect: every shape's final markers (top view), coloured by the
    displacement the effect causes (mm, own colour scale per shape)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dst.mkdir(parents=True, exist_ok=True)
    label = {"dry_rest": "dry rest on a table vs final shape in water"}
    for eff in effects:
        fig, axs = plt.subplots(2, 3, figsize=(10, 6.4))
        for ax, shape in zip(axs.ravel(), shapes, strict=True):
            f = src / f"{shape}_{eff}.npz"
            ax.set_xticks([])
            ax.set_yticks([])
            if not f.exists():
                ax.set_title(f"{shape}: not run", fontsize=9)
                continue
            z = np.load(f)
            P, d = z["P"], z["d"]
            sc = ax.scatter(P[:, 0], P[:, 1], c=d, s=5, cmap="viridis", vmin=0)
            ax.set_aspect("equal")
            ax.set_title(f"{shape}: max {d.max():.3g} mm", fontsize=9)
            fig.colorbar(sc, ax=ax, shrink=0.7, label="mm")
        fig.suptitle(f"{eff}: {label.get(eff, 'on vs off, final marker tips, rigidly aligned')}",
                     fontsize=10)
        fig.tight_layout()
        fig.savefig(dst / f"{eff}.png", dpi=72)
        plt.close(fig)


def table(results: dict, shapes=SHAPES, effects=EFFECTS) -> str:
    """The markdown table of ``docs/physics.md`` from ``effects.json``."""
    rows = ["| shape (size) | effect | final shape: RMS / max displacement, mm (RMS % of size) "
            "| timing: median / max abs change of completion, s | cells completed (off -> on) "
            "| wall s (off -> on) |", "|---|---|---|---|---|---|"]
    for sh in shapes:
        v = results.get(sh)
        if not v:
            continue
        for eff in effects:
            x = v.get(eff)
            if x is None:
                continue
            head = f"{sh} ({v['size_mm']:.0f} mm)"
            if eff == "dry_rest":
                y = x["sag_vs_wet_final"]
                rows.append(f"| {head} | dry rest (vs final in water) | {y['rms_mm']:.3f} / "
                            f"{y['max_mm']:.3f} ({y['rms_pct_size']:.2f} %) | - | - | "
                            f"{v['wall_off_s']:.1f} -> {x['wall_s']:.1f} |")
                continue
            rows.append(f"| {head} | {eff} | {x['rms_mm']:.3f} / {x['max_mm']:.3f} "
                        f"({x['rms_pct_size']:.2f} %) | {x['dt_median_s']:+.1f} / "
                        f"{x['dt_abs_max_s']:.1f} | {x['completed_ref']} -> {x['completed']} of "
                        f"{x['cells']} | {v['wall_off_s']:.1f} -> {x['wall_s']:.1f} |")
    return "\n".join(rows) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shapes", default=",".join(SHAPES))
    ap.add_argument("--effects", default=",".join(EFFECTS))
    ap.add_argument("--out", default=str(ROOT / "build" / "physics"))
    ap.add_argument("--figures", default=None, help="draw the per-effect pictures into DIR")
    ap.add_argument("--table", action="store_true", help="print the markdown table")
    args = ap.parse_args(argv)
    if args.table:
        print(table(json.loads((Path(args.out) / "effects.json").read_text())))
        return 0
    if args.figures:
        figures(Path(args.out), Path(args.figures))
        return 0
    from pysolver.build import build
    from pysolver.material.model import load_bracket_model
    from pysolver.mechanics import load_model
    from pysolver.params import PHYSICS_OFF
    from sim.model.simulate import simulate_model

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    mat = load_bracket_model()
    jpath = out / "effects.json"
    results = json.loads(jpath.read_text()) if jpath.exists() else {}
    for shape in args.shapes.split(","):
        folder = out / shape
        if not (folder / "cells.csv").exists():
            build(shape, out=folder, render=False, simulate=False, progress=False)
        size = float(np.ptp(load_model(folder, physics=PHYSICS_OFF).V, axis=0).max())
        t0 = time.perf_counter()
        ref = simulate_model(load_model(folder, physics=PHYSICS_OFF), mat, physics=PHYSICS_OFF)
        w_ref = time.perf_counter() - t0
        res = results.setdefault(shape, {})
        res["size_mm"] = size
        res["wall_off_s"] = round(w_ref, 2)
        for eff in args.effects.split(","):
            ph = dataclasses.replace(PHYSICS_OFF, **{eff: True})
            t0 = time.perf_counter()
            fr = simulate_model(load_model(folder, physics=ph), mat, physics=ph)
            w = time.perf_counter() - t0
            r, d = compare(ref, fr, size, rest=False)
            r["wall_s"] = round(w, 2)
            r["converged"] = bool(np.all(fr["converged"]))
            if eff == "dry_rest":
                r2, d = compare(fr, fr, size, rest=True)
                r = {"sag_vs_wet_final": {k: r2[k] for k in ("rms_mm", "max_mm", "rms_pct_size")},
                     "wall_s": r["wall_s"], "converged": bool(fr["rest_converged"]),
                     "weight_N": float(fr["rest_weight_N"])}
                picture(fr, fr, d, out / f"{shape}_{eff}.png",
                        f"{shape}: dry rest on a table vs final shape in water", rest=True)
            else:
                picture(ref, fr, d, out / f"{shape}_{eff}.png",
                        f"{shape}: {eff} on vs off (final shape, rigidly aligned)")
            res[eff] = r
            P = kabsch(markers(fr, eff == "dry_rest"), markers(fr if eff == "dry_rest" else ref))
            np.savez_compressed(out / f"{shape}_{eff}.npz", P=P, d=d)
            print(shape, eff, json.dumps(r), file=sys.stderr, flush=True)
            jpath.write_text(json.dumps(results, indent=2, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
