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
//   [p0, p1] = support_frame_bar(centre, dir, edge_dist, [r0], [offset_out], [bar_w]);
// Description:
//   Centre line (2D, flat frame) of the breakaway connector of one boundary
//   base: from r0 away from the base centre, along the outward normal `dir` of
//   its boundary edge, to bar_w short of the frame ring's outer edge
//   (edge_dist + offset_out - bar_w from the centre), so it ends inside the ring.
// Arguments:
//   centre = [x, y] base centre, mm
//   dir = outward direction, deg
//   edge_dist = distance from the centre to the boundary edge, mm
//   r0 = start distance from the centre, mm. Default: CONNECTOR_R0 (1)
//   offset_out = ring outer offset, mm. Default: FRAME_OFFSET_OUT (9)
//   bar_w = connector section side, mm. Default: CONNECTOR_W (0.5)
function support_frame_bar(centre, dir, edge_dist, r0=CONNECTOR_R0, offset_out=FRAME_OFFSET_OUT,
                           bar_w=CONNECTOR_W) =
    assert(is_num(edge_dist) && edge_dist > 0,
           str("support_frame_bar(): edge distance must be > 0 mm, got ", edge_dist))
    [centre + r0 * unit2(dir), centre + (edge_dist + offset_out - bar_w) * unit2(dir)];

// Module: support_frame()
// Usage:
//   support_frame(outline, [connectors], [layer], [offset_in], [offset_out], [bar_w], [height]);
// Description:
//   The support frame of one layer in the flat shell frame: a ring between the
//   offsets offset_in and offset_out (rounded) of the flat outline of the
//   stencil, over the layer's height, plus one square breakaway connector of
//   side bar_w per entry of `connectors`, lying on the far face (printed on the
//   bed) and reaching from inside the base into the ring (support_frame_bar()).
// Arguments:
//   outline = flat boundary loop of the stencil, list of [x, y], mm (support_frame.csv)
//   connectors = list of [[x, y] base centre, outward dir (deg), edge distance (mm)]. Default: []
//   layer = "top" (z in [0, height]) or "bottom" (z in [-height, 0]). Default: "top"
//   offset_in = inner ring offset from the outline, mm. Default: FRAME_OFFSET_IN (6)
//   offset_out = outer ring offset, mm. Default: FRAME_OFFSET_OUT (9)
//   bar_w = connector section side, mm. Default: CONNECTOR_W (0.5)
//   height = layer height, mm. Default: LAYER_H (2.3)
module support_frame(outline, connectors=[], layer="top", offset_in=FRAME_OFFSET_IN,
                     offset_out=FRAME_OFFSET_OUT, bar_w=CONNECTOR_W, height=LAYER_H) {
    assert(is_list(outline) && len(outline) >= 3,
           "support_frame(): outline must be a list of at least 3 [x, y] points (mm)");
    assert(abs(polygon_area(outline)) > 0, "support_frame(): the outline has zero area");
    assert(is_num(offset_in) && is_num(offset_out) && 0 < offset_in && offset_in < offset_out,
           str("support_frame(): need 0 < offset_in < offset_out, got ", offset_in, ", ", offset_out));
    assert(is_num(bar_w) && bar_w > 0 && bar_w <= height,
           str("support_frame(): bar_w must be in (0, ", height, "] mm, got ", bar_w));
    assert(layer == "top" || layer == "bottom",
           str("support_frame(): layer must be \"top\" or \"bottom\", got ", layer));
    mirror([0, 0, layer == "top" ? 0 : 1]) {
        linear_extrude(height=height)
            difference() {
                offset(r=offset_out, $fn=facets(offset_out)) polygon(outline);
                offset(r=offset_in, $fn=facets(offset_in)) polygon(outline);
            }
        for (c = connectors) {
            bar = support_frame_bar(c[0], c[1], c[2], offset_out=offset_out, bar_w=bar_w);
            d = bar[1] - bar[0];
            translate([bar[0][0], bar[0][1], height - bar_w])
                rotate([0, 0, atan2(d[1], d[0])])
                    translate([0, -bar_w / 2, 0]) cube([norm(d), bar_w, bar_w]);
        }
    }
}
