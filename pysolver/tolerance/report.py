"""Pictures and HTML page of a tolerance analysis (:mod:`pysolver.tolerance`).

``<out>/report.html`` embeds (as files beside it):

* ``tolerance_shell.png``: the target shell seen from above, unit cells coloured by their
  probability of completing on time, bases by the spread of their final position;
* ``tolerance_timing.png``: per cell (sorted by t*) the programmed time, the nominal
  completion and the 5-95 % band over the samples; and the fraction of completed cells over
  time with its 5-95 % band;
* ``tolerance_sensitivity.png``: each factor's share of the one-at-a-time variance.
"""

from __future__ import annotations

import html

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402

from pysolver.core.writes import atomic_file, atomic_write_text, remove_file  # noqa: E402
from pysolver.tables import read_table

_CSS = ("body{font-family:sans-serif;max-width:1100px;margin:1em auto;padding:0 1em}"
        "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 8px;"
        "text-align:right}th{background:#eee}img{max-width:100%}.note{color:#555}"
        ".big{font-size:1.6em;font-weight:bold}")


def _save(fig, path):
    with atomic_file(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def plot_shell(path, target, pairs, p_on_time, pos_sd):
    """Top view of the target: cells coloured by P(on time), bases by position spread.

    Parameters
    ----------
    target : (m, 3) float, mm -- target base centres
    pairs : (c, 2) int -- bases of each unit cell
    p_on_time : (c,) float -- probability in [0, 1]
    pos_sd : (m,) float, mm -- RMS spread of the final base position
    """
    fig, ax = plt.subplots(figsize=(7.5, 7.2))
    seg = target[np.asarray(pairs)][:, :, :2]
    lc = LineCollection(seg, cmap="RdYlGn", linewidths=3.0)
    lc.set_array(np.asarray(p_on_time, float))
    lc.set_clim(0.0, 1.0)
    ax.add_collection(lc)
    sc = ax.scatter(target[:, 0], target[:, 1], c=pos_sd, cmap="viridis", s=36,
                    edgecolors="k", linewidths=0.4, zorder=3)
    fig.colorbar(lc, ax=ax, location="right", fraction=0.04, pad=0.02,
                 label="unit cells: P(completes on time)")
    fig.colorbar(sc, ax=ax, location="bottom", fraction=0.04, pad=0.1,
                 label="bases: final position spread (mm, RMS)")
    ax.set_aspect("equal")
    ax.autoscale()
    ax.set_ylabel("y (mm)")
    ax.set_title("Target shell from above: unit cells and bases")
    fig.tight_layout()
    _save(fig, path)


def plot_timing(path, t_star, t_nominal, T, time_tol_s, t_end):
    """Completion-time spread per cell and completed fraction over time.

    Parameters
    ----------
    t_star : (c,) float, s
    t_nominal : (c,) float, s (NaN = never)
    T : (S, c) float, s -- completion time per sample (NaN = never)
    time_tol_s, t_end : float, s
    """
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.6))
    order = np.argsort(t_star, kind="stable")
    x = np.arange(len(order))
    Tf = np.where(np.isfinite(T), T, t_end)  # never = at least t_end, for the band
    lo, med, hi = np.percentile(Tf[:, order], [5, 50, 95], axis=0) if len(T) else (
        np.full(len(x), np.nan),) * 3
    a.fill_between(x, t_star[order] - time_tol_s, t_star[order] + time_tol_s,
                   color="0.85", label=f"t* +- {time_tol_s:g} s")
    a.fill_between(x, lo, hi, color="tab:blue", alpha=0.35, label="5-95 % of samples")
    a.plot(x, med, color="tab:blue", lw=1.2, label="median")
    a.plot(x, t_star[order], color="k", lw=1.2, label="t* (programmed)")
    a.plot(x, t_nominal[order], ".", color="tab:red", ms=3, label="nominal simulation")
    a.set_xlabel("unit cell (sorted by t*)")
    a.set_ylabel("completion time (s)")
    a.set_title("Completion time per cell")
    a.legend(fontsize=8, loc="upper left")
    grid = np.linspace(0.0, t_end, 241)
    frac = (np.isfinite(T)[:, None, :] & (T[:, None, :] <= grid[None, :, None])).mean(axis=2)
    flo, fmed, fhi = np.percentile(frac, [5, 50, 95], axis=0)
    b.fill_between(grid, flo, fhi, color="tab:blue", alpha=0.35, label="5-95 % of samples")
    b.plot(grid, fmed, color="tab:blue", label="median")
    ts = np.sort(t_star)
    b.step(ts, np.arange(1, len(ts) + 1) / len(ts), where="post", color="k", label="t*")
    b.set_xlabel("time in water (s)")
    b.set_ylabel("fraction of cells completed")
    b.set_title("Morph progress")
    b.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    _save(fig, path)


