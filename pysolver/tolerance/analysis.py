"""Will the printed shell still morph right?  Monte Carlo tolerance analysis of a design.

A printed shell differs from its design.  Each Monte Carlo **sample** is the nominal design
(its ``cells.csv`` thicknesses, the simulator constants of :data:`pysolver.params.SIM`, the
bracket model) with these factors drawn independently (defaults in
:class:`pysolver.params.Uncertainty`, seeds fixed):

``thickness``
    Every printed bracket (one draw per cell and layer) is ``h + N(0, thickness_sd)`` mm
    (default 0.02 mm; floored at 0.05 mm).  Note: the bracket model *clamps* thicknesses
    to its grid (0.30-0.65 mm), so a bracket programmed at 0.30 mm that prints thinner is
    simulated as 0.30 mm (no measurement supports thinner ones).
``stretch``
    The membrane pre-stretch ``tau ~ N(stretch_mean, stretch_sd)`` (default 3 +- 0.1).
``modulus``
    The membrane shear modulus ``mu * (1 + N(0, modulus_rel_sd))`` (default +-10 %).
``material``
    The bracket material model within its fit residuals.  The wet tests of the fit
    (``data/material-measurements``) are compared curve by curve with the fitted model:
    each curve's measured compressions are ``r`` times the model's (least squares over the
    curve).  The spread of ``ln r`` over the 80 curves is the specimen-to-specimen scatter
    the fit could not explain; its robust standard deviation (1.4826 x the median absolute
    deviation) is ``material_sd`` (:func:`material_scatter`).  A sample draws one
    compliance factor ``s = exp(N(0, material_sd))`` for the whole print (one filament, one
    printer, one bath) and simulates brackets with ``F_s(x) = F(x / s)``, i.e. force
    coefficients ``c_k / s^k`` (:class:`CompliantBracketModel`): a bracket that creeps
    ``s`` times as far under the same load.  The median is kept at the fit (the median
    bias of the fit is a model error, not scatter).
``relaxation`` (optional, ``--relaxation``)
    Membrane stress relaxation (SI Fig. 10, ``rubber_stress_relaxation.csv``): a
    dog-bone at stretch 3 loses force over hours.  A sample draws the waiting time between
    stretching and the bath log-uniformly in ``relaxation_window_s`` (10 min .. 24 h) and
    scales the membrane modulus by ``g(wait)``, the project's one relaxation model
    (:func:`pysolver.material.relaxation.relaxation_factor`, the Prony fit of the measured
    curve that the simulator's ``--physics relaxation`` also uses): here a scalar pre-stress
    factor per sample, independent of the simulator's option.

Everything a simulation needs travels with its task (:class:`DesignPayload`: the design
folder's files as bytes, the material file as bytes, a :class:`Perturbation`), so any Dask
worker can run it (:mod:`pysolver.distributed`).  The worker rebuilds the nominal
:class:`~pysolver.mechanics.ShellModel` once per design and applies a perturbation with
:func:`pysolver.mechanics.vary_model`, and asks the orchestrator to simulate it and check the
result with the report's one check (:func:`pysolver.simulator.simulate_and_check`,
:func:`sim.report.verdict.check_morph`: the same metrics and verdict, the design's own unit
cell included).

Outputs in ``<design>/tolerance/`` (``summary.json``, ``report.html``, pictures and
``samples/*.json``, one result per task, written atomically so a rerun only computes what
is missing):

* per cell: probability of completing within ``time_tol_s`` of t*, completion-time spread
  (a cell that does not complete within the simulated time counts as completing at ``t_end``
  in the spread -- right-censored, so the spread is a lower bound -- and is never on time);
* per base: spread of the final (rigidly aligned) position;
* P(PASS) and P(not FAIL) of the simulation check, with 95 % Wilson intervals;
* sensitivity: one-at-a-time runs (each factor alone, the same draws as the first samples,
  the others nominal); each factor's share of the summed one-at-a-time variance of the
  completion times and of the final positions names the factor that drives the spread.  As a
  cross-check from the samples themselves, :func:`regression_sensitivity` gives each
  factor's first-order ``R^2`` (Sobol-style, linear) on the mean completion time and the
  shape error.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pysolver import distributed
from pysolver.core.ownership import claim_result_folder
from pysolver.core.progress import say
from pysolver.core.records import finite, json_text
from pysolver.core.writes import atomic_write_text
from pysolver.errors import InputError, MorphshellError, refuse_first
from pysolver.material.measurements import SPECIMEN_BRACKETS, load_measurements, wet_eval_rows
from pysolver.material.model import CompliantBracketModel, load_bracket_model
from pysolver.material.relaxation import relaxation_factor
from pysolver.mechanics import load_model, vary_model
from pysolver.params import (
    BRACKET_MODEL_FILE,
    COUPON,
    SIM,
    TOLERANCE_RUN,
    UNCERTAINTY,
    Uncertainty,
)
from pysolver.simulator import check_sim_span, simulate_and_check
from pysolver.tables import MODEL_FILE, read_design, read_table

from . import coupon as cp
from .report import write_report

FACTORS = ("thickness", "stretch", "modulus", "material", "relaxation")
DESIGN_FILES = ("stencil.obj", "bases.csv", "cells.csv", "bumpers.csv", "time_landscape.csv",
                "support_frame.csv", "design.json", MODEL_FILE)
SUMMARY_FORMAT = "morphshell.tolerance"


# ------------------------------------------------------------------------------------------
# the perturbed material


def material_scatter(material=None, data_dir=None) -> dict:
    """Specimen-to-specimen scatter of the wet creep tests around the bracket model.

    For each wet test curve, ``r`` = least-squares factor between the measured and the
    modelled compressions (model inverted at the measured load and time); returns the
    robust standard deviation of ``ln r``.

    Parameters
    ----------
    material : BracketModel or path-like, optional
        Default: the committed model.
    data_dir : path-like, optional
        Measurement folder (default ``data/material-measurements``).

    Returns
    -------
    dict
        ``sd_log`` (float), ``median_log`` (float), ``n_curves`` (int), ``method`` (str).
    """
    mod = material if hasattr(material, "compression_for_force") else load_bracket_model(
        material)
    meas = load_measurements(data_dir)
    obs = wet_eval_rows(meas.wet, float(mod.grid_max[2]))
    x = mod.compression_for_force(obs.h, obs.b, obs.t * 60.0, obs.F / SPECIMEN_BRACKETS)
    logs = []
    for k in np.unique(obs.series):
        m = (obs.series == k) & np.isfinite(x)
        den = float(np.sum(x[m] ** 2))
        if m.sum() >= 3 and den > 0:
            r = float(np.sum(x[m] * obs.x[m]) / den)
            if r > 0:
                logs.append(math.log(r))
    if len(logs) < 3:
        raise InputError("too few wet test curves to estimate the material scatter",
                         fix="pass --material-sd explicitly")
    logs = np.array(logs)
    med = float(np.median(logs))
    sd = TOLERANCE_RUN.material_robust_k * float(np.median(np.abs(logs - med)))
    return {"sd_log": sd, "median_log": med, "n_curves": int(len(logs)),
            "method": "per wet curve: ln of the least-squares ratio measured/model "
                      "compression; 1.4826 x MAD"}


# ------------------------------------------------------------------------------------------
# data that travel with a task


@dataclass(frozen=True)
class DesignPayload:
    """A design folder's input files, as bytes (a worker needs no shared file system).

    Attributes
    ----------
    files : tuple of (str, bytes)
    material : bytes
        The bracket model JSON.
    sha : str
        SHA-256 of everything above.
    """

    files: tuple
    material: bytes
    sha: str

    def to_dict(self) -> dict:
        return {"sha": self.sha}


def read_payload(design_dir, material=None) -> DesignPayload:
    """Read a design folder (and the material file) into a :class:`DesignPayload`."""
    folder = Path(design_dir)
    files = []
    for name in DESIGN_FILES:
        p = folder / name
        if p.is_file():
            files.append((name, p.read_bytes()))
        elif name in ("stencil.obj", "bases.csv", "cells.csv", MODEL_FILE):
            raise InputError(f"{folder}: no {name}", fix="give a programmed design folder "
                             "(morphshell build NAME --no-render, or make sim shape=NAME)")
    mpath = Path(material) if material is not None else BRACKET_MODEL_FILE
    try:
        mbytes = mpath.read_bytes()
    except OSError as e:
        raise InputError(f"material file {mpath}: {e.strerror}",
                         fix="give an existing bracket model JSON (--material)") from None
    h = hashlib.sha256()
    for name, b in files:
        h.update(name.encode() + b"\0" + hashlib.sha256(b).digest())
    h.update(b"material\0" + hashlib.sha256(mbytes).digest())
    return DesignPayload(tuple(files), mbytes, h.hexdigest())


@dataclass(frozen=True)
class Perturbation:
    """One sample's deviations from the design (all plain numbers: it travels with a task).

    Attributes
    ----------
    name : str
    thickness_delta : tuple of (float, float), mm
        Added to the programmed (top, bottom) bracket thickness of each cell.
    tau : float
        Pre-stretch factor.
    modulus_factor, relaxation_factor : float
        Multiply the membrane shear modulus mu.
    compliance : float
        Bracket compliance factor ``s`` (:class:`CompliantBracketModel`).
    """

    name: str
    thickness_delta: tuple
    tau: float
    modulus_factor: float
    relaxation_factor: float
    compliance: float

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def _draw(seed: int, i: int, n_cells: int, unc: Uncertainty, sd_mat: float):
    """All factor draws of sample ``i`` (the same stream whatever is switched off)."""
    rng = np.random.default_rng([int(seed), int(i)])
    z_th = rng.standard_normal((n_cells, 2))
    z_tau, z_mu, z_mat = rng.standard_normal(3)
    u = rng.random()
    lo, hi = unc.relaxation_window_s
    wait = math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo)))
    relax = float(relaxation_factor(wait)) if unc.relaxation else 1.0
    return {"thickness": unc.thickness_sd * z_th,
            "stretch": unc.stretch_mean + unc.stretch_sd * z_tau,
            "modulus": max(1.0 + unc.modulus_rel_sd * z_mu, TOLERANCE_RUN.modulus_floor),
            "material": math.exp(sd_mat * z_mat),
            "relaxation": relax}


def make_perturbation(name: str, draw: dict, n_cells: int, only: str | None = None,
                      unc: Uncertainty = UNCERTAINTY) -> Perturbation:
    """A :class:`Perturbation` from draws; ``only`` keeps one factor, the others nominal."""
    def use(f):
        return only is None or only == f

    th = draw["thickness"] if use("thickness") else np.zeros((n_cells, 2))
    return Perturbation(
        name=name, thickness_delta=tuple(map(tuple, np.asarray(th, float).tolist())),
        tau=float(draw["stretch"]) if use("stretch") else float(unc.stretch_mean),
        modulus_factor=float(draw["modulus"]) if use("modulus") else 1.0,
        relaxation_factor=float(draw["relaxation"]) if use("relaxation") else 1.0,
        compliance=float(draw["material"]) if use("material") else 1.0)


def nominal_perturbation(n_cells: int, unc: Uncertainty = UNCERTAINTY) -> Perturbation:
    return Perturbation("nominal", tuple((0.0, 0.0) for _ in range(n_cells)),
                        float(unc.stretch_mean), 1.0, 1.0, 1.0)


# ------------------------------------------------------------------------------------------
# the worker side


_CONTEXTS: dict = {}


def _context(payload: DesignPayload) -> dict:
    """Nominal model, check data and material of a payload, built once per worker process."""
    ctx = _CONTEXTS.get(payload.sha)
    if ctx is not None:
        return ctx

    with tempfile.TemporaryDirectory(prefix="morphshell-tol-") as tmp:
        d = Path(tmp)
        for name, b in payload.files:
            (d / name).write_bytes(b)
        (d / "material.json").write_bytes(payload.material)
        model = load_model(d)
        des = read_design(d)
        material = load_bracket_model(d / "material.json")
    ctx = {"model": model, "material": material, "design": des}
    if len(_CONTEXTS) >= 4:
        _CONTEXTS.pop(next(iter(_CONTEXTS)))
    _CONTEXTS[payload.sha] = ctx
    return ctx


def run_sample(payload: DesignPayload, pert: Perturbation, settings: dict) -> dict:
    """Simulate and check one perturbed shell (the Dask task).

    Parameters
    ----------
    payload : DesignPayload
    pert : Perturbation
    settings : dict
        ``t_end`` (s), ``dt`` (s), ``thresholds`` (dict or None).

    Returns
    -------
    dict
        The figures of the check (:meth:`sim.report.Check.figures`), plus ``diverged`` (bool),
        ``message``, ``steps`` and ``wall_s`` (the only non-reproducible field).
    """
    t0 = time.perf_counter()
    ctx = _context(payload)
    model = ctx["model"]
    th = np.maximum(model.cell_thickness + np.asarray(pert.thickness_delta, float),
                    TOLERANCE_RUN.thickness_floor_mm)
    consts = dataclasses.replace(model.consts, tau=pert.tau,
                                 mu=model.consts.mu * pert.modulus_factor
                                 * pert.relaxation_factor)
    varied = vary_model(model, thickness=th, consts=consts)
    material = (ctx["material"] if pert.compliance == 1.0
                else CompliantBracketModel(ctx["material"], pert.compliance))
    diverged, message = False, ""
    try:
        frames, check = simulate_and_check(varied, material, ctx["design"],
                                           t_end=settings["t_end"], dt=settings["dt"],
                                           thresholds=settings.get("thresholds"))
    except (MorphshellError, ArithmeticError) as e:  # a diverged sample is a result: it fails
        # the check (ArithmeticError: the solver's kernels divided by zero on a collapsed state)
        diverged, message = True, f"{type(e).__name__}: {e}" if isinstance(
            e, ArithmeticError) else str(e)
        frames = check = None
    if check is None:
        n_c, n_b = model.n_cells, model.n_bases
        out = {"verdict": "FAIL", "reasons": [f"FAIL solver: {message}"],
               "t_done": [None] * n_c, "base_final": [[None] * 3] * n_b,
               "shape_rms_pct": None, "shape_rms_mm": None, "shape_max_mm": None,
               "normal_rms_deg": None, "fold_rms_deg": None, "timing_rms_s": None,
               "timing_bias_s": None, "timing_max_abs_s": None, "n_never_due": n_c,
               "n_completed": 0, "longest_cell_s": None}
        steps = 0
    else:
        out = check.figures()
        steps = int(len(frames["t"]))
    dth = np.asarray(pert.thickness_delta, float)
    out.update({"name": pert.name, "diverged": diverged, "message": message, "steps": steps,
                "perturbation": {"tau": pert.tau, "modulus_factor": pert.modulus_factor,
                                 "relaxation_factor": pert.relaxation_factor,
                                 "compliance": pert.compliance,
                                 "thickness_delta_mean_mm": float(dth.mean()),
                                 "thickness_delta_sd_mm": float(dth.std())},
                "wall_s": round(time.perf_counter() - t0, 3)})
    return out


# ------------------------------------------------------------------------------------------
# the caller side


def _check_options(samples, sensitivity, unc: Uncertainty, time_tol_s, seed=0):
    if not isinstance(samples, int) or isinstance(samples, bool) or not (
            1 <= samples <= TOLERANCE_RUN.max_samples):
        raise InputError(f"--samples {samples!r}",
                         fix=f"use a whole number from 1 to {TOLERANCE_RUN.max_samples}")
    if not isinstance(sensitivity, int) or not 0 <= sensitivity <= samples:
        raise InputError(f"--sensitivity {sensitivity!r}",
                         fix=f"use a whole number from 0 to --samples ({samples})")
    for name in ("thickness_sd", "stretch_sd", "modulus_rel_sd"):
        v = getattr(unc, name)
        if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
            raise InputError(f"{name} = {v!r}", fix="use a finite number >= 0")
    if unc.material_sd is not None and not (math.isfinite(unc.material_sd)
                                            and unc.material_sd >= 0):
        raise InputError(f"material_sd = {unc.material_sd!r}", fix="use a number >= 0")
    if not (math.isfinite(unc.stretch_mean) and unc.stretch_mean > 1.0):
        raise InputError(f"pre-stretch mean {unc.stretch_mean!r}", fix="use a number > 1")
    sd_max = Uncertainty.MAX_STRETCH_SD_FRACTION * (unc.stretch_mean - 1.0)
    if unc.stretch_sd > sd_max:
        raise InputError(f"pre-stretch sd {unc.stretch_sd} is too large for a mean of "
                         f"{unc.stretch_mean}", fix="the stretch must stay well above 1: "
                         f"use sd <= {sd_max:g}")
    m = Uncertainty.MAX_MODULUS_REL_SD
    if unc.modulus_rel_sd > m:
        raise InputError(f"modulus sd {unc.modulus_rel_sd:g} (relative)",
                         fix=f"use at most {m:g} ({100 * m:g} %); e.g. 0.1 for +-10 %")
    lo, hi = unc.relaxation_window_s
    if not (0 <= lo < hi):
        raise InputError(f"relaxation window {unc.relaxation_window_s}",
                         fix="use 0 <= start < end seconds")
    if not (math.isfinite(time_tol_s) and time_tol_s > 0):
        raise InputError(f"--time-tol {time_tol_s!r}", fix="use a positive number of seconds")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
        raise InputError(f"--seed {seed!r}", fix="use a whole number >= 0")


def _claim(folder: Path) -> Path:
    """The tolerance folder: new, or morphshell's (every file in it recorded as written)."""
    return claim_result_folder(folder, what="tolerance folder")


