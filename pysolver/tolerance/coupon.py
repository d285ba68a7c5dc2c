"""The coupon workflow checked by simulation (``morphshell tolerance DIR --coupon``, issue #45).

For each Monte Carlo sample, the print's draws (bracket compliance, membrane modulus and
relaxation) apply to the timing coupon as to the shell.  The coupon's closing times come from
the programming's time model (:func:`pysolver.temporal.coupon.closing_times`) with the
coupon's own bracket thickness scatter (``thickness_sd``, drawn from
``default_rng([seed, i, COUPON_STREAM])``, so the shell's draws are unchanged) and a reading
error of :attr:`pysolver.params.Coupon.reading_sd_s`; they are fitted by
``calibrate-time``'s own code (:func:`pysolver.temporal.coupon.fit_coupon`).  The shell is then
programmed again with the fit: each layer's bracket gets the thickness with which the fitted
print closes it when the shipped model closed the nominal one
(:func:`reprogrammed_thickness`), so the programming's own corrections (the refinement's
requested times) are kept.  That shell, printed with the sample's own thickness scatter, is
simulated like the sample.

Also here: the figures a maker reads (:func:`order_kept`, :func:`variance_share`,
:func:`collision_free`, :func:`error_split`).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from pysolver.design.pipeline import run_design
from pysolver.errors import InputError
from pysolver.material.model import CompliantBracketModel
from pysolver.params import COUPON, TOLERANCE_RUN
from pysolver.simulator import BASE_COLLISION_TEXT
from pysolver.tables import read_table
from pysolver.temporal import coupon as tc
from pysolver.temporal.program import completion_time, solve_thickness, time_limit, timing_sd

COUPON_STREAM = 45
"""Third seed word of a sample's coupon draws (thickness scatter, reading error)."""
PER_PRINT = ("stretch", "modulus", "material", "relaxation")
"""Factors drawn once per print (the rest, ``thickness``, once per bracket)."""


def coupon_setup(material) -> dict:
    """The coupon's timed cells as ``morphshell coupon`` makes them (designed in a temporary
    folder; nothing is rendered): :func:`pysolver.temporal.coupon.cell_geometry` of the timed
    cells plus ``thickness`` (n, 2) mm."""
    with tempfile.TemporaryDirectory(prefix="morphshell-coupon-") as tmp:
        folder = Path(tmp) / "coupon"
        run_design(tc.coupon_source(), folder, progress=False, plots=False)
        geom = tc.cell_geometry(folder)
    th, timed = tc.coupon_thicknesses(material, geom)
    out = {k: v[timed] for k, v in geom.items()}
    out["thickness"] = th[timed]
    return out


def simulated_coupon(setup: dict, material, draw: dict, rng, thickness_sd: float) -> dict:
    """The coupon of one print as the maker would type it: :func:`read_coupon_csv`'s dict.

    Parameters
    ----------
    draw : dict -- the sample's draws (``material`` compliance, ``modulus``, ``relaxation``)
    rng : numpy Generator -- the coupon's own stream
    thickness_sd : float, mm
    """
    n = len(setup["b0"])
    th = np.maximum(setup["thickness"] + thickness_sd * rng.standard_normal((n, 2)),
                    TOLERANCE_RUN.thickness_floor_mm)
    t = tc.closing_times(material, setup["b0"], setup["x"], setup["f_bracket"], th,
                         draw["material"], draw["modulus"] * draw["relaxation"])
    t = t + COUPON.reading_sd_s * rng.standard_normal(n)
    # the maker stops at the end of the model's range: a later cell is written "never"
    t = np.where(np.isfinite(t) & (t <= time_limit(material)),
                 np.maximum(t, COUPON.reading_sd_s), np.inf)
    return {"label": np.array([str(k) for k in range(n)], dtype=object),
            "thickness": setup["thickness"], "b0": setup["b0"], "x": setup["x"],
            "f_bracket": setup["f_bracket"], "t": t}


