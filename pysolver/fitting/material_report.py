"""Pictures of the bracket-model fit (SI Fig. 5, 6) and a two-model comparison plot.

All figures are drawn with matplotlib's Agg backend and written as PNG.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..core.writes import atomic_file  # noqa: E402
from ..material.measurements import (  # noqa: E402
    SCORE_STRAIN_CUT,
    SPECIMEN_BRACKETS,
    preprocess_dry,
    preprocess_wet,
)
from ..material.model import load_bracket_model
from ..params import PICTURES, UNIT_CELL  # noqa: E402
from ..params import tol as TOL  # noqa: E402

_LOAD_COLORS = {1.0: "tab:blue", 2.0: "tab:orange", 3.0: "tab:green", 4.0: "tab:red",
                5.0: "tab:purple"}


def _specimen_grid(hl_pairs):
    """Panels ordered like the paper's design: rows = l (5..9), columns = thickness rank."""
    ls = sorted({round(l, 6) for _h, l in hl_pairs})
    cols = max(sum(1 for _h, l in hl_pairs if round(l, 6) == lv) for lv in ls)
    pos = {}
    for r, lv in enumerate(ls):
        hs = sorted(h for h, l in hl_pairs if round(l, 6) == lv)
        for c, h in enumerate(hs):
            pos[(round(h, 6), lv)] = (r, c)
    return len(ls), cols, pos


