"""Simulation check report: is the simulated morph the designed one?

:func:`make_report` reads a design folder (``bases.csv``, ``cells.csv``,
``stencil.obj``, ``time_landscape.csv``, ``sim/frames.npz``; see
``docs/design-folder.md``), measures the morph and writes
``<design_dir>/report/index.html`` (self-contained: every picture is embedded as
a base64 data URI) and ``report.json``, then prints the verdict
(PASS / WARN / FAIL with reasons).  The checks and their thresholds
(:class:`Thresholds`) are explained in ``docs/report.md``.

Sections: verdict; final shape vs target (rigid Kabsch alignment of the base
centres, error in mm and % of the target size, base-normal orientation);
timing (simulated unit-cell completion vs the programmed t*); collisions along
the path (:mod:`sim.model.collisions`); solver health; shaded renders at chosen
times and an animated GIF; flat layout coloured by bracket thickness; time
landscape.

Run as ``python -m sim.report <design_dir>`` or ``morphshell report <dir>``.
"""

from __future__ import annotations

import argparse
import base64
import dataclasses
import html
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from scipy import stats

from pysolver.atomic import atomic_dir
from pysolver.errors import InputError
from pysolver.geometry import fold_angles_deg, rigid_fit
from pysolver.params import UNIT_CELL, ReportThresholds
from pysolver.params import tol as TOL
from pysolver.tables import Design, read_design, read_table

from ..model.collisions import base_collisions, membrane_collisions, never_due
from ..model.collisions import completion_times as collision_completion_times
from ..viewer import asset_text, frame_alignments, viewer_data, viewer_json
from . import fabrication as fab
from . import plots as rp

SECTIONS = ("verdict", "viewer", "shape", "timing", "collisions", "solver", "renders",
            "layout", "landscape", "fabrication", "stls", "provenance")
"""Section ids of ``index.html``, in order."""

FRAME_KEYS = ("t", "base_center", "base_rotation", "bracket_length", "collided")
OPTIONAL_KEYS = ("membrane_vertices", "membrane_triangles", "newton_iterations", "residual",
                 "wall_s", "converged", "marker_top", "marker_bottom")


# --------------------------------------------------------------------------------------------
# thresholds
# --------------------------------------------------------------------------------------------

Thresholds = ReportThresholds
"""The verdict limits, :class:`pysolver.params.ReportThresholds` (kept under this name)."""


# --------------------------------------------------------------------------------------------
# loading
# --------------------------------------------------------------------------------------------

@dataclass
class SimData:
    """A design folder and its simulation, loaded and validated.

    The design is read by the one design-folder reader (:func:`pysolver.tables.read_design`,
    tables cross-checked against the stencil); the attributes below are views of it.

    Attributes
    ----------
    design : pysolver.tables.Design
    frames : dict of arrays — ``sim/frames.npz``
    folder : Path
    bases, cells : dict of (r,) arrays — ``bases.csv`` / ``cells.csv`` columns
    V, UV : (n, 3), (n, 2) float, mm — stencil (target, flat)
    F : (m, 3) int
    landscape : (n,) float, s — time landscape per stencil vertex
    """

    design: Design
    frames: dict

    folder = property(lambda self: self.design.folder)
    bases = property(lambda self: self.design.bases)
    cells = property(lambda self: self.design.cells)
    V = property(lambda self: self.design.V)
    UV = property(lambda self: self.design.UV)
    F = property(lambda self: self.design.F)
    landscape = property(lambda self: self.design.time)
    n_bases = property(lambda self: self.design.n_bases)
    n_cells = property(lambda self: self.design.n_cells)

    @property
    def t(self):
        return self.frames["t"]

    @property
    def target(self):
        b = self.bases
        return np.c_[b["target_x_mm"], b["target_y_mm"], b["target_z_mm"]]

    @property
    def target_normals(self):
        b = self.bases
        return np.c_[b["normal_x"], b["normal_y"], b["normal_z"]]

    @property
    def flat_xy(self):
        return np.c_[self.bases["flat_x_mm"], self.bases["flat_y_mm"]]

    @property
    def cell_pairs(self):
        return np.c_[self.cells["base_a"], self.cells["base_b"]]


