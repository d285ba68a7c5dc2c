// morphshell SCAD library: support frame printed around a layer (kept flat during
// fabrication, broken off after gluing).
include <params.scad>
use <util.scad>

// Function: polygon_area()
// Usage:
//   a = polygon_area(poly);
// Description: signed area of a 2D polygon (mm^2), > 0 when counter-clockwise.
function polygon_area(poly) =
    let(n = len(poly))
    0.5 * sum_list([for (i = [0:n - 1]) let(p = poly[i], q = poly[(i + 1) % n])
                    p[0] * q[1] - q[0] * p[1]]);

function sum_list(v, i=0) = i >= len(v) ? 0 : v[i] + sum_list(v, i + 1);

// Function: support_frame_bar()
// Usage:
//   [p0, p1] = support_frame_bar(centre, dir, length, [r0]);
// Description:
//   Centre line (2D, flat frame) of the breakaway connector of one boundary
//   base: from r0 away from the base centre, along the outward normal `dir` of
//   its boundary edge, to `length` from the centre.  The length is data, one per
//   connector (pysolver.scad_io.ring_reach): the connector ends in the middle of
//   the frame ring along its own direction, which in a concave notch of the
//   outline is farther than the ring's offset from the base's own edge.
// Arguments:
//   centre = [x, y] base centre, mm
//   dir = outward direction, deg
//   length = distance from the centre to the connector's end, mm (> r0)
//   r0 = start distance from the centre, mm. Default: CONNECTOR_R0 (1)
// Example:
//   b = support_frame_bar([1, 2], 90, 12.5);   // [[1, 3], [1, 14.5]]
function support_frame_bar(centre, dir, length, r0=CONNECTOR_R0) =
    assert(is_num(length) && length > r0,
           str("support_frame_bar(): connector length must be > r0 = ", r0, " mm, got ", length))
    [centre + r0 * unit2(dir), centre + length * unit2(dir)];

// Module: support_frame()
// Usage:
//   support_frame(outline, [connectors], [layer], [offset_in], [offset_out], [bar_w], [height], [holes]);
// Description:
//   The support frame of one layer in the flat shell frame: a ring between the
//   offsets offset_in and offset_out (rounded) of the flat outline of the
//   stencil, over the layer's height, plus one square breakaway connector of
//   side bar_w per entry of `connectors`, lying on the far face (printed on the
//   bed) and reaching from inside the base into the ring (support_frame_bar();
//   the lengths are computed for offset_in/offset_out by pysolver.scad_io).
//   `holes` are filled in the inner offset: where a notch of the outline is
//   wider inside than at its mouth, the inner offset has a hole and the ring
//   would get a loose island around it (pysolver.scad_io.frame_holes).
// Arguments:
//   outline = flat boundary loop of the stencil, list of [x, y], mm (support_frame.csv)
//   connectors = list of [[x, y] base centre, outward dir (deg), length from the centre (mm)]. Default: []
//   layer = "top" (z in [0, height]) or "bottom" (z in [-height, 0]). Default: "top"
//   offset_in = inner ring offset from the outline, mm. Default: FRAME_OFFSET_IN (6)
//   offset_out = outer ring offset, mm. Default: FRAME_OFFSET_OUT (9)
//   bar_w = connector section side, mm. Default: CONNECTOR_W (0.5)
//   height = layer height, mm. Default: LAYER_H (2.3)
//   holes = polygons (lists of [x, y], mm) added to the inner offset. Default: []
// Example:
//   support_frame([[0, 0], [40, 0], [40, 30], [0, 30]], [[[20, 2], -90, 9.5]]);
module support_frame(outline, connectors=[], layer="top", offset_in=FRAME_OFFSET_IN,
                     offset_out=FRAME_OFFSET_OUT, bar_w=CONNECTOR_W, height=LAYER_H, holes=[]) {
    assert(is_list(outline) && len(outline) >= 3,
           "support_frame(): outline must be a list of at least 3 [x, y] points (mm)");
    assert(abs(polygon_area(outline)) > 0, "support_frame(): the outline has zero area");
    assert(is_num(offset_in) && is_num(offset_out) && 0 < offset_in && offset_in < offset_out,
           str("support_frame(): need 0 < offset_in < offset_out, got ", offset_in, ", ", offset_out));
    assert(is_num(bar_w) && bar_w > 0 && bar_w <= height,
           str("support_frame(): bar_w must be in (0, ", height, "] mm, got ", bar_w));
    assert(is_list(holes) && len([for (h = holes) if (!is_list(h) || len(h) < 3) 1]) == 0,
           "support_frame(): holes must be a list of polygons of at least 3 [x, y] points");
    assert(layer == "top" || layer == "bottom",
           str("support_frame(): layer must be \"top\" or \"bottom\", got ", layer));
    mirror([0, 0, layer == "top" ? 0 : 1]) {
        linear_extrude(height=height)
            difference() {
                offset(r=offset_out, $fn=facets(offset_out)) polygon(outline);
                union() {
                    offset(r=offset_in, $fn=facets(offset_in)) polygon(outline);
                    for (h = holes) polygon(h);
                }
            }
        for (c = connectors) {
            bar = support_frame_bar(c[0], c[1], c[2]);
            d = bar[1] - bar[0];
            translate([bar[0][0], bar[0][1], height - bar_w])
                rotate([0, 0, atan2(d[1], d[0])])
                    translate([0, -bar_w / 2, 0]) cube([norm(d), bar_w, bar_w]);
        }
    }
}