def wilson(k: int, n: int, z: float = 1.959964) -> tuple:
    """95 % Wilson score interval of a proportion ``k / n``."""
    if n == 0:
        return (float("nan"), float("nan"))
    p = k / n
    den = 1 + z * z / n
    c = (p + z * z / (2 * n)) / den
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, c - h), min(1.0, c + h))


def _arr(results, key, shape_tail=()):
    return np.array([[np.nan if v is None else v for v in np.ravel(
        np.array(r[key], dtype=object))] for r in results], float).reshape(
        (len(results),) + shape_tail)


def _spread(results, n_cells, n_bases, t_end):
    """Completion-time and final-position variance of a set of results.

    A cell that does not complete within the simulated time counts as completing at
    ``t_end`` for the variance (right-censored: the spread is then a lower bound).
    """
    T = _arr(results, "t_done", (n_cells,))
    P = _arr(results, "base_final", (n_bases, 3))
    # variances about a finite sample first (shift-invariant): identical samples give
    # exactly 0, not round-off of the mean
    ok = np.flatnonzero(np.isfinite(P).all(axis=(1, 2)))
    Q = P - P[ok[0]] if len(ok) else P
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # cells no sample completes
        Tc = np.where(np.isfinite(T), T, t_end)
        var_t = np.var(Tc, axis=0) if len(T) > 1 else np.zeros(n_cells)
        dev = Q - np.nanmean(Q, axis=0)
        var_p = np.nanmean(np.sum(dev ** 2, axis=2), axis=0)
    return T, P, np.nan_to_num(var_t), np.nan_to_num(var_p)


