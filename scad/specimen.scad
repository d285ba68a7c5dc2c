// morphshell SCAD library: unit-cell test specimen (bracket characterisation,
// Supplementary Note 3), built from the same base() and bracket() as the shells.
include <params.scad>
use <util.scad>
use <base.scad>
use <bracket.scad>
use <label.scad>

// Specimen dimensions (reference specimen generator: two 2.5 mm halves, 40 x 5 mm
// handles, pins r 1.00 in holes r 1.04, 0.05 mm gap).
SPEC_HALF_H = 2.5;      // thickness of one half-cell
SPEC_GAP = 0.05;        // gap between the two halves (printed with support, never fused)
SPEC_LENGTH = 40;       // overall length, handle end to handle end
SPEC_WIDTH = 5;         // handle width
SPEC_PIN_R = 1.0;       // alignment pin radius (lower half)
SPEC_HOLE_R = 1.04;     // alignment hole radius (upper half), 0.04 mm radial play
SPEC_PIN_H = 2.0;       // pin height above the lower half's inner face
SPEC_PIN_INSET = 4.0;   // pin axis distance from the handle end
SPEC_LABEL_SIZE = 3;    // label cap height
SPEC_LABEL_H = 0.3;     // label relief height (raised on top) / depth (engraved below)

// Function: specimen_labels()
// Usage:
//   [left, right] = specimen_labels(l, h);
// Description:
//   The two handle labels of a specimen: "L" + central length (mm) and "H" +
//   bracket thickness (mm) without its leading zero, e.g. ["L7", "H.45"].
function specimen_labels(l, h) =
    let(hs = str(h), hx = (h < 1 && hs[0] == "0") ? _tail(hs) : hs) [str("L", l), str("H", hx)];

function _tail(s, i=1) = i >= len(s) ? "" : str(s[i], _tail(s, i + 1));

// Function: specimen_label_centres()
// Usage:
//   [pl, pr] = specimen_label_centres(l, [length], [pin_inset], [pin_r], [base_r]);
// Description: label centres on the left and right handle ([x, y], mm).
function specimen_label_centres(l, length=SPEC_LENGTH, pin_inset=SPEC_PIN_INSET,
                                pin_r=SPEC_PIN_R, base_r=BASE_R) =
    let(x0 = l / 2 + base_r, x1 = length / 2 - pin_inset - pin_r, xm = (x0 + x1) / 2)
    [[-xm, 0], [xm, 0]];