def reprogrammed_thickness(shell: dict, thickness, material, fit: dict):
    """Thicknesses (n, 2) mm with which the fitted print closes each layer when the shipped
    model closes the programmed one (a layer that never closes keeps its thickness)."""
    th = np.asarray(thickness, float)
    bb = np.repeat(shell["b0"][:, None], 2, 1)
    ff = np.repeat(shell["f_bracket"][:, None], 2, 1)
    t = completion_time(material, th, bb, shell["x"], ff)
    s, m = fit["compliance"]["value"], fit["modulus"]["value"]
    cal = CompliantBracketModel(material, s)
    ok = np.isfinite(t)
    h, _ = solve_thickness(cal, bb, shell["x"], np.where(ok, t, 0.0), ff * m)
    return np.where(ok, h, th)


def shell_geometry(folder) -> dict:
    """What the time model needs of a design folder's cells
    (:func:`pysolver.temporal.coupon.cell_geometry`)."""
    return tc.cell_geometry(folder)


def predicted_timing_sd(folder, material, thickness_sd: float):
    """Each cell's completion-time sd (n,) s under the per-bracket thickness scatter, as the
    bracket model predicts it (:func:`pysolver.temporal.program.timing_sd`)."""
    cells = read_table(folder, "cells")
    geom = tc.cell_geometry(folder)
    h = np.c_[cells["thickness_top_mm"], cells["thickness_bottom_mm"]].astype(float)
    sd, _, _ = timing_sd(material, h, geom["b0"], geom["x"], geom["f_bracket"], thickness_sd)
    return sd


def coupon_fit(setup: dict, material, draw: dict, rng, thickness_sd: float):
    """The fit of one print's coupon, or None when ``calibrate-time`` would refuse it."""
    d = simulated_coupon(setup, material, draw, rng, thickness_sd)
    try:
        return tc.fit_coupon(d, material, thickness_sd=thickness_sd)
    except InputError:
        return None


# ----------------------------------------------------------------------------------------------
# figures


def neighbour_pairs(cells: dict, t_star, separation_s: float):
    """Pairs (k, 2) int of cells sharing a base whose programmed times are at least
    ``separation_s`` apart, the earlier cell first."""
    ts = np.asarray(t_star, float)
    by_base: dict = {}
    for j, (a, b) in enumerate(zip(cells["base_a"], cells["base_b"], strict=True)):
        by_base.setdefault(int(a), []).append(j)
        by_base.setdefault(int(b), []).append(j)
    pairs = set()
    for js in by_base.values():
        for p in js:
            for q in js:
                if p != q and ts[q] - ts[p] >= separation_s:
                    pairs.add((p, q))
    return np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)


def order_kept(T, pairs) -> float | None:
    """Fraction of (sample, pair) in which the earlier-programmed cell completes first.

    Parameters
    ----------
    T : (S, n) float, s -- completion times, NaN where a cell never completes (it then counts
        as completing after every cell that does; two that never complete: order lost)
    pairs : (k, 2) int -- :func:`neighbour_pairs`
    """
    if not len(pairs) or not len(T):
        return None
    Tc = np.where(np.isfinite(T), T, np.inf)
    a, b = Tc[:, pairs[:, 0]], Tc[:, pairs[:, 1]]
    return float(np.mean(a < b))


def variance_share(sensitivity: list, total_var=None, bracket_var=None,
                   bracket_runs: int = 0) -> dict | None:
    """Shares of the timing variance drawn once per print and once per bracket.

    With the Monte Carlo samples' own variance (``total_var``, mean over cells, s^2, all
    factors drawn together) and the one-at-a-time thickness runs' (``bracket_var``, mean over
    cells, s^2), the split is measured: per bracket = ``bracket_var / total_var``, per print =
    the rest.  The thickness draws are independent per cell, so the mean over cells of the
    thickness runs' variance is well estimated even from a few runs (its relative standard
    error, ``sqrt(2 / (runs - 1) / cells)`` for independent cells, is given as
    ``per_bracket_rel_se``); the per-print part, drawn once per sample, is estimated from all
    the samples, not from the few one-at-a-time runs of each per-print factor.  Without them,
    the shares of the summed one-at-a-time variances (``method`` says which).

    Parameters
    ----------
    sensitivity : list of dict -- :func:`pysolver.tolerance.analysis.sensitivity_table`
    total_var, bracket_var : float or None, s^2
    bracket_runs : int -- one-at-a-time thickness runs behind ``bracket_var``

    Returns
    -------
    dict or None -- ``per_print``, ``per_bracket``, ``method`` and, when measured,
        ``total_var_s2``, ``per_bracket_var_s2``, ``per_bracket_runs``
    """
    if total_var and bracket_var is not None and bracket_runs >= 2:
        pb = min(float(bracket_var) / float(total_var), 1.0)
        return {"per_print": 1.0 - pb, "per_bracket": pb,
                "method": "per bracket: one-at-a-time thickness runs over all samples' "
                          "variance; per print: the rest",
                "total_var_s2": float(total_var), "per_bracket_var_s2": float(bracket_var),
                "per_bracket_runs": int(bracket_runs)}
    if not sensitivity:
        return None
    pp = sum(r["timing_share"] for r in sensitivity if r["factor"] in PER_PRINT)
    pb = sum(r["timing_share"] for r in sensitivity if r["factor"] not in PER_PRINT)
    return {"per_print": float(pp), "per_bracket": float(pb),
            "method": "shares of the summed one-at-a-time variances"}


