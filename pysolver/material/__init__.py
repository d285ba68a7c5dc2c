"""Data-driven bracket material model (SI Note 3).

Public API
----------
load_bracket_model(path=None, outside="clamp") -> BracketModel
    The fitted per-bracket force/energy polynomials on the (thickness, length, time) grid;
    ``force``, ``energy``, ``stiffness``, ``coefficients``, ``thickness_for_force`` (seconds, mm,
    N; vectorised).
plastic_rest_length(rest, rest0, length, eta)
    Rest-length update of the elasto-plastic spring.
load_measurements(data_dir=None)
    Read and validate the measurement CSVs.

The offline fit lives apart from this runtime model, in :mod:`pysolver.fitting`:
:mod:`~pysolver.fitting.material_fit` (``fit_material``, ``make material``) and
:mod:`~pysolver.fitting.material_report` (its pictures, ``compare_models``).
"""

from .measurements import load_measurements
from .model import BracketModel, load_bracket_model, plastic_rest_length
from .polyfit import poly_energy, poly_force, poly_stiffness

__all__ = ["BracketModel", "load_bracket_model",
           "plastic_rest_length", "load_measurements", "poly_force", "poly_energy",
           "poly_stiffness"]
