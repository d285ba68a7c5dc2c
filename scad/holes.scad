// morphshell SCAD library: alignment hole and marker-dot pocket (cutting tools).
include <params.scad>
use <util.scad>

// Module: alignment_hole()
// Usage:
//   difference() { base(); alignment_hole(); }
// Description:
//   Cutting tool for the through-hole of an alignment base (layer-local frame):
//   a cylinder of radius r on the base axis over the whole layer height plus
//   CUT_EPS beyond both faces.  Push pins through these holes align the two
//   layers on the membrane (Supplementary Note 5).
// Arguments:
//   r = hole radius, mm. Default: ALIGN_R (0.75, i.e. diameter 1.5 mm)
//   height = layer height, mm. Default: LAYER_H (2.3)
module alignment_hole(r=ALIGN_R, height=LAYER_H) {
    assert(is_num(r) && r > 0, str("alignment_hole(): r must be > 0 mm, got ", r));
    assert(r < BASE_R, str("alignment_hole(): r = ", r, " mm must be below the base radius ", BASE_R));
    assert(is_num(height) && height > 0, str("alignment_hole(): height must be > 0 mm, got ", height));
    translate([0, 0, -CUT_EPS]) cylinder(r=r, h=height + 2 * CUT_EPS, $fn=facets(r));
}

// Module: marker_pocket()
// Usage:
//   difference() { base(); marker_pocket(); }
// Description:
//   Cutting tool for the marker-dot pocket (layer-local frame): a cylinder of
//   radius r on the base axis, depth `depth` into the far face (z = height),
//   overshooting the far face by CUT_EPS.  The pocket is filled by the dots of
//   the markers STL (marker_dot()), printed in a second colour and tracked in
//   3D scans.
// Arguments:
//   r = pocket radius, mm. Default: MARKER_R (0.3)
//   depth = pocket depth, mm. Default: MARKER_DEPTH (0.5)
//   height = layer height (z of the far face), mm. Default: LAYER_H (2.3)
module marker_pocket(r=MARKER_R, depth=MARKER_DEPTH, height=LAYER_H) {
    assert(is_num(r) && r > 0, str("marker_pocket(): r must be > 0 mm, got ", r));
    assert(is_num(depth) && depth > 0 && depth < height,
           str("marker_pocket(): depth must be in (0, ", height, ") mm, got ", depth));
    translate([0, 0, height - depth]) cylinder(r=r, h=depth + CUT_EPS, $fn=facets(r));
}

// Module: marker_dot()
// Usage:
//   marker_dot();
// Description:
//   The dot that fills one marker pocket (layer-local frame): the pocket
//   without its overshoot, z in [height - depth, height].
// Arguments: as marker_pocket().
module marker_dot(r=MARKER_R, depth=MARKER_DEPTH, height=LAYER_H) {
    assert(is_num(r) && r > 0, str("marker_dot(): r must be > 0 mm, got ", r));
    assert(is_num(depth) && depth > 0 && depth < height,
           str("marker_dot(): depth must be in (0, ", height, ") mm, got ", depth));
    translate([0, 0, height - depth]) cylinder(r=r, h=depth, $fn=facets(r));
}