def aggregate(results: list, nominal: dict, t_star, time_tol_s: float, oat: dict,
              n_cells: int, n_bases: int, t_end: float) -> dict:
    """Per-cell, per-base and whole-shell figures of the samples (see module docstring)."""
    S = len(results)
    T, P, var_t, var_p = _spread(results, n_cells, n_bases, t_end)
    t_star = np.asarray(t_star, float)

    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # cells no sample completes
        on_time = cp.on_time(T, t_star, time_tol_s)
        done = np.isfinite(T)
        q = (np.nanpercentile(T, [5, 50, 95], axis=0) if done.any()
             else np.full((3, n_cells), np.nan))
    t_nom = np.array([np.nan if v is None else v for v in nominal["t_done"]], float)
    cells = [{"cell_id": j, "t_star_s": float(t_star[j]),
              "t_nominal_s": None if not np.isfinite(t_nom[j]) else float(t_nom[j]),
              "p_on_time": float(on_time[:, j].mean()), "p_complete": float(done[:, j].mean()),
              "t_sd_s": float(math.sqrt(var_t[j])),
              "t_p05_s": _num(q[0, j]), "t_median_s": _num(q[1, j]), "t_p95_s": _num(q[2, j])}
             for j in range(n_cells)]
    nom_p = np.array(nominal["base_final"], dtype=float)
    with np.errstate(invalid="ignore"):
        dmax = np.nanmax(np.linalg.norm(P - nom_p, axis=2), axis=0) if S else np.zeros(n_bases)
    bases = [{"base_id": i, "position_sd_mm": float(math.sqrt(var_p[i])),
              "max_from_nominal_mm": _num(dmax[i])} for i in range(n_bases)]
    verdicts = [r["verdict"] for r in results]
    n_pass = verdicts.count("PASS")
    n_ok = n_pass + verdicts.count("WARN")
    checks = {}
    for r in results:
        for msg in r["reasons"]:
            key = msg.split(":", 1)[0]
            checks[key] = checks.get(key, 0) + 1
    figures = {
        "samples": S, "p_pass": n_pass / S if S else float("nan"),
        "p_pass_ci95": list(wilson(n_pass, S)),
        "p_not_fail": n_ok / S if S else float("nan"), "p_not_fail_ci95": list(wilson(n_ok, S)),
        "verdicts": {v: verdicts.count(v) for v in ("PASS", "WARN", "FAIL")},
        "reasons": dict(sorted(checks.items())),
        "diverged": int(sum(bool(r["diverged"]) for r in results)),
        "diverged_samples": [{"name": r.get("name"), "message": r["message"][:300],
                              "perturbation": r.get("perturbation")}
                             for r in results if r["diverged"]][:20],
        "p_all_cells_on_time": float(on_time.all(axis=1).mean()) if S else float("nan"),
        "p_on_time_cell_min": float(on_time.mean(axis=0).min()) if S else float("nan"),
        "p_on_time_cell_mean": float(on_time.mean()) if S else float("nan"),
        "completion_sd_s_mean": float(np.sqrt(var_t).mean()),
        "completion_sd_s_max": float(np.sqrt(var_t).max()),
        "position_sd_mm_mean": float(np.sqrt(var_p).mean()),
        "position_sd_mm_max": float(np.sqrt(var_p).max()),
        "longest_cell_s": _stats([r["longest_cell_s"] for r in results]),
        "shape_rms_pct": _stats([r["shape_rms_pct"] for r in results]),
        "timing_rms_s": _stats([r["timing_rms_s"] for r in results]),
        "nominal_verdict": nominal["verdict"],
    }
    sens = sensitivity_table(oat, n_cells, n_bases, t_end)
    if sens:
        figures["most_influential"] = sens[0]["factor"]
    return {"figures": figures, "cells": cells, "bases": bases, "sensitivity": sens}