def load_frames(path, n_bases=None, n_cells=None) -> dict:
    """Read and validate ``sim/frames.npz``.

    Parameters
    ----------
    path : path-like
    n_bases, n_cells : int, optional
        Expected counts (from the tables).

    Returns
    -------
    dict of arrays (all contract keys present in the file).
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: file not found",
                         fix="run the simulation first (morphshell simulate <design_dir>)")
    try:
        with np.load(path, allow_pickle=False) as z:
            fr = {k: z[k] for k in z.files}
    except Exception as e:
        raise InputError(f"{path}: cannot read ({type(e).__name__}: {e})",
                         fix="re-run the simulation; the file is damaged") from None
    missing = [k for k in FRAME_KEYS if k not in fr]
    if missing:
        raise InputError(f"{path}: missing array(s) {missing}",
                         fix="re-run the simulation with the current sim.model.simulate")
    t = np.asarray(fr["t"], float)
    nf = len(t)
    if t.ndim != 1 or nf < 1:
        raise InputError(f"{path}: t has shape {t.shape}, expected (n_frames,) with n_frames >= 1")
    nb = fr["base_center"].shape[1] if fr["base_center"].ndim == 3 else -1
    nc = fr["collided"].shape[1] if fr["collided"].ndim == 3 else -1
    shapes = {"base_center": (nf, nb, 3), "base_rotation": (nf, nb, 3, 3),
              "bracket_length": (nf, nc, 4), "collided": (nf, nc, 4)}
    for k, s in shapes.items():
        if fr[k].shape != s:
            raise InputError(f"{path}: {k} has shape {fr[k].shape}, expected {s} "
                             "(n_frames, n_bases/n_cells, ...)",
                             fix="re-run the simulation; frames.npz does not follow the contract")
    if n_bases is not None and nb != n_bases:
        raise InputError(f"{path}: {nb} bases in the frames but {n_bases} rows in bases.csv",
                         fix="re-run the simulation after the last design change")
    if n_cells is not None and nc != n_cells:
        raise InputError(f"{path}: {nc} cells in the frames but {n_cells} rows in cells.csv",
                         fix="re-run the simulation after the last design change")
    if "membrane_vertices" in fr:
        mv = fr["membrane_vertices"]
        if mv.ndim != 3 or mv.shape[0] != nf or mv.shape[2] != 3:
            raise InputError(f"{path}: membrane_vertices has shape {mv.shape}, expected "
                             f"({nf}, n_mem, 3)")
        tri = fr.get("membrane_triangles")
        if tri is not None and tri.size and (tri.ndim != 2 or tri.shape[1] != 3 or tri.min() < 0
                                             or tri.max() >= mv.shape[1]):
            raise InputError(f"{path}: membrane_triangles must be (n_tri, 3) indices into "
                             f"0..{mv.shape[1] - 1}")
    for k in ("newton_iterations", "residual", "wall_s", "converged"):
        if k in fr and fr[k].shape != (nf,):
            raise InputError(f"{path}: {k} has shape {fr[k].shape}, expected ({nf},)")
    fr["t"] = t
    return fr


def load_sim(design_dir) -> SimData:
    """Load a design folder (:func:`pysolver.tables.read_design`) and its ``sim/frames.npz``."""
    folder = Path(design_dir)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a design folder",
                         fix="pass the folder written by the design stage (build/<shape>)")
    design = read_design(folder)
    frames = load_frames(folder / "sim" / "frames.npz", design.n_bases, design.n_cells)
    return SimData(design, frames)


def _n_valid_frames(fr: dict) -> int:
    """Number of frames up to the first one with a non-finite position.

    Parameters
    ----------
    fr : dict
        ``frames.npz`` arrays: ``base_center`` (f, m, 3) mm, ``base_rotation`` (f, m, 3, 3),
        optionally ``membrane_vertices`` (f, k, 3) mm.
    """
    finite = (np.isfinite(fr["base_center"]).all(axis=(1, 2))
              & np.isfinite(fr["base_rotation"]).all(axis=(1, 2, 3)))
    M = fr.get("membrane_vertices")
    if M is not None and np.asarray(M).ndim == 3:
        finite &= np.isfinite(M).all(axis=(1, 2))
    return int(np.argmin(finite)) if not finite.all() else len(finite)


def base_base_collisions(design_dir, thresholds=None) -> dict:
    """Non-neighbouring bases passing through each other in a simulated design folder, by the
    report's own rule (:func:`sim.model.collisions.base_collisions`, depth above
    ``Thresholds.collision_depth_mm``).

    Parameters
    ----------
    design_dir : path-like
        Design folder with ``sim/frames.npz``.
    thresholds : Thresholds or dict, optional

    Returns
    -------
    dict
        :meth:`sim.model.collisions.CollisionResult.summary` (``count``, ``first``, ...).
    """
    th = Thresholds.coerce(thresholds)
    sd = load_sim(design_dir)
    fr = sd.frames
    n_ok = _n_valid_frames(fr)
    return base_collisions(fr["base_center"][:n_ok], fr["base_rotation"][:n_ok], sd.cell_pairs,
                           t=sd.t[:n_ok], tol=th.collision_depth_mm).summary()


# --------------------------------------------------------------------------------------------
# metrics
# --------------------------------------------------------------------------------------------

def completion_times(t, collided, bracket_length=None, collision_length=None):
    """Completion time per cell: :func:`sim.model.collisions.completion_times`, the project's
    one rule (every bracket at its bumper within the printing clearance).

    Returns
    -------
    t_done : (n_cells,) float, s (NaN = never)
    source : str
    """
    out = np.asarray(collision_completion_times(t, collided, bracket_length=bracket_length,
                                                collision_length=collision_length), float)
    return out, "sim.model.collisions.completion_times"


def shape_metrics(C, R, target, target_normals):
    """Final shape vs target after rigid (Kabsch) alignment of the base centres.

    Parameters
    ----------
    C : (n_bases, 3) float, mm — simulated base centres
    R : (n_bases, 3, 3) float — simulated base rotations (flat -> current)
    target : (n_bases, 3) float, mm — target base centres
    target_normals : (n_bases, 3) float — target face normals

    Returns
    -------
    dict with ``rms_mm, max_mm, size_mm, rms_pct, max_pct, normal_rms_deg,
    normal_max_deg, worst_base`` and arrays ``err`` (n_bases,), ``angle`` (n_bases,),
    ``Q`` (3, 3), ``s`` (3,) (the alignment x -> Q x + s).
    """
    Q, s = rigid_fit(C, target)
    A = C @ Q.T + s
    err = np.linalg.norm(A - target, axis=1)
    size = float(np.linalg.norm(np.ptp(target, axis=0)))
    n_sim = np.einsum("ij,bj->bi", Q, R[:, :, 2])
    cosang = np.clip(np.sum(n_sim * target_normals, axis=1)
                     / np.linalg.norm(target_normals, axis=1), -1.0, 1.0)
    ang = np.degrees(np.arccos(cosang))
    rms = float(np.sqrt(np.mean(err ** 2)))
    return {
        "rms_mm": rms, "max_mm": float(err.max()), "mean_mm": float(err.mean()),
        "size_mm": size, "rms_pct": 100 * rms / size if size > 0 else float("nan"),
        "max_pct": 100 * float(err.max()) / size if size > 0 else float("nan"),
        "normal_rms_deg": float(np.sqrt(np.mean(ang ** 2))), "normal_max_deg": float(ang.max()),
        "worst_base": int(np.argmax(err)),
        "err": err, "angle": ang, "Q": Q, "s": s, "aligned": A,
    }


def fold_metrics(C, R, cell_pairs, target_fold_deg, th: Thresholds):
    """Signed fold angle per unit cell in the final frame vs the target's.

    Parameters
    ----------
    C : (n_bases, 3) float, mm
    R : (n_bases, 3, 3) float
    cell_pairs : (n_cells, 2) int
    target_fold_deg : (n_cells,) float, deg — ``cells.csv`` fold_angle_deg

    Returns
    -------
    dict with ``rms_deg, max_deg, n_folded, n_flipped, flipped_fraction, flipped_cells``
    and the array ``fold_deg`` (n_cells,).
    """
    fold = fold_angles_deg(C, R[:, :, 2], SimpleNamespace(faces=np.asarray(cell_pairs)))
    tgt = np.asarray(target_fold_deg, float)
    d = fold - tgt
    folded = np.abs(tgt) >= th.fold_min_deg
    flipped = folded & (np.sign(fold) != np.sign(tgt))
    return {
        "rms_deg": float(np.sqrt(np.mean(d ** 2))) if d.size else 0.0,
        "max_deg": float(np.abs(d).max()) if d.size else 0.0,
        "n_folded": int(folded.sum()), "n_flipped": int(flipped.sum()),
        "flipped_fraction": float(flipped.sum() / max(folded.sum(), 1)),
        "flipped_cells": [int(i) for i in np.flatnonzero(flipped)[:th.listed_cells]],
        "fold_deg": fold,
    }


def shape_rms_over_time(C_frames, target):
    """RMS distance (mm) of every frame's base centres to the target after its own alignment."""
    out = np.empty(len(C_frames))
    for f, C in enumerate(C_frames):
        Q, s = rigid_fit(C, target)
        out[f] = np.sqrt(np.mean(np.sum((C @ Q.T + s - target) ** 2, axis=1)))
    return out


def timing_metrics(t, collided, t_star, th: Thresholds, bracket_length=None,
                   collision_length=None, clamped=None):
    """Simulated completion of every unit cell vs its programmed t*.

    The headline error (``rms_s``, ``spearman``, ``bias_s``) is over the cells whose t*
    the temporal stage could program (``clamped`` = 0): a clamped cell was already
    reported infeasible there, and its error says nothing about the simulation.  The
    same figures over every cell are ``*_all``.
    """
    t_done, source = completion_times(t, collided, bracket_length, collision_length)
    t_star = np.asarray(t_star, float)
    t_end = float(t[-1])
    done = np.isfinite(t_done)
    due = t_star <= t_end
    stuck = never_due(t_done, t_star, t_end)
    feasible = (np.ones_like(done) if clamped is None
                else ~np.asarray(clamped, bool)[: len(done)])

    def errors(mask):
        m = done & mask
        d = t_done[m] - t_star[m]
        rms = float(np.sqrt(np.mean(d ** 2))) if d.size else float("nan")
        rho = None
        spread = float(np.std(t_star[m])) if m.sum() >= 3 else 0.0
        if m.sum() >= 3 and spread >= th.timing_spread_min_s and np.std(t_done[m]) > 0:
            rho = float(stats.spearmanr(t_star[m], t_done[m]).statistic)
        return m, d, rms, rho, spread

    m, d, rms, rho, spread = errors(feasible)
    _, d_all, rms_all, rho_all, _ = errors(np.ones_like(done))
    return {
        "source": source, "t_end_s": t_end, "n_cells": int(len(t_star)),
        "n_completed": int(done.sum()), "n_never": int((~done).sum()),
        "n_never_due": int(stuck.sum()),
        "never_due_fraction": float(stuck.sum() / max(due.sum(), 1)),
        "never_due_cells": [int(i) for i in np.flatnonzero(stuck)[:th.listed_cells]],
        "n_clamped": int((~feasible).sum()),
        "rms_s": rms, "bias_s": float(d.mean()) if d.size else float("nan"),
        "max_abs_s": float(np.abs(d).max()) if d.size else float("nan"),
        "spearman": rho, "t_star_spread_s": spread,
        "rms_all_s": rms_all, "spearman_all": rho_all,
        "bias_all_s": float(d_all.mean()) if d_all.size else float("nan"),
        "worst_cell": int(np.flatnonzero(m)[np.argmax(np.abs(d))]) if d.size else None,
        "t_done": t_done,
    }


