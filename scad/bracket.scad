// morphshell SCAD library: the V-shaped bracket (the spring that softens in hot water).
include <params.scad>
use <util.scad>

// Function: bracket_arms()
// Usage:
//   arms = bracket_arms(dir, l, h, [base_r], [alpha], [span]);
// Description:
//   Centre lines of the two arms (k = -1, +1) that a base sends toward one
//   neighbour, in the layer-local frame of the base (2D, mm).  Arm k leaves
//   the base rim at polar angle dir + k*alpha and runs radially (its line passes
//   through the base centre) for lng = l / (2 cos(alpha)) - base_r, so its tip
//   (the apex of the V) lies on the perpendicular bisector of the cell axis, at
//   (l/2, k (l/2) tan(alpha)) in the cell frame: the two bases' arms form a
//   rhombus.  The printed box of an arm starts h inside the base (overlap) and
//   ends (h/2) tan(alpha) + overlap past the apex: at (h/2) tan(alpha) its outer
//   edge meets the outer edge of the neighbour's arm on the bisector (apex
//   closure); the small extra `overlap` (0.01 mm) makes the two arms cross
//   instead of meeting corner to corner, since two corners that coincide only
//   up to rounding (they come from two parts) leave a sliver in the union.
//   With `span` (actuated preview) the arms turn about their roots, away from
//   the axis, by acr = acos((span - 2 base_r cos(alpha)) / (2 lng)) - alpha so
//   that the tips reach span/2 along the axis; the boxes then stop `gap`/2 short
//   of the bisector, so each node of the preview is a separate solid (two
//   rotated parts never meet corner to corner).
//   Returns [[root, tip, start, end], [root, tip, start, end]] for k = -1, +1:
//   root on the rim, tip = apex, [start, end] = centre line of the printed box.
// Arguments:
//   dir = direction of the neighbour's centre (flat frame), deg
//   l = central length: distance of the two base centres in the flat layout, mm
//   h = bracket thickness (in-plane width of an arm), mm
//   base_r = base radius, mm. Default: BASE_R (2.0)
//   alpha = arm angle to the cell axis, deg. Default: ALPHA (37)
//   span = actuated distance of the two centres, mm. Default: undef (flat, as printed)
//   overlap = extra arm length past the apex closure, mm. Default: APEX_OVERLAP (0.01)
//   gap = actuated preview only: gap left between facing arms, mm. Default: APEX_GAP (0.05)
function bracket_arms(dir, l, h, base_r=BASE_R, alpha=ALPHA, span=undef, overlap=APEX_OVERLAP,
                      gap=APEX_GAP) =
    assert(is_num(dir), str("bracket_arms(): dir must be a number (deg), got ", dir))
    assert(is_num(l) && l > 2 * base_r * cos(alpha),
           str("bracket_arms(): central length l = ", l, " mm must exceed 2 base_r cos(alpha) = ",
               2 * base_r * cos(alpha), " mm (the bases would overlap)"))
    assert(is_num(h) && h > 0 && h < base_r,
           str("bracket_arms(): thickness h must be in (0, ", base_r, ") mm, got ", h))
    let(lng = l / (2 * cos(alpha)) - base_r,
        c = is_undef(span) ? 0 : (span - 2 * base_r * cos(alpha)) / (2 * lng))
    assert(c >= -1 && c <= 1,
           str("bracket_arms(): actuated span ", span, " mm is unreachable for l = ", l, " mm"))
    let(acr = is_undef(span) ? 0 : acos(c) - alpha, b = alpha + acr)
    [for (k = [-1, 1])
        let(root = base_r * unit2(dir + k * alpha),
            a = dir + k * b,
            u = unit2(a),
            tip = root + lng * u,
            // flat: apex closure + overlap; actuated: farthest box corner gap/2 before the bisector
            t_end = is_undef(span) ? lng + (h / 2) * tan(b) + overlap
                  : cos(b) < 1e-6 ? lng
                  : min(lng, max(0, (span / 2 - gap / 2 - base_r * cos(alpha) - (h / 2) * sin(b))
                                    / cos(b))))
        [root, tip, root - h * u, root + t_end * u]];

// Function: bracket_volume()
// Usage:
//   v = bracket_volume(l, h, [height], [base_r], [alpha], [overlap]);
// Description: volume of one flat bracket() (two boxes, mm^3), closed form.
function bracket_volume(l, h, height=BRACKET_W, base_r=BASE_R, alpha=ALPHA, overlap=APEX_OVERLAP) =
    2 * h * height * (l / (2 * cos(alpha)) - base_r + h + (h / 2) * tan(alpha) + overlap);

// Module: bracket()
// Usage:
//   bracket(dir, l, h, [height], [base_r], [alpha], [layer_h], [span]);
// Description:
//   The V arm pair that one base of one layer sends toward one neighbour
//   (layer-local frame of the base): two boxes of in-plane width h (the bracket
//   thickness) and height `height`, flush with the far face (z in
//   [layer_h - height, layer_h]), along the centre lines of bracket_arms().
//   The neighbour draws the other half of the rhombus; the boxes overlap at the
//   apexes so the layer is one connected solid.
// Arguments:
//   dir = direction of the neighbour's centre, deg
//   l = central length (flat distance of the base centres), mm
//   h = bracket thickness, mm (0.30-0.65 in the paper's designs)
//   height = bracket height (out of plane), mm. Default: BRACKET_W (1.0)
//   base_r = base radius, mm. Default: BASE_R (2.0)
//   alpha = arm angle to the cell axis, deg. Default: ALPHA (37)
//   layer_h = layer height (z of the far face), mm. Default: LAYER_H (2.3)
//   span = actuated distance of the centres (preview only), mm. Default: undef
//   overlap = extra arm length past the apex closure, mm. Default: APEX_OVERLAP (0.01)
//   gap = gap between facing arms in the actuated preview, mm. Default: APEX_GAP (0.05)
// Example:
//   bracket(0, 7, 0.45);
module bracket(dir, l, h, height=BRACKET_W, base_r=BASE_R, alpha=ALPHA, layer_h=LAYER_H,
               span=undef, overlap=APEX_OVERLAP, gap=APEX_GAP) {
    assert(is_num(height) && height > 0 && height <= layer_h,
           str("bracket(): height must be in (0, ", layer_h, "] mm, got ", height));
    for (arm = bracket_arms(dir, l, h, base_r, alpha, span, overlap, gap)) {
        d = arm[3] - arm[2];
        translate([arm[2][0], arm[2][1], layer_h - height])
            rotate([0, 0, atan2(d[1], d[0])])
                translate([0, -h / 2, 0]) cube([norm(d), h, height]);
    }
}