def _num(v):
    return None if v is None or not np.isfinite(v) else float(v)


def _stats(vals):
    a = np.array([np.nan if v is None else v for v in vals], float)
    a = a[np.isfinite(a)]
    if not a.size:
        return {"mean": None, "sd": None, "p05": None, "p95": None}
    return {"mean": float(a.mean()), "sd": float(a.std()),
            "p05": float(np.percentile(a, 5)), "p95": float(np.percentile(a, 95))}


def sensitivity_table(oat: dict, n_cells: int, n_bases: int, t_end: float) -> list:
    """One-at-a-time sensitivity: each factor's share of the summed variances.

    Parameters
    ----------
    oat : dict of str -> list of result dicts
        Runs with only that factor perturbed.

    Returns
    -------
    list of dict, most influential first
        ``factor``, ``runs``, ``completion_var_s2`` (mean over cells), ``position_var_mm2``
        (mean over bases), ``timing_share``, ``position_share``, ``p_pass``.
    """
    rows = []
    for f, res in oat.items():
        if not res:
            continue
        _, _, vt, vp = _spread(res, n_cells, n_bases, t_end)
        rows.append({"factor": f, "runs": len(res), "completion_var_s2": float(vt.mean()),
                     "position_var_mm2": float(vp.mean()),
                     "p_pass": sum(r["verdict"] == "PASS" for r in res) / len(res)})
    st = sum(r["completion_var_s2"] for r in rows)
    sp = sum(r["position_var_mm2"] for r in rows)
    for r in rows:
        r["timing_share"] = r["completion_var_s2"] / st if st > 0 else 0.0
        r["position_share"] = r["position_var_mm2"] / sp if sp > 0 else 0.0
    rows.sort(key=lambda r: (-r["timing_share"], -r["position_share"], r["factor"]))
    return rows