def solver_metrics(fr, th: Thresholds):
    """Newton iterations, residuals and wall time per step; non-converged steps."""
    t = fr["t"]
    n = len(t)
    present = all(k in fr for k in ("newton_iterations", "residual", "wall_s", "converged"))
    if not present:
        return {"recorded": False, "n_steps": n, "n_nonconverged": 0, "n_bad_residual": 0,
                "nonconverged_frames": []}
    it = np.asarray(fr["newton_iterations"], float)
    res = np.asarray(fr["residual"], float)
    wall = np.asarray(fr["wall_s"], float)
    conv = np.asarray(fr["converged"], bool)
    bad = np.flatnonzero(~conv)
    bad_res = bad[~(res[bad] <= th.residual_fail_N)]       # NaN residual counts as bad
    return {
        "recorded": True, "n_steps": n,
        "iterations_total": int(np.nansum(it)), "iterations_mean": float(np.nanmean(it)),
        "iterations_max": int(np.nanmax(it)) if n else 0,
        "residual_max": float(np.nanmax(res)) if n else float("nan"),
        "wall_total_s": float(np.nansum(wall)), "wall_mean_s": float(np.nanmean(wall)),
        "wall_max_s": float(np.nanmax(wall)) if n else float("nan"),
        "n_nonconverged": int(len(bad)), "n_bad_residual": int(len(bad_res)),
        "nonconverged_frames": [int(i) for i in bad[:th.listed_cells]],
        "nonconverged_times_s": [float(t[i]) for i in bad[:th.listed_cells]],
    }


def decide(metrics: dict, th: Thresholds):
    """Verdict from the metrics.

    Returns
    -------
    verdict : {"PASS", "WARN", "FAIL"}
    reasons : list of dict(level, check, message)
    """
    reasons = []

    def add(level, check, msg):
        reasons.append({"level": level, "check": check, "message": msg})

    nf = metrics.get("nonfinite")
    if nf is not None:
        add("FAIL", "solver", f"non-finite positions from frame {nf['frame']} "
                              f"(t = {nf['time_s']:g} s): the simulation diverged")
    def graded(value, warn, fail):
        """(level, limit) for a value against WARN/FAIL limits, or (None, None)."""
        if value > fail:
            return "FAIL", fail
        return ("WARN", warn) if value > warn else (None, None)

    sh = metrics["shape"]
    level, lim = graded(sh["rms_pct"], th.shape_rms_warn_pct, th.shape_rms_fail_pct)
    if level:
        add(level, "shape", f"final shape RMS error {sh['rms_mm']:.2f} mm = "
                            f"{sh['rms_pct']:.1f} % of the size > {lim:g} %")
    if sh["max_pct"] > th.shape_max_warn_pct:
        add("WARN", "shape", f"base {sh['worst_base']} ends {sh['max_mm']:.2f} mm "
                             f"({sh['max_pct']:.1f} % of the size) from its target "
                             f"> {th.shape_max_warn_pct:g} %")
    level, lim = graded(sh["normal_rms_deg"], th.normal_warn_deg, th.normal_fail_deg)
    if level:
        add(level, "shape", f"base orientation RMS error {sh['normal_rms_deg']:.0f} deg > "
                            f"{lim:g} deg" + (" (bent the wrong way?)" if level == "FAIL" else ""))
    fo = metrics.get("fold")
    if fo is not None:
        if fo["flipped_fraction"] > th.fold_flip_fail_fraction:
            add("FAIL", "shape", f"{fo['n_flipped']} of {fo['n_folded']} folded unit cells fold "
                                 "the wrong way (bent the wrong way; > "
                                 f"{100 * th.fold_flip_fail_fraction:g} %)")
        elif fo["n_flipped"]:
            add("WARN", "shape", f"{fo['n_flipped']} folded unit cell(s) fold the wrong way "
                                 f"(e.g. cell {fo['flipped_cells'][0]})")
        if fo["rms_deg"] > th.fold_rms_warn_deg:
            add("WARN", "shape", f"fold angle RMS error {fo['rms_deg']:.1f} deg > "
                                 f"{th.fold_rms_warn_deg:g} deg")
    tm = metrics["timing"]
    if tm["never_due_fraction"] > th.incomplete_fail_fraction:
        add("FAIL", "timing", f"{tm['n_never_due']} of {tm['n_cells']} unit cells never "
                              f"complete by t = {tm['t_end_s']:g} s "
                              f"(> {100 * th.incomplete_fail_fraction:g} %)")
    elif tm["n_never_due"]:
        add("WARN", "timing", f"{tm['n_never_due']} unit cell(s) never complete by "
                              f"t = {tm['t_end_s']:g} s although t* <= t_end "
                              f"(e.g. cell {tm['never_due_cells'][0]})")
    if np.isfinite(tm["rms_s"]) and tm["rms_s"] > th.timing_rms_warn_s:
        add("WARN", "timing", f"completion time RMS error {tm['rms_s']:.1f} s > "
                              f"{th.timing_rms_warn_s:g} s (bias {tm['bias_s']:+.1f} s)")
    if tm["spearman"] is not None and tm["spearman"] < th.spearman_warn:
        add("WARN", "timing", f"completion order differs from the programmed one: Spearman "
                              f"{tm['spearman']:.2f} < {th.spearman_warn:g}")
    bc = metrics["collisions"]["base_base"]
    if bc["count"]:
        f = bc["first"]
        add("FAIL", "collisions",
            f"{bc['count']} pair(s) of non-neighbouring bases collide; first bases "
            f"{f['pair'][0]} and {f['pair'][1]} at t = {f['time_s']:g} s, depth "
            f"{f['depth_mm']:.2f} mm (max {bc['max_depth_mm']:.2f} mm)")
    mc = metrics["collisions"].get("membrane_base")
    if mc and mc["count"]:
        f = mc["first"]
        add("FAIL" if th.membrane_collision_fail else "WARN", "collisions",
            f"membrane passes through bases ({mc['count']} vertex/base pairs); first vertex "
            f"{f['pair'][0]} in base {f['pair'][1]} at t = {f['time_s']:g} s, depth "
            f"{f['depth_mm']:.2f} mm")
    so = metrics["solver"]
    if so["n_bad_residual"]:
        add("FAIL", "solver", f"{so['n_bad_residual']} step(s) did not converge, residual above "
                              f"{th.residual_fail_N:g} N (first at t = "
                              f"{so['nonconverged_times_s'][0]:g} s)")
    elif so["n_nonconverged"]:
        add("WARN", "solver", f"{so['n_nonconverged']} step(s) stopped before the Newton "
                              f"tolerance, residual <= {th.residual_fail_N:g} N")
    levels = {r["level"] for r in reasons}
    verdict = "FAIL" if "FAIL" in levels else "WARN" if "WARN" in levels else "PASS"
    order = {"FAIL": 0, "WARN": 1}
    reasons.sort(key=lambda r: order[r["level"]])
    return verdict, reasons


def _finite_list(a):
    return [None if not np.isfinite(v) else float(v) for v in np.ravel(a)]


