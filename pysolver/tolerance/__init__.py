"""Monte Carlo tolerance analysis over print and material scatter (on Dask).

Modules: :mod:`.analysis` (:func:`tolerance_analysis`) and :mod:`.report`.
"""
from .analysis import (
    FACTORS,
    CompliantBracketModel,
    DesignPayload,
    Perturbation,
    aggregate,
    make_perturbation,
    material_scatter,
    nominal_perturbation,
    read_payload,
    regression_sensitivity,
    relaxation_factor,
    run_sample,
    sensitivity_table,
    tolerance_analysis,
    wilson,
)

__all__ = [
    "CompliantBracketModel",
    "DesignPayload",
    "FACTORS",
    "Perturbation",
    "aggregate",
    "make_perturbation",
    "material_scatter",
    "nominal_perturbation",
    "read_payload",
    "regression_sensitivity",
    "relaxation_factor",
    "run_sample",
    "sensitivity_table",
    "tolerance_analysis",
    "wilson",
]