def regression_sensitivity(perts: list, results: list, t_end: float) -> list:
    """Sobol-style first-order check from the Monte Carlo samples themselves (no extra runs).

    For each factor, the squared correlation ``R^2`` between its draw in a sample and the
    sample's mean completion time (over cells, censored at ``t_end``) and its shape RMS error:
    the fraction of the output variance a linear function of that factor alone explains (the
    first-order Sobol index of a linear model).  Thickness is summarised by the sample's mean
    thickness deviation, so only its shell-wide part is seen.

    Parameters
    ----------
    perts : list of Perturbation
        The samples' perturbations, in the order of ``results``.
    results : list of dict

    Returns
    -------
    list of dict
        ``factor``, ``r2_mean_completion``, ``r2_shape_rms``; factors that do not vary are
        left out.
    """
    if len(results) < 3:
        return []
    x = {"thickness": [float(np.mean(p.thickness_delta)) for p in perts],
         "stretch": [p.tau for p in perts], "modulus": [p.modulus_factor for p in perts],
         "material": [math.log(p.compliance) for p in perts],
         "relaxation": [p.relaxation_factor for p in perts]}
    T = np.array([[t_end if v is None else v for v in r["t_done"]] for r in results], float)
    ys = {"r2_mean_completion": T.mean(axis=1),
          "r2_shape_rms": np.array([np.nan if r["shape_rms_pct"] is None
                                    else r["shape_rms_pct"] for r in results], float)}
    rows = []
    for f, xv in x.items():
        xv = np.asarray(xv, float)
        if np.ptp(xv) == 0:
            continue
        row = {"factor": f}
        for k, y in ys.items():
            m = np.isfinite(y)
            ok = m.sum() >= 3 and np.ptp(y[m]) > 0
            row[k] = float(np.corrcoef(xv[m], y[m])[0, 1] ** 2) if ok else 0.0
        rows.append(row)
    rows.sort(key=lambda r: -r["r2_mean_completion"])
    return rows