def plot_sensitivity(path, rows):
    fig, ax = plt.subplots(figsize=(7, 0.6 + 0.5 * max(len(rows), 1)))
    names = [r["factor"] for r in rows][::-1]
    y = np.arange(len(names))
    ax.barh(y - 0.2, [r["timing_share"] for r in rows][::-1], 0.4, label="completion times")
    ax.barh(y + 0.2, [r["position_share"] for r in rows][::-1], 0.4, label="final positions")
    ax.set_yticks(y, names)
    ax.set_xlim(0, 1)
    ax.set_xlabel("share of the one-at-a-time variance")
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    _save(fig, path)


def _f(v, fmt="{:.3g}"):
    return "-" if v is None else fmt.format(v)


def _table(header, rows):
    h = "".join(f"<th>{html.escape(str(c))}</th>" for c in header)
    b = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>"
                for r in rows)
    return f"<table><tr>{h}</tr>{b}</table>"


def write_report(out, summary: dict, design_dir, results: list, nominal: dict) -> None:
    """Write the pictures and ``report.html`` of a tolerance analysis into ``out``."""
    _pictures(out, summary, design_dir, results, nominal)
    parts = (_head(summary, design_dir) + _error_split(summary) + _sensitivity(summary)
             + _least_reliable(summary))
    atomic_write_text(out / "report.html", "\n".join(parts) + "\n")


def _pictures(out, summary: dict, design_dir, results: list, nominal: dict) -> None:
    """The shell, timing and sensitivity pictures."""
    b = read_table(design_dir, "bases")
    c = read_table(design_dir, "cells")
    target = np.c_[b["target_x_mm"], b["target_y_mm"], b["target_z_mm"]]
    pairs = np.c_[c["base_a"], c["base_b"]]
    t_star = np.asarray(c["t_star_s"], float)
    opt = summary["options"]
    p_on = np.array([r["p_on_time"] for r in summary["cells"]])
    sd = np.array([r["position_sd_mm"] for r in summary["bases"]])
    T = np.array([[np.nan if v is None else v for v in r["t_done"]] for r in results], float)
    t_nom = np.array([np.nan if v is None else v for v in nominal["t_done"]], float)
    plot_shell(out / "tolerance_shell.png", target, pairs, p_on, sd)
    plot_timing(out / "tolerance_timing.png", t_star, t_nom, T.reshape(len(results), -1),
                opt["time_tol_s"], opt["t_end_s"])
    if summary["sensitivity"]:
        plot_sensitivity(out / "tolerance_sensitivity.png", summary["sensitivity"])
    else:  # ours (the folder is claimed): a picture of an earlier run must not linger
        remove_file(out / "tolerance_sensitivity.png")


def _head(summary: dict, design_dir) -> list:
    """The page up to the pictures: P(PASS), the uncertainty, the whole-shell figures."""
    fig, opt = summary["figures"], summary["options"]
    unc = opt["uncertainty"]
    lo, hi = fig["p_pass_ci95"]
    return [f"<!doctype html><html lang='en'><head><meta charset='utf-8'><title>morphshell "
            f"tolerance: {html.escape(str(design_dir))}</title><style>{_CSS}</style></head>"
            f"<body><h1>Tolerance analysis: {html.escape(str(design_dir))}</h1>",
            f"<p class='big'>P(PASS) = {fig['p_pass']:.2f} "
            f"<span class='note'>(95 % CI {lo:.2f}-{hi:.2f})</span>, "
            f"P(not FAIL) = {fig['p_not_fail']:.2f}</p>",
            f"<p>{fig['samples']} Monte Carlo samples (seed {opt['seed']}), simulated to "
            f"t = {opt['t_end_s']:g} s; nominal verdict {html.escape(fig['nominal_verdict'])}."
            f" Most influential factor: <b>{html.escape(fig.get('most_influential', '-'))}"
            "</b>.</p>",
            "<h2>Uncertainty</h2>",
            _table(["factor", "distribution"], [
                ("thickness", f"per bracket, normal, sd {unc['thickness_sd']:g} mm"),
                ("stretch", f"pre-stretch normal {unc['stretch_mean']:g} +- "
                            f"{unc['stretch_sd']:g}"),
                ("modulus", f"membrane modulus x (1 + normal(0, {unc['modulus_rel_sd']:g}))"),
                ("material", f"bracket compliance x exp(normal(0, {unc['material_sd']:.3g}))"
                             " (fit residuals, per print)"),
                ("relaxation", "on: modulus x F(wait)/F(peak), wait log-uniform "
                               f"{unc['relaxation_window_s']} s" if unc["relaxation"]
                 else "off (--relaxation)")]),
            "<h2>Whole shell</h2>",
            _table(["figure", "value"], [
                ("verdicts", ", ".join(f"{k} {v}" for k, v in fig["verdicts"].items())),
                ("reasons (samples)", "; ".join(f"{k}: {v}" for k, v in
                                                fig["reasons"].items()) or "-"),
                ("P(cell on time), mean over cells: without / with the coupon",
                 f"{_f(fig['p_on_time_cell_mean'])} / "
                 f"{_f(fig.get('p_on_time_cell_mean_coupon'))}"),
                ("P(order kept), neighbours >= 15 s apart: without / with the coupon",
                 f"{_f(fig.get('p_order_kept'))} / {_f(fig.get('p_order_kept_coupon'))}"),
                ("P(no collision on the way): without / with the coupon",
                 " / ".join(_f((fig.get(k) or {}).get("p"))
                            for k in ("p_no_collision", "p_no_collision_coupon"))),
                ("timing variance share: per print / per bracket",
                 " / ".join(_f((fig.get("timing_variance_share") or {}).get(k))
                            for k in ("per_print", "per_bracket"))),
                ("P(every cell on time)", _f(fig["p_all_cells_on_time"])),
                ("P(on time), worst cell", _f(fig["p_on_time_cell_min"])),
                ("completion time sd, mean / max over cells",
                 f"{_f(fig['completion_sd_s_mean'])} / {_f(fig['completion_sd_s_max'])} s"),
                ("final position sd, mean / max over bases",
                 f"{_f(fig['position_sd_mm_mean'])} / {_f(fig['position_sd_mm_max'])} mm"),
                ("shape RMS error, mean (p95)",
                 f"{_f(fig['shape_rms_pct']['mean'])} % ({_f(fig['shape_rms_pct']['p95'])} %)"),
                ("timing RMS error, mean (p95)",
                 f"{_f(fig['timing_rms_s']['mean'])} s ({_f(fig['timing_rms_s']['p95'])} s)"),
                ("diverged samples", fig["diverged"])]),
            "<h2>Pictures</h2><img src='tolerance_shell.png' alt='shell'>"
            "<img src='tolerance_timing.png' alt='timing'>"]


