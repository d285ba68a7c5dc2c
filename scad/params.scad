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

BASE_R = 2;          // base disc radius
BASE_TH = 2;         // layer core thickness = side of the square bumper prism
BASE_P = 0.3;          // base indent below the bumpers, on the membrane side
BRACKET_W = 1;       // bracket height (out of plane): the material model's
CLEARANCE = 0.05;      // printing clearance removed from every bumper tip
ALIGN_R = 0.75;        // alignment through-hole radius
MARKER_R = 0.3;        // marker-dot pocket radius
MARKER_DEPTH = 0.5;    // marker-dot pocket depth from the far face
ALPHA_MARGIN = 7;      // deg, margin added to the rim-clearing bracket angle
APEX_GAP = 0.05;      // actuated preview only: gap between facing arms
LAYER_H = BASE_TH + BASE_P;                           // 2.3 mm
ALPHA = asin(BASE_TH / (2 * BASE_R)) + ALPHA_MARGIN;  // arm to cell axis, 37 deg

// Support frame (reference implementation: ring offset +6..+9 mm, 0.5 mm sprues).
FRAME_OFFSET_IN = 6;   // inner edge of the frame ring, offset from the flat outline
FRAME_OFFSET_OUT = 9;  // outer edge of the frame ring
CONNECTOR_W = 0.5;     // square section of a breakaway connector (on the far face)
CONNECTOR_R0 = 1;    // connectors start this far from the base centre

// Faceting.  Every circle of radius r is a regular polygon inscribed in it with
// facets(r) sides (a multiple of 4) and a sagitta (largest distance between
// polygon and circle) of at most FACET_TOL.
FACET_TOL = 0.005;

// Margin by which cutting tools overshoot the faces they cut (avoids coplanar cuts).
CUT_EPS = 0.01;