def check_frames(frames: dict, ctx: dict, thresholds=None) -> dict:
    """The report's simulation check on in-memory frames (the tolerance analysis's samples).

    Parameters
    ----------
    frames : dict
        As returned by :func:`sim.model.simulate.simulate_model`.
    ctx : dict
        ``target`` (m, 3) mm, ``normals`` (m, 3), ``pairs`` (c, 2), ``t_star`` (c,) s,
        ``fold`` (c,) deg, ``clamped`` (c,) bool or None.

    Returns
    -------
    dict
        ``verdict``, ``reasons``, figures, ``t_done`` (c,) s (None = never),
        ``base_final`` (m, 3) mm (final centres rigidly aligned to the target).
    """
    th = Thresholds.coerce(thresholds)
    t = np.asarray(frames["t"], float)
    C, R = np.asarray(frames["base_center"], float), np.asarray(frames["base_rotation"], float)
    M = frames.get("membrane_vertices")
    last = len(t) - 1
    metrics = {"t_end_s": float(t[-1])}
    sh = shape_metrics(C[last], R[last], ctx["target"], ctx["normals"])
    metrics["shape"] = sh
    metrics["fold"] = fold_metrics(C[last], R[last], ctx["pairs"], ctx["fold"], th)
    tm = timing_metrics(t, frames["collided"], ctx["t_star"], th,
                        frames.get("bracket_length"), frames.get("collision_length"),
                        ctx["clamped"])
    metrics["timing"] = tm
    bc = base_collisions(C, R, ctx["pairs"], t=t, tol=th.collision_depth_mm)
    col = {"base_base": bc.summary()}
    if M is not None and np.asarray(M).shape[1]:
        col["membrane_base"] = membrane_collisions(
            C, R, M, t=t, tol=th.collision_depth_mm,
            flat_vertices=frames.get("flat_membrane_vertices"),
            flat_centers=frames.get("flat_base_center")).summary()
    metrics["collisions"] = col
    metrics["solver"] = solver_metrics(frames, th)
    verdict, reasons = decide(metrics, th)
    t_done = tm["t_done"]
    return {"verdict": verdict,
            "reasons": [f"{r['level']} {r['check']}: {r['message']}" for r in reasons],
            "shape_rms_pct": sh["rms_pct"], "shape_rms_mm": sh["rms_mm"],
            "shape_max_mm": sh["max_mm"], "normal_rms_deg": sh["normal_rms_deg"],
            "fold_rms_deg": metrics["fold"]["rms_deg"],
            "timing_rms_s": tm["rms_s"], "timing_bias_s": tm["bias_s"],
            "timing_max_abs_s": tm["max_abs_s"], "n_never_due": tm["n_never_due"],
            "n_completed": tm["n_completed"],
            "longest_cell_s": float(np.nanmax(t_done)) if np.isfinite(t_done).any() else None,
            "t_done": _finite_list(t_done),
            "base_final": np.asarray(sh["aligned"], float).tolist()}


# --------------------------------------------------------------------------------------------
# report
# --------------------------------------------------------------------------------------------

class _Progress:
    def __init__(self, enabled, n):
        self.enabled, self.n, self.k = enabled, n, 0
        self.t0 = self.t_last = time.perf_counter()

    def step(self, name):
        self.k += 1
        now = time.perf_counter()
        if self.enabled:
            print(f"report [{self.k}/{self.n}] {name} (+{now - self.t_last:.1f} s)",
                  file=sys.stderr, flush=True)
        self.t_last = now


def _nearest_frames(t, times):
    """Nearest frame per requested time, plus the last frame; de-duplicated, in time order."""
    t = np.asarray(t, float)
    idx = [int(np.argmin(np.abs(t - x))) for x in times] + [len(t) - 1]
    return sorted(set(idx))


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, (np.bool_, bool)):
        return bool(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (float, np.floating)):
        x = float(o)
        return x if math.isfinite(x) else None
    if isinstance(o, Path):
        return str(o)
    return o