STAGES = {"nominal": "nominal print (programming error; clamped cells)",
          "thickness": "+ per-bracket thickness scatter (a perfect coupon)",
          "coupon": "+ per-print factors, corrected by the coupon's fit",
          "samples": "+ per-print factors, uncorrected (no coupon)"}


def _error_split(summary: dict) -> list:
    """Where a cell's timing error comes from
    (:func:`pysolver.tolerance.coupon.error_split`)."""
    split = summary["figures"].get("timing_error_split") or {}
    if not split:
        return []
    return ["<h2>Where the timing error comes from</h2><p class='note'>Each row adds one "
            "source to the row above, all simulated. Squared error of a cell that never "
            "completes counted at the end of the simulation (a lower bound).</p>",
            _table(["runs", "simulations", "P(cell on time)", "mean squared error (s^2)",
                    "added (s^2)", "off-time cells that are clamped"],
                   [(STAGES[k], r["runs"], _f(r["p_on_time"]), _f(r["mse_s2"]),
                     _f(r["added_mse_s2"]), f"{100 * r['off_time_clamped_share']:.0f} %")
                    for k, r in split.items()])]


def _sensitivity(summary: dict) -> list:
    """The one-at-a-time sensitivity and its cross-check from the samples."""
    parts = []
    sens = summary["sensitivity"]
    if sens:
        parts += ["<h2>Sensitivity (one at a time)</h2><p class='note'>Each factor alone "
                  f"({sens[0]['runs']} runs, the draws of the first samples, the others "
                  "nominal). Share = its variance over the sum of the factors' variances "
                  "(interactions not counted).</p>",
                  _table(["factor", "runs", "completion var (s^2)", "timing share",
                          "position var (mm^2)", "position share", "P(PASS)"],
                         [(r["factor"], r["runs"], _f(r["completion_var_s2"]),
                           f"{100 * r['timing_share']:.0f} %", _f(r["position_var_mm2"]),
                           f"{100 * r['position_share']:.0f} %", _f(r["p_pass"]))
                          for r in sens]),
                  "<img src='tolerance_sensitivity.png' alt='sensitivity'>"]
    reg = summary.get("sensitivity_regression") or []
    if reg:
        parts += ["<h3>Cross-check from the Monte Carlo samples</h3><p class='note'>R^2 of "
                  "each factor's draw against the sample's mean completion time and shape "
                  "error (first-order, linear; thickness as the sample's mean deviation).</p>",
                  _table(["factor", "R^2 mean completion time", "R^2 shape error"],
                         [(r["factor"], _f(r["r2_mean_completion"]), _f(r["r2_shape_rms"]))
                          for r in reg])]
    return parts


def _least_reliable(summary: dict) -> list:
    """The 15 cells least often on time, and the end of the page."""
    worst = sorted(summary["cells"], key=lambda r: (r["p_on_time"], -r["t_sd_s"]))[:15]
    return ["<h2>Least reliable cells</h2>",
            _table(["cell", "t* (s)", "nominal (s)", "P(on time)", "P(complete)", "sd (s)",
                    "predicted sd, thickness (s)", "5 % (s)", "95 % (s)"],
                   [(r["cell_id"], _f(r["t_star_s"]), _f(r["t_nominal_s"]),
                     _f(r["p_on_time"]), _f(r["p_complete"]), _f(r["t_sd_s"]),
                     _f(r.get("t_sd_predicted_s")), _f(r["t_p05_s"]), _f(r["t_p95_s"]))
                    for r in worst]),
            "<p class='note'>All cells and bases: summary.json.</p></body></html>"]


__all__ = ["write_report", "plot_shell", "plot_timing", "plot_sensitivity"]
