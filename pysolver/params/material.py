"""The material (bracket) and membrane models: where they are, how they are read and fitted.

Source: the committed models (``pysolver/data``), fitted from the measurements in
``data/material-measurements`` (``docs/calibration.md``); the fit settings are morphshell's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

PAPER_BRACKET_HEIGHT_MM = 1.0
"""Bracket height of the paper's specimens: the material models fitted before the model file
recorded its bracket geometry were fitted on these brackets."""

DATA_DIR = Path(__file__).resolve().parent.parent / "data"
"""The committed model files (``bracket_model.json``, ``membrane_model.json``)."""
BRACKET_MODEL_FILE = DATA_DIR / "bracket_model.json"
"""The committed bracket (material) model, the default of ``--material`` (``make material``
re-fits it, :func:`pysolver.fitting.material_fit.fit_material`)."""
MEMBRANE_MODEL_FILE = DATA_DIR / "membrane_model.json"
"""The committed membrane model (``make membrane-model`` re-fits it,
:func:`pysolver.fitting.membrane_fit.fit_membrane_model`)."""


@dataclass(frozen=True)
class ModelFileRules:
    """Rules of the model-file validator (:mod:`pysolver.material.validate`).

    The bracket (material) model and the membrane model are read from JSON files that a user
    can write or edit; every rule below is checked before any stage runs.  Source:
    morphshell's, measured on the committed models where a field says so.

    Attributes
    ----------
    max_bytes : int, bytes
        Largest model file read (the committed bracket model is ~0.3 MB).
    format_version : int
        Newest bracket-model ``format_version`` this code reads.
    grid_min_nodes : int
        Nodes per grid axis at least (trilinear interpolation needs a cell).
    stiffness_min : float, N/mm
        The stiffness at zero compression, ``c1 = F'(0)``, must exceed this at every node.
    stiffness_tol : float, N/mm
        Negative ``F'(x)`` allowed on ``[0, b]`` at a node (round-off of the fit's
        constraints; the committed model reaches -8e-9 N/mm).
    compressions : int
        Compressions ``x = b/n, 2b/n, .., b`` checked at each grid node.
    force_rise_tol : float
        Forces must fall with time in water: at every node and compression, ``F(t)`` may rise
        above its minimum over earlier times by at most this fraction of ``F(t=0)`` (the
        committed model rises by up to 4.9 %, a fit without one specimen by 5.5 %, both at
        b = 0.81 mm, below the measured lengths).
    softening_median_max : float
        The brackets must soften in water: the median over nodes and compressions of
        ``F(t_last) / F(t=0)`` must not exceed this (committed model: 0.056).
    plastic_fraction_max : float
        Upper bound (exclusive) of a stored plastic fraction ``eta`` (lower bound 0).
    membrane_b_range_mm : (float, float), mm
        Flat bracket lengths at which the membrane force is checked (the bracket model's grid
        starts at 0.81 mm; the longest cell, 9.5 mm, has b = 6.31 mm).
    membrane_d_fraction : float
        Shortenings ``d`` in ``[0, membrane_d_fraction * b]`` are checked: the membrane force
        must stay positive and must not grow as the cell shortens (the pre-stretch relaxes).
    membrane_samples : int
        Samples per axis of that check.
    boundary_factor_range : (float, float)
        Allowed ``boundary_factor`` (exclusive lower, inclusive upper bound).
    """

    max_bytes: int = 64 * 1024 * 1024
    format_version: int = 1
    grid_min_nodes: int = 2
    stiffness_min: float = 0.0
    stiffness_tol: float = 1e-6
    compressions: int = 20
    force_rise_tol: float = 0.10
    softening_median_max: float = 0.5
    plastic_fraction_max: float = 1.0
    membrane_b_range_mm: tuple = (0.8, 6.4)
    membrane_d_fraction: float = 0.7
    membrane_samples: int = 12
    boundary_factor_range: tuple = (0.0, 1.0)


@dataclass(frozen=True)
class ModelFits:
    """Ranges, sample counts and mesh sizes of the fits of the membrane model
    (:mod:`pysolver.fitting.membrane_fit`, :mod:`pysolver.fitting.cell_membrane`) and of the
    membrane's stress relaxation (:mod:`pysolver.material.relaxation`).

    Source: morphshell's; the mesh size was converged as the field says.

    Attributes
    ----------
    membrane_b0_mm : (float, float), mm
        Range of the flat bracket length b0 of :func:`pysolver.fitting.cell_membrane.
        membrane_traction` (its unit-cell membrane patch).
    membrane_d_max_fraction : float
        Largest contraction d of that patch, as a fraction of b0 (exclusive).
    membrane_fit_max_area : float, mm^2
        Largest flat triangle of the membrane patches of the membrane-model fit (converged
        to ~0.3 %; the simulator uses ``SimConstants.membrane_max_area``).
    relaxation_min_samples : int
        Fewest samples of the hold step of a stress-relaxation test.
    relaxation_weight_floor_s : float, s
        Floor of the time in the 1/sqrt(t) weights of the Prony fit of stress relaxation
        (the test records every 4 s).
    """

    membrane_b0_mm: tuple = (0.3, 7.0)
    membrane_d_max_fraction: float = 0.95
    membrane_fit_max_area: float = 0.5
    relaxation_min_samples: int = 10
    relaxation_weight_floor_s: float = 4.0


MODEL_FILES = ModelFileRules()
MODEL_FITS = ModelFits()

__all__ = ["ModelFileRules", "MODEL_FILES", "ModelFits", "MODEL_FITS", "PAPER_BRACKET_HEIGHT_MM",
           "DATA_DIR", "BRACKET_MODEL_FILE", "MEMBRANE_MODEL_FILE"]
