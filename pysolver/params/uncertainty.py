"""The tolerance analysis (``morphshell tolerance``) and design sweeps: what is uncertain,
and how the runs are made."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Uncertainty:
    """Default fabrication and material uncertainty of ``morphshell tolerance``.

    Every sample of the Monte Carlo analysis (:mod:`pysolver.tolerance`) draws each factor below
    independently; a standard deviation of 0 switches a factor off.  Source: the printing
    and fabrication tolerances given with each field (morphshell's estimates), the measured
    relaxation curve (SI Fig. 10) and the material fit's residuals.

    Attributes
    ----------
    thickness_sd : float, mm
        Per-bracket printed thickness, normal around the programmed value (FDM prints
        bracket thickness within about +-0.02 mm).  One draw per cell and layer.
    stretch_mean, stretch_sd : float
        Membrane pre-stretch factor tau, normal (set by hand, "near 3").
    modulus_rel_sd : float
        Relative standard deviation of the membrane shear modulus mu (+-10 %).
    material_sd : float or None
        Standard deviation of the natural log of the bracket compliance factor (the fitted
        bracket is ``s`` times as compliant: ``F_s(x) = F(x / s)``), one draw per sample.
        ``None``: derived from the wet fit residuals of the material model
        (:func:`pysolver.tolerance.material_scatter`).
    relaxation : bool
        Also draw a membrane stress-relaxation factor from the measured curve
        (``data/material-measurements/rubber_stress_relaxation.csv``, SI Fig. 10).
    relaxation_window_s : (float, float), s
        Time between stretching the membrane and the hot-water bath, log-uniform in this
        window (10 min .. 24 h; after about 1.5 h the curve hardly moves).
    """

    thickness_sd: float = 0.02
    stretch_mean: float = 3.0
    stretch_sd: float = 0.1
    modulus_rel_sd: float = 0.10
    material_sd: float | None = None
    relaxation: bool = False
    relaxation_window_s: tuple = (600.0, 86400.0)

    MAX_MODULUS_REL_SD = 0.3
    """Largest accepted ``modulus_rel_sd`` (30 %: a wider normal draws non-positive moduli)."""
    MAX_STRETCH_SD_FRACTION = 0.25
    """Largest accepted ``stretch_sd``, as a fraction of ``stretch_mean - 1`` (the drawn
    stretch stays well above 1)."""


@dataclass(frozen=True)
class ToleranceRun:
    """Run settings of ``morphshell tolerance`` and ``morphshell sweep``.

    Source: morphshell's.

    Attributes
    ----------
    samples : int
        Monte Carlo samples (``--samples``, ``make tolerance SAMPLES=``).
    max_samples : int
        Upper bound of ``--samples`` (a typo is refused, not run for days).
    seed : int
        Seed of the sample draws (fixed: a rerun gives the same numbers).
    time_tol_s : float, s
        A cell is *on time* when it completes within this of its programmed t* (the
        report's timing RMS warning limit).
    sensitivity_samples : int
        One-at-a-time runs per uncertainty factor for the sensitivity table (0 = off).
    material_robust_k : float
        MAD-to-standard-deviation factor of a normal distribution (1.4826), used to turn
        the per-curve fit residuals into :attr:`Uncertainty.material_sd` robustly.
    max_variants : int
        Upper bound of the variants of one sweep.
    progress_every_s : float, s
        Shortest interval between two progress lines of a distributed run.
    thickness_floor_mm : float, mm
        Smallest bracket thickness a sample draws (a printed bracket has a thickness).
    modulus_floor : float
        Smallest membrane modulus factor a sample draws.
    order_separation_s : float, s
        P(order kept) counts pairs of neighbouring cells (sharing a base) programmed at least
        this far apart (issue #45: regions a maker would see close one after the other).
    """

    samples: int = 64
    max_samples: int = 10000
    seed: int = 0
    time_tol_s: float = 10.0
    sensitivity_samples: int = 8
    material_robust_k: float = 1.4826
    max_variants: int = 2000
    progress_every_s: float = 2.0
    thickness_floor_mm: float = 0.05
    modulus_floor: float = 0.05
    order_separation_s: float = 15.0


UNCERTAINTY = Uncertainty()
TOLERANCE_RUN = ToleranceRun()

__all__ = ["Uncertainty", "UNCERTAINTY", "ToleranceRun", "TOLERANCE_RUN"]
