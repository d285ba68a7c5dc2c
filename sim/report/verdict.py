"""The simulation check, computed once: metrics and verdict of a simulated morph.

:func:`check_morph` is the one place where a morph is judged.  It takes the frames (from
``sim/frames.npz`` or in memory) and the design (:class:`pysolver.tables.Design`, whose own
unit cell sets the collision radius) and returns a :class:`Check`: the metrics, the verdict
(PASS / WARN / FAIL) and its reasons.  The report (:func:`sim.report.make_report`) and the
tolerance analysis (through :func:`pysolver.simulator.simulate_and_check`) both call it, so
the two can never judge the same frames differently.  The limits are
:class:`pysolver.params.ReportThresholds`, explained in ``docs/report.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pysolver.errors import InputError
from pysolver.params import ReportThresholds
from pysolver.tables import Design

from ..model.collisions import CollisionResult, base_collisions
from .load import cell_pairs, load_sim, n_valid_frames, target_normals, targets
from .metrics import (
    collision_results,
    fold_metrics,
    shape_metrics,
    solver_metrics,
    timing_metrics,
)

SOLVER_KEYS = ("newton_iterations", "residual", "wall_s", "converged")
"""Per-step solver records of the frames (cut at the first non-finite frame too)."""
SHAPE_ARRAYS = ("err", "angle", "Q", "s", "aligned")
"""Arrays of :func:`shape_metrics` that are not figures (kept on :class:`Check`)."""


@dataclass
class Check:
    """A judged morph.

    Attributes
    ----------
    verdict : {"PASS", "WARN", "FAIL"}
    reasons : list of dict
        ``{level, check, message}``, FAILs first.
    metrics : dict
        The figures (``report.json``'s ``metrics``): ``n_bases``, ``n_cells``,
        ``n_frames``, ``t_end_s``, ``stopped_early``, ``shape``, ``fold``, ``timing``,
        ``collisions``, ``solver`` and, when given or found, ``tables`` and ``nonfinite``.
    n_valid : int
        Frames up to the first one with a non-finite position (the ones checked).
    shape : dict
        :func:`~sim.report.metrics.shape_metrics` of the last valid frame, arrays included.
    t_done : (c,) float, s
        Completion time per cell (NaN = never).
    base_base : CollisionResult
    membrane_base : CollisionResult or None
    """

    verdict: str
    reasons: list
    metrics: dict
    n_valid: int
    shape: dict
    t_done: np.ndarray
    base_base: CollisionResult
    membrane_base: CollisionResult | None

    def reason_lines(self) -> list[str]:
        """The reasons as ``"LEVEL check: message"`` lines."""
        return [f"{r['level']} {r['check']}: {r['message']}" for r in self.reasons]

    def figures(self) -> dict:
        """The headline figures of one tolerance sample: ``verdict``, ``reasons`` (lines),
        shape, fold and timing errors, ``t_done`` (c,) s (None = never) and ``base_final``
        (m, 3) mm (the last valid centres rigidly aligned to the target)."""
        sh, tm = self.metrics["shape"], self.metrics["timing"]
        t_done = self.t_done
        return {"verdict": self.verdict, "reasons": self.reason_lines(),
                "shape_rms_pct": sh["rms_pct"], "shape_rms_mm": sh["rms_mm"],
                "shape_max_mm": sh["max_mm"], "normal_rms_deg": sh["normal_rms_deg"],
                "fold_rms_deg": self.metrics["fold"]["rms_deg"],
                "timing_rms_s": tm["rms_s"], "timing_bias_s": tm["bias_s"],
                "timing_max_abs_s": tm["max_abs_s"], "n_never_due": tm["n_never_due"],
                "n_completed": tm["n_completed"],
                "longest_cell_s": (float(np.nanmax(t_done)) if np.isfinite(t_done).any()
                                   else None),
                "t_done": [None if not np.isfinite(v) else float(v) for v in t_done],
                "base_final": np.asarray(self.shape["aligned"], float).tolist()}


def check_morph(frames: dict, design: Design, thresholds=None, *, tables: dict | None = None,
                where: str = "the frames") -> Check:
    """Measure a simulated morph against its design and judge it.

    Frames from the first one with a non-finite position on are left out (and that is a
    FAIL: the simulation diverged).  The membrane-vs-base check uses the design's own unit
    cell (``design.params``: ``--max-cell-length``), not the default one.

    Parameters
    ----------
    frames : dict of arrays
        ``t`` (f,) s, ``base_center`` (f, m, 3) mm, ``base_rotation`` (f, m, 3, 3),
        ``collided`` (f, c, 4) and, when recorded, ``bracket_length``,
        ``collision_length``, ``membrane_vertices``, the solver records, ``stopped_early``,
        ``flat_membrane_vertices``, ``flat_base_center`` (``frames.npz`` or
        :func:`sim.model.simulate.simulate_model`).
    design : pysolver.tables.Design
        The design the frames were simulated from.
    thresholds : ReportThresholds or dict, optional
        Verdict limits (default :class:`ReportThresholds`).
    tables : dict, optional
        What the frames and STLs were made from (the report's file checks: ``sha256``,
        ``frames_sha256``, ``parts``); None when the frames are in memory.
    where : str
        Names the frames in the error below.

    Returns
    -------
    Check

    Raises
    ------
    InputError
        The first frame already has non-finite positions.
    """
    th = ReportThresholds.coerce(thresholds)
    t = np.asarray(frames["t"], float)
    n_ok = n_valid_frames(frames)
    if n_ok == 0:
        raise InputError(f"{where}: the first frame has non-finite positions",
                         fix="re-run the simulation; the flat state is broken")
    C = np.asarray(frames["base_center"], float)[:n_ok]
    R = np.asarray(frames["base_rotation"], float)[:n_ok]
    M = frames.get("membrane_vertices")
    last = n_ok - 1
    metrics = {"n_bases": design.n_bases, "n_cells": design.n_cells, "n_frames": int(len(t)),
               "t_end_s": float(t[-1]),
               "stopped_early": bool(np.asarray(frames.get("stopped_early", False)).any())}
    if tables is not None:
        metrics["tables"] = tables
    if n_ok < len(t):
        metrics["nonfinite"] = {"frame": n_ok, "time_s": float(t[n_ok])}
    pairs = cell_pairs(design)
    sh = shape_metrics(C[last], R[last], targets(design), target_normals(design))
    metrics["shape"] = {k: v for k, v in sh.items() if k not in SHAPE_ARRAYS}
    metrics["shape"]["final_frame"] = int(last)
    fo = fold_metrics(C[last], R[last], pairs, design.cells["fold_angle_deg"], th)
    metrics["fold"] = {k: v for k, v in fo.items() if k != "fold_deg"}
    tm = timing_metrics(t[:n_ok], np.asarray(frames["collided"])[:n_ok],
                        design.cells["t_star_s"], th, frames.get("bracket_length"),
                        frames.get("collision_length"), design.cells.get("clamped"))
    metrics["timing"] = {k: v for k, v in tm.items() if k != "t_done"}
    bc, mc = collision_results(C, R, None if M is None else np.asarray(M)[:n_ok], t[:n_ok],
                               pairs, design.params, th,
                               flat_vertices=frames.get("flat_membrane_vertices"),
                               flat_centers=frames.get("flat_base_center"))
    metrics["collisions"] = {"base_base": bc.summary()}
    if mc is not None:
        metrics["collisions"]["membrane_base"] = mc.summary()
    metrics["solver"] = solver_metrics(
        {k: (np.asarray(v)[:n_ok] if k in SOLVER_KEYS + ("t",) else v)
         for k, v in frames.items()}, th)
    verdict, reasons = decide(metrics, th)
    return Check(verdict, reasons, metrics, n_ok, sh, np.asarray(tm["t_done"], float), bc, mc)


def decide(metrics: dict, th: ReportThresholds):
    """Verdict from the metrics of :func:`check_morph`.

    Returns
    -------
    verdict : {"PASS", "WARN", "FAIL"}
    reasons : list of dict(level, check, message)
        FAILs first, then WARNs, each in the order of the checks.
    """
    found = []
    for rule in (_divergence, _shape, _folds, _timing, _collisions, _solver, _tables):
        found += rule(metrics, th)
    reasons = [{"level": lv, "check": ck, "message": msg} for lv, ck, msg in found]
    levels = {r["level"] for r in reasons}
    verdict = "FAIL" if "FAIL" in levels else "WARN" if "WARN" in levels else "PASS"
    order = {"FAIL": 0, "WARN": 1}
    reasons.sort(key=lambda r: order[r["level"]])
    return verdict, reasons


def _graded(value, warn, fail):
    """(level, limit) for a value against WARN/FAIL limits, or (None, None)."""
    if value > fail:
        return "FAIL", fail
    return ("WARN", warn) if value > warn else (None, None)


def _divergence(m: dict, th: ReportThresholds) -> list:
    nf = m.get("nonfinite")
    if nf is None:
        return []
    return [("FAIL", "solver", f"non-finite positions from frame {nf['frame']} "
                               f"(t = {nf['time_s']:g} s): the simulation diverged")]


def _shape(m: dict, th: ReportThresholds) -> list:
    out = []
    sh = m["shape"]
    level, lim = _graded(sh["rms_pct"], th.shape_rms_warn_pct, th.shape_rms_fail_pct)
    if level:
        out.append((level, "shape", f"final shape RMS error {sh['rms_mm']:.2f} mm = "
                                    f"{sh['rms_pct']:.1f} % of the size > {lim:g} %"))
    if sh["max_pct"] > th.shape_max_warn_pct:
        out.append(("WARN", "shape", f"base {sh['worst_base']} ends {sh['max_mm']:.2f} mm "
                                     f"({sh['max_pct']:.1f} % of the size) from its target "
                                     f"> {th.shape_max_warn_pct:g} %"))
    level, lim = _graded(sh["normal_rms_deg"], th.normal_warn_deg, th.normal_fail_deg)
    if level:
        out.append((level, "shape", f"base orientation RMS error {sh['normal_rms_deg']:.0f} "
                                    f"deg > {lim:g} deg"
                                    + (" (bent the wrong way?)" if level == "FAIL" else "")))
    return out


def _folds(m: dict, th: ReportThresholds) -> list:
    fo = m.get("fold")
    if fo is None:
        return []
    out = []
    if fo["flipped_fraction"] > th.fold_flip_fail_fraction:
        out.append(("FAIL", "shape", f"{fo['n_flipped']} of {fo['n_folded']} folded unit "
                                     "cells fold the wrong way (bent the wrong way; > "
                                     f"{100 * th.fold_flip_fail_fraction:g} %)"))
    elif fo["n_flipped"]:
        out.append(("WARN", "shape", f"{fo['n_flipped']} folded unit cell(s) fold the wrong "
                                     f"way (e.g. cell {fo['flipped_cells'][0]})"))
    if fo["rms_deg"] > th.fold_rms_warn_deg:
        out.append(("WARN", "shape", f"fold angle RMS error {fo['rms_deg']:.1f} deg > "
                                     f"{th.fold_rms_warn_deg:g} deg"))
    return out


def _timing(m: dict, th: ReportThresholds) -> list:
    out = []
    tm = m["timing"]
    if tm["never_due_fraction"] > th.incomplete_fail_fraction:
        out.append(("FAIL", "timing", f"{tm['n_never_due']} of {tm['n_cells']} unit cells "
                                      f"never complete by t = {tm['t_end_s']:g} s "
                                      f"(> {100 * th.incomplete_fail_fraction:g} %)"))
    elif tm["n_never_due"]:
        out.append(("WARN", "timing", f"{tm['n_never_due']} unit cell(s) never complete by "
                                      f"t = {tm['t_end_s']:g} s although t* <= t_end "
                                      f"(e.g. cell {tm['never_due_cells'][0]})"))
    if np.isfinite(tm["rms_s"]) and tm["rms_s"] > th.timing_rms_warn_s:
        out.append(("WARN", "timing", f"completion time RMS error {tm['rms_s']:.1f} s > "
                                      f"{th.timing_rms_warn_s:g} s (bias "
                                      f"{tm['bias_s']:+.1f} s)"))
    if tm["spearman"] is not None and tm["spearman"] < th.spearman_warn:
        out.append(("WARN", "timing", "completion order differs from the programmed one: "
                                      f"Spearman {tm['spearman']:.2f} < {th.spearman_warn:g}"))
    return out


BASE_COLLISION_TEXT = "pair(s) of non-neighbouring bases collide"
"""The words of the collision check's FAIL line (read back by the tolerance analysis's
P(no collision on the way), :func:`pysolver.tolerance.coupon.collision_free`)."""


def _collisions(m: dict, th: ReportThresholds) -> list:
    out = []
    bc = m["collisions"]["base_base"]
    if bc["count"]:
        f = bc["first"]
        out.append(("FAIL", "collisions",
                    f"{bc['count']} {BASE_COLLISION_TEXT}; first bases "
                    f"{f['pair'][0]} and {f['pair'][1]} at t = {f['time_s']:g} s, depth "
                    f"{f['depth_mm']:.2f} mm (max {bc['max_depth_mm']:.2f} mm)"))
    mc = m["collisions"].get("membrane_base")
    if mc and mc["count"]:
        f = mc["first"]
        out.append(("FAIL" if th.membrane_collision_fail else "WARN", "collisions",
                    f"membrane passes through bases ({mc['count']} vertex/base pairs); first "
                    f"vertex {f['pair'][0]} in base {f['pair'][1]} at t = {f['time_s']:g} s, "
                    f"depth {f['depth_mm']:.2f} mm"))
    return out


def _solver(m: dict, th: ReportThresholds) -> list:
    so = m["solver"]
    if so["n_bad_residual"]:
        return [("FAIL", "solver", f"{so['n_bad_residual']} step(s) did not converge, "
                                   f"residual above {th.residual_fail_N:g} N (first at t = "
                                   f"{so['nonconverged_times_s'][0]:g} s)")]
    if so["n_nonconverged"]:
        return [("WARN", "solver", f"{so['n_nonconverged']} step(s) stopped before the Newton "
                                   f"tolerance, residual <= {th.residual_fail_N:g} N")]
    return []


def _tables(m: dict, th: ReportThresholds) -> list:
    tb = m.get("tables")
    if tb is None:
        return []
    out = []
    if tb["frames_sha256"] is not None and tb["frames_sha256"] != tb["sha256"]:
        out.append(("FAIL", "tables", "the simulation was made from other tables than the "
                                      "design folder's now (a later program stage or an "
                                      "edit): this check is not about these tables; simulate "
                                      "again"))
    if not tb["parts"]["fresh"]:
        out.append(("WARN", "parts", tb["parts"]["problem"] + ": they are not listed and must "
                                     "not be printed; render again (morphshell render DIR)"))
    return out


def base_base_collisions(design_dir, thresholds=None) -> dict:
    """Non-neighbouring bases passing through each other in a simulated design folder, by the
    check's own rule (:func:`sim.model.collisions.base_collisions`, depth above
    ``ReportThresholds.collision_depth_mm``, frames up to the first non-finite one).

    Parameters
    ----------
    design_dir : path-like
        Design folder with ``sim/frames.npz``.
    thresholds : ReportThresholds or dict, optional

    Returns
    -------
    dict
        :meth:`sim.model.collisions.CollisionResult.summary` (``count``, ``first``, ...).
    """
    th = ReportThresholds.coerce(thresholds)
    sd = load_sim(design_dir)
    fr = sd.frames
    n_ok = n_valid_frames(fr)
    return base_collisions(fr["base_center"][:n_ok], fr["base_rotation"][:n_ok],
                           sd.cell_pairs, t=sd.t[:n_ok], tol=th.collision_depth_mm).summary()


__all__ = ["Check", "check_morph", "decide", "base_base_collisions", "BASE_COLLISION_TEXT"]