// Module: specimen()
// Usage:
//   specimen(l, h, [half_h], [gap], [length], [width], [label]);
// Description:
//   One unit-cell specimen, assembled as printed (bed at z = 0, cell axis along
//   x, centred on the origin).  Two half-cells stacked with a `gap` between
//   them, like the two layers of a shell on either side of the membrane; each
//   half = two bases (base()) at x = -+l/2, the full bracket rhombus (one flat
//   bracket() from the left base toward the right one, on the half's outer
//   face) and a handle from each base to the specimen end.  The lower half (z in [0, half_h], brackets
//   on the bed) carries a pin on each handle that passes through the gap into
//   a through-hole of the upper half (z in [half_h + gap, 2 half_h + gap]), so
//   the halves stay aligned in the test rig but are separate solids.  Labels
//   ("L<l>" left, "H<h>" right): raised on the upper half's top face and
//   engraved (mirrored, readable from below) in the lower half's bed face.
//   No bumpers: the specimen measures the bracket alone.
// Arguments:
//   l = central length (base-centre distance), mm
//   h = bracket thickness, mm
//   half_h = thickness of one half, mm. Default: SPEC_HALF_H (2.5)
//   gap = gap between the halves, mm. Default: SPEC_GAP (0.05)
//   length = overall length, mm. Default: SPEC_LENGTH (40)
//   width = handle width, mm. Default: SPEC_WIDTH (5)
//   label = [left, right] label strings, or undef for specimen_labels(l, h). Default: undef
// Example:
//   specimen(7, 0.45);
module specimen(l, h, half_h=SPEC_HALF_H, gap=SPEC_GAP, length=SPEC_LENGTH, width=SPEC_WIDTH,
                label=undef) {
    assert(is_num(l) && l > 2 * BASE_R * cos(ALPHA) && l + 4 * BASE_R + 4 * SPEC_PIN_INSET <= length,
           str("specimen(): central length l = ", l, " mm must be in (", 2 * BASE_R * cos(ALPHA),
               ", ", length - 4 * BASE_R - 4 * SPEC_PIN_INSET, "] mm for a ", length, " mm specimen"));
    assert(is_num(h) && h > 0 && h < BRACKET_W,
           str("specimen(): bracket thickness h must be in (0, ", BRACKET_W, ") mm, got ", h));
    assert(is_num(half_h) && half_h > BRACKET_W + SPEC_LABEL_H,
           str("specimen(): half_h must exceed the bracket height + label depth, got ", half_h));
    assert(is_num(gap) && gap >= 0, str("specimen(): gap must be >= 0 mm, got ", gap));
    assert(is_num(width) && width >= 2 * SPEC_HOLE_R + 1, str("specimen(): width too small: ", width));
    labels = is_undef(label) ? specimen_labels(l, h) : label;
    centres = specimen_label_centres(l, length);
    room = 2 * (abs(centres[0][0]) - l / 2 - BASE_R);
    assert(max([for (t = labels) seg7_width(t, SPEC_LABEL_SIZE) - 0.12 * SPEC_LABEL_SIZE]) <= room,
           str("specimen(): labels ", labels, " are longer than the ", room,
               " mm between base and pin; pass a shorter label=[left, right]"));
    pins = [for (s = [-1, 1]) [s * (length / 2 - SPEC_PIN_INSET), 0]];
    // lower half: local z (from the inner face) mirrored so the far face is the bed
    difference() {
        union() {
            translate([0, 0, half_h]) mirror([0, 0, 1]) _specimen_half(l, h, half_h, length, width);
            for (p = pins) translate([p[0], p[1], half_h - CUT_EPS])
                cylinder(r=SPEC_PIN_R, h=SPEC_PIN_H + CUT_EPS, $fn=facets(SPEC_PIN_R));
        }
        for (i = [0, 1]) translate([centres[i][0], centres[i][1], -CUT_EPS])
            mirror([1, 0, 0]) seg7_text(labels[i], SPEC_LABEL_SIZE, SPEC_LABEL_H + CUT_EPS, center=true);
    }
    // upper half: far face on top
    translate([0, 0, half_h + gap]) {
        difference() {
            _specimen_half(l, h, half_h, length, width);
            for (p = pins) translate([p[0], p[1], -CUT_EPS])
                cylinder(r=SPEC_HOLE_R, h=half_h + 2 * CUT_EPS, $fn=facets(SPEC_HOLE_R));
        }
        for (i = [0, 1]) translate([centres[i][0], centres[i][1], half_h - CUT_EPS])
            seg7_text(labels[i], SPEC_LABEL_SIZE, SPEC_LABEL_H + CUT_EPS, center=true);
    }
}

// One half-cell in its local frame (z = 0 inner face, z = half_h far face with the brackets):
// two bases with their handles and the whole bracket rhombus, drawn once from the left base
// (as the owner base of a shell cell draws it, see unit_node()).
module _specimen_half(l, h, half_h, length, width) {
    for (s = [-1, 1]) translate([s * l / 2, 0, 0]) {
        base(height=half_h);
        translate([s > 0 ? 0 : -(length / 2 - l / 2), -width / 2, 0])
            cube([length / 2 - l / 2, width, half_h]);
    }
    translate([-l / 2, 0, 0]) bracket(0, l, h, layer_h=half_h);
}
