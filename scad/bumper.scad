// morphshell SCAD library: the bumper (the stop that ends a cell's contraction).
include <params.scad>
use <util.scad>

// Function: bumper_trim_plane()
// Usage:
//   [p, n] = bumper_trim_plane(plane_p, plane_n, [clearance]);
// Description:
//   The plane that actually trims a bumper: the ideal contact plane (point
//   plane_p, normal plane_n pointing away from the base) moved back toward the
//   base by `clearance` along its unit normal.  Two facing bumpers thus keep a
//   gap of 2 * clearance (0.1 mm) in the target state.  Returns [point, unit normal].
// Arguments:
//   plane_p = a point of the ideal contact plane, relative to the base centre, mm
//   plane_n = normal of that plane (any length > 0), pointing away from the base
//   clearance = printing clearance, mm. Default: CLEARANCE (0.05)
function bumper_trim_plane(plane_p, plane_n, clearance=CLEARANCE) =
    assert(is_list(plane_p) && len(plane_p) == 3, str("bumper: plane point must be [x,y,z], got ", plane_p))
    assert(is_list(plane_n) && len(plane_n) == 3 && norm(plane_n) > 0,
           str("bumper: plane normal must be a non-zero [x,y,z], got ", plane_n))
    assert(is_num(clearance) && clearance >= 0, str("bumper: clearance must be >= 0 mm, got ", clearance))
    let(n = plane_n / norm(plane_n)) [plane_p - clearance * n, n];

// Function: bumper_points()
// Usage:
//   pts = bumper_points(dir, plane_p, plane_n, [side], [z0], [clearance]);
// Description:
//   The 8 corners of a trimmed bumper (layer-local frame): a square prism of
//   side `side` along the flat direction `dir`, laterally centred on the axis,
//   z in [z0, z0 + side], from the base centre (t = 0) to the trim plane
//   bumper_trim_plane().  Corners 0-3 lie on the start face, 4-7 on the plane,
//   corner i+4 on the axial edge of corner i; corner order (lateral, z):
//   (-,low), (+,low), (+,high), (-,high).
// Arguments:
//   dir = bumper axis direction (flat frame), deg
//   plane_p, plane_n, clearance = see bumper_trim_plane()
//   side = prism side, mm. Default: BASE_TH (2.0)
//   z0 = height of the prism's membrane-side face, mm. Default: BASE_P (0.3)
function bumper_points(dir, plane_p, plane_n, side=BASE_TH, z0=BASE_P, clearance=CLEARANCE) =
    assert(is_num(dir), str("bumper: dir must be a number (deg), got ", dir))
    assert(is_num(side) && side > 0, str("bumper: side must be > 0 mm, got ", side))
    let(pl = bumper_trim_plane(plane_p, plane_n, clearance),
        p = pl[0], n = pl[1],
        u = [cos(dir), sin(dir), 0],
        v = [-sin(dir), cos(dir), 0],
        un = u * n)
    assert(un > 0.1, str("bumper: the trim plane (normal ", n, ") must face away from the base along ",
                         "the axis dir = ", dir, " deg (u.n = ", un, ")"))
    let(corners = [[-side / 2, z0], [side / 2, z0], [side / 2, z0 + side], [-side / 2, z0 + side]],
        start = [for (c = corners) c[0] * v + [0, 0, c[1]]],
        ts = [for (q = start) ((p - q) * n) / un])
    assert(min(ts) > 0, str("bumper: the trim plane cuts the bumper behind the base centre (lengths ", ts, ")"))
    concat(start, [for (i = [0:3]) start[i] + ts[i] * u]);

// Function: bumper_volume()
// Usage:
//   v = bumper_volume(dir, plane_p, plane_n, [side], [z0], [clearance]);
// Description:
//   Volume of bumper() alone (mm^3), closed form: the section side^2 times the
//   mean of the four axial edge lengths (exact for a prism cut by a plane).
function bumper_volume(dir, plane_p, plane_n, side=BASE_TH, z0=BASE_P, clearance=CLEARANCE) =
    let(pts = bumper_points(dir, plane_p, plane_n, side, z0, clearance))
    side * side * (norm(pts[4] - pts[0]) + norm(pts[5] - pts[1]) + norm(pts[6] - pts[2])
                   + norm(pts[7] - pts[3])) / 4;

// Module: bumper()
// Usage:
//   bumper(dir, plane_p, plane_n, [side], [z0], [clearance]);
// Description:
//   Square prism of side `side` (= base_th) along the flat direction `dir`,
//   from the base centre to the trimming plane (point plane_p, normal plane_n,
//   layer-local frame relative to the base centre) moved back by the printing
//   clearance.  The prism spans z in [z0, z0 + side]: it stops base_p short of
//   the membrane and is flush with the far face.  Drawn as the exact convex
//   polyhedron of bumper_points() (no boolean needed).
// Arguments: see bumper_points().
// Example:
//   bumper(0, [3.5, 0, 1.3], [1, 0, 0]);   // flat cell of length 7: vertical cut at l/2
module bumper(dir, plane_p, plane_n, side=BASE_TH, z0=BASE_P, clearance=CLEARANCE) {
    pts = bumper_points(dir, plane_p, plane_n, side, z0, clearance);
    polyhedron(points=pts,
               faces=[[0, 1, 2, 3], [4, 7, 6, 5], [0, 4, 5, 1], [1, 5, 6, 2], [2, 6, 7, 3],
                      [3, 7, 4, 0]]);
}

// Function: bumper_rim_angles()
// Usage:
//   a = bumper_rim_angles(dir, [side], [r]);
// Description:
//   Polar angles (deg) where the two side walls of a bumper along `dir` cross the
//   rim of a base of radius r: dir -+ asin(side / (2 r)) (30 deg off the axis for
//   the paper's 2 mm prism on a 4 mm disc).  For base_phase().
// Arguments:
//   dir = bumper axis direction, deg
//   side = prism side, mm. Default: BASE_TH (2.0)
//   r = base radius, mm. Default: BASE_R (2.0)
function bumper_rim_angles(dir, side=BASE_TH, r=BASE_R) =
    assert(is_num(side) && side > 0 && side < 2 * r,
           str("bumper_rim_angles(): side must be in (0, 2 r) mm, got ", side))
    [dir - asin(side / (2 * r)), dir + asin(side / (2 * r))];
