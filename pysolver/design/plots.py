"""Pictures of a design (matplotlib, Agg): flat layout by cell length and by thickness,
the target in 3D, the time landscape.  Written as PNGs into the design folder."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection, PatchCollection, PolyCollection  # noqa: E402
from matplotlib.patches import Circle  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

from ..params import UNIT_CELL  # noqa: E402
from ..params import tol as TOL  # noqa: E402
from .layout import Layout, footprint_rectangles  # noqa: E402


def _flat_axes(ax, lay: Layout, values, label, cmap, vmin=None, vmax=None, layer=0):
    b = lay.bumpers
    sel = b.layer == layer
    Q = footprint_rectangles(b, lay.C2)[sel]
    ax.add_collection(PolyCollection(Q, facecolor="0.85", edgecolor="0.55", lw=0.3))
    ax.add_collection(PatchCollection([Circle(c, UNIT_CELL.base_r) for c in lay.C2],
                                      facecolor="0.75", edgecolor="0.3", lw=0.4))
    if lay.alignment is not None and len(lay.alignment):
        ax.add_collection(PatchCollection([Circle(lay.C2[i], UNIT_CELL.align_r)
                                           for i in lay.alignment], facecolor="k"))
    segs = lay.C2[lay.cells.faces]
    lc = LineCollection(segs, array=np.asarray(values, float), cmap=cmap, lw=2.2)
    if vmin is not None:
        lc.set_clim(vmin, vmax)
    ax.add_collection(lc)
    S = np.vstack([lay.support, lay.support[:1]])
    ax.plot(S[:, 0], S[:, 1], color="tab:blue", lw=0.6, alpha=0.6)
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    plt.colorbar(lc, ax=ax, label=label, shrink=0.8)


def plot_flat_length(lay: Layout, path, title=""):
    fig, ax = plt.subplots(figsize=(8, 7), dpi=110)
    _flat_axes(ax, lay, lay.central_length, "central length l (mm)", "viridis",
               vmin=min(lay.central_length.min(), 4.0),
               vmax=max(UNIT_CELL.max_cell_length, lay.central_length.max()))
    ax.set_title(title or f"flat layout: {len(lay.F)} bases, {len(lay.cells.faces)} cells, "
                 f"l {lay.central_length.min():.2f}-{lay.central_length.max():.2f} mm")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_flat_thickness(lay: Layout, thickness, path):
    thickness = np.asarray(thickness, float)
    fig, axs = plt.subplots(1, 2, figsize=(14, 6.5), dpi=100)
    for s, name in enumerate(("top", "bottom")):
        _flat_axes(axs[s], lay, thickness[:, s], f"bracket thickness {name} (mm)", "plasma",
                   vmin=UNIT_CELL.thickness_min, vmax=UNIT_CELL.thickness_max, layer=s)
        axs[s].set_title(f"{name} layer (bumpers of this layer shown)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _set_equal_3d(ax, V):
    c = 0.5 * (V.max(0) + V.min(0))
    r = 0.5 * np.ptp(V, axis=0).max()
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.set_box_aspect((1, 1, 1))


def _shade(V, F, values, cmap, vmin, vmax, light=(0.3, -0.4, 0.85)):
    P = V[F]
    N = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    lt = np.asarray(light) / np.linalg.norm(light)
    k = 0.55 + 0.45 * np.abs(N @ lt)
    col = plt.get_cmap(cmap)((np.asarray(values) - vmin) / max(vmax - vmin, TOL.exact))
    col[:, :3] *= k[:, None]
    return col


def plot_target(lay: Layout, path, face_values=None, label="contraction flat->target"):
    """Target shape in 3D, faces coloured by the mean contraction of their cells."""
    V, F = lay.V, lay.F
    if face_values is None:
        ratio = lay.target_length / lay.central_length
        acc = np.zeros(len(F))
        cnt = np.zeros(len(F))
        for k in (0, 1):
            np.add.at(acc, lay.cells.faces[:, k], ratio)
            np.add.at(cnt, lay.cells.faces[:, k], 1)
        face_values = acc / np.maximum(cnt, 1)
    vmin, vmax = float(np.min(face_values)), float(np.max(face_values))
    fig = plt.figure(figsize=(12, 6), dpi=100)
    for k, (elev, azim) in enumerate(((30, -60), (75, -90))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        col = _shade(V, F, face_values, "viridis", vmin, vmax)
        ax.add_collection3d(Poly3DCollection(V[F], facecolors=col, edgecolor=(0, 0, 0, 0.25),
                                             lw=0.2))
        _set_equal_3d(ax, V)
        ax.view_init(elev=elev, azim=azim)
        ax.set_title(f"target (elev {elev})")
    sm = plt.cm.ScalarMappable(cmap="viridis", norm=plt.Normalize(vmin, vmax))
    fig.colorbar(sm, ax=fig.axes, label=label, shrink=0.7)
    fig.savefig(path)
    plt.close(fig)


def plot_time(lay: Layout, t_vertex, path):
    t = np.asarray(t_vertex, float)
    fig = plt.figure(figsize=(13, 6), dpi=100)
    ax = fig.add_subplot(1, 2, 1)
    vmin, vmax = float(t.min()), float(t.max())
    if vmax - vmin < TOL.rel:
        vmin, vmax = vmin - 1, vmax + 1
    tp = ax.tripcolor(lay.UV[:, 0], lay.UV[:, 1], lay.F, t, shading="gouraud", cmap="coolwarm",
                      vmin=vmin, vmax=vmax)
    ax.triplot(lay.UV[:, 0], lay.UV[:, 1], lay.F, color="k", lw=0.2, alpha=0.4)
    ax.set_aspect("equal")
    ax.set_title("time landscape on the flat stencil")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    fig.colorbar(tp, ax=ax, label="completion time t* (s)", shrink=0.8)
    ax3 = fig.add_subplot(1, 2, 2, projection="3d")
    col = _shade(lay.V, lay.F, t[lay.F].mean(1), "coolwarm", vmin, vmax)
    ax3.add_collection3d(Poly3DCollection(lay.V[lay.F], facecolors=col,
                                          edgecolor=(0, 0, 0, 0.2), lw=0.2))
    _set_equal_3d(ax3, lay.V)
    ax3.view_init(elev=30, azim=-60)
    ax3.set_title("time landscape on the target")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def write_design_plots(lay: Layout, folder, t_vertex, thickness) -> list[Path]:
    """Write ``design_flat_length.png``, ``design_flat_thickness.png``,
    ``design_target.png``, ``design_time.png``; returns the paths."""
    folder = Path(folder)
    out = [folder / n for n in ("design_flat_length.png", "design_flat_thickness.png",
                                "design_target.png", "design_time.png")]
    plot_flat_length(lay, out[0])
    plot_flat_thickness(lay, thickness, out[1])
    plot_target(lay, out[2])
    plot_time(lay, t_vertex, out[3])
    return out


__all__ = ["plot_flat_length", "plot_flat_thickness", "plot_target", "plot_time",
           "write_design_plots"]