def make_report(design_dir, *, times=(0, 3, 30, 50, 80), thresholds=None, out_dir=None,
                progress=True, image_px=560, gif_frames=0, renderer="auto", build_info=None,
                viewer_frames=80) -> dict:
    """Check a simulated morph and write the HTML/JSON report.

    Parameters
    ----------
    design_dir : path-like
        Design folder with ``bases.csv``, ``cells.csv`` and ``sim/frames.npz``
        (``stencil.obj`` and ``time_landscape.csv`` are used when present).
    times : sequence of float, s
        Times of the still renders (nearest frame; the last frame is always added).
    thresholds : Thresholds or dict, optional
        Verdict limits (default :class:`Thresholds`).
    out_dir : path-like, optional
        Report folder (default ``<design_dir>/report``).  Written into a
        temporary folder beside it and moved into place when complete.
    progress : bool
        One line per step on stderr.
    image_px : int, px
        Width of the renders (height = 3/4); the GIF is at most 480 px wide.
    gif_frames : int
        Frames of an animated GIF written beside the report (at most 60; 0 = none, the
        default: the page embeds the interactive viewer instead).
    renderer : {"auto", "pyvista", "matplotlib"}
        Shell renderer; "auto" uses pyvista when off-screen rendering works.
    build_info : dict, optional
        ``source``, ``options``, ``inputs_sha256`` of the build (provenance).
    viewer_frames : int
        Frames of the embedded 3D viewer (evenly spaced, the end kept).

    Returns
    -------
    dict
        The content of ``report.json``: ``verdict``, ``reasons``, ``metrics``,
        ``thresholds``, ``files``, ``renderer``, ``timings_s``, ``out_dir``.
    """
    th = Thresholds.coerce(thresholds)
    if renderer not in ("auto", "pyvista", "matplotlib"):
        raise InputError(f"renderer = {renderer!r}", fix="use 'auto', 'pyvista' or 'matplotlib'")
    if not (16 <= int(image_px) <= 4096):
        raise InputError(f"image_px = {image_px}", fix="use a width between 16 and 4096 px")
    gif_frames = 0 if not gif_frames else int(min(max(gif_frames, 2), 60))
    t_start = time.perf_counter()
    timings = {}
    pr = _Progress(progress, 10)

    def lap(name, t0):
        timings[name] = round(time.perf_counter() - t0, 3)

    t0 = time.perf_counter()
    sd = load_sim(design_dir)
    folder = sd.folder
    out_dir = Path(out_dir) if out_dir is not None else folder / "report"
    fr = sd.frames
    t = fr["t"]
    C_all = np.asarray(fr["base_center"], float)
    R_all = np.asarray(fr["base_rotation"], float)
    M_all = fr.get("membrane_vertices")
    tri = fr.get("membrane_triangles")
    lap("load", t0)
    pr.step("loaded")

    metrics = {"n_bases": sd.n_bases, "n_cells": sd.n_cells, "n_frames": int(len(t)),
               "t_end_s": float(t[-1]),
               "stopped_early": bool(np.asarray(fr.get("stopped_early", False)).any())}
    n_ok = _n_valid_frames(fr)
    if n_ok < len(t):
        metrics["nonfinite"] = {"frame": n_ok, "time_s": float(t[n_ok])}
    if n_ok == 0:
        raise InputError(f"{folder / 'sim/frames.npz'}: the first frame has non-finite positions",
                         fix="re-run the simulation; the flat state is broken")
    last = n_ok - 1

    # ---- shape
    t0 = time.perf_counter()
    sh = shape_metrics(C_all[last], R_all[last], sd.target, sd.target_normals)
    rms_t = shape_rms_over_time(C_all[:n_ok], sd.target)
    metrics["shape"] = {k: v for k, v in sh.items()
                        if k not in ("err", "angle", "Q", "s", "aligned")}
    metrics["shape"]["final_frame"] = int(last)
    fo = fold_metrics(C_all[last], R_all[last], sd.cell_pairs, sd.cells["fold_angle_deg"], th)
    metrics["fold"] = {k: v for k, v in fo.items() if k != "fold_deg"}
    lap("shape", t0)
    pr.step("shape vs target")

    # ---- timing
    t0 = time.perf_counter()
    tm = timing_metrics(t[:n_ok], fr["collided"][:n_ok], sd.cells["t_star_s"], th,
                        fr.get("bracket_length", None), fr.get("collision_length", None),
                        sd.cells.get("clamped", None))
    metrics["timing"] = {k: v for k, v in tm.items() if k != "t_done"}
    lap("timing", t0)
    pr.step("timing")

    # ---- collisions
    t0 = time.perf_counter()
    bc = base_collisions(C_all[:n_ok], R_all[:n_ok], sd.cell_pairs, t=t[:n_ok],
                         tol=th.collision_depth_mm)
    col = {"base_base": bc.summary()}
    mc = None
    if M_all is not None and M_all.shape[1]:

        uc = sd.design.params  # the design's own max cell length, not the default
        mc = membrane_collisions(C_all[:n_ok], R_all[:n_ok], M_all[:n_ok], t=t[:n_ok],
                                 tol=th.collision_depth_mm,
                                 local_radius=uc.base_r + uc.max_cell_length,
                                 flat_vertices=fr.get("flat_membrane_vertices"),
                                 flat_centers=fr.get("flat_base_center"))
        col["membrane_base"] = mc.summary()
    metrics["collisions"] = col
    lap("collisions", t0)
    pr.step("collisions")

    # ---- solver
    so = solver_metrics({k: (v[:n_ok] if k in ("newton_iterations", "residual", "wall_s",
                                                 "converged", "t") else v)
                         for k, v in fr.items()}, th)
    metrics["solver"] = so
    verdict, reasons = decide(metrics, th)
    pr.step("verdict")

    files = {}
    notes = []
    if metrics.get("stopped_early"):
        # the simulator stops only when every cell rests on its bumpers in both layers and
        # nothing moved in a step: the bumpers then lock the shape, later times add nothing
        notes.append(f"The simulation settled at t = {metrics['t_end_s']:g} s (every unit cell "
                     "on its bumpers in both layers, no motion) and stopped there.")
    if "physics" in fr:  # effects beyond the reference model the frames were simulated with
        on = [k for k, v in json.loads(str(fr["physics"])).items() if v is True]
        if on:
            metrics["physics"] = on
            notes.append("Simulated with physics beyond the reference model: "
                         f"{', '.join(on)} (docs/physics.md).")
    with atomic_dir(out_dir) as tmp:
        # ---- 2D plots
        t0 = time.perf_counter()
        files["timing"] = rp.plot_timing(tmp / "timing.png", sd.cells["t_star_s"],
                                         tm["t_done"], float(t[last]),
                                         clamped=sd.cells.get("clamped")).name
        files["clearance"] = rp.plot_clearance(
            tmp / "collisions.png", t[:n_ok], bc.min_clearance,
            mc.min_clearance if mc is not None else None, th.collision_depth_mm,
            reach=bc.extra["reach_mm"]).name
        if so["recorded"]:
            files["solver"] = rp.plot_solver(tmp / "solver.png", t[:n_ok],
                                             fr["newton_iterations"][:n_ok],
                                             fr["residual"][:n_ok], fr["wall_s"][:n_ok],
                                             fr["converged"][:n_ok], th.residual_fail_N).name
        files["shape_over_time"] = _plot_shape_over_time(tmp / "shape_over_time.png",
                                                         t[:n_ok], rms_t, sh["size_mm"], th).name
        files["layout"] = rp.plot_layout_thickness(
            tmp / "layout_thickness.png", sd.flat_xy, sd.cell_pairs,
            sd.cells["thickness_top_mm"], sd.cells["thickness_bottom_mm"]).name
        files["landscape"] = rp.plot_time_landscape(
            tmp / "time_landscape.png", sd.flat_xy, sd.cell_pairs, sd.cells["t_star_s"],
            tm["t_done"], uv=sd.UV, faces=sd.F, landscape=sd.landscape, t_end=float(t[last])).name
        lap("plots", t0)
        pr.step("plots")

        # ---- shell renders (each frame in the target frame by its own rigid fit, so the
        # camera sees the shell from the same side all along the morph)
        t0 = time.perf_counter()

        Qs, ss = frame_alignments(C_all[:n_ok], sd.target)
        sh["Qs"], sh["ss"] = Qs, ss
        C_d = np.einsum("fij,fbj->fbi", Qs, C_all[:n_ok]) + ss[:, None]
        R_d = np.einsum("fij,fbjk->fbik", Qs, R_all[:n_ok])
        M_d = (np.einsum("fij,fvj->fvi", Qs, M_all[:n_ok]) + ss[:, None]
               if M_all is not None else None)
        T_d = np.asarray(tri, np.int64) if tri is not None and M_d is not None else None
        w = int(image_px)
        size = (w, int(round(0.75 * w)))
        ren = rp.ShellRenderer(C_d, R_d, M_d, T_d, normals=sd.target_normals, size=size,
                               backend=renderer)
        try:
            imgs = _render_all(ren, rp, tmp, files, t, last, times, sh, bc, gif_frames, w)
        except Exception as e:  # pyvista failed mid-way: redo everything with matplotlib
            if ren.backend != "pyvista":
                raise
            notes.append(f"pyvista rendering failed ({type(e).__name__}: {e}); "
                         "fell back to matplotlib 3D")
            ren.backend = "matplotlib"
            imgs = _render_all(ren, rp, tmp, files, t, last, times, sh, bc, gif_frames, w)
        if ren.backend == "matplotlib":
            notes.append((ren.note + "; " if ren.note else "")
                         + "renders use matplotlib 3D (no depth buffer: parts may be drawn "
                           "in the wrong order)")
        files.update(imgs)
        lap("renders", t0)
        pr.step(f"renders ({ren.backend})")

        # ---- standing alone: viewer, fabrication sheet, template, STLs, provenance
        t0 = time.perf_counter()
        extra = _standalone(sd, tm, tmp, folder, build_info, viewer_frames)
        files.update(extra.pop("files"))
        lap("standalone", t0)
        pr.step("viewer, fabrication sheet, provenance")

        # ---- json + html
        t0 = time.perf_counter()
        timings["total_before_write"] = round(time.perf_counter() - t_start, 3)
        result = {
            "design_dir": str(folder), "out_dir": str(out_dir), "verdict": verdict,
            "reasons": reasons, "metrics": metrics, "thresholds": dataclasses.asdict(th),
            "renderer": ren.backend, "notes": notes, "files": files, "timings_s": timings,
            "render_frames": {"frames": files.get("render_frames", []),
                              "times_s": [float(t[f]) for f in files.get("render_frames", [])]},
            "provenance": extra["provenance"], "stls": extra["stls"],
            "fabrication": extra["fabrication"],
        }
        result = _jsonable(result)
        (tmp / "report.json").write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
        (tmp / "index.html").write_text(_html(result, tmp, sd, extra["viewer"]),
                                        encoding="utf-8")
        lap("write", t0)
    timings["total"] = round(time.perf_counter() - t_start, 3)
    result["timings_s"] = timings
    pr.step("written")
    return result


