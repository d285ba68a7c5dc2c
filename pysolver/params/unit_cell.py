"""The printed unit cell and the support frame: every dimension of a printed layer (mm, deg).

Sources: the paper's Supplementary Note 1 and the reference implementation's options
(``shared/design/pipeline.md`` §1.1-1.6); where they disagree, the field says which is used.
The SCAD library reads the same numbers from ``scad/params.scad``, generated from these
classes (:mod:`pysolver.render.scad_params`, ``make scad-params``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from ..errors import InputError
from .limits import LIMITS


@dataclass(frozen=True)
class UnitCell:
    """Geometry of bases, brackets and bumpers (mm, deg).

    Source: the reference's ``SmpOptions`` defaults (``pipeline.md`` §1.1, ``simulator.md``
    §1) unless a field says otherwise.  The whole record is written into ``design.json``
    (``options.params``) and later stages read it from there.

    Attributes
    ----------
    base_r : float, mm
        Base disc radius (Ø 4 mm).
    base_th : float, mm
        Layer core thickness; also the side of the square bumper prism.
    base_p : float, mm
        Base indent: extra base height on the membrane side (0.3 mm), which
        leaves a 2 * base_p slot between opposing bumpers for the membrane.
    bracket_w : float, mm
        Bracket height (out of plane), 1 mm: the height of the brackets the material model
        was measured on (a model file records it, :func:`pysolver.material.model.
        check_bracket_geometry`).
    min_gap : float, mm
        Minimal flat gap between facing bumper tips (2D scaling rule), 0.1 mm.
        The reference's json has 0.0 (stale); its examples and the paper use 0.1.
    min_bumper : float, mm
        Minimal bumper length beyond the base rim (3D scaling rule).  The paper
        says 0.3 mm, most reference examples 0.1 mm; we follow the paper: a
        longer bumper stops the bracket further from its breaking strain.
    clearance : float, mm
        Printing clearance removed from every bumper tip, 0.05 mm (reference,
        ``pipeline.md`` §1.4).  Also the distance under which a bracket counts as closed on
        its bumper when the simulation's completion times are measured.
    align_r : float, mm
        Alignment hole radius (Ø 1.5 mm; the reference passes 0.75 as radius).
    marker_r, marker_depth : float, mm
        Marker-dot pocket radius and depth on the far face (reference, ``pipeline.md``
        §1.5).
    max_cell_length : float, mm
        Longest printable unit cell (flat centre distance), 9.5 mm: the bracket model's
        measured lengths plus two steps of its length grid (see
        :attr:`Limits.max_cell_length_mm`, its upper bound for ``--max-cell-length``).
    alpha_margin_deg : float, deg
        Margin added to the bracket arm angle that just clears the base rim,
        ``asin(base_th / (2 base_r))`` (30 deg): the arms stand at 37 deg to the cell axis
        (reference ``smpup.cpp``, ``pipeline.md`` §1.3; its specimen generator hard-codes 37).
    thickness_min, thickness_max : float, mm
        Printable bracket thickness range, 0.30-0.65 mm: the thicknesses the bracket
        (material) model was measured for (its grid, ``pipeline.md`` §2.9) and the range of
        the reference's shipped designs.  Temporal programming chooses every bracket's
        thickness in it (the thinnest bracket finishes earliest), and the tables reader
        refuses thicknesses outside it (:func:`pysolver.tables.check_thickness`).
    """

    base_r: float = 2.0
    base_th: float = 2.0
    base_p: float = 0.3
    bracket_w: float = 1.0
    min_gap: float = 0.1
    min_bumper: float = 0.3
    clearance: float = 0.05
    align_r: float = 0.75
    marker_r: float = 0.3
    marker_depth: float = 0.5
    max_cell_length: float = 9.5
    alpha_margin_deg: float = 7.0
    thickness_min: float = 0.30
    thickness_max: float = 0.65

    @property
    def layer_h(self) -> float:
        """Height of one printed layer (base_th + base_p = 2.3 mm)."""
        return self.base_th + self.base_p

    @property
    def alpha_deg(self) -> float:
        """Bracket arm angle to the cell axis: asin(base_th / (2 base_r)) + 7 deg = 37 deg."""
        return math.degrees(math.asin(self.base_th / (2 * self.base_r))) + self.alpha_margin_deg

    @property
    def alpha_rad(self) -> float:
        return math.radians(self.alpha_deg)

    @property
    def bracket_offset(self) -> float:
        """l - b: central length minus bracket length, 2 base_r cos(alpha) = 3.1945 mm."""
        return 2 * self.base_r * math.cos(self.alpha_rad)

    def bracket_length(self, central_length):
        """Bracket length b (mm) of a cell of flat central length l (mm): b = l - 2 r cos(alpha)."""
        return central_length - self.bracket_offset

    def shortest_cell(self) -> float:
        """Shortest flat central length the scaling rules allow, mm: a flat cell whose
        bumpers stick out ``min_bumper`` and keep ``min_gap``, ``2 (base_r + min_bumper) +
        min_gap``."""
        return 2 * (self.base_r + self.min_bumper) + self.min_gap

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class SupportFrame:
    """The support frame printed around each layer (``scad/support_frame.scad``), mm.

    Source: the reference's support frame (``pipeline.md`` §1.6) for the ring and the
    connectors; the search settings are morphshell's.

    Attributes
    ----------
    offset_in, offset_out : float, mm
        The ring lies between these offsets of the flat outline (reference: 6 and 9);
        the same values as ``FRAME_OFFSET_IN``/``FRAME_OFFSET_OUT`` of ``scad/params.scad``.
    connector_w : float, mm
        Square section of a breakaway connector (``CONNECTOR_W``; reference 0.5 mm sprues).
    connector_r0 : float, mm
        Connectors start this far from the base centre, inside the base (``CONNECTOR_R0``).
    spacing : float, mm
        A boundary base gets a connector only if no connected base lies within this flat
        distance (greedy in base order, as the reference).
    connector_max_reach : float, mm
        Longest connector beyond its base's boundary edge.  Each connector ends in the
        middle of the ring along its own direction; where the ring is farther (deep in a
        notch of the outline) or the direction crosses the shell again, the base gets no
        connector and the next boundary base is tried.
    step : float, mm
        Sampling step along a connector when its end in the ring is searched.
    hole_margin : float, mm
        Holes of the ring's inner offset (which would leave loose ring islands) are filled
        grown by this much, to overlap the inner offset whatever its faceting.
    circle_segments : int
        Segments per full circle of the round offsets computed in Python (manifold3d).
    """

    offset_in: float = 6.0
    offset_out: float = 9.0
    connector_w: float = 0.5
    connector_r0: float = 1.0
    spacing: float = 30.0
    connector_max_reach: float = 15.0
    step: float = 0.02
    hole_margin: float = 0.1
    circle_segments: int = 256


UNIT_CELL = UnitCell()
SUPPORT_FRAME = SupportFrame()

LAYERS = ("top", "bottom")
"""Layer names.  ``top`` = +z in the flat print frame = +face-normal side of the
target (the reference's ``o``); ``bottom`` = -z = -normal side (``u``)."""


def layer_sign(layer) -> int:
    """+1 for the top layer (index 0 / ``"top"``), -1 for the bottom layer (1 / ``"bottom"``)."""
    if layer in (0, "top"):
        return 1
    if layer in (1, "bottom"):
        return -1
    raise ValueError(f"layer must be 0/'top' or 1/'bottom', got {layer!r}")


def check_unit_cell(params: UnitCell) -> None:
    """Check the user-variable tolerances of a unit cell against :class:`~pysolver.params.Limits`.

    Raises
    ------
    InputError
        Naming the option, its value, the allowed range and a fix.
    """
    for opt, v, (lo, hi), why in (
            ("--min-bumper", params.min_bumper, LIMITS.min_bumper_mm,
             "the paper uses 0.3 mm, most reference examples 0.1 mm"),
            ("--min-gap", params.min_gap, LIMITS.min_gap_mm,
             "the paper and the reference examples use 0.1 mm")):
        if not (math.isfinite(v) and lo <= v <= hi):
            raise InputError(f"{opt} {v!r} mm is outside {lo:g}-{hi:g} mm",
                             fix=f"give a length in that range ({why})")
    lo, hi = params.shortest_cell(), LIMITS.max_cell_length_mm
    v = params.max_cell_length
    if not (math.isfinite(v) and lo < v <= hi):
        raise InputError(
            f"--max-cell-length {v!r} mm is outside {lo:g}-{hi:g} mm: no cell is shorter than "
            f"2 (base radius + min bumper) + min gap = {lo:g} mm, and the bracket model is "
            f"measured up to {LIMITS.model_max_central_length_mm:g} mm (used up to {hi:g} mm)",
            fix=f"give a length above {lo:g} and up to {hi:g} mm (default "
                f"{UNIT_CELL.max_cell_length:g} mm)")


__all__ = ["UnitCell", "UNIT_CELL", "SupportFrame", "SUPPORT_FRAME", "LAYERS", "layer_sign",
           "check_unit_cell"]
