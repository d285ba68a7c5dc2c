"""The report: the limits of its verdict and the floors of its pictures."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from ..errors import InputError


@dataclass(frozen=True)
class ReportThresholds:
    """Limits of the report's verdict; imported by :mod:`sim.report.report` as ``Thresholds``.

    Source: morphshell's, each justified in ``docs/report.md`` (the paper reports its shells'
    shape errors, 1-3 % of their size, and orders of completion, not limits).

    Attributes
    ----------
    shape_rms_warn_pct, shape_rms_fail_pct : float, %
        RMS distance of the aligned final base centres to the target centres,
        in % of the target size (bounding-box diagonal of the target centres).
    shape_max_warn_pct : float, %
        Largest single base distance, % of the target size (a local defect).
    normal_warn_deg, normal_fail_deg : float, deg
        RMS angle between the aligned final base normals (flat +z of each base)
        and the target face normals (global orientation of the layers).
    fold_rms_warn_deg : float, deg
        RMS error of the signed fold angle per unit cell (angle between the two
        base normals, + when folding toward the top layer; ``cells.csv``
        ``fold_angle_deg``).  Alignment-free: measures the local bending.
    fold_flip_fail_fraction : float
        Fraction of the folded cells (target ``|fold| >= fold_min_deg``) whose
        simulated fold has the opposite sign, above which the shell is bent
        the wrong way: FAIL.  Any flipped folded cell is a WARN.
    fold_min_deg : float, deg
        A cell counts as folded (for the flip check) when its target fold is at least this.
    timing_rms_warn_s : float, s
        RMS of (simulated completion - t*) over the cells that complete.
    spearman_warn : float
        Rank correlation of simulated completion vs t* below this: the order of
        morphing is not the programmed one.  Only checked when the programmed
        t* spread (std) is at least ``timing_spread_min_s``.
    timing_spread_min_s : float, s
        Smallest standard deviation of the programmed t* for the rank correlation to be
        checked (a near-constant landscape has no order to keep).
    incomplete_fail_fraction : float
        Fraction of unit cells (with t* <= the simulated end time) that never
        complete above which the morph has not happened: FAIL.  Any such cell
        is a WARN.
    collision_depth_mm : float, mm
        Penetration deeper than this counts as a collision (base/base and
        membrane/base).
    membrane_collision_fail : bool
        Membrane-through-base collisions are FAIL (True) or WARN (False).
    residual_fail_N : float, N
        A non-converged step whose final residual is above this is FAIL; below
        it, WARN.
    listed_cells : int
        Longest list of cell (or frame) ids a report or refinement record names.
    """

    shape_rms_warn_pct: float = 2.0
    shape_rms_fail_pct: float = 5.0
    shape_max_warn_pct: float = 10.0
    normal_warn_deg: float = 15.0
    normal_fail_deg: float = 45.0
    fold_rms_warn_deg: float = 5.0
    fold_flip_fail_fraction: float = 0.25
    fold_min_deg: float = 1.0
    timing_rms_warn_s: float = 10.0
    spearman_warn: float = 0.5
    timing_spread_min_s: float = 2.0
    incomplete_fail_fraction: float = 0.5
    collision_depth_mm: float = 0.1
    membrane_collision_fail: bool = False
    residual_fail_N: float = 1e-3
    listed_cells: int = 50

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.type in ("float", float) and not (isinstance(v, (int, float))
                                                    and math.isfinite(v) and v >= 0):
                raise InputError(f"Thresholds.{f.name} = {v!r}: must be a finite number >= 0",
                                 fix="pass a non-negative number")
        if not (isinstance(self.listed_cells, int) and self.listed_cells >= 1):
            raise InputError(f"Thresholds.listed_cells = {self.listed_cells!r}: must be a "
                             "whole number >= 1", fix="pass how many cell ids a list names")
        if self.shape_rms_warn_pct > self.shape_rms_fail_pct:
            raise InputError("Thresholds: shape_rms_warn_pct > shape_rms_fail_pct",
                             fix="the WARN limit must not exceed the FAIL limit")
        if self.normal_warn_deg > self.normal_fail_deg:
            raise InputError("Thresholds: normal_warn_deg > normal_fail_deg",
                             fix="the WARN limit must not exceed the FAIL limit")

    @classmethod
    def coerce(cls, value) -> ReportThresholds:
        """``None`` -> defaults; a mapping -> defaults updated by it; a Thresholds as is."""
        if value is None:
            return cls()
        if isinstance(value, cls):
            return value
        if isinstance(value, dict):
            names = {f.name for f in dataclasses.fields(cls)}
            bad = sorted(set(value) - names)
            if bad:
                raise InputError(f"unknown threshold(s) {bad}",
                                 fix=f"use some of {sorted(names)}")
            return cls(**value)
        raise InputError(f"thresholds must be a Thresholds or a dict, got {type(value).__name__}")


REPORT = ReportThresholds()


@dataclass(frozen=True)
class Pictures:
    """Floors of the colour and log scales of the pictures (report, material-fit report).

    Source: morphshell's.

    Attributes
    ----------
    colour_floor_mm : float, mm
        Smallest upper limit of a colour scale of distances (a perfect result is not drawn
        with an arbitrary scale).
    rate_floor : float, mm/min
        Floor of a measured rate drawn on a logarithmic axis.
    """

    colour_floor_mm: float = 1e-3
    rate_floor: float = 1e-3


PICTURES = Pictures()


@dataclass(frozen=True)
class ScanAgreement:
    """What the check can promise: how far the default simulation put a printed shell's
    marker dots from its 3D scan (stated in every report).

    Source: ``bench/bench_printed.py`` on the printed spiral of the paper's authors (their
    stencil and thicknesses, scored by ``morphshell compare-scan``; ``docs/physics.md``).
    The authors' simulator scores 1.58 mm mean by the same procedure.  One shell was
    measured: the promise names it and says nothing of other shapes.

    Attributes
    ----------
    shell : str
        The printed shell measured.
    span_mm : float, mm
        Its largest extent.
    n_bases : int
        Its bases per layer.
    mean_mm, median_mm, max_mm : float, mm
        Mean, median and largest distance of the scanned dots to the simulated ones after a
        rigid registration, with the default physics.
    """

    shell: str = "the printed spiral of the paper's authors"
    span_mm: float = 65.0
    n_bases: int = 221
    mean_mm: float = 1.44
    median_mm: float = 1.19
    max_mm: float = 5.3

    def promise(self) -> str:
        """One sentence for the report."""
        return (f"What this check can promise: measured on one printed shell ({self.shell}, "
                f"{self.span_mm:g} mm, {self.n_bases} bases), the default simulation placed "
                f"the dried shell's marker dots within {self.mean_mm:g} mm mean "
                f"({100 * self.mean_mm / self.span_mm:.1f} % of its span), "
                f"{self.median_mm:g} mm median and {self.max_mm:g} mm at most of its 3D scan; "
                "no other shape was measured (docs/physics.md).")


SCAN_AGREEMENT = ScanAgreement()


__all__ = ["ReportThresholds", "REPORT", "Pictures", "PICTURES", "ScanAgreement", "SCAN_AGREEMENT"]
