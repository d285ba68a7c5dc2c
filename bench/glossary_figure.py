"""The one-picture glossary of the README, drawn from a real design (not a test).

Designs the small built-in patch ``regular:rows=2,cols=3`` (design stage only, a few
seconds) into a temporary folder and draws, from its files:

* left, the flat layout seen from above: the **stencil** (``stencil.obj``, its ``vt``), one
  **base** per stencil triangle (a disc of ``UnitCell.base_r`` at ``bases.csv``'s flat
  centre), the **brackets** of every cell (their two arms, as the simulator's springs join
  the bracket nodes of ``model.npz``), the **bumpers** (``bumpers.csv``: from the base rim to
  ``length_mm`` along ``dir_deg``), and one **cell** (two bases across a stencil edge)
  shaded;
* right, a section across that cell: the two **layers** (top and bottom, ``base_th`` thick,
  ``bumpers.csv``'s plane height apart) on both sides of the membrane.

Usage::

    .venv/bin/python bench/glossary_figure.py [--out docs/img/glossary.png]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Circle, Polygon, Rectangle  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pysolver.core.writes import atomic_file  # noqa: E402
from pysolver.design import run_design  # noqa: E402
from pysolver.params import UNIT_CELL  # noqa: E402
from pysolver.tables import read_stencil, read_table  # noqa: E402

SHAPE = "regular:rows=2,cols=3"
CELL = 3
"""The cell shaded and cut in the section (an interior cell of the patch)."""


def draw_plan(ax, folder: Path) -> None:
    """The flat layout from above: stencil, bases, brackets, bumpers, one cell."""
    _, UV, F = read_stencil(folder / "stencil.obj")
    bases = read_table(folder, "bases")
    cells = read_table(folder, "cells")
    bumpers = read_table(folder, "bumpers")
    with np.load(folder / "model.npz") as z:
        nodes = z["nodes_flat"]                      # (m, 3 slots, 2 arms, 2 layers, 3), mm
    C = np.c_[bases["flat_x_mm"], bases["flat_y_mm"]]
    a, b = int(cells["base_a"][CELL]), int(cells["base_b"][CELL])
    for f in F:
        ax.add_patch(Polygon(UV[f], closed=True, fill=False, ec="0.75", lw=0.8, ls="--"))
    ax.add_patch(Polygon(np.r_[C[a], UV[int(cells["vertex_a"][CELL])], C[b],
                               UV[int(cells["vertex_b"][CELL])]].reshape(4, 2),
                         closed=True, fc="#ffe9a8", ec="none", zorder=0))
    for i, c in enumerate(C):
        ax.add_patch(Circle(c, UNIT_CELL.base_r, fc="#9ecae1" if i in (a, b) else "#c6dbef",
                            ec="#08519c", lw=1.0, zorder=2))
    for k in range(len(cells["cell_id"])):
        ba, bb = int(cells["base_a"][k]), int(cells["base_b"][k])
        sa, sb = int(cells["slot_a"][k]), int(cells["slot_b"][k])
        for arm in (0, 1):   # each arm joins a node of one base to the facing node of the other
            p, q = nodes[ba, sa, arm, 0, :2], nodes[bb, sb, 1 - arm, 0, :2]
            ax.plot([p[0], q[0]], [p[1], q[1]], color="#d94801", lw=2.2, zorder=3)
    top = bumpers["layer"] == "top"
    for i, d, L in zip(bumpers["base_id"][top], bumpers["dir_deg"][top],
                       bumpers["length_mm"][top], strict=True):
        u = np.array([np.cos(np.radians(d)), np.sin(np.radians(d))])
        p, q = C[int(i)] + 0.55 * UNIT_CELL.base_r * u, C[int(i)] + float(L) * u
        ax.plot([p[0], q[0]], [p[1], q[1]], color="#238b45", lw=4, solid_capstyle="butt",
                zorder=4)
    _label_plan(ax, C, UV, F, a, b, cells)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title("flat layout, from above (top layer)", fontsize=10)


def _label_plan(ax, C, UV, F, a, b, cells) -> None:
    mid = 0.5 * (C[a] + C[b])
    kw = dict(fontsize=9, arrowprops=dict(arrowstyle="->", lw=0.8), zorder=6)
    lo = UV.min(axis=0)
    ax.annotate("base", C[a], C[a] + [-3.5, -6.5], **kw)
    ax.annotate("cell\n(two bases across\na stencil edge)", mid, mid + [5.0, 6.0], **kw)
    k = next(i for i in range(len(cells["cell_id"])) if i != CELL)
    p = 0.5 * (C[int(cells["base_a"][k])] + C[int(cells["base_b"][k])])
    ax.annotate("bracket", p, p + [-6.0, 4.5], **kw)
    ax.annotate("bumper", C[b] + [UNIT_CELL.base_r * 0.9, 0.4], C[b] + [5.5, -5.0], **kw)
    v = UV[F[0, 0]]
    ax.annotate("stencil\n(triangle mesh)", v, lo + [-4.0, -6.0], **kw)


def draw_section(ax, folder: Path) -> None:
    """A section across the shaded cell: the two layers on both sides of the membrane."""
    cells = read_table(folder, "cells")
    bumpers = read_table(folder, "bumpers")
    L = float(cells["central_length_mm"][CELL])
    r, th = UNIT_CELL.base_r, UNIT_CELL.base_th
    zb = float(np.abs(bumpers["plane_pz"]).max())     # height of a layer's bumper plane, mm
    gap = 0.5                                         # drawn gap for the membrane, mm
    for x in (-L / 2, L / 2):
        for sign in (1, -1):
            y0 = gap / 2 if sign > 0 else -gap / 2 - th
            ax.add_patch(Rectangle((x - r, y0), 2 * r, th, fc="#c6dbef", ec="#08519c"))
    for sign in (1, -1):
        y = sign * (gap / 2 + 0.5 * th)
        ax.plot([-L / 2 + r, L / 2 - r], [y, y], color="#d94801", lw=2.2)
        for x, s in ((-L / 2 + r, 1), (L / 2 - r, -1)):
            ax.plot([x, x + s * UNIT_CELL.min_bumper * 2], [y + sign * 0.6] * 2,
                    color="#238b45", lw=4, solid_capstyle="butt")
    ax.plot([-L / 2 - r - 1, L / 2 + r + 1], [0, 0], color="0.3", lw=1.2)
    ax.text(L / 2 + r + 1.2, gap / 2 + th / 2, "top layer", va="center", fontsize=9)
    ax.text(L / 2 + r + 1.2, -gap / 2 - th / 2, "bottom layer", va="center", fontsize=9)
    ax.text(L / 2 + r + 1.2, 0, "membrane", va="center", fontsize=9, color="0.3")
    ax.text(0, gap / 2 + th + 0.6, f"one cell, {L:.1f} mm between base centres", ha="center",
            fontsize=9)
    ax.set_xlim(-L / 2 - r - 1.5, L / 2 + r + 9)
    ax.set_ylim(-zb - 2.5, zb + 2.5)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title("section across the shaded cell", fontsize=10)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "img" / "glossary.png"))
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "glossary"
        run_design(SHAPE, folder, progress=False, plots=False)
        fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.6),
                                       gridspec_kw={"width_ratios": [1.35, 1]})
        draw_plan(ax1, folder)
        draw_section(ax2, folder)
        fig.suptitle(f"base, bracket, bumper, cell, stencil, layer (a real design: {SHAPE})",
                     fontsize=11)
        fig.tight_layout()
        with atomic_file(a.out) as t:
            fig.savefig(t, dpi=110, metadata={"Software": None})
        plt.close(fig)
    print(a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
