"""Fabrication: the numbers of the procedure the report's fabrication sheet prints (SI Note 5)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Fabrication:
    """Numbers of the fabrication procedure (SI Note 5) used by the report's fabrication
    sheet and the membrane stretch template (:mod:`sim.report.fabrication`).

    Source: the paper's fabrication procedure (SI Note 5 steps 7-9: the 5 min wait, the
    release "near 2", the 56 C bath, about 15 min of drying) and the reference's helper
    scripts (``pipeline.md`` §1.7: the stretching devices, the push pin); the margins and
    the drawing sizes are morphshell's.

    Attributes
    ----------
    star_diameters_mm : tuple of float, mm
        Tip-circle diameters D of the star-shaped stretching devices the template can be
        drawn for (the reference's marker script: 200, 400, 500 mm).
    star_teeth : int
        Teeth of the device = markers on the sheet (16-point star).
    release_stretch : float
        Stretch factor the sheet is released to before cutting ("near 2").
    cut_margin_mm : float, mm
        Latex left around the shell when cutting (in the glued, stretched state).
    sheet_wrap_mm : float, mm
        Sheet beyond the marker circle, to wrap around the teeth (unstretched).
    pin_diameter_mm : float, mm
        Push-pin shaft through the alignment holes (reference push_pin.scad: r 0.4).
    water_c : float, degC
        Water temperature of the morphing bath.
    glue_wait_min, dry_min : float, min
        Wait after gluing before releasing the sheet; drying after the bath.
    marker_r_mm : float, mm
        Radius of a marker dot drawn on the template.
    """

    star_diameters_mm: tuple = (200.0, 400.0, 500.0)
    star_teeth: int = 16
    release_stretch: float = 2.0
    cut_margin_mm: float = 3.0
    sheet_wrap_mm: float = 15.0
    pin_diameter_mm: float = 0.8
    water_c: float = 56.0
    glue_wait_min: float = 5.0
    dry_min: float = 15.0
    marker_r_mm: float = 1.5


FABRICATION = Fabrication()

__all__ = ["Fabrication", "FABRICATION"]
