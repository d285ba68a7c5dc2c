"""``scad/params.scad`` generated from :mod:`pysolver.params`: one source for the unit cell.

The SCAD library reads its dimensions from ``scad/params.scad``; the simulator, the layout
and the material model read the same numbers from :class:`pysolver.params.UnitCell`.  This
module writes the SCAD file from the Python values, so the two cannot drift apart:

    python -m pysolver.render.scad_params         # rewrite scad/params.scad
    python -m pysolver.render.scad_params --check # exit 1 if it is out of date

(``make scad-params`` runs the first; ``tests/test_scad_modules.py`` the second.)  A
changed bracket height also needs a material model fitted for it (``make material``):
a build refuses a model fitted for other brackets
(:func:`pysolver.material.model.check_bracket_geometry`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..params import SUPPORT_FRAME, UNIT_CELL, SupportFrame, Tolerances, UnitCell
from ..params import tol as TOL
from .scad_io import SCAD_DIR

PARAMS_SCAD = SCAD_DIR / "params.scad"

_TEMPLATE = """\
// morphshell SCAD library: dimensions and faceting.
//
// GENERATED from pysolver/params.py (UnitCell, SupportFrame, Tolerances) by
// `python -m pysolver.render.scad_params` (make scad-params): edit the Python values,
// not this file.  `tests/test_scad_modules.py` checks that the file is up to date.
// The next `morphshell render` re-renders every part: the part cache key contains the
// text of every file in this folder.
//
// Every dimension of a printed layer, in mm and degrees.
//
// Frames used by the modules ("layer-local" frame of one base of one layer):
//   origin = base centre on the membrane plane, z = height above the membrane
//   toward the layer's far face (the face with the brackets, printed on the bed),
//   so a layer occupies z in [0, LAYER_H].  `unit_node()` maps this frame to the
//   flat shell frame (top layer z in [0, 2.3], bottom layer z in [-2.3, 0]).

BASE_R = {u.base_r:g};          // base disc radius
BASE_TH = {u.base_th:g};         // layer core thickness = side of the square bumper prism
BASE_P = {u.base_p:g};          // base indent below the bumpers, on the membrane side
BRACKET_W = {u.bracket_w:g};       // bracket height (out of plane): the material model's
CLEARANCE = {u.clearance:g};      // printing clearance removed from every bumper tip
ALIGN_R = {u.align_r:g};        // alignment through-hole radius
MARKER_R = {u.marker_r:g};        // marker-dot pocket radius
MARKER_DEPTH = {u.marker_depth:g};    // marker-dot pocket depth from the far face
ALPHA_MARGIN = {u.alpha_margin_deg:g};      // deg, margin added to the rim-clearing bracket angle
APEX_GAP = {t.apex_gap:g};      // actuated preview only: gap between facing arms
LAYER_H = BASE_TH + BASE_P;                           // {u.layer_h:g} mm
ALPHA = asin(BASE_TH / (2 * BASE_R)) + ALPHA_MARGIN;  // arm to cell axis, {u.alpha_deg:g} deg

// Support frame (reference implementation: ring offset +6..+9 mm, 0.5 mm sprues).
FRAME_OFFSET_IN = {f.offset_in:g};   // inner edge of the frame ring, offset from the flat outline
FRAME_OFFSET_OUT = {f.offset_out:g};  // outer edge of the frame ring
CONNECTOR_W = {f.connector_w:g};     // square section of a breakaway connector (on the far face)
CONNECTOR_R0 = {f.connector_r0:g};    // connectors start this far from the base centre

// Faceting.  Every circle of radius r is a regular polygon inscribed in it with
// facets(r) sides (a multiple of 4) and a sagitta (largest distance between
// polygon and circle) of at most FACET_TOL.
FACET_TOL = {t.facet:g};

// Margin by which cutting tools overshoot the faces they cut (avoids coplanar cuts).
CUT_EPS = {t.scad_cut:g};
"""


def params_scad_text(unit: UnitCell = UNIT_CELL, frame: SupportFrame = SUPPORT_FRAME,
                     tols: Tolerances = TOL) -> str:
    """The text of ``scad/params.scad`` for these values."""
    return _TEMPLATE.format(u=unit, f=frame, t=tols)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true",
                    help="exit 1 if scad/params.scad differs from the generated text")
    a = ap.parse_args(argv)
    text = params_scad_text()
    if a.check:
        same = PARAMS_SCAD.read_text() == text
        print(f"{PARAMS_SCAD}: {'up to date' if same else 'OUT OF DATE (make scad-params)'}")
        return 0 if same else 1
    Path(PARAMS_SCAD).write_text(text)
    print(f"wrote {PARAMS_SCAD}")
    return 0


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["params_scad_text", "PARAMS_SCAD", "main"]
