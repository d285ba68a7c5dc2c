// morphshell SCAD library: the labels of the timing coupon (pysolver/coupon.py).
// The coupon itself is a shell (a strip of unit cells) drawn by unit_node(); this
// file only draws the numbers engraved in its top layer, one per base.
include <params.scad>
use <label.scad>

// Module: coupon_labels()
// Usage:
//   coupon_labels(labels, [size], [stroke], [depth], [height]);
// Description:
//   The cutting solids of the base numbers, in the flat shell frame of the top
//   layer (z in [0, height], far face at z = height): each label's seven-segment
//   text, centred on its base centre, from `depth` below the far face to just
//   above it.  Python subtracts them from the top layer, so after the bath (far
//   face up) each base shows its number, read from above; a cell is named by its
//   two bases ("3-4").
// Arguments:
//   labels = list of [text, [x, y]]: text (0-9) and base centre (flat frame, mm)
//   size = cap height, mm. Default: 1.6 (two digits fit a 4 mm base)
//   stroke = segment width, mm. Default: 0.3
//   depth = engraving depth, mm. Default: 0.3
//   height = layer height (far face), mm. Default: LAYER_H
// Example:
//   coupon_labels([["12", [0, 0]]]);
module coupon_labels(labels, size=1.6, stroke=0.3, depth=0.3, height=LAYER_H) {
    assert(is_list(labels), "coupon_labels(): labels must be a list of [text, [x, y]]");
    assert(is_num(depth) && depth > 0 && depth < height,
           str("coupon_labels(): depth must be in (0, ", height, ") mm, got ", depth));
    for (l = labels)
        translate([l[1][0], l[1][1], height - depth])
            seg7_text(l[0], size, depth + CUT_EPS, stroke, center=true);
}
