"""The temporal-programming stage: bracket thicknesses from the time landscape.

Modules: :mod:`.program` (force balance, thickness solve, :func:`program_design`),
:mod:`.membrane_model` (the linearised membrane model ``F_mem``, the FEM membrane of the
per-cell correction), :mod:`.plots`, :mod:`.coupon` (the timing coupon's calibration),
:mod:`.reference_compare` (the thicknesses against a reference design's, for
``bench/bench_reference.py``).  The fit of ``F_mem`` (``make membrane-model``) is an
offline tool, in :mod:`pysolver.fitting.membrane_fit`.  Every membrane here is the one membrane
energy of :mod:`pysolver.mechanics.energies` on the one membrane mesh of a flat layout
(:func:`pysolver.mechanics.membrane_mesh`); nothing here imports the simulator (``sim``).
"""
from .program import (
    CORRECTIONS,
    PICTURE,
    PREDICTED_SD,
    REFINE_LOG,
    STAGE_FILE,
    both_layers_latest,
    bracket_target_force,
    closing_lengths,
    completion_time,
    load_material,
    membrane_factors,
    program_cells,
    program_design,
    sd_list,
    solve_thickness,
    target_compressions,
    time_limit,
    time_ranges,
    timing_errors,
    timing_sd,
)

__all__ = [
    "CORRECTIONS",
    "PICTURE",
    "REFINE_LOG",
    "STAGE_FILE",
    "both_layers_latest",
    "bracket_target_force",
    "closing_lengths",
    "completion_time",
    "load_material",
    "membrane_factors",
    "program_cells",
    "program_design",
    "solve_thickness",
    "target_compressions",
    "time_limit",
    "time_ranges",
    "timing_errors",
    "timing_sd",
    "PREDICTED_SD",
    "sd_list",
]