def tolerance_analysis(design_dir, *, samples: int = TOLERANCE_RUN.samples,
                       uncertainty: Uncertainty = UNCERTAINTY, seed: int = TOLERANCE_RUN.seed,
                       time_tol_s: float = TOLERANCE_RUN.time_tol_s,
                       sensitivity: int | None = None, t_end: float = SIM.t_end,
                       dt: float = SIM.dt, material=None, out=None, scheduler=None,
                       workers=None, client=None, progress: bool = True, report: bool = True,
                       on_result=None, dashboard: bool = False, coupon: bool = False) -> dict:
    """Monte Carlo tolerance analysis of a programmed design folder.

    Parameters
    ----------
    design_dir : path-like
        Design folder with thicknesses (``cells.csv``).
    samples : int
        Monte Carlo samples.
    uncertainty : Uncertainty
        Standard deviations (``material_sd=None``: from the fit, :func:`material_scatter`).
    seed : int
        Sample ``i`` draws from ``numpy.random.default_rng([seed, i])``.
    time_tol_s : float, s
        On-time tolerance around t*.
    sensitivity : int, optional
        One-at-a-time runs per active factor (default ``min(8, samples)``; 0 = none).
    t_end, dt : float, s
        Simulated time and step.
    material : path-like, optional
        Bracket model file (default: the committed one).
    out : path-like, optional
        Output folder (default ``<design_dir>/tolerance``).
    scheduler, workers, client, dashboard
        Dask cluster (:func:`pysolver.distributed.dask_client`).
    progress, report : bool
        Progress lines; write ``report.html`` and pictures.
    on_result : callable, optional
        Passed to :func:`pysolver.distributed.run_tasks`.
    coupon : bool
        Also simulate the coupon workflow (:mod:`pysolver.tolerance.coupon`): one more
        simulation per sample, ``coupon-NNNNN``.

    Returns
    -------
    dict
        The content of ``summary.json`` (``figures``, ``cells``, ``bases``,
        ``sensitivity``, ``options``, ``run``).

    Examples
    --------
    Two samples of the ``folder`` programmed in :func:`pysolver.temporal.program_design`'s
    example, 5 s each, on a Dask client in this process:

    >>> from distributed import Client
    >>> from pysolver.tolerance import tolerance_analysis
    >>> with Client(processes=False, n_workers=1, threads_per_worker=1,
    ...             dashboard_address=":0") as client:
    ...     s = tolerance_analysis(folder, samples=2, sensitivity=0, t_end=5.0,
    ...                            client=client, report=False, progress=False)
    >>> s["figures"]["samples"], 0.0 <= s["figures"]["p_pass"] <= 1.0
    (2, True)
    """
    scheduler, workers = distributed.check_scheduler(scheduler), distributed.check_workers(workers)
    if sensitivity is None:
        sensitivity = min(TOLERANCE_RUN.sensitivity_samples, samples)
    _check_options(samples, sensitivity, uncertainty, time_tol_s, seed)
    check_sim_span(t_end, dt)  # a bad t_end/dt is refused now
    if material is not None:  # a bad model file is refused here, not on every worker
        material = load_bracket_model(material).path
    folder = Path(design_dir).absolute()
    payload = read_payload(folder, material)
    cells, n_bases = _programmed_cells(folder)
    n_cells = len(cells["cell_id"])
    out = _claim(Path(out) if out is not None else folder / "tolerance")
    t_start = time.perf_counter()
    unc, mat_info = _uncertainty(uncertainty, material)
    perts, active = _perturbations(seed, samples, sensitivity, unc, n_cells)
    coupon_info = None
    if coupon:
        extra, coupon_info = _coupon_perturbations(seed, samples, unc, folder, material, cells)
        perts += extra
    settings = {"t_end": float(t_end), "dt": float(dt), "thresholds": None}
    results, stats = _simulate_all(payload, perts, settings, out, client=client,
                                   scheduler=scheduler, workers=workers, progress=progress,
                                   dashboard=dashboard, on_result=on_result)
    summary = _summary(results, stats, perts, active, cells, n_bases, folder, payload,
                       options={"samples": samples, "seed": seed, "time_tol_s": time_tol_s,
                                "sensitivity_runs": sensitivity, "t_end_s": float(t_end),
                                "dt_s": float(dt), "uncertainty": dataclasses.asdict(unc),
                                "material_scatter": mat_info, "factors": active,
                                "material": None if material is None else str(material),
                                "coupon": coupon_info},
                       wall_s=round(time.perf_counter() - t_start, 3))
    atomic_write_text(out / "summary.json", json_text(summary, indent=1, strict=True))
    if report:
        write_report(out, summary, folder,
                     [results[p.name] for p in perts if p.name.startswith("sample-")],
                     results["nominal"])
    f = summary["figures"]
    say("tolerance", folder.name, f"P(PASS) = {f['p_pass']:.2f} (95 % CI "
        f"{f['p_pass_ci95'][0]:.2f}-{f['p_pass_ci95'][1]:.2f}), P(not FAIL) = "
        f"{f['p_not_fail']:.2f}, most influential: {f.get('most_influential', '-')} -> {out}",
        progress)
    return summary


