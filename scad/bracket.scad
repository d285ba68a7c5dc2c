// morphshell SCAD library: the V-shaped bracket (the spring that softens in hot water).
include <params.scad>
use <util.scad>

// Function: bracket_arms()
// Usage:
//   arms = bracket_arms(dir, l, h, [base_r], [alpha], [span], [gap]);
// Description:
//   Centre lines of the two arms (k = -1, +1) that a base sends toward one
//   neighbour, in the layer-local frame of the base (2D, mm).  Arm k leaves
//   the base rim at polar angle dir + k*alpha and runs radially (its line passes
//   through the base centre) for lng = l / (2 cos(alpha)) - base_r, so its tip
//   (the apex of the V) lies on the perpendicular bisector of the cell axis, at
//   (l/2, k (l/2) tan(alpha)) in the cell frame: the two bases' arms form a
//   rhombus.  The printed arm starts h inside the base (it is anchored in the
//   disc, not glued to its rim); flat (as printed) its centre line ends at the
//   apex, where bracket_outline() mitres it with the facing arm.
//   With `span` (actuated preview) the arms turn about their roots, away from
//   the axis, by acr = acos((span - 2 base_r cos(alpha)) / (2 lng)) - alpha so
//   that the tips reach span/2 along the axis; the boxes then stop `gap`/2 short
//   of the bisector, so each node of the preview is a separate solid (two
//   rotated parts never meet corner to corner).
//   Returns [[root, tip, start, end], [root, tip, start, end]] for k = -1, +1:
//   root on the rim, tip = apex, [start, end] = centre line of the printed arm
//   (flat: end = tip; actuated: the centre line of the printed box).
// Arguments:
//   dir = direction of the neighbour's centre (flat frame), deg
//   l = central length: distance of the two base centres in the flat layout, mm
//   h = bracket thickness (in-plane width of an arm), mm
//   base_r = base radius, mm. Default: BASE_R (2.0)
//   alpha = arm angle to the cell axis, deg. Default: ALPHA (37)
//   span = actuated distance of the two centres, mm. Default: undef (flat, as printed)
//   gap = actuated preview only: gap left between facing arms, mm. Default: APEX_GAP (0.05)
function bracket_arms(dir, l, h, base_r=BASE_R, alpha=ALPHA, span=undef, gap=APEX_GAP) =
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
            // flat: up to the apex (mitred there); actuated: farthest box corner gap/2
            // before the bisector
            t_end = is_undef(span) ? lng
                  : cos(b) < 1e-6 ? lng
                  : min(lng, max(0, (span / 2 - gap / 2 - base_r * cos(alpha) - (h / 2) * sin(b))
                                    / cos(b))))
        [root, tip, root - h * u, root + t_end * u]];

