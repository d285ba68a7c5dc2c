"""Every setting of morphshell, by topic, each documented (meaning, unit, source).

All lengths mm, forces N, times s, moduli MPa, angles deg unless a name says ``_rad``.  The
defaults are the paper's (Supplementary Notes 1-5) and the reference implementation's
(``shared/design/pipeline.md``, ``simulator.md``); where they disagree, or where a value is
morphshell's own, the field says so.  Each class is a frozen dataclass with a default
instance; import either from here (``from pysolver.params import UNIT_CELL, tol as TOL``).

=========================================  ==================================================
module                                     settings
=========================================  ==================================================
:mod:`~pysolver.params.unit_cell`          :class:`UnitCell` (the printed cell, printable
                                           thickness range), :class:`SupportFrame`, layers
:mod:`~pysolver.params.stencil`            :class:`StencilSearch`, by topic:
                                           :class:`StencilRemesh`, :class:`StencilOptimiser`,
                                           :class:`TimingEstimate`,
                                           :class:`CountSearchSettings`, :class:`LayoutChecks`
:mod:`~pysolver.params.landscape`          :class:`Sequencing`: the automatic time landscape
:mod:`~pysolver.params.programming`        :class:`Programming`: thickness solve, refinement;
                                           :class:`Coupon`: the timing coupon
:mod:`~pysolver.params.simulation`         :class:`SimConstants`, :class:`NewtonSettings`,
                                           :class:`PhysicsOptions`
:mod:`~pysolver.params.material`           :class:`ModelFileRules`, :class:`ModelFits`, the
                                           committed model files
:mod:`~pysolver.params.report`             :class:`ReportThresholds`, :class:`Pictures`,
                                           :class:`ScanAgreement`
:mod:`~pysolver.params.fabrication`        :class:`Fabrication`
:mod:`~pysolver.params.uncertainty`        :class:`Uncertainty`, :class:`ToleranceRun`
:mod:`~pysolver.params.limits`             :class:`Limits`: bounds of options and inputs
:mod:`~pysolver.params.tolerances`         :class:`Tolerances` (``tol``): slacks and floors
=========================================  ==================================================

The OpenSCAD modules in ``scad/`` take the same numbers from ``scad/params.scad``, which is
generated from :class:`UnitCell`, :class:`SupportFrame` and :class:`Tolerances`
(``make scad-params``, :mod:`pysolver.render.scad_params`); a test checks it is up to date.
"""

from .fabrication import FABRICATION, Fabrication
from .landscape import SEQUENCING, Sequencing
from .limits import LIMITS, Limits
from .material import (
    BRACKET_MODEL_FILE,
    DATA_DIR,
    MEMBRANE_MODEL_FILE,
    MODEL_FILES,
    MODEL_FITS,
    PAPER_BRACKET_HEIGHT_MM,
    ModelFileRules,
    ModelFits,
)
from .mechtest import MECHTEST, TESTS, MechTest
from .programming import COUPON, DEFAULT_REFINE, PROGRAMMING, Coupon, Programming
from .report import PICTURES, REPORT, SCAN_AGREEMENT, Pictures, ReportThresholds, ScanAgreement
from .simulation import (
    BUMPER_MODULUS,
    NEWTON,
    PHYSICS_DEFAULT,
    PHYSICS_OFF,
    RELAXATION_PRONY,
    SIM,
    NewtonSettings,
    PhysicsOptions,
    SimConstants,
)
from .stencil import (
    REFERENCE_MIN_BUMPER_MM,
    STENCIL,
    CountSearchSettings,
    LayoutChecks,
    StencilOptimiser,
    StencilRemesh,
    StencilSearch,
    TimingEstimate,
)
from .tolerances import Tolerances, tol
from .uncertainty import TOLERANCE_RUN, UNCERTAINTY, ToleranceRun, Uncertainty
from .unit_cell import (
    LAYERS,
    SUPPORT_FRAME,
    UNIT_CELL,
    SupportFrame,
    UnitCell,
    check_unit_cell,
    layer_sign,
)

__all__ = [
    "UnitCell", "UNIT_CELL", "SupportFrame", "SUPPORT_FRAME", "LAYERS", "layer_sign",
    "check_unit_cell",
    "StencilSearch", "STENCIL", "REFERENCE_MIN_BUMPER_MM", "StencilRemesh", "StencilOptimiser",
    "TimingEstimate", "CountSearchSettings", "LayoutChecks",
    "Sequencing", "SEQUENCING",
    "Programming", "PROGRAMMING", "DEFAULT_REFINE", "Coupon", "COUPON",
    "SimConstants", "SIM", "NewtonSettings", "NEWTON", "PhysicsOptions", "PHYSICS_OFF",
    "PHYSICS_DEFAULT", "RELAXATION_PRONY", "BUMPER_MODULUS",
    "ModelFileRules", "MODEL_FILES", "ModelFits", "MODEL_FITS", "PAPER_BRACKET_HEIGHT_MM",
    "DATA_DIR", "BRACKET_MODEL_FILE", "MEMBRANE_MODEL_FILE",
    "ReportThresholds", "REPORT", "Pictures", "PICTURES", "ScanAgreement", "SCAN_AGREEMENT",
    "Fabrication", "FABRICATION", "MechTest", "MECHTEST", "TESTS",
    "Uncertainty", "UNCERTAINTY", "ToleranceRun", "TOLERANCE_RUN",
    "Limits", "LIMITS",
    "Tolerances", "tol",
]
