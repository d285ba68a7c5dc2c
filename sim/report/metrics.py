"""The measurements of the simulation check: shape, folds, timing, collisions, solver.

Each function measures one aspect of a simulated morph from frame arrays and the design's
arrays; :func:`sim.report.verdict.check_morph` composes them and judges the result.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from scipy import stats

from pysolver.geometry import fold_angles_deg, rigid_fit
from pysolver.params import ReportThresholds

from ..model.collisions import (
    base_collisions,
    completion_times,
    membrane_collisions,
    never_due,
)

COMPLETION_RULE = "sim.model.collisions.completion_times"
"""Where the completion rule of the timing check lives (named in the report)."""


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


def fold_metrics(C, R, cell_pairs, target_fold_deg, th: ReportThresholds):
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


def timing_metrics(t, collided, t_star, th: ReportThresholds, bracket_length=None,
                   collision_length=None, clamped=None):
    """Simulated completion of every unit cell vs its programmed t*.

    The headline error (``rms_s``, ``spearman``, ``bias_s``) is over the cells whose t*
    the temporal stage could program (``clamped`` = 0): a clamped cell was already
    reported infeasible there, and its error says nothing about the simulation.  The
    same figures over every cell are ``*_all``.

    Parameters
    ----------
    t : (f,) float, s -- frame times
    collided : (f, c, 4) bool
    t_star : (c,) float, s -- programmed times
    th : ReportThresholds
    bracket_length : (f, c, 4) float, mm, optional
    collision_length : (c, 4) float, mm, optional
    clamped : (c,) bool, optional -- cells the temporal stage could not program

    Returns
    -------
    dict
        Counts, errors and ``t_done`` (c,) float, s (NaN = never), :func:`completion_times`.
    """
    t_done = completion_times(t, collided, bracket_length=bracket_length,
                              collision_length=collision_length)
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
        "source": COMPLETION_RULE, "t_end_s": t_end, "n_cells": int(len(t_star)),
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


def collision_results(C, R, M, t, pairs, unit, th: ReportThresholds, *, flat_vertices=None,
                      flat_centers=None):
    """Parts passing through each other along the morph.

    Parameters
    ----------
    C : (f, m, 3) float, mm -- base centres
    R : (f, m, 3, 3) float -- base rotations
    M : (f, k, 3) float, mm, or None -- membrane vertices (None or k = 0: not checked)
    t : (f,) float, s
    pairs : (c, 2) int -- the bases of every unit cell (neighbours are not checked)
    unit : UnitCell
        The design's own unit cell: a membrane vertex is far from a base beyond
        ``unit.base_r + unit.max_cell_length`` in the flat layout.
    th : ReportThresholds
    flat_vertices, flat_centers : optional
        Flat membrane vertices and base centres of the frames (``frames.npz``).

    Returns
    -------
    base_base : sim.model.collisions.CollisionResult
    membrane_base : CollisionResult or None
    """
    bc = base_collisions(C, R, pairs, t=t, tol=th.collision_depth_mm)
    mc = None
    if M is not None and np.asarray(M).shape[1]:
        mc = membrane_collisions(C, R, M, t=t, tol=th.collision_depth_mm,
                                 local_radius=unit.base_r + unit.max_cell_length,
                                 flat_vertices=flat_vertices, flat_centers=flat_centers)
    return bc, mc


def solver_metrics(fr, th: ReportThresholds):
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


__all__ = ["COMPLETION_RULE", "shape_metrics", "fold_metrics", "shape_rms_over_time",
           "timing_metrics", "collision_results", "solver_metrics"]