def plot_dry(meas, res, out_png) -> None:
    """SI Fig. 5: dry force-displacement per specimen, data vs p_dry and the t = 0 model."""
    t = meas.dry
    obs = preprocess_dry(t, res.options.dry_time_cut_s)
    pairs = sorted({(round(float(h), 6), round(float(l), 6)) for h, l in zip(t.h, t.l,
                                                                                strict=True)})
    nr, nc, pos = _specimen_grid(pairs)
    fig, axs = plt.subplots(nr, nc, figsize=(3.0 * nc, 2.4 * nr), squeeze=False, sharey=True)
    for ax in axs.ravel():
        ax.set_visible(False)
    for k, name, sl in t.series_slices():
        h, l, b = float(t.h[sl][0]), float(t.l[sl][0]), float(t.b[sl][0])
        ax = axs[pos[(round(h, 6), round(l, 6))]]
        ax.set_visible(True)
        keep = obs.series == k
        ax.plot(t.x[sl], t.force[sl], color="0.8", lw=1, label="all rows")
        ax.plot(obs.x[keep], obs.F[keep], color="k", lw=1.5, label="data (t < 5.25 s)")
        F = np.linspace(0.0, 10.0, 101)
        ax.plot(res.creep.dry(np.full_like(F, h), np.full_like(F, b), F), F, "--",
                color="tab:red", lw=1.5, label="p_dry fit")
        xm = np.linspace(0.0, max(float(obs.x[keep].max()) * 1.2, 0.1), 101)
        ax.plot(xm, SPECIMEN_BRACKETS * res.model.force(h, b, 0.0, xm), ":", color="tab:blue",
                lw=1.5, label="model t = 0 (4 brackets)")
        ax.set_xlim(0, max(float(obs.x[keep].max()) * 1.25, 0.1))
        ax.set_ylim(0, 11)
        ax.set_title(f"{name}: h={h:.2f}, l={l:g} mm", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.set_xlabel("displacement (mm)", fontsize=7)
        ax.set_ylabel("force (N)", fontsize=7)
    axs[0, 0].legend(fontsize=6, loc="lower right")
    rms = res.residuals["dry_model"]["rms_mm"]
    fig.suptitle(f"Dry compression: data (solid) vs fit (dashed: p_dry; dotted: tabulated model "
                 f"at t = 0). Model RMS displacement error {rms:.3f} mm", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    with atomic_file(out_png) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


def plot_wet(meas, res, out_png) -> None:
    """SI Fig. 6: displacement over time per specimen and load, data vs model."""
    t = meas.wet
    full = preprocess_wet(t, apply_strain_cut=False)
    pairs = sorted({(round(float(h), 6), round(float(l), 6)) for h, l in zip(t.h, t.l,
                                                                                strict=True)})
    nr, nc, pos = _specimen_grid(pairs)
    fig, axs = plt.subplots(nr, nc, figsize=(3.2 * nc, 2.5 * nr), squeeze=False)
    for ax in axs.ravel():
        ax.set_visible(False)
    cut = res.options.wet_strain_cut
    for k, _name, sl in t.series_slices():
        h, l, b, F = (float(a[sl][0]) for a in (t.h, t.l, t.b, t.nominal))
        ax = axs[pos[(round(h, 6), round(l, 6))]]
        ax.set_visible(True)
        keep = full.series == k
        ts, xs = full.t[keep] * 60.0, full.x[keep]
        col = _LOAD_COLORS.get(round(F), "k")
        inside = xs / b < cut
        ax.plot(ts, np.where(inside, xs, np.nan), color=col, lw=1.5)
        ax.plot(ts, np.where(inside, np.nan, xs), color=col, lw=0.8, alpha=0.35)
        tm = np.linspace(res.model.grid_min[2], res.model.grid_max[2], 121)
        xm = res.model.compression_for_force(h, b, tm, F / SPECIMEN_BRACKETS)
        ax.plot(tm, xm, "--", color=col, lw=1.2)
        ax.set_title(f"h={h:.2f}, l={l:g} mm (b={b:.2f})", fontsize=8)
        ax.set_xlim(0, 1.04 * res.model.grid_max[2])
        ax.set_ylim(0, b * 1.05)
        ax.axhline(cut * b, color="0.6", lw=0.5, ls=":")
        ax.tick_params(labelsize=7)
        ax.set_xlabel("time in water (s)", fontsize=7)
        ax.set_ylabel("displacement (mm)", fontsize=7)
    handles = [plt.Line2D([], [], color=c, label=f"{F:g} N") for F, c in _LOAD_COLORS.items()]
    axs[0, 0].legend(handles=handles, fontsize=6, loc="upper left")
    r = res.residuals["wet_model"]
    fig.suptitle("Creep in hot water at constant load: data (solid; faint beyond the strain cut "
                 f"x/b = {cut:.3g}) vs tabulated model (dashed). RMS {r['rms_mm']:.3f} mm "
                 f"(x/b < {SCORE_STRAIN_CUT:g}, t <= {res.model.grid_max[2]:g} s)", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    with atomic_file(out_png) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


def plot_rates(meas, res, out_png) -> None:
    """Creep rate divided by load vs thickness: measured (points) and p_wet (lines)."""
    obs = preprocess_wet(meas.wet, strain_cut=res.options.wet_strain_cut)
    loads = sorted({round(float(f), 6) for f in obs.F})
    fig, axs = plt.subplots(1, len(loads), figsize=(3.3 * len(loads), 3.3), squeeze=False,
                            sharey=True)
    ls = sorted({round(float(v), 6) for v in meas.wet.l})
    cmap = plt.get_cmap("viridis")
    window = (10.0 / 60.0, 40.0 / 60.0)
    for j, F in enumerate(loads):
        ax = axs[0, j]
        for i, lv in enumerate(ls):
            col = cmap(i / max(len(ls) - 1, 1))
            b = UNIT_CELL.bracket_length(lv)
            pts = []
            for k in np.unique(obs.series):
                s = ((obs.series == k) & (np.abs(obs.F - F) < TOL.same_setting)
                     & (np.abs(obs.b - b) < TOL.same_setting))
                s &= (obs.t >= window[0]) & (obs.t <= window[1])
                if np.count_nonzero(s) >= 3:
                    rate = np.polyfit(obs.t[s], obs.x[s], 1)[0]
                    pts.append((obs.h[s][0], max(rate, PICTURES.rate_floor) / F))
            if pts:
                p = np.array(pts)
                ax.semilogy(p[:, 0], p[:, 1], "o", color=col, ms=4)
            hh = np.linspace(UNIT_CELL.thickness_min, UNIT_CELL.thickness_max, 50)
            tm = np.full_like(hh, np.mean(window))
            ax.semilogy(hh, np.exp(res.creep.ln_rate(hh, np.full_like(hh, b), np.full_like(hh, F),
                                                     tm)), color=col, lw=1, ls="-" if pts else ":",
                        label=f"l = {lv:g}")
        ax.set_title(f"F = {F:g} N", fontsize=9)
        ax.set_xlabel("thickness h (mm)", fontsize=8)
        ax.tick_params(labelsize=7)
    axs[0, 0].set_ylabel("creep rate / load (mm min^-1 N^-1)", fontsize=8)
    axs[0, 0].legend(fontsize=6)
    fig.suptitle("Deformation rate vs thickness: measured mean rate over 10-40 s (points, floored "
                 "at 1e-3) and p_wet at 25 s (lines; dotted where that l was not tested at that "
                 "load)", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    with atomic_file(out_png) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


def compare_models(model_a, model_b, out_png, labels=("a", "b"),
                   times_s=(0.0, 30.0, 60.0, 120.0), cells=None) -> None:
    """Plot force vs displacement of two bracket models at a few times (calibration loop).

    Parameters
    ----------
    model_a, model_b : BracketModel or path-like
        Models (paths are loaded with :func:`load_bracket_model`).
    out_png : path-like
    labels : (2,) str
        Legend names (solid = a, dashed = b).
    times_s : sequence of float, s
    cells : sequence of (h_mm, b_mm), optional
        Panels; default three thicknesses x two lengths.
    """
    ma = model_a if hasattr(model_a, "force") else load_bracket_model(model_a)
    mb = model_b if hasattr(model_b, "force") else load_bracket_model(model_b)
    if cells is None:
        h_mid = 0.5 * (UNIT_CELL.thickness_min + UNIT_CELL.thickness_max)
        cells = [(h, UNIT_CELL.bracket_length(l)) for l in (6.0, 9.0)
                 for h in (UNIT_CELL.thickness_min, h_mid, UNIT_CELL.thickness_max)]
    nc = 3
    nr = int(np.ceil(len(cells) / nc))
    fig, axs = plt.subplots(nr, nc, figsize=(3.4 * nc, 2.8 * nr), squeeze=False)
    cmap = plt.get_cmap("plasma")
    for ax, (h, b) in zip(axs.ravel(), cells, strict=False):
        x = np.linspace(0.0, 0.7 * b, 100)
        wet_max = 0.0
        for i, t in enumerate(times_s):
            col = cmap(i / max(len(times_s), 1))
            fa, fb = ma.force(h, b, t, x), mb.force(h, b, t, x)
            ax.plot(x, fa, color=col, lw=1.5, label=f"{t:g} s")
            ax.plot(x, fb, "--", color=col, lw=1.5)
            if t > 0:
                wet_max = max(wet_max, float(np.max(fa)), float(np.max(fb)))
        if wet_max > 0:  # the dry (t = 0) curves are far stiffer: let them leave the axes
            ax.set_ylim(0.0, 1.5 * wet_max)
        ax.set_title(f"h = {h:.2f} mm, b = {b:.2f} mm", fontsize=8)
        ax.set_xlabel("compression x (mm)", fontsize=7)
        ax.set_ylabel("force per bracket (N)", fontsize=7)
        ax.tick_params(labelsize=7)
    for ax in axs.ravel()[len(cells):]:
        ax.set_visible(False)
    axs[0, 0].legend(fontsize=6, title="time", title_fontsize=6)
    fig.suptitle(f"Force per bracket vs compression. solid: {labels[0]}   dashed: {labels[1]}   "
                 "(y axis scaled to the wet curves; t = 0 leaves the axes)", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    with atomic_file(out_png) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


def write_report(report_dir, meas, res, summary) -> None:
    """Write the fit figures into ``report_dir`` (``fit_report.json`` is written by the caller)."""
    report_dir = Path(report_dir)
    plot_dry(meas, res, report_dir / "dry_fit.png")
    plot_wet(meas, res, report_dir / "wet_fit.png")
    plot_rates(meas, res, report_dir / "rates_vs_thickness.png")
    summary["figures"] = sorted(p.name for p in report_dir.glob("*.png"))
