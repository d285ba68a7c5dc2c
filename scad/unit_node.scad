// morphshell SCAD library: one node = one base of one layer with its bumpers,
// brackets, marker pocket and alignment hole.  A generated part file calls
// unit_node() once with the node's data (see pysolver/scad_io.py).
include <params.scad>
use <util.scad>
use <base.scad>
use <bumper.scad>
use <bracket.scad>
use <holes.scad>

// Module: unit_node()
// Usage:
//   unit_node(centre, layer, bumpers, brackets, [alignment], [marker], [pose]);
// Description:
//   One base of one layer with everything attached to it, in the flat shell
//   frame (x, y = flat layout, z = 0 membrane mid-plane; top layer z in
//   [0, 2.3], bottom layer z in [-2.3, 0]): the base disc, one bumper per
//   interior neighbour trimmed by its plane (minus the printing clearance), the
//   brackets listed in `brackets`, the marker pocket in the far face and, for
//   alignment bases, the through-hole.  Dimensions are the defaults of base(),
//   bumper(), bracket(), marker_pocket() and alignment_hole(): edit them there
//   (or in params.scad).
//   Flat (as printed) every cell's bracket in a layer has ONE owner, the base
//   with the lower base id (chosen by pysolver/scad_io.py): its node lists the
//   cell and draws the whole bracket (both V's of the rhombus, see bracket());
//   the other base's node does not list it.  Every bracket apex thus lies
//   inside one part, and two nodes join only where a V end crosses the wall of
//   the neighbour's disc.
//   Actuated preview: every cell of the base is listed with its actuated span
//   (4th element), and the node draws its own two arms per cell, opened and
//   stopping short of the neighbour's (each node its own solid).  With `pose`
//   the node is placed in the target shape: p_target = t + R p_local, p_local =
//   flat position relative to the base centre (render.py passes no pose and
//   places the node itself).
// Arguments:
//   centre = [x, y] flat base centre, mm
//   layer = "top" or "bottom"
//   bumpers = list of [dir, plane_p, plane_n]: axis direction (deg, flat frame),
//       a point of the ideal contact plane ([x,y,z] mm, flat shell frame,
//       relative to the base centre) and its normal pointing away from the base
//       (rows of bumpers.csv)
//   brackets = list of [dir, l, h] (flat: the cells this node owns) or
//       [dir, l, h, span, fold] (actuated: every cell of the base): direction of
//       the neighbour (deg), central length l (mm), this layer's bracket
//       thickness h (mm), actuated span (mm), the cell's fold angle (deg,
//       optional, see bracket())
//   alignment = cut the alignment through-hole. Default: false
//   marker = cut the marker pocket. Default: true
//   pose = [rotation vector (rad), target centre [x,y,z] mm] or undef (flat). Default: undef
//   rim = list of [dir, l, h] for EVERY cell of this base in this layer, owned or
//       not: where their bracket edges cross the rim (with the bumper walls) sets
//       the rotation of the base polygon (base_phase()). Default: `brackets`
// Example:
//   unit_node([0, 0], "top", bumpers=[[0, [3.5, 0, 1.3], [1, 0, 0]]], brackets=[[0, 7, 0.45]]);
module unit_node(centre=[0, 0], layer="top", bumpers=[], brackets=[], alignment=false, marker=true,
                 pose=undef, rim=undef) {
    assert(layer == "top" || layer == "bottom",
           str("unit_node(): layer must be \"top\" or \"bottom\", got ", layer));
    assert(is_list(centre) && len(centre) == 2 && is_num(centre[0]) && is_num(centre[1]),
           str("unit_node(): centre must be [x, y] in mm, got ", centre));
    assert(is_list(bumpers) && len([for (b = bumpers) if (!(is_list(b) && len(b) == 3)) 0]) == 0,
           "unit_node(): bumpers must be a list of [dir, plane_p, plane_n]");
    assert(is_list(brackets)
           && len([for (b = brackets) if (!(is_list(b) && (len(b) >= 3 && len(b) <= 5))) 0]) == 0,
           "unit_node(): brackets must be a list of [dir, l, h] or [dir, l, h, span(, fold)]");
    assert(is_undef(pose) || (is_list(pose) && len(pose) == 2 && len(pose[0]) == 3 && len(pose[1]) == 3),
           str("unit_node(): pose must be [rotation vector, target centre] or undef, got ", pose));
    assert(is_undef(rim) || (is_list(rim) && len([for (c = rim) if (!(is_list(c) && len(c) >= 3)) 0]) == 0),
           "unit_node(): rim must be a list of [dir, l, h]");
    phase = base_phase(concat(
        [for (b = bumpers) each bumper_rim_angles(b[0])],
        [for (c = is_undef(rim) ? brackets : rim)
            each bracket_rim_angles(c[0], c[1], c[2], span=len(c) > 3 ? c[3] : undef,
                                    fold=len(c) > 4 ? c[4] : 0)]));
    if (is_undef(pose))
        translate([centre[0], centre[1], 0])
            _unit_node_flat(layer, bumpers, brackets, alignment, marker, phase);
    else
        multmatrix(rotvec_matrix(pose[0], pose[1]))
            _unit_node_flat(layer, bumpers, brackets, alignment, marker, phase);
}

// The node relative to its base centre, in the flat shell frame.
module _unit_node_flat(layer, bumpers, brackets, alignment, marker, phase) {
    mirror([0, 0, layer == "top" ? 0 : 1])
    difference() {
        union() {
            base(phase=phase);
            for (b = bumpers) bumper(b[0], to_layer_local(b[1], layer), to_layer_local(b[2], layer));
            for (b = brackets) bracket(b[0], b[1], b[2], span=len(b) > 3 ? b[3] : undef,
                                         fold=len(b) > 4 ? b[4] : 0);
        }
        if (marker) marker_pocket();
        if (alignment) alignment_hole();
    }
}
