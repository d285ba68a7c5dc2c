"""The simulation check report.

Modules: :mod:`.report` (verdict, metrics, HTML), :mod:`.plots`, :mod:`.fabrication`
(provenance and the fabrication sheet) and :mod:`.scan` (3D scan comparison).
"""
from .report import (
    SECTIONS,
    SimData,
    Thresholds,
    base_base_collisions,
    check_frames,
    completion_times,
    decide,
    fold_metrics,
    load_frames,
    load_sim,
    make_report,
    print_verdict,
    shape_metrics,
    shape_rms_over_time,
    solver_metrics,
    timing_metrics,
)

__all__ = [
    "SECTIONS",
    "SimData",
    "Thresholds",
    "base_base_collisions",
    "check_frames",
    "completion_times",
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
