// morphshell SCAD library: small vector and frame functions used by the modules.
include <params.scad>

// Function: facets()
// Usage:
//   n = facets(r, [tol]);
// Description:
//   Number of sides of the regular polygon standing for a circle of radius r so
//   that its sagitta r (1 - cos(180/n)) is at most tol.  Rounded up to a multiple
//   of 4, at least 8.
// Arguments:
//   r = circle radius, mm (> 0)
//   tol = largest allowed distance polygon-circle, mm. Default: FACET_TOL (0.005)
function facets(r, tol=FACET_TOL) =
    assert(is_num(r) && r > 0, str("facets(): radius must be > 0 mm, got ", r))
    assert(is_num(tol) && tol > 0, str("facets(): tolerance must be > 0 mm, got ", tol))
    tol >= r ? 8 : max(8, 4 * ceil(180 / acos(1 - tol / r) / 4));

// Function: unit2()
// Usage:
//   u = unit2(angle);
// Description: unit vector of the flat frame at polar angle `angle` (deg).
function unit2(a) = [cos(a), sin(a)];

// Function: to_layer_local()
// Usage:
//   v_local = to_layer_local(v, layer);
// Description:
//   Maps a point or direction given in the flat shell frame (relative to the
//   base centre) to the layer-local frame (z measured from the membrane toward
//   the layer's far face): z is negated for the bottom layer.  Its own inverse.
// Arguments:
//   v = [x, y, z], mm
//   layer = "top" or "bottom"
function to_layer_local(v, layer) =
    assert(layer == "top" || layer == "bottom",
           str("layer must be \"top\" or \"bottom\", got ", layer))
    layer == "top" ? v : [v[0], v[1], -v[2]];

// Function: rotvec_matrix()
// Usage:
//   M = rotvec_matrix(rv, [t]);
// Description:
//   4x4 affine matrix p -> t + R p, R = rotation of the rotation vector rv
//   (axis * angle, radians; Rodrigues' formula), as stored in bases.csv.
// Arguments:
//   rv = [rx, ry, rz], rad
//   t = translation [x, y, z], mm. Default: [0, 0, 0]
function rotvec_matrix(rv, t=[0, 0, 0]) =
    let(th = norm(rv),
        k = th < 1e-12 ? [0, 0, 1] : rv / th,
        c = cos(th * 180 / PI), s = sin(th * 180 / PI), v = 1 - c,
        R = [[c + k[0]*k[0]*v,      k[0]*k[1]*v - k[2]*s, k[0]*k[2]*v + k[1]*s],
             [k[1]*k[0]*v + k[2]*s, c + k[1]*k[1]*v,      k[1]*k[2]*v - k[0]*s],
             [k[2]*k[0]*v - k[1]*s, k[2]*k[1]*v + k[0]*s, c + k[2]*k[2]*v]])
    [[R[0][0], R[0][1], R[0][2], t[0]],
     [R[1][0], R[1][1], R[1][2], t[1]],
     [R[2][0], R[2][1], R[2][2], t[2]],
     [0, 0, 0, 1]];