def _summary(results: dict, stats, perts, active, cells, n_bases: int, folder: Path, payload,
             *, options: dict, wall_s: float) -> dict:
    """The content of ``summary.json`` (JSON-ready: non-finite numbers as None)."""
    t_end = options["t_end_s"]
    nominal = results["nominal"]
    main = [results[p.name] for p in perts if p.name.startswith("sample-")]
    oat = {f: [results[p.name] for p in perts if p.name.startswith(f"oat-{f}-")]
           for f in active}
    agg = aggregate(main, nominal, cells["t_star_s"], options["time_tol_s"], oat,
                    len(cells["cell_id"]), n_bases, float(t_end))
    agg["figures"].update(_maker_figures(results, perts, cells, agg, options))
    agg["figures"]["predicted_timing_sd"] = _predicted_sd(agg, folder, options, oat,
                                                          (n_bases, float(t_end)))
    agg["sensitivity_regression"] = regression_sensitivity(
        [p for p in perts if p.name.startswith("sample-")], main, float(t_end))
    return finite({
        "format": SUMMARY_FORMAT, "format_version": 1, "design": str(folder),
        "design_sha256": payload.sha, "options": options,
        "nominal": {k: nominal[k] for k in ("verdict", "shape_rms_pct", "timing_rms_s",
                                             "longest_cell_s", "reasons")},
        **agg,
        "run": dict(stats.to_dict(), wall_s=wall_s,
                    sample_wall_s=_stats([results[p.name]["wall_s"] for p in perts]))})


def _maker_figures(results: dict, perts, cells, agg: dict, options: dict) -> dict:
    """P(on time) with the coupon, P(order kept) and P(no collision on the way) with and
    without it, the per-print / per-bracket split of the timing variance and where a cell's
    timing error comes from (:mod:`pysolver.tolerance.coupon`)."""
    t_star = np.asarray(cells["t_star_s"], float)
    n, t_end = len(t_star), float(options["t_end_s"])
    pairs = cp.neighbour_pairs(cells, t_star, TOLERANCE_RUN.order_separation_s)

    def named(prefix):
        return [results[p.name] for p in perts if p.name.startswith(prefix)]

    def times(prefix):
        return _arr(named(prefix), "t_done", (n,))

    T, Tc, Tb = times("sample-"), times("coupon-"), times("oat-thickness-")
    out = {"p_order_kept": cp.order_kept(T, pairs), "order_pairs": int(len(pairs)),
           "timing_variance_share": _variance_share(agg, T, Tb, t_end),
           "p_no_collision": _with_ci(cp.collision_free(named("sample-"))),
           "p_no_collision_coupon": _with_ci(cp.collision_free(named("coupon-"))),
           "p_on_time_cell_mean_coupon": None, "p_order_kept_coupon": None,
           "timing_error_split": cp.error_split(
               {"nominal": times("nominal"), "thickness": Tb, "coupon": Tc, "samples": T},
               t_star, np.asarray(cells["clamped"], bool), options["time_tol_s"], t_end)}
    if len(Tc):
        on = cp.on_time(Tc, t_star, options["time_tol_s"])
        out.update(p_on_time_cell_mean_coupon=float(on.mean()),
                   p_all_cells_on_time_coupon=float(on.all(axis=1).mean()),
                   p_order_kept_coupon=cp.order_kept(Tc, pairs))
    return out


def _variance_share(agg: dict, T, Tb, t_end: float):
    """:func:`pysolver.tolerance.coupon.variance_share` from the samples' variance (mean over
    cells, censored at ``t_end``) and the one-at-a-time thickness runs'."""
    def mean_var(X):
        return float(np.var(np.where(np.isfinite(X), X, t_end), axis=0).mean())

    ok = len(T) >= 2 and len(Tb) >= 2
    return cp.variance_share(agg["sensitivity"], mean_var(T) if ok else None,
                             mean_var(Tb) if ok else None, len(Tb))


def _with_ci(free: dict | None):
    """:func:`pysolver.tolerance.coupon.collision_free` with its 95 % Wilson interval."""
    if free is not None:
        free["ci95"] = list(wilson(free["n_free"], free["n"]))
    return free


def _predicted_sd(agg: dict, folder: Path, options: dict, oat: dict, sizes: tuple) -> dict:
    """Each cell's completion-time sd under the per-bracket thickness scatter as the bracket
    model predicts it (:func:`pysolver.temporal.program.timing_sd`), written into
    ``agg["cells"]`` (``t_sd_predicted_s``); returns its mean and, with one-at-a-time
    thickness runs (``sizes``: bases, t_end s), their mean sd and the correlation over
    cells."""
    sd = cp.predicted_timing_sd(folder, load_bracket_model(options["material"]),
                                options["uncertainty"]["thickness_sd"])
    for row, v in zip(agg["cells"], sd, strict=True):
        row["t_sd_predicted_s"] = _num(v)
    out = {"mean_s": _num(np.nanmean(sd)) if np.isfinite(sd).any() else None,
           "oat_thickness_mean_s": None, "correlation": None}
    runs = oat.get("thickness") or []
    if len(runs) >= 2:
        _, _, var_t, _ = _spread(runs, len(sd), *sizes)
        mc = np.sqrt(var_t)
        ok = np.isfinite(sd)
        out["oat_thickness_mean_s"] = float(mc.mean())
        if ok.sum() >= 3 and np.ptp(sd[ok]) > 0 and np.ptp(mc[ok]) > 0:
            out["correlation"] = float(np.corrcoef(sd[ok], mc[ok])[0, 1])
    return out


