// morphshell SCAD library: the base (the rigid disc glued to the membrane).
include <params.scad>
use <util.scad>

// Function: base_phase()
// Usage:
//   phase = base_phase(angles, [r], [tries]);
// Description:
//   Rotation (deg) of the faceted base (a facets(r)-gon) that keeps the polar
//   angles `angles` (where bracket edges and bumper walls cross the rim:
//   bracket_rim_angles(), bumper_rim_angles()) as far as possible from a polygon
//   vertex: the first best of `tries` rotations spread evenly over one facet, so
//   the choice is deterministic.  A wall crossing the rim within ~1e-5 mm of a
//   vertex leaves vertices so close together in the united layer that an STL's
//   float32 coordinates merge them (non-manifold edges).  With k angles the best
//   rotation keeps every crossing at least 360 / n (1 / (2 k) - 1 / (2 tries)) deg
//   from a vertex (0.065 deg = 2e-3 mm for k = 36, the most a base with 6 cells
//   has, n = 48, tries = 96).  No angles: half a facet (a vertex-free direction
//   for the axes and multiples of 7.5 deg).
// Arguments:
//   angles = polar angles, deg (layer-local frame of the base)
//   r = base radius, mm. Default: BASE_R (2.0)
//   tries = number of candidate rotations. Default: 96
// Example:
//   echo(base_phase([0, 30, 37 + 6.5]));
function base_phase(angles, r=BASE_R, tries=96) =
    assert(is_list(angles), str("base_phase(): angles must be a list of degrees, got ", angles))
    assert(is_num(tries) && tries >= 1, str("base_phase(): tries must be >= 1, got ", tries))
    let(step = 360 / facets(r))
    len(angles) == 0 ? step / 2
    : let(cand = [for (i = [0:tries - 1]) (i + 0.5) * step / tries],
          score = [for (p = cand) min([for (a = angles)
                                          let(x = (a - p) - step * floor((a - p) / step))
                                          min(x, step - x)])],
          best = max(score))
      cand[[for (i = [0:tries - 1]) if (score[i] == best) i][0]];

// Module: base()
// Usage:
//   base([r], [height], [phase]);
// Description:
//   One base of one layer in the layer-local frame: a cylinder of radius r on
//   the membrane plane, from z = 0 (membrane, glued) to z = height (far face,
//   printed on the bed).  Faceted as a facets(r)-gon inscribed in the circle,
//   turned by `phase`: unit_node() passes base_phase() of the directions where
//   its brackets and bumpers cross the rim, so that no wall meets the rim at a
//   vertex (the two would coincide up to rounding and leave near-duplicate
//   vertices that an STL's float32 coordinates merge).
// Arguments:
//   r = base radius, mm. Default: BASE_R (2.0)
//   height = layer height base_th + base_p, mm. Default: LAYER_H (2.3)
//   phase = rotation of the polygon, deg. Default: half a facet (no vertex on the
//       axes or at a multiple of 7.5 deg, where bumper walls and regular cells meet the rim)
// Example:
//   base();   // the paper's 4 mm x 2.3 mm disc
module base(r=BASE_R, height=LAYER_H, phase=undef) {
    assert(is_num(r) && r > 0, str("base(): r must be > 0 mm, got ", r));
    assert(is_num(height) && height > 0, str("base(): height must be > 0 mm, got ", height));
    assert(is_undef(phase) || is_num(phase), str("base(): phase must be a number (deg), got ", phase));
    rotate([0, 0, is_undef(phase) ? 180 / facets(r) : phase]) cylinder(r=r, h=height, $fn=facets(r));
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
