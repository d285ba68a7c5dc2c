"""The shell's mechanics, shared by the simulator (:mod:`sim.model`) and temporal programming.

One membrane energy and one solver for every stage that needs them: the model of a shell
(rigid bases, bracket springs, cross pairs, the membrane mesh) assembled from the design's
arrays or read from a design folder (:mod:`.model`), its energies with analytic gradients and
Hessians (:mod:`.energies`, compiled element loops in :mod:`.kernels`), the Newton solver of
the static equilibrium (:mod:`.solver`) and the latex margin at the rim (:mod:`.rim`).

It is its own layer just above the core: it imports only core modules (``errors``,
``params``, ``geometry``, ``tables``), so the simulator and the design side both stand above
it (``tests/test_architecture.py``).
"""
from .model import (
    CROSS_REST_MODES,
    MembraneMesh,
    ShellModel,
    build_model,
    bumper_clearance,
    load_model,
    membrane_mesh,
    vary_model,
)
from .rim import margin_rest, rim_margin

__all__ = [
    "CROSS_REST_MODES",
    "MembraneMesh",
    "ShellModel",
    "build_model",
    "bumper_clearance",
    "load_model",
    "margin_rest",
    "membrane_mesh",
    "rim_margin",
    "vary_model",
]
