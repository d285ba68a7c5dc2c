"""The simulation check report.

Modules: :mod:`.load` (a simulated design folder, read and validated), :mod:`.metrics` (the
measurements), :mod:`.verdict` (:func:`check_morph`: every check and the verdict, the one
place a morph is judged), :mod:`.html` (the page, from the files in ``templates/``),
:mod:`.report` (:func:`make_report`: pictures, JSON and HTML), :mod:`.plots`,
:mod:`.fabrication` (provenance and the fabrication sheet) and :mod:`.scan` (3D scan
comparison).
"""
from .html import SECTIONS
from .load import SimData, load_frames, load_sim
from .metrics import (
    fold_metrics,
    shape_metrics,
    shape_rms_over_time,
    solver_metrics,
    timing_metrics,
)
from .report import make_report, print_verdict
from .verdict import Check, base_base_collisions, check_morph, decide

__all__ = [
    "SECTIONS",
    "Check",
    "SimData",
    "base_base_collisions",
    "check_morph",
    "decide",
    "fold_metrics",
    "load_frames",
    "load_sim",
    "make_report",
    "print_verdict",
    "shape_metrics",
    "shape_rms_over_time",
    "solver_metrics",
    "timing_metrics",
]
