"""The simulator proper: model assembly from the design folder, energies, solver, time stepping.

Modules: :mod:`.model` (:class:`ShellModel` from the design tables and ``model.npz``),
:mod:`.energies`, :mod:`.kernels`, :mod:`.solver`, :mod:`.contact`, :mod:`.physics`,
:mod:`.rim`, :mod:`.collisions` and :mod:`.simulate` (``simulate_design``,
``completion_times``).
"""
from .model import (
    CROSS_REST_MODES,
    ShellModel,
    build_model,
    load_model,
    membrane_mesh,
    rim_margin,
    vary_model,
)

__all__ = [
    "CROSS_REST_MODES",
    "ShellModel",
    "build_model",
    "load_model",
    "membrane_mesh",
    "rim_margin",
    "vary_model",
]