def _render_all(ren, rp, tmp, files, t, last, times, sh, bc, gif_frames, w):
    """Still renders, error picture, collision picture and the GIF; returns their file names."""
    out = {}
    sel = _nearest_frames(t[:last + 1], times)
    names = []
    # each still framed on its own frame (the flat sheet is 2-4x the size of the target, so
    # one camera for all would leave the end shape small); the GIF keeps one camera.  No
    # label in the picture: the page's caption gives the time (one caption each)
    stills = [ren.images([f], fit="these", zoom=1.3)[0] for f in sel]
    for f, img in zip(sel, stills, strict=True):
        name = f"render_f{f:04d}.png"
        rp.save_png(img, tmp / name)
        names.append(name)
    out["renders"] = names
    out["render_frames"] = sel
    err = sh["err"]
    clim = (0.0, max(float(err.max()), TOL.colour_floor_mm))
    img = ren.images([last], base_scalars=err, clim=clim,
                     cmap="plasma", scalar_title="error (mm)", fit="these")[0]
    out["shape_error"] = rp.save_png(img, tmp / "shape_error.png").name
    if bc.count:
        ev = bc.first()
        f = ev["frame"]
        hit = np.unique(bc.pairs[bc.first_frame == f].ravel())
        point = (np.asarray(ev["point_mm"]) @ sh["Qs"][f].T + sh["ss"][f])[None]
        label = f"first collision, t = {t[f]:g} s: bases {ev['pair'][0]} & {ev['pair'][1]}"
        over = ren.images([f], labels=[label + " (red)"], highlight=hit, fit="these",
                          extra_points=point)[0]
        # close-up: 25 mm box around the contact, seen from the first base's top side
        a = ev["pair"][0]
        box = (point[0] - 12.5, point[0] + 12.5)
        close = ren.images([f], labels=["close-up"], highlight=hit, fit=box,
                           normal=ren.R[f, a, :, 2], extra_points=point)[0]
        img = np.concatenate([over, close], axis=1)
        out["collision_frame"] = rp.save_png(img, tmp / "collision_frame.png").name
    if not gif_frames:
        return out
    # animation: at most gif_frames frames, at most 480 px wide
    gw = min(w, 480)
    saved = ren.size
    ren.size = (gw, int(round(0.75 * gw)))
    try:
        gsel = sorted(set(np.linspace(0, last, min(gif_frames, last + 1)).round().astype(int)))
        gimgs = ren.images(gsel, labels=[f"t = {t[f]:5.1f} s" for f in gsel])
    finally:
        ren.size = saved
    out["animation"] = rp.save_gif(gimgs, tmp / "morph.gif").name
    return out