// Function: bracket_outline()
// Usage:
//   pts = bracket_outline(dir, l, h, side, [base_r], [alpha]);
// Description:
//   Outline of one flat V of the bracket rhombus (2D polygon, 6 points, mm) in
//   the layer-local frame of the base at the origin, the neighbour's centre
//   being at l unit2(dir): the arm of this base on side `side` (bracket_arms()
//   index k = side) and the facing arm of the neighbour (its k = -side), each of
//   width h about its centre line, joined by an exact mitre.  Points, in order:
//   this arm's root-end corners (inner, outer; h inside this base's rim along
//   the centre line, the end perpendicular to the arm), the outer apex (the
//   intersection of the two outer edge lines, on the bisector at
//   (l/2) tan(alpha) + (h/2) / cos(alpha) from the axis), the neighbour arm's
//   root-end corners (outer, inner; h inside the neighbour's rim) and the inner
//   apex (the intersection of the two inner edge lines, at
//   (l/2) tan(alpha) - (h/2) / cos(alpha)).  "Outer" = away from the cell axis.
//   Area 2 h (lng + h), lng = l / (2 cos(alpha)) - base_r: each half is a strip
//   of width h whose centre line runs lng + h from its root end to the mitre.
// Arguments:
//   dir = direction of the neighbour's centre, deg
//   l = central length, mm
//   h = bracket thickness, mm
//   side = -1 or +1: side of the cell axis (the V of arm k = side of this base)
//   base_r = base radius, mm. Default: BASE_R (2.0)
//   alpha = arm angle to the cell axis, deg. Default: ALPHA (37)
// Example:
//   linear_extrude(1) polygon(bracket_outline(0, 7, 0.45, 1));
function bracket_outline(dir, l, h, side, base_r=BASE_R, alpha=ALPHA) =
    assert(side == -1 || side == 1, str("bracket_outline(): side must be -1 or +1, got ", side))
    let(mine = bracket_arms(dir, l, h, base_r, alpha)[(side + 1) / 2],
        far = bracket_arms(dir + 180, l, h, base_r, alpha)[(1 - side) / 2],
        c = l * unit2(dir),
        // start point, unit direction and outward offset (h/2, away from the axis) of each arm;
        // the neighbour's arm has index -side in its own frame, so its outward side is -side
        a0 = mine[2], au = _unit(mine[1] - mine[0]), ao = side * (h / 2) * _left(au),
        b0 = c + far[2], bu = _unit(far[1] - far[0]), bo = -side * (h / 2) * _left(bu))
    [a0 - ao, a0 + ao, _line_cross(a0 + ao, au, b0 + bo, bu),
     b0 + bo, b0 - bo, _line_cross(a0 - ao, au, b0 - bo, bu)];

// Function: bracket_volume()
// Usage:
//   v = bracket_volume(l, h, [height], [base_r], [alpha]);
// Description:
//   Volume of one flat bracket() (the whole rhombus: two V's, mm^3), closed form:
//   2 x 2 h (lng + h) x height, lng = l / (2 cos(alpha)) - base_r (see bracket_outline()).
// Arguments:
//   l = central length, mm
//   h = bracket thickness, mm
//   height = bracket height, mm. Default: BRACKET_W (1.0)
//   base_r = base radius, mm. Default: BASE_R (2.0)
//   alpha = arm angle to the cell axis, deg. Default: ALPHA (37)
function bracket_volume(l, h, height=BRACKET_W, base_r=BASE_R, alpha=ALPHA) =
    4 * h * height * (l / (2 * cos(alpha)) - base_r + h);

// Module: bracket()
// Usage:
//   bracket(dir, l, h, [height], [base_r], [alpha], [layer_h], [span], [gap]);
// Description:
//   The bracket of one cell in one layer, drawn from the base at the origin
//   (layer-local frame) toward the neighbour at l unit2(dir), height `height`,
//   flush with the far face (z in [layer_h - height, layer_h]).
//   Flat (span = undef, as printed): the WHOLE bracket, i.e. both V's of the
//   rhombus, each one linear_extrude() of bracket_outline(): every apex lies
//   inside one solid, and the V's far ends are anchored h deep in the
//   neighbour's disc.  Only one of the two bases of a cell draws it (its owner,
//   see unit_node()), so two parts join only where a V end crosses the wall of
//   the neighbour's disc.
//   Actuated (span given, preview only): this base's own two arms, as boxes of
//   width h along the opened centre lines of bracket_arms(), stopping gap/2
//   short of the bisector; every base draws its own arms.
// Arguments:
//   dir = direction of the neighbour's centre, deg
//   l = central length (flat distance of the base centres), mm
//   h = bracket thickness, mm (0.30-0.65 in the paper's designs)
//   height = bracket height (out of plane), mm. Default: BRACKET_W (1.0)
//   base_r = base radius, mm. Default: BASE_R (2.0)
//   alpha = arm angle to the cell axis, deg. Default: ALPHA (37)
//   layer_h = layer height (z of the far face), mm. Default: LAYER_H (2.3)
//   span = actuated distance of the centres (preview only), mm. Default: undef
//   gap = gap between facing arms in the actuated preview, mm. Default: APEX_GAP (0.05)
//   fold = actuated preview only: the cell's fold angle, deg. The two nodes of a
//       folded cell are turned by `fold` against each other, so the end faces of
//       facing arms close (concave side) by up to 2 layer_h tan(|fold| / 2) over
//       the layer height; the arms stop that much shorter as well, so facing arms
//       never touch (their end faces would cross at the small angle `fold`, and
//       the union would keep vertices too close for a float32 STL). Default: 0
// Example:
//   bracket(0, 7, 0.45);
module bracket(dir, l, h, height=BRACKET_W, base_r=BASE_R, alpha=ALPHA, layer_h=LAYER_H,
               span=undef, gap=APEX_GAP, fold=0) {
    assert(is_num(height) && height > 0 && height <= layer_h,
           str("bracket(): height must be in (0, ", layer_h, "] mm, got ", height));
    if (is_undef(span)) {
        for (side = [-1, 1])
            translate([0, 0, layer_h - height])
                linear_extrude(height) polygon(bracket_outline(dir, l, h, side, base_r, alpha));
    } else {
        assert(is_num(fold) && abs(fold) < 90,
               str("bracket(): fold must be an angle in (-90, 90) deg, got ", fold));
        for (arm = bracket_arms(dir, l, h, base_r, alpha, span,
                                bracket_preview_gap(gap, fold, layer_h))) {
            d = arm[3] - arm[2];
            translate([arm[2][0], arm[2][1], layer_h - height])
                rotate([0, 0, atan2(d[1], d[0])])
                    translate([0, -h / 2, 0]) cube([norm(d), h, height]);
        }
    }
}

