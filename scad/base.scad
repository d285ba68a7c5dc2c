// morphshell SCAD library: the base (the rigid disc glued to the membrane).
include <params.scad>
use <util.scad>

// Module: base()
// Usage:
//   base([r], [height]);
// Description:
//   One base of one layer in the layer-local frame: a cylinder of radius r on
//   the membrane plane, from z = 0 (membrane, glued) to z = height (far face,
//   printed on the bed).  Faceted as a facets(r)-gon inscribed in the circle,
//   turned by half a facet so that no vertex lies on the axes or at a multiple
//   of 7.5 deg: a bumper wall (half-width base_th/2 = r/2) meets the rim 30 deg
//   off the bumper axis, and cells point in multiples of 30 deg in regular
//   patches, so with a vertex there the two would coincide up to rounding and
//   leave near-duplicate vertices that an STL's float32 coordinates merge.
// Arguments:
//   r = base radius, mm. Default: BASE_R (2.0)
//   height = layer height base_th + base_p, mm. Default: LAYER_H (2.3)
// Example:
//   base();   // the paper's 4 mm x 2.3 mm disc
module base(r=BASE_R, height=LAYER_H) {
    assert(is_num(r) && r > 0, str("base(): r must be > 0 mm, got ", r));
    assert(is_num(height) && height > 0, str("base(): height must be > 0 mm, got ", height));
    rotate([0, 0, 180 / facets(r)]) cylinder(r=r, h=height, $fn=facets(r));
}

// Function: base_volume()
// Usage:
//   v = base_volume([r], [height], [n]);
// Description:
//   Volume of base() (mm^3).  With n = undef (default) the exact faceted
//   volume (n = facets(r)); with n = 0 the ideal cylinder pi r^2 height.
function base_volume(r=BASE_R, height=LAYER_H, n=undef) =
    let(m = is_undef(n) ? facets(r) : n)
    m == 0 ? PI * r * r * height : m / 2 * r * r * sin(360 / m) * height;
