"""Stress relaxation of the latex membrane (SI Note 5 step 2, SI Fig. 10).

The measurement (``data/material-measurements/rubber_stress_relaxation.csv``) stretches a
dog-bone latex specimen to stretch 3 in 240 s (tester step 1) and holds it for 24 h
(step 2), recording the load every 4 s.  The load falls by 15 % in the first hour and by 19 %
in 24 h.  We model it as a normalised Prony series

    ``g(t) = g_inf + sum_i g_i exp(-t / tau_i)``,  ``g(0) = 1``,

with ``t`` the time since the end of the stretching (s).  The relaxation times are fixed at
half decades from 10 s to 1e5 s and the weights found by non-negative least squares
(``scipy.optimize.nnls``), so ``g`` falls monotonically; samples are weighted by
``1 / sqrt(t)`` so that the first minutes, which matter for fabrication, count as much as
the last hours.  The committed coefficients are :data:`pysolver.params.RELAXATION_PRONY`.

How the simulator uses it (``PhysicsOptions.relaxation``): the membrane is held at a fixed
stretch from stretching to immersion, so its pre-stress is the measured curve; the
neo-Hookean modulus ``mu`` is scaled by ``g`` of the time since stretching.  Strain changes
after the release are treated as elastic on the relaxed modulus (quasi-linear
viscoelasticity with a single stretch step), and the faster relaxation in 56 C water is not
measured, so not modelled.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pysolver.errors import InputError
from pysolver.params import MODEL_FITS, RELAXATION_PRONY

DATA_FILE = "rubber_stress_relaxation.csv"
HOLD_STEP = 2  # tester step of the hold at constant stretch
TIME_COL, STEP_COL, LOAD_COL = 0, 4, 7
PRONY_TAUS = tuple(float(10.0 ** e) for e in np.arange(1.0, 5.01, 0.5))


def load_relaxation_data(data_dir=None):
    """The hold phase of the relaxation test.

    Parameters
    ----------
    data_dir : path-like, optional
        Folder with ``rubber_stress_relaxation.csv`` (default: the project's
        ``data/material-measurements``).

    Returns
    -------
    t : (n,) float, s -- time since the start of the hold (end of stretching)
    load : (n,) float, N -- load on the specimen
    """
    if data_dir is None:
        data_dir = Path(__file__).resolve().parents[2] / "data" / "material-measurements"
    path = Path(data_dir) / DATA_FILE
    if not path.is_file():
        raise InputError(f"{path}: relaxation measurement not found",
                         fix="pass the folder holding rubber_stress_relaxation.csv")
    try:
        d = np.genfromtxt(path, delimiter=",", skip_header=1, usecols=(TIME_COL, STEP_COL,
                                                                        LOAD_COL))
    except ValueError as e:
        raise InputError(f"{path}: cannot read ({e})", fix="use the Instron export as shipped") \
            from None
    if d.ndim != 2 or not np.all(np.isfinite(d)):
        raise InputError(f"{path}: non-numeric or missing values",
                         fix="use the Instron export as shipped")
    hold = d[:, 1] == HOLD_STEP
    if hold.sum() < MODEL_FITS.relaxation_min_samples:
        raise InputError(f"{path}: fewer than {MODEL_FITS.relaxation_min_samples} samples "
                         f"in the hold step {HOLD_STEP}",
                         fix="use the Instron export as shipped")
    t = d[hold, 0] - d[hold, 0][0]
    return t, d[hold, 2]


def prony(t, taus, weights) -> np.ndarray:
    """``g(t) = weights[0] + sum_i weights[i+1] exp(-t / taus[i])``; ``t`` (s) array-like."""
    t = np.asarray(t, float)
    taus = np.asarray(taus, float)
    w = np.asarray(weights, float)
    return w[0] + np.exp(-t[..., None] / taus) @ w[1:]


def fit_relaxation(t, load, taus=PRONY_TAUS):
    """Fit the normalised Prony series to a relaxation curve.

    Parameters
    ----------
    t : (n,) float, s
    load : (n,) float, N
    taus : sequence of float, s

    Returns
    -------
    weights : (len(taus) + 1,) float -- ``(g_inf, g_1, ...)``, summing to 1
    F0 : float, N -- the fitted load at t = 0
    """
    from scipy.optimize import nnls  # heavy: this scipy submodule loads only where it is used

    t = np.asarray(t, float)
    A = np.c_[np.ones_like(t), np.exp(-t[:, None] / np.asarray(taus, float))]
    w = 1.0 / np.sqrt(np.maximum(t, MODEL_FITS.relaxation_weight_floor_s))
    c, _ = nnls(A * w[:, None], np.asarray(load, float) * w)
    F0 = float(c.sum())
    return c / F0, F0


def relaxation_factor(t_s) -> np.ndarray:
    """Membrane pre-stress after ``t_s`` seconds at stretch 3, relative to t = 0 (committed fit).

    Parameters
    ----------
    t_s : float or array, s (>= 0)

    Returns
    -------
    g : same shape, in (0, 1]
    """
    t = np.asarray(t_s, float)
    if np.any(~np.isfinite(t)) or np.any(t < 0):
        raise InputError(f"relaxation time must be finite and >= 0 s, got {t_s!r}",
                         fix="pass the time since stretching in seconds")
    taus, weights = RELAXATION_PRONY
    return prony(t, taus, weights)


__all__ = ["load_relaxation_data", "fit_relaxation", "prony", "relaxation_factor", "PRONY_TAUS"]
