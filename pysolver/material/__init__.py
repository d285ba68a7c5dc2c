"""Data-driven bracket material model (SI Note 3).

Public API
----------
load_bracket_model(path=None, outside="clamp") -> BracketModel
    The fitted per-bracket force/energy polynomials on the (thickness, length, time) grid;
    ``force``, ``energy``, ``stiffness``, ``coefficients``, ``thickness_for_force`` (seconds, mm,
    N; vectorised).
fit_material(data_dir=None, out_path=None, report_dir=None, compare_to=None) -> dict
    Fit the model from the tensile-test CSVs, write the model file and the report.
compare_models(model_a, model_b, out_png)
    Force-displacement curves of two models at a few times.
plastic_rest_length(rest, rest0, length, eta)
    Rest-length update of the elasto-plastic spring.
load_measurements(data_dir=None)
    Read and validate the measurement CSVs.
"""

from .fit import fit_material
from .measurements import load_measurements
from .model import (
    BracketModel,
    load_bracket_model,
    plastic_rest_length,
    poly_energy,
    poly_force,
    poly_stiffness,
)
from .report import compare_models

__all__ = ["BracketModel", "load_bracket_model", "fit_material", "compare_models",
           "plastic_rest_length", "load_measurements", "poly_force", "poly_energy",
           "poly_stiffness"]
