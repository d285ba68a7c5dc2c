"""The temporal-programming stage: bracket thicknesses from the time landscape.

Modules: :mod:`.program` (force balance, thickness solve, :func:`program_design`),
:mod:`.membrane_model` (the linearised membrane model ``F_mem`` and its fit),
:mod:`.cell_membrane` (membrane traction samples from the simulator, an offline fitting
tool) and :mod:`.plots`.
"""
from .program import (
    COMPLETION_TOL_MM,
    CORRECTIONS,
    PICTURE,
    REFINE_DAMPING,
    REFINE_LOG,
    STAGE_FILE,
    bracket_target_force,
    completion_time,
    load_material,
    membrane_factors,
    program_cells,
    program_design,
    solve_thickness,
    target_compressions,
    time_limit,
    time_ranges,
    timing_errors,
)

__all__ = [
    "COMPLETION_TOL_MM",
    "CORRECTIONS",
    "PICTURE",
    "REFINE_DAMPING",
    "REFINE_LOG",
    "STAGE_FILE",
    "bracket_target_force",
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
]