// Function: bracket_preview_gap()
// Usage:
//   g = bracket_preview_gap(gap, fold, [layer_h]);
// Description:
//   Gap (mm) between the opened arms of facing nodes in the actuated preview:
//   `gap` plus 2 layer_h tan(|fold| / 2), what the end faces of the two nodes of
//   a cell folded by `fold` (deg) close by over the layer height (see bracket()).
// Arguments:
//   gap = gap of an unfolded cell, mm
//   fold = the cell's fold angle, deg
//   layer_h = layer height, mm. Default: LAYER_H (2.3)
function bracket_preview_gap(gap, fold, layer_h=LAYER_H) = gap + 2 * layer_h * tan(abs(fold) / 2);

// Function: bracket_rim_angles()
// Usage:
//   a = bracket_rim_angles(dir, l, h, [base_r], [alpha], [span], [gap], [fold]);
// Description:
//   Polar angles (deg, layer-local frame of the base) where the side edges of
//   the two arms that this base's bracket toward `dir` anchors in its disc cross
//   the rim: flat, the arms of bracket_arms() (radial, so the same whether this
//   base owns the bracket or its neighbour does); with `span`, the opened arms of
//   the actuated preview.  Each edge is the line of the arm's side, h/2 off its
//   centre line, starting inside the disc; the angle is that of its first
//   crossing of the circle of radius base_r.  For base_phase().
// Arguments:
//   dir, l, h, base_r, alpha, span, gap, fold = see bracket()
function bracket_rim_angles(dir, l, h, base_r=BASE_R, alpha=ALPHA, span=undef, gap=APEX_GAP,
                            fold=0, layer_h=LAYER_H) =
    let(arms = bracket_arms(dir, l, h, base_r, alpha, span,
                            is_undef(span) ? gap : bracket_preview_gap(gap, fold, layer_h)))
    [for (arm = arms, w = [-h / 2, h / 2])
        let(u = _unit(arm[3] - arm[2]),
            q = arm[2] + w * _left(u),
            qu = q * u,
            t = -qu + sqrt(max(0, qu * qu - (q * q - base_r * base_r))),
            p = q + t * u)
        atan2(p[1], p[0])];

// 2D helpers: unit vector, left normal, and the crossing of the lines p + s u and q + t v.
function _unit(v) = v / norm(v);
function _left(u) = [-u[1], u[0]];
function _line_cross(p, u, q, v) =
    let(den = u[0] * v[1] - u[1] * v[0])
    assert(abs(den) > 1e-9, "bracket_outline(): the two arms are parallel")
    p + ((q - p)[0] * v[1] - (q - p)[1] * v[0]) / den * u;