def _plot_shape_over_time(path, t, rms_t, size, th):
    # optional heavy dependency: matplotlib loads only when a picture is drawn
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.4))
    ax.plot(t, rms_t, lw=1.2)
    for pct, c in ((th.shape_rms_warn_pct, "orange"), (th.shape_rms_fail_pct, "red")):
        ax.axhline(size * pct / 100, color=c, ls="--", lw=0.8, label=f"{pct:g} % of size")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("RMS distance to target (mm)")
    ax.set_title("base centres vs target (each frame aligned rigidly)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()

    return rp._save(fig, path)  # (through the module: tests wrap it)


# --------------------------------------------------------------------------------------------
# HTML
# --------------------------------------------------------------------------------------------

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:1.5em auto;
max-width:1200px;color:#222;padding:0 1em;line-height:1.4}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;
margin-top:1.4em}
.verdict{font-size:2em;font-weight:bold;padding:.2em .6em;display:inline-block;border-radius:6px}
.PASS{background:#d7f5d7;color:#135e13}.WARN{background:#fff0c2;color:#7a5a00}
.FAIL{background:#ffd6d6;color:#8a1010}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #ddd;padding:.25em .6em;
text-align:left;vertical-align:top}th{background:#f4f4f4}
.figs{display:grid;grid-template-columns:repeat(auto-fill,minmax(460px,1fr));gap:.8em;
align-items:start}
.figs.wide{grid-template-columns:1fr}
figure{margin:0}figcaption{font-size:.9em;color:#444;margin-top:.2em}img{max-width:100%;
display:block}
li.FAIL{color:#8a1010}li.WARN{color:#7a5a00}.note{color:#555;font-size:.9em}
ol.steps li{margin:.3em 0}code{background:#f4f4f4;padding:0 .2em}
@media print{.mv,#viewer .note{display:none}.figs{display:block}figure{break-inside:avoid}}
"""


def _img(tmp, name, caption):
    p = Path(tmp) / name
    mime = {".gif": "image/gif", ".svg": "image/svg+xml"}.get(p.suffix, "image/png")
    data = base64.b64encode(p.read_bytes()).decode("ascii")
    return (f'<figure><img src="data:{mime};base64,{data}" alt="{html.escape(caption)}" '
            f'data-file="{html.escape(name)}"><figcaption>{html.escape(caption)}</figcaption>'
            "</figure>")


def _figs(*items, wide=False):
    return f"<div class='figs{' wide' if wide else ''}'>" + "".join(items) + "</div>"


def _table(rows, head=None):
    out = ["<table>"]
    if head:
        out.append("<tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in head) + "</tr>")
    for row in rows:
        cells = []
        for k, v in enumerate(row):
            if isinstance(v, float):
                v = "n/a" if not math.isfinite(v) else f"{v:.4g}"
            elif v is None:
                v = "n/a"
            tag = "th" if k == 0 and not head else "td"
            cells.append(f"<{tag}>{html.escape(str(v))}</{tag}>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def _f(x, fmt="{:.3g}"):
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else fmt.format(x)


def _standalone(sd, tm, tmp, folder, build_info, viewer_frames) -> dict:
    """Viewer data, stretch template, STL list, fabrication sheet and provenance."""
    files = {}
    viewer = viewer_data(sd, tm["t_done"], max_frames=int(viewer_frames))
    template = None
    if (folder / "support_frame.csv").exists():
        sf = read_table(folder, "support_frame")
        if len(sf["x_mm"]) >= 3:
            template = fab.stretch_template(np.c_[sf["x_mm"], sf["y_mm"]])
            (tmp / "stretch_template.svg").write_text(
                fab.template_svg(template, f"{folder.resolve().name}: membrane stretch "
                                           "template"), encoding="utf-8")
            files["stretch_template"] = "stretch_template.svg"
            fab.template_pdf(template, tmp / "stretch_template.pdf",
                             f"{folder.resolve().name}: membrane stretch template")
            files["stretch_template_pdf"] = "stretch_template.pdf"
    align = np.flatnonzero(np.asarray(sd.bases.get("alignment", np.zeros(sd.n_bases)), int))
    t_star = np.asarray(sd.cells["t_star_s"], float)
    t_done = np.asarray(tm["t_done"], float)
    ok = np.isfinite(t_done)
    span = (float(np.min(t_done[ok])), float(np.max(t_done[ok]))) if ok.any() else None
    cell_xyz = sd.target[sd.cell_pairs].mean(axis=1)
    steps = fab.fabrication_steps(
        n_align=len(align), align_ids=align.tolist(),
        side=fab.top_layer_side(sd.target, sd.target_normals),
        template=template or {"device_d_mm": max(fab.FABRICATION.star_diameters_mm),
                              "fits": True},
        t_span=span)
    fabrication = {"steps": [{"title": a, "text": b} for a, b in steps],
                   "timeline": fab.timeline(t_star, t_done, cell_xyz,
                                            sd.cells.get("clamped")),
                   "alignment_bases": align.tolist(),
                   "template": None if template is None else {
                       k: template[k] for k in ("device_d_mm", "fits", "tau", "sheet_mm",
                                                "marker_radius_mm", "shell_radius_mm")}}
    return {"files": files, "viewer": viewer, "stls": fab.stl_inventory(folder),
            "provenance": fab.provenance(folder, build_info), "fabrication": fabrication}


def _viewer_html(viewer) -> str:

    return ("<div id='morph-viewer'></div>"
            "<noscript><p class='note'>The 3D viewer needs JavaScript; the stills below show "
            "the same morph.</p></noscript>"
            f"<style>{asset_text('viewer.css')}</style>"
            f"<script>{asset_text('three.min.js')}</script>"
            f"<script>{asset_text('morph_viewer.js')}</script>"
            f"<script type='application/json' id='viewer-data'>{viewer_json(viewer)}</script>"
            "<script>(function(){var el=document.getElementById('morph-viewer');"
            "var d=JSON.parse(document.getElementById('viewer-data').textContent);"
            "window.morphViewer=new MorphViewer(el,d,{width:Math.min(1100,"
            "el.parentNode.clientWidth||900),title:''});})();</script>")


def _fmt_bytes(n):
    return f"{n / 1e6:.2f} MB" if n >= 1e6 else f"{n / 1e3:.1f} kB"


def _html(r, tmp, sd, viewer=None) -> str:
    m, fl, th = r["metrics"], r["files"], r["thresholds"]
    name = sd.folder.resolve().name
    sh, tm, co, so = m["shape"], m["timing"], m["collisions"], m["solver"]
    fo = m["fold"]
    parts = [f"<!doctype html><html lang='en'><head><meta charset='utf-8'>"
             f"<title>morphshell simulation check: {html.escape(name)}</title>"
             f"<style>{_CSS}</style></head><body>",
             f"<h1>Simulation check: {html.escape(name)}</h1>",
             f"<p class='note'>{m['n_bases']} bases, {m['n_cells']} unit cells, "
             f"{m['n_frames']} frames to t = {m['t_end_s']:g} s. Renderer: "
             f"{html.escape(r['renderer'])}. Thresholds: docs/report.md. Sections: "
             + ", ".join(f"<a href='#{s}'>{s}</a>" for s in SECTIONS) + ".</p>"]
    # verdict
    items = "".join(f"<li class='{x['level']}'><b>{x['level']}</b> [{x['check']}] "
                    f"{html.escape(x['message'])}</li>" for x in r["reasons"])
    parts.append(f"<section id='verdict'><h2>Verdict</h2><span class='verdict {r['verdict']}'>"
                 f"{r['verdict']}</span><ul>{items or '<li>all checks within thresholds</li>'}"
                 "</ul>" + "".join(f"<p class='note'>{html.escape(n)}</p>" for n in r["notes"])
                 + "</section>")
    # interactive viewer (replaces the GIF; the stills below are kept for print)
    parts.append("<section id='viewer'><h2>The morph in 3D</h2><p class='note'>Drag to turn, "
                 "right-drag or shift-drag to pan, wheel to zoom, the slider or play for time; "
                 "colour by completion time, timing error, thickness or distance to the "
                 "target; click a base for its unit cells. Each frame is shown aligned "
                 "rigidly to the target. Works offline (three.js is inside this page).</p>"
                 + (_viewer_html(viewer) if viewer is not None else "") + "</section>")
    # shape
    parts.append("<section id='shape'><h2>Final shape vs target</h2>"
                 "<p>Base centres of the last frame, rigidly aligned (Kabsch, no scaling) to the "
                 "target base centres. Size = bounding-box diagonal of the target centres.</p>"
                 + _table([("RMS distance", f"{_f(sh['rms_mm'])} mm ({_f(sh['rms_pct'])} %)"),
                           ("max distance", f"{_f(sh['max_mm'])} mm ({_f(sh['max_pct'])} %), "
                                            f"base {sh['worst_base']}"),
                           ("target size", f"{_f(sh['size_mm'])} mm"),
                           ("base normal error", f"RMS {_f(sh['normal_rms_deg'])} deg, max "
                                                 f"{_f(sh['normal_max_deg'])} deg"),
                           ("fold angle error per cell",
                            f"RMS {_f(fo['rms_deg'])} deg, max {_f(fo['max_deg'])} deg; "
                            f"{fo['n_flipped']} of {fo['n_folded']} folded cells fold the "
                            "wrong way"),
                           ("limits", f"WARN > {th['shape_rms_warn_pct']} %, FAIL > "
                                      f"{th['shape_rms_fail_pct']} % RMS; normals WARN > "
                                      f"{th['normal_warn_deg']} deg, FAIL > "
                                      f"{th['normal_fail_deg']} deg; folds WARN RMS > "
                                      f"{th['fold_rms_warn_deg']} deg or any flipped, FAIL > "
                                      f"{100 * th['fold_flip_fail_fraction']:g} % flipped")])
                 + _figs(_img(tmp, fl["shape_error"], f"final shell (t = {m['t_end_s']:g} s) "
                                                      "in the target frame, bases coloured by "
                                                      "their distance to the target (mm)"),
                         _img(tmp, fl["shape_over_time"], "RMS distance of the base centres to "
                                                          "the target over time, each frame "
                                                          "aligned rigidly"))
                 + "</section>")
    # timing: every cell first, then the programmable ones
    never = ", ".join(map(str, tm["never_due_cells"][:20])) or "none"
    n_prog = tm["n_cells"] - tm["n_clamped"]
    parts.append("<section id='timing'><h2>Timing</h2><p>A unit cell completes at the first "
                 "frame where all 4 of its bracket springs are at their bumpers, within "
                 "0.05 mm, the size of the printing clearance (source: "
                 f"{html.escape(tm['source'])}). Figures over all cells first; then over the "
                 f"{n_prog} programmable cells (the temporal stage could reach their t* with "
                 f"{UNIT_CELL.thickness_min:.2f}-{UNIT_CELL.thickness_max:.2f} mm brackets; "
                 "the verdict uses these).</p>"
                 + _table([("completed cells", f"{tm['n_completed']} / {tm['n_cells']}"),
                           ("never completed (t* <= t_end)", f"{tm['n_never_due']}: {never}"),
                           ("RMS error vs t*, all cells", f"{_f(tm['rms_all_s'])} s"),
                           ("mean error (bias), all cells",
                            f"{_f(tm.get('bias_all_s'), '{:+.3g}')} s"),
                           ("Spearman rank correlation, all cells", _f(tm["spearman_all"])),
                           ("cells clamped by the temporal stage", f"{tm['n_clamped']}"),
                           ("RMS error vs t*, programmable cells", f"{_f(tm['rms_s'])} s"),
                           ("mean error (bias), programmable cells",
                            f"{_f(tm['bias_s'], '{:+.3g}')} s"),
                           ("max |error|, programmable cells", f"{_f(tm['max_abs_s'])} s"),
                           ("Spearman rank correlation, programmable cells",
                            _f(tm["spearman"])),
                           ("limits", f"WARN RMS > {th['timing_rms_warn_s']} s, Spearman < "
                                      f"{th['spearman_warn']}, any never-completed cell; "
                                      f"FAIL > {100 * th['incomplete_fail_fraction']:g} % "
                                      "never completed")])
                 + _figs(_img(tmp, fl["timing"], "simulated completion vs programmed t*: "
                                                 "programmable cells as dots, clamped cells as "
                                                 "open squares, never-completed cells as red "
                                                 "crosses on the t_end line"))
                 + "</section>")
    # collisions
    bb = co["base_base"]
    rows = [("base vs base (non-neighbours)",
             "none" if not bb["count"] else
             f"{bb['count']} pairs, first bases {bb['first']['pair']} at t = "
             f"{bb['first']['time_s']:g} s, point {np.round(bb['first']['point_mm'], 2).tolist()}"
             f" mm, max depth {bb['max_depth_mm']:.3g} mm"),
            ("closest approach (base vs base)", f"{_f(bb['min_clearance_mm'])} mm"
             if bb["min_clearance_mm"] is not None else
             f"no non-neighbouring pair came within {bb['reach_mm']:.1f} mm (centres)")]
    mb = co.get("membrane_base")
    if mb:
        rows.append(("membrane vs far base",
                     "none" if not mb["count"] else
                     f"{mb['count']} vertex/base pairs, first vertex {mb['first']['pair'][0]} "
                     f"in base {mb['first']['pair'][1]} at t = {mb['first']['time_s']:g} s"))
    else:
        rows.append(("membrane vs far base", "not checked (no membrane in frames.npz)"))
    parts.append("<section id='collisions'><h2>Collisions along the path</h2>"
                 f"<p>Bases are solid cylinders of radius {UNIT_CELL.base_r:g} mm and height "
                 f"{2 * UNIT_CELL.layer_h:g} mm centred on the membrane; bases sharing a unit "
                 "cell are not checked (their bumpers touch by design). A collision is a "
                 f"penetration deeper than {th['collision_depth_mm']} mm.</p>" + _table(rows)
                 + _figs(_img(tmp, fl["clearance"], "smallest clearance between parts per "
                                                    "frame"),
                         *([_img(tmp, fl["collision_frame"], "first collision: the colliding "
                                                             "bases in red, and a close-up")]
                           if "collision_frame" in fl else []))
                 + "</section>")
    # solver
    if so["recorded"]:
        srows = [("steps", so["n_steps"]),
                 ("Newton iterations", f"total {so['iterations_total']}, mean "
                                       f"{_f(so['iterations_mean'])}, max {so['iterations_max']}"),
                 ("largest residual", f"{_f(so['residual_max'])} N"),
                 ("wall time", f"total {_f(so['wall_total_s'])} s, mean "
                               f"{_f(so['wall_mean_s'])} s, max {_f(so['wall_max_s'])} s"),
                 ("non-converged steps", f"{so['n_nonconverged']} "
                  + (f"(t = {', '.join(f'{x:g}' for x in so['nonconverged_times_s'][:20])} s)"
                     if so["n_nonconverged"] else "")),
                 ("limit", f"FAIL if a non-converged step ends above {th['residual_fail_N']} N,"
                           " else WARN")]
        body = _table(srows) + _figs(_img(tmp, fl["solver"], "Newton iterations, residual and "
                                                             "wall time per step"))
    else:
        body = "<p>The frames hold no solver statistics.</p>"
    parts.append(f"<section id='solver'><h2>Solver health</h2>{body}</section>")
    # renders (for print; the viewer above is interactive)
    figs = "".join(_img(tmp, n, f"t = {x:g} s" + (" (end)" if k == len(fl["renders"]) - 1
                                                   else ""))
                   for k, (n, x) in enumerate(zip(fl["renders"], r["render_frames"]["times_s"],
                                                  strict=True)))
    parts.append("<section id='renders'><h2>Shell at chosen times</h2><p>Top layer amber, "
                 "bottom layer blue, membrane grey; each frame aligned rigidly to the target "
                 "and framed on its own (nearest frames to "
                 f"{html.escape(str(list(r['render_frames']['times_s'])))} s).</p>"
                 + _figs(figs) + "</section>")
    parts.append("<section id='layout'><h2>Flat layout</h2>"
                 + _figs(_img(tmp, fl["layout"], "bracket thickness per unit cell, top and "
                                                 "bottom layer"), wide=True)
                 + "</section>")
    parts.append("<section id='landscape'><h2>Time landscape</h2>"
                 + _figs(_img(tmp, fl["landscape"], "programmed time landscape on the flat "
                                                    "stencil, and the simulated completion per "
                                                    "cell on the same colour scale"), wide=True)
                 + "</section>")
    parts.append(_fabrication_html(r, tmp))
    parts.append(_stls_html(r))
    parts.append(_provenance_html(r))
    parts.append("</body></html>\n")
    return "\n".join(parts)


def _fabrication_html(r, tmp) -> str:
    fab = r.get("fabrication") or {}
    steps = "".join(f"<li><b>{html.escape(s['title'])}.</b> {html.escape(s['text'])}</li>"
                    for s in fab.get("steps", []))
    rows = []
    for g in fab.get("timeline", []):
        lo, hi = g["t_star_s"]
        sim = ("never" if g["sim_range_s"] is None else
               f"{g['sim_range_s'][0]:.0f}-{g['sim_range_s'][1]:.0f} s "
               f"(median {g['sim_median_s']:.0f} s)")
        rows.append((f"{lo:.0f}-{hi:.0f} s", g["cells"], sim, g["never"], g["clamped"],
                     "({:.0f}, {:.0f}, {:.0f})".format(*g["where_mm"])))
    tl = _table(rows, head=("programmed t*", "cells", "simulated completion", "never",
                            "clamped", "where: centre of the group in the target (x, y, z) mm"))
    tpl = fab.get("template")
    tpl_html = ""
    if tpl and "stretch_template" in r["files"]:
        tpl_html = ("<p>Membrane stretch template <code>stretch_template.svg</code> and "
                    "<code>stretch_template.pdf</code> (beside this page; print at 100 %): "
                    f"{tpl['device_d_mm']:.0f} mm star device, "
                    f"markers at radius {tpl['marker_radius_mm']:.1f} mm on the unstretched "
                    f"sheet, which stretched {tpl['tau']:g}x land on the teeth.</p>"
                    + _figs(_img(tmp, r["files"]["stretch_template"],
                                 "the template (reduced here; the file is 1:1)")))
    return ("<section id='fabrication'><h2>Fabrication sheet</h2><p>Following the paper's "
            "procedure (Supplementary Note 5). The whole procedure after printing and before "
            "drying takes 30-50 minutes.</p>"
            f"<ol class='steps'>{steps}</ol><h3>Expected timeline in the bath, per region</h3>"
            "<p>Unit cells grouped by programmed time (equal counts); where each group sits "
            "and when the simulation completes it.</p>" + tl + tpl_html + "</section>")


def _stls_html(r) -> str:
    stls = r.get("stls") or []
    if not stls:
        body = "<p>No STL in this build (rendering skipped: <code>--no-render</code>).</p>"
    else:
        body = _table([(s["name"], _fmt_bytes(s["bytes"]), s["triangles"],
                        " x ".join(f"{v:g}" for v in s["size_mm"]), s["purpose"])
                       for s in stls],
                      head=("file", "size", "triangles", "extent (mm)", "what it is for"))
    return ("<section id='stls'><h2>Printable files</h2><p>In the build folder's "
            "<code>stl/</code>, in the print frame (bed at z = 0).</p>" + body + "</section>")


def _provenance_html(r) -> str:
    p = r.get("provenance") or {}
    inp = p.get("input") or {}
    rows = [("input", f"{inp.get('source')} ({inp.get('kind')})"),
            ("input sha256", inp.get("sha256")),
            ("build inputs sha256", p.get("build_inputs_sha256")),
            ("time landscape", p.get("landscape")),
            ("stencil", p.get("stencil")),
            ("refinement rounds", p.get("refine_rounds"))]
    for k, v in (p.get("models") or {}).items():
        rows.append((k, f"{v.get('path')} (sha256 {v.get('sha256')})"
                        + (f", correction {v['correction']}" if v.get("correction") else "")))
    for k, v in sorted((p.get("options") or {}).items()):
        rows.append((f"option {k}", json.dumps(v) if not isinstance(v, str) else v))
    if p.get("unit_cell_params"):
        rows.append(("unit-cell parameters", json.dumps(p["unit_cell_params"])))
    for k, v in (p.get("simulation") or {}).items():
        rows.append((f"simulation {k}", v))
    rows.append(("versions", ", ".join(f"{k} {v}" for k, v in (p.get("versions") or {}).items())))
    rows.append(("report date", p.get("date_utc")))
    return ("<section id='provenance'><h2>Provenance</h2>" + _table(rows) + "</section>")


def print_verdict(r, out_dir):
    """Print the verdict line, naming ``out_dir/index.html``, and its reasons and notes."""
    print(f"simulation check: {r['verdict']}  ({out_dir / 'index.html'})")
    for x in r["reasons"]:
        print(f"  {x['level']}: [{x['check']}] {x['message']}")
    for n in r["notes"]:
        print(f"  note: {n}")


def main(argv=None) -> int:

    ap = argparse.ArgumentParser(prog="python -m sim.report", description=__doc__.split("\n")[0])
    ap.add_argument("design_dir")
    ap.add_argument("--out", default=None)
    ap.add_argument("--quiet", action="store_true")
    ap.add_argument("--renderer", default="auto", choices=("auto", "pyvista", "matplotlib"))
    a = ap.parse_args(argv)
    r = make_report(a.design_dir, out_dir=a.out, progress=not a.quiet, renderer=a.renderer)
    print_verdict(r, Path(a.out) if a.out else Path(a.design_dir) / "report")
    return 3 if r["verdict"] == "FAIL" else 0


__all__ = ["Thresholds", "SECTIONS", "SimData", "load_frames", "load_sim", "completion_times",
           "shape_metrics", "fold_metrics", "shape_rms_over_time", "timing_metrics",
           "solver_metrics", "decide", "make_report", "print_verdict", "base_base_collisions"]

if __name__ == "__main__":
    sys.exit(main())
