"""The design stage: target surface -> stencil -> flat layout -> the design tables.

Modules: :mod:`.mesh_input` (input meshes), :mod:`.surfaces` (built-in shapes),
:mod:`.time_landscape` (the user's time landscape), the package :mod:`.stencil` (the
stencil search: remeshing, the stencil optimisation, the vertex-count search),
:mod:`.flatten` (conformal flattening), :mod:`.layout` (scaling rules, bases, bumpers),
:mod:`.cellnodes` (bracket nodes and the simulator's ``model.npz``), :mod:`.checks`,
:mod:`.plots`, and :mod:`.pipeline` (:func:`run_design`, which writes the design folder).
"""
from .pipeline import (
    FLATTENINGS,
    check_design_options,
    design_layout,
    run_design,
    unit_cell_options,
    write_design_tables,
)

__all__ = [
    "FLATTENINGS",
    "check_design_options",
    "design_layout",
    "run_design",
    "unit_cell_options",
    "write_design_tables",
]