def _coupon_perturbations(seed: int, samples: int, unc: Uncertainty, folder: Path, material,
                          cells):
    """One ``coupon-NNNNN`` perturbation per sample: the sample's print, its shell
    programmed again from the fit of its own coupon (:mod:`pysolver.tolerance.coupon`);
    returns (perturbations, record of the fits)."""
    mat = load_bracket_model(material)
    setup = cp.coupon_setup(mat)
    shell = cp.shell_geometry(folder)
    n = len(cells["cell_id"])
    h = np.c_[cells["thickness_top_mm"], cells["thickness_bottom_mm"]].astype(float)
    perts, fits = [], []
    for i in range(samples):
        d = _draw(seed, i, n, unc, unc.material_sd)
        rng = np.random.default_rng([int(seed), int(i), cp.COUPON_STREAM])
        fit = cp.coupon_fit(setup, mat, d, rng, unc.thickness_sd)
        h2 = h if fit is None else cp.reprogrammed_thickness(shell, h, mat, fit)
        perts.append(make_perturbation(f"coupon-{i:05d}",
                                       dict(d, thickness=d["thickness"] + (h2 - h)), n,
                                       unc=unc))
        fits.append(None if fit is None else {
            "compliance": fit["compliance"]["value"], "modulus": fit["modulus"]["value"],
            "drawn_compliance": d["material"], "drawn_modulus": d["modulus"] * d["relaxation"],
            "residual_rms_s": fit["residual_rms_s"]})
    return perts, {"cells": int(len(setup["b0"])), "reading_sd_s": COUPON.reading_sd_s,
                   "refused": sum(f is None for f in fits), "fits": fits}


def _simulate_all(payload, perts, settings: dict, out: Path, **run):
    """Every perturbed simulation as a Dask task (:func:`run_sample`), through the result
    store of ``out`` (a rerun computes only the missing ones).

    Raises
    ------
    MorphshellError
        Some tasks failed (the finished ones are kept).
    """
    code = distributed.code_fingerprint()
    tasks = [distributed.Task(p.name, run_sample, (payload, p, settings),
                              distributed.fingerprint(payload.sha, p, settings, code))
             for p in perts]
    store = distributed.ResultStore(out / "samples")
    results, stats = distributed.run_tasks(tasks, store, label="tolerance", **run)
    if stats.failed:
        raise MorphshellError(
            f"{len(stats.failed)} of {stats.total} simulations failed (first: "
            f"{next(iter(stats.failed.items()))}); the {len(results)} finished ones are kept "
            f"in {store.folder}", fix="re-run the same command: only the missing ones run")
    return results, stats


def _programmed_cells(folder: Path):
    """``cells.csv`` of a programmed design (every cell with a thickness and a t*; refused
    here, not by every worker) and the number of bases."""
    cells = read_table(folder, "cells")
    th = np.c_[cells["thickness_top_mm"], cells["thickness_bottom_mm"]].astype(float)
    ts = np.asarray(cells["t_star_s"], float)
    refuse_first(~(np.all(np.isfinite(th) & (th > 0), axis=1) & np.isfinite(ts)),
                 lambda i, _: f"{folder / 'cells.csv'}:{i + 2}: cell {i} has no programmed "
                              "thickness or t*",
                 fix="run the program stage first (morphshell build NAME --no-render, or "
                     "make sim shape=NAME)")
    return cells, len(read_table(folder, "bases")["base_id"])


def _uncertainty(unc: Uncertainty, material):
    """The uncertainty with the material scatter filled in (from the fit residuals when
    ``material_sd`` is None: :func:`material_scatter`, also returned; else None)."""
    mat_info = None
    sd_mat = unc.material_sd
    if sd_mat is None:
        mat_info = material_scatter(material)
        sd_mat = mat_info["sd_log"]
    return dataclasses.replace(unc, material_sd=float(sd_mat)), mat_info


def _perturbations(seed: int, samples: int, sensitivity: int, unc: Uncertainty,
                   n_cells: int):
    """The nominal run, the Monte Carlo samples and the one-at-a-time runs of every factor
    that varies; returns (perturbations, active factors)."""
    sd_mat = unc.material_sd
    draws = [_draw(seed, i, n_cells, unc, sd_mat) for i in range(samples)]
    active = [f for f, on in (("thickness", unc.thickness_sd > 0),
                              ("stretch", unc.stretch_sd > 0),
                              ("modulus", unc.modulus_rel_sd > 0),
                              ("material", sd_mat > 0), ("relaxation", unc.relaxation))
              if on]
    perts = [nominal_perturbation(n_cells, unc)]
    perts += [make_perturbation(f"sample-{i:05d}", d, n_cells, unc=unc)
              for i, d in enumerate(draws)]
    for f in active:
        perts += [make_perturbation(f"oat-{f}-{i:05d}", draws[i], n_cells, only=f, unc=unc)
                  for i in range(sensitivity)]
    return perts, active


__all__ = ["tolerance_analysis", "run_sample", "Perturbation",
           "DesignPayload", "read_payload", "CompliantBracketModel", "material_scatter",
           "relaxation_factor", "aggregate", "sensitivity_table",
           "regression_sensitivity",
           "make_perturbation", "nominal_perturbation", "wilson", "FACTORS"]
