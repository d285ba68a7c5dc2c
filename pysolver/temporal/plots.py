"""Pictures of the temporal programming stage (matplotlib, Agg)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.writes import atomic_file
from ..params import UNIT_CELL
from ..tables import read_stencil


def plot_feasibility(design_dir, t_vertex, t_star, cells: dict, res: dict, png) -> Path:
    """Time landscape on the flat layout with the clamped cells marked, and the ranges.

    Left: the landscape (s) interpolated on the flat stencil, base outlines, and the
    cells whose ``t*`` is out of reach (too early: thinnest bracket still too stiff;
    too late: even the slower layer's thickest bracket yields earlier).  Right: every cell's
    achievable range (grey bar) and ``t*`` (dot), sorted by ``t*``.

    Parameters
    ----------
    design_dir : path-like
        Design folder (its ``stencil.obj`` gives the flat layout).
    t_vertex : (n_vertices,) float, s
        The time landscape.
    t_star : (n_cells,) float, s
        The cells' programmed times (from that landscape).
    cells : dict of (n_cells,) arrays -- ``cells.csv`` columns
    res : dict -- :func:`pysolver.temporal.program_cells` output
    png : path-like

    Returns
    -------
    Path of the PNG.
    """
    # optional heavy dependency: matplotlib loads only when a picture is drawn
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # (matplotlib, as above)
    from matplotlib.tri import Triangulation  # (matplotlib, as above)

    png = Path(png)
    _, UV, F = read_stencil(Path(design_dir) / "stencil.obj")
    t_vertex = np.asarray(t_vertex, float)
    va, vb = np.asarray(cells["vertex_a"]), np.asarray(cells["vertex_b"])
    mid = 0.5 * (UV[va] + UV[vb])
    side = np.asarray(res["side"])
    t_star = np.asarray(t_star, float)
    n = len(side)

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(13, 5.6),
                                  gridspec_kw={"width_ratios": [1.15, 1]})
    tri = Triangulation(UV[:, 0], UV[:, 1], F)
    pc = ax.tripcolor(tri, t_vertex, shading="gouraud", cmap="viridis")
    ax.triplot(tri, color="w", lw=0.3, alpha=0.6)
    fig.colorbar(pc, ax=ax, label="time landscape (s)", shrink=0.85)
    early, late = side < 0, side > 0
    ax.plot(mid[early, 0], mid[early, 1], "v", ms=6, mfc="none", mec="tab:red", mew=1.4,
            label=f"too early: t* < t_min ({early.sum()})")
    ax.plot(mid[late, 0], mid[late, 1], "^", ms=6, mfc="none", mec="tab:orange", mew=1.4,
            label=f"too late: t* > t_max ({late.sum()})")
    ok = ~(early | late)
    ax.plot(mid[ok, 0], mid[ok, 1], ".", ms=2, color="k", alpha=0.5,
            label=f"achievable ({ok.sum()})")
    ax.set_aspect("equal")
    ax.set_xlabel("flat x (mm)")
    ax.set_ylabel("flat y (mm)")
    ax.set_title(f"{Path(design_dir).name}: time landscape, clamped cells "
                 f"{early.sum() + late.sum()} / {n} ({100 * (early.sum() + late.sum()) / n:.1f} %)",
                 fontsize=10)
    ax.legend(fontsize=8, loc="upper right", framealpha=0.8)

    _ranges_panel(ax2, t_star, res, side)
    fig.tight_layout()
    with atomic_file(png) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return png


def _ranges_panel(ax2, t_star, res: dict, side) -> None:
    """Every cell's achievable range (grey bar) and ``t*`` (marked by side), sorted by ``t*``."""
    n = len(side)
    order = np.argsort(t_star, kind="stable")
    k = np.arange(n)
    lo, hi = np.asarray(res["t_min"])[order], np.asarray(res["t_max"])[order]
    lo_f = np.where(np.isfinite(lo), lo, np.nan)
    ax2.vlines(k, lo_f, hi, color="0.75", lw=max(0.3, min(2.0, 300 / max(n, 1))),
               label=f"achievable range: {UNIT_CELL.thickness_min:.2f} mm bracket (earliest) to "
                     f"{UNIT_CELL.thickness_max:.2f} mm (latest)")
    so = side[order]
    ax2.plot(k[so == 0], t_star[order][so == 0], ".", ms=2.5, color="k", label="t* (achievable)")
    ax2.plot(k[so < 0], t_star[order][so < 0], "v", ms=4, color="tab:red", label="t* too early")
    ax2.plot(k[so > 0], t_star[order][so > 0], "^", ms=4, color="tab:orange",
             label="t* too late")
    ax2.set_xlabel("cells sorted by t*")
    ax2.set_ylabel("completion time (s)")
    ax2.set_title("achievable completion time per cell", fontsize=10)
    ax2.legend(fontsize=8, loc="upper left")
    ax2.grid(alpha=0.3)


def plot_coupon(bases: dict, cells: dict, rows: list, png) -> Path:
    """The timing coupon seen from its numbered (top) face: each base's number, each timed
    cell's bracket thickness (colour) and predicted closing time (s).

    Parameters
    ----------
    bases, cells : dict of arrays -- ``bases.csv`` and ``cells.csv`` of the coupon
    rows : list of dict -- :func:`pysolver.temporal.coupon.coupon_rows` (labelled)
    png : path-like

    Returns
    -------
    Path of the PNG.
    """
    # optional heavy dependency: matplotlib loads only when a picture is drawn
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # (matplotlib, as above)

    xy = np.c_[bases["flat_x_mm"], bases["flat_y_mm"]]
    fig, ax = plt.subplots(figsize=(11, 3.6))
    cmap = plt.get_cmap("viridis")
    for j in range(len(cells["cell_id"])):
        a, b = xy[int(cells["base_a"][j])], xy[int(cells["base_b"][j])]
        ax.plot(*np.c_[a, b], color="0.85", lw=1, zorder=1)
    for r in rows:
        j = r["cell_id"]
        a, b = xy[int(cells["base_a"][j])], xy[int(cells["base_b"][j])]
        lo, hi = UNIT_CELL.thickness_min, UNIT_CELL.thickness_max
        u = (r["thickness_top_mm"] - lo) / (hi - lo)
        ax.plot(*np.c_[a, b], color=cmap(min(max(u, 0.0), 1.0)), lw=5, zorder=2)
        m = (a + b) / 2
        ax.text(m[0], m[1], f"{r['predicted_s']:.0f} s", fontsize=7, ha="center",
                va="center", zorder=4, bbox={"fc": "white", "ec": "none", "pad": 0.5})
    for i, p in enumerate(xy):
        ax.add_patch(plt.Circle(p, 2.0, color="0.3", zorder=3))
        ax.text(p[0], p[1], str(i + 1), color="white", fontsize=7, ha="center",
                va="center", zorder=5)
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(UNIT_CELL.thickness_min,
                                                             UNIT_CELL.thickness_max))
    fig.colorbar(sm, ax=ax, label="bracket thickness (mm)", fraction=0.03)
    ax.set_aspect("equal")
    ax.set_xlabel("mm")
    ax.set_title("timing coupon, numbered face up: cells by bracket thickness, with the "
                 "predicted closing time", fontsize=10)
    fig.tight_layout()
    with atomic_file(png) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return Path(png)


__all__ = ["plot_coupon", "plot_feasibility"]