def collision_free(results: list) -> dict | None:
    """P(no collision on the way): the fraction of simulated prints in which no two
    non-neighbouring bases collide at any frame (the simulation check's collision line,
    :data:`pysolver.simulator.BASE_COLLISION_TEXT`).  A diverged simulation counts as not
    collision-free (unknown).

    Returns
    -------
    dict or None -- ``p``, ``n``, ``n_free``, ``n_collided``, ``n_diverged``
    """
    if not results:
        return None
    hit = [any(BASE_COLLISION_TEXT in line for line in r["reasons"]) or bool(r["diverged"])
           for r in results]
    k = len(hit) - sum(hit)
    return {"p": k / len(hit), "n": len(hit), "n_free": int(k),
            "n_collided": int(sum(hit) - sum(bool(r["diverged"]) for r in results)),
            "n_diverged": int(sum(bool(r["diverged"]) for r in results))}


def on_time(T, t_star, tol: float):
    """(S, n) bool: each completion time of ``T`` (s, NaN = never) within ``tol`` s of its
    cell's ``t_star`` (n,) s."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(T) & (np.abs(T - t_star) <= tol)


def error_split(runs: dict, t_star, clamped, tol: float, t_end: float) -> dict:
    """Where a cell's timing error comes from, measured step by step with the simulator.

    Each stage adds one source to the one before: the ``nominal`` run (the programming's own
    error: clamped cells never reach their time, the rest is the time model's miss), the
    one-at-a-time ``thickness`` runs (+ the per-bracket scatter, every per-print factor
    nominal: what a perfect coupon would leave), the ``coupon`` runs (+ the per-print
    factors as the coupon's fit leaves them) and the plain ``samples`` (+ the per-print
    factors uncorrected).  For each: P(cell within ``tol``), the mean squared error (a cell
    that never completes counts at ``t_end``: a lower bound) and its increase over the stage
    before; and the share of off-time (print, cell) pairs that are clamped cells.

    Parameters
    ----------
    runs : dict of str -> (S, n) float, s (NaN = never) -- keys among ``nominal``,
        ``thickness``, ``coupon``, ``samples``, in that order
    t_star : (n,) float, s
    clamped : (n,) bool
    tol, t_end : float, s

    Returns
    -------
    dict -- per stage: ``runs``, ``p_on_time``, ``mse_s2``, ``added_mse_s2``,
        ``off_time_clamped_share``
    """
    t_star = np.asarray(t_star, float)
    clamped = np.asarray(clamped, bool)
    out, before = {}, 0.0
    for name in ("nominal", "thickness", "coupon", "samples"):
        T = runs.get(name)
        if T is None or not len(T):
            continue
        T = np.asarray(T, float)
        on = on_time(T, t_star, tol)
        mse = float(np.mean((np.where(np.isfinite(T), T, t_end) - t_star) ** 2))
        off = ~on
        out[name] = {"runs": int(len(T)), "p_on_time": float(on.mean()), "mse_s2": mse,
                     "added_mse_s2": mse - before,
                     "off_time_clamped_share": float((off & clamped).sum() / off.sum())
                     if off.any() else 0.0}
        before = mse
    return out


__all__ = ["COUPON_STREAM", "coupon_setup", "simulated_coupon", "reprogrammed_thickness",
           "shell_geometry", "predicted_timing_sd", "coupon_fit", "neighbour_pairs",
           "order_kept", "variance_share", "collision_free", "error_split", "on_time"]
