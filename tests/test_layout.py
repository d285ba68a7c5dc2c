"""Layout: scaling rules (closed form), bumpers in 3D and flat (actual geometry), nodes."""

from __future__ import annotations

import numpy as np
import pytest
from _shared import designed

from pysolver import tables
from pysolver.design.cellnodes import bracket_nodes, collision_lengths
from pysolver.design.layout import alignment_bases, build_layout, convex_polygon_distance
from pysolver.errors import InputError
from pysolver.geometry import face_adjacency, rotvec_to_matrix, unit_cells
from pysolver.params import UNIT_CELL as P

H = np.sqrt(3) / 2  # height of the unit equilateral triangle


def two_cells(alpha):
    """Two unit equilateral triangles sharing edge AB, each wing raised by ``alpha`` (rad).

    The angle between the face normals is 2 alpha; for alpha > 0 the +normal side is
    the inside of the V (concave).
    """
    c, s = np.cos(alpha), np.sin(alpha)
    V = np.array([[0, 0, 0], [1, 0, 0], [0.5, H * c, H * s], [0.5, -H * c, H * s]])
    UV = np.array([[0, 0], [1, 0], [0.5, H], [0.5, -H]])
    F = np.array([[0, 1, 2], [1, 0, 3]])
    return V, UV, F


@pytest.mark.parametrize("alpha_deg", [0.0, 10.0, 25.0, -15.0])
def test_scaling_rules_closed_form(alpha_deg):
    a = np.radians(alpha_deg)
    t = abs(np.tan(a))
    V, UV, F = two_cells(a)
    lay = build_layout(V, UV, F)
    # 3D rule: required = r + 2.3 tan(theta) + min_bumper, available = |dFc| / (2 cos) = H/3
    s3 = (P.base_r + P.layer_h * t + P.min_bumper) / (H / 3)
    assert lay.scale3d == pytest.approx(s3, rel=1e-12)
    D = 2 * s3 * H / 3 * np.cos(a)
    assert lay.target_length[0] == pytest.approx(D, rel=1e-8)
    # 2D rule: half flat distance = D / (2 cos) + 2.3 tan + min_gap / 2
    l = 2 * (D / (2 * np.cos(a)) + P.layer_h * t + P.min_gap / 2)
    assert lay.central_length[0] == pytest.approx(l, rel=1e-8)
    assert lay.scale2d == pytest.approx(l / (2 * H / 3), rel=1e-8)
    assert lay.fold_angle_deg[0] == pytest.approx(2 * alpha_deg, abs=1e-6)
    b = lay.bumpers
    concave = 0 if alpha_deg > 0 else 1  # top layer is on the +normal side
    for s in (0, 1):
        sel = b.layer == s
        if alpha_deg != 0 and s == concave:
            # concave side: vertical cut where the far face meets the bisector:
            # bumper = base_r + min_bumper exactly (the critical cell)
            assert set(b.cut[sel]) == {"straight"}
            np.testing.assert_allclose(b.length[sel], P.base_r + P.min_bumper, atol=1e-7)
        else:
            assert set(b.cut[sel]) == {"bisector"}
            # convex side: the two tips are min_gap apart in the flat layout
            np.testing.assert_allclose(l - b.length[sel].sum(), P.min_gap, atol=1e-7)
            # printed: each tip moved back by the clearance along its plane's normal, i.e.
            # by clearance / |n_xy| in the flat plane
            n = b.plane_n[sel] / np.linalg.norm(b.plane_n[sel], axis=1, keepdims=True)
            printed = P.min_gap + np.sum(P.clearance / np.hypot(n[:, 0], n[:, 1]))
            convex_gap = printed
    # the printed gap (what footprint_gaps measures) is the convex side's, >= min_gap + 0.1
    assert lay.gaps.gap.min() == pytest.approx(convex_gap, abs=1e-6)
    assert lay.gaps.gap.min() >= P.min_gap + 2 * P.clearance - 1e-9


def test_layout_refuses_bad_stencils():
    V, UV, F = two_cells(0.2)
    with pytest.raises(InputError, match="inverted"):
        build_layout(V, UV * np.array([1, 1]), np.array([[0, 1, 2], [0, 1, 3]]))
    with pytest.raises(InputError, match="same direction"):
        face_adjacency(np.array([[0, 1, 2], [0, 1, 3]]))
    with pytest.raises(InputError, match="non-manifold edge"):
        face_adjacency(np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]))
    with pytest.raises(InputError, match="no interior edge"):
        build_layout(V[:3], UV[:3], F[:1])
    with pytest.raises(InputError, match="shorter than the min-gap rule"):
        build_layout(V, UV, F, central_length=4.0)


def test_unit_cell_order_and_slots():
    # 2 x 2 grid of squares split in triangles
    X, Y = np.meshgrid(np.arange(3.0), np.arange(3.0))
    np.c_[X.ravel(), Y.ravel(), np.zeros(9)]
    F = []
    for i in range(2):
        for j in range(2):
            a, b, c, d = 3 * i + j, 3 * i + j + 1, 3 * (i + 1) + j, 3 * (i + 1) + j + 1
            F += [[a, b, d], [a, d, c]]
    F = np.array(F)
    ff = face_adjacency(F)
    cells = unit_cells(F, ff)
    # face-major, neighbour > face, each interior edge once
    keys = [(a, j) for a, j in zip(cells.faces[:, 0], cells.slots[:, 0], strict=True)]
    assert keys == sorted(keys) and np.all(cells.faces[:, 0] < cells.faces[:, 1])
    assert len(cells.faces) == 3 * len(F) // 2 - np.sum(ff < 0) // 2
    for (a, b), (ja, jb), (va, vb) in zip(cells.faces, cells.slots, cells.verts, strict=True):
        assert ff[a, ja] == b and ff[b, jb] == a
        assert {va, vb} == {F[a, (ja + 1) % 3], F[a, (ja + 2) % 3]} == \
            {F[b, (jb + 1) % 3], F[b, (jb + 2) % 3]}
    assert np.all(cells.boundary[np.isin(cells.verts, [4]).all(1)] == 0)


def test_alignment_rule():
    C2 = np.array([[0, 0], [100, 0], [50, 40], [50, -40], [5, 0], [50, 35]], float)
    sel = alignment_bases(C2, np.arange(6))
    # farthest pair (0, 1); 4 is within 10 mm of 0; farthest of the rest: 2, 3
    assert sel.tolist() == [0, 1, 2, 3]


def test_convex_polygon_distance():
    sq = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    P = np.stack([sq, sq, sq])
    Q = np.stack([sq + [2.5, 0], sq + [0.5, 0.5], sq + [2, 2]])
    d = convex_polygon_distance(P, Q)
    np.testing.assert_allclose(d, [1.5, 0.0, np.sqrt(2)])


# --------------------------------------------------------------------------------------
# designs: real geometry from the tables


@pytest.fixture(scope="module")
def dome_design(tmp_path_factory):
    return tables.read_design(designed("dome", tmp_path_factory))


@pytest.fixture(scope="module")
def regular_design(tmp_path_factory):
    from pysolver.design import run_design

    out = tmp_path_factory.mktemp("regular")
    run_design("regular", out, progress=False, plots=False)
    return tables.read_design(out)


def _bumper_geometry(d):
    """Tips, planes (target frame) and flat rectangles from the tables alone."""
    b, bs = d.bumpers, d.bases
    R = rotvec_to_matrix(np.c_[bs["rot_x_rad"], bs["rot_y_rad"], bs["rot_z_rad"]])
    Fc = np.c_[bs["target_x_mm"], bs["target_y_mm"], bs["target_z_mm"]]
    i = b["base_id"]
    p_rel = np.c_[b["plane_px"], b["plane_py"], b["plane_pz"]]
    n_rel = np.c_[b["plane_nx"], b["plane_ny"], b["plane_nz"]]
    tip = Fc[i] + np.einsum("kij,kj->ki", R[i], p_rel)
    nrm = np.einsum("kij,kj->ki", R[i], n_rel)
    return R, Fc, tip, nrm


@pytest.mark.parametrize("which", ["dome_design", "regular_design"])
def test_bumpers_meet_in_3d(which, request):
    d = request.getfixturevalue(which)
    b, bs = d.bumpers, d.bases
    _, Fc, tip, nrm = _bumper_geometry(d)
    N = np.c_[bs["normal_x"], bs["normal_y"], bs["normal_z"]]
    hc = P.base_th / 2 + P.base_p
    layer = np.where(b["layer"] == "top", 0, 1)
    for s, sg in ((0, 1.0), (1, -1.0)):
        sel = np.flatnonzero(layer == s)
        by_cell = {}
        for k in sel:
            by_cell.setdefault(b["cell_id"][k], []).append(k)
        assert len(by_cell) == d.n_cells and all(len(v) == 2 for v in by_cell.values())
        for _c, (k0, k1) in by_cell.items():
            i0, i1 = b["base_id"][k0], b["base_id"][k1]
            # the bisector plane of the two layer centres (the ideal contact plane)
            c0, c1 = Fc[i0] + sg * hc * N[i0], Fc[i1] + sg * hc * N[i1]
            m = (c1 - c0) / np.linalg.norm(c1 - c0)
            mid = 0.5 * (c0 + c1)
            for k in (k0, k1):
                # the far-face tip lies on the common contact plane
                assert abs(np.dot(tip[k] - mid, m)) < 1e-6
            # facing tips meet: after the printing clearance on both sides they are at most
            # 2 clearance (+ 0.05 mm) apart along the contact normal, and their 2 mm wide
            # end faces overlap laterally
            sep = abs(np.dot(tip[k1] - tip[k0], m)) + 2 * P.clearance
            assert sep <= 0.05 + 2 * P.clearance + 1e-9
            lat = tip[k1] - tip[k0] - np.dot(tip[k1] - tip[k0], m) * m
            assert np.linalg.norm(lat) < P.base_th / 2
            # concave-side bumpers still stick out at least min_bumper (within 0.05 mm)
            for k in (k0, k1):
                if b["cut"][k] == "straight":
                    assert b["length_mm"][k] >= P.base_r + P.min_bumper - 0.05


@pytest.mark.parametrize("which", ["dome_design", "regular_design"])
def test_flat_gaps_with_manifold3d(which, request):
    """Independent check with exact 2D booleans (manifold3d CrossSection): per layer, the
    printed footprints (disc + bumper rectangles, each bumper shortened by the printing
    clearance, docs/design-folder.md) of different bases, each grown by (min_gap - 1e-3)/2,
    never overlap."""
    from manifold3d import CrossSection, JoinType
    from scipy.spatial import cKDTree

    d = request.getfixturevalue(which)
    b, bs = d.bumpers, d.bases
    C2 = np.c_[bs["flat_x_mm"], bs["flat_y_mm"]]
    grow = (P.min_gap - 1e-3) / 2
    pairs = cKDTree(C2).query_pairs(2 * (P.base_r + 4.0) + P.min_gap)
    for layer in ("top", "bottom"):
        shapes = []
        for i in range(len(C2)):
            # circumscribed 256-gon: contains the disc, exceeds it by < 2e-4 mm
            cs = CrossSection.circle(P.base_r / np.cos(np.pi / 256), 256).translate(tuple(C2[i]))
            for k in np.flatnonzero((b["base_id"] == i) & (b["layer"] == layer)):
                a = np.radians(b["dir_deg"][k])
                u = np.array([np.cos(a), np.sin(a)])
                w = np.array([-u[1], u[0]])
                # far-face length = the longest point of the bumper, as printed
                L = b["length_mm"][k] - P.clearance
                h = P.base_th / 2
                pts = [C2[i] - h * w, C2[i] + L * u - h * w, C2[i] + L * u + h * w,
                       C2[i] + h * w]
                cs = cs + CrossSection([np.array(pts)])
            shapes.append(cs.offset(grow, JoinType.Round, circular_segments=256))
        for i, j in pairs:
            assert (shapes[i] ^ shapes[j]).area() < 1e-6, (layer, i, j)


def test_bracket_nodes_regular(regular_design):
    d = regular_design
    nt, nf = bracket_nodes(d.V, d.UV, d.F)
    assert nt.shape == nf.shape == (d.n_bases, 3, 2, 2, 3)
    cells = unit_cells(d.F)
    # flat: facing nodes are the bracket roots, b = l - 2 r cos(alpha) apart
    a, b_ = cells.faces[:, 0], cells.faces[:, 1]
    ja, jb = cells.slots[:, 0], cells.slots[:, 1]
    for s in (0, 1):
        for q in (0, 1):
            dist = np.linalg.norm(nf[a, ja, q, s] - nf[b_, jb, 1 - q, s], axis=1)
            np.testing.assert_allclose(dist, P.bracket_length(d.cells["central_length_mm"]),
                                       atol=1e-6)
    coll = collision_lengths(nt, cells)
    np.testing.assert_allclose(coll, 4.6 - P.bracket_offset, atol=1e-6)
    np.testing.assert_allclose(d.cells["collision_length_top_mm"], coll[:, 0], atol=1e-8)


def test_bracket_nodes_general(dome_design):
    d = dome_design
    rot = np.c_[d.bases["rot_x_rad"], d.bases["rot_y_rad"], d.bases["rot_z_rad"]]
    nt, nf = bracket_nodes(d.V, d.UV, d.F, rotvec=rot)
    nt2, nf2 = bracket_nodes(d.V, d.UV, d.F)
    np.testing.assert_allclose(nf, nf2, atol=1e-6)  # stored rotation = recomputed one
    C2 = np.c_[d.bases["flat_x_mm"], d.bases["flat_y_mm"]]
    np.testing.assert_allclose(nf[..., 2][:, :, :, 0], P.layer_h, atol=1e-9)
    np.testing.assert_allclose(nf[..., 2][:, :, :, 1], -P.layer_h, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(nf[..., :2] - C2[:, None, None, None], axis=-1),
                               P.base_r, atol=1e-9)
    # k = 0 sits next to F[i, j+1], k = 1 next to F[i, j+2] (target)
    for j in range(3):
        v1, v2 = d.V[d.F[:, (j + 1) % 3]], d.V[d.F[:, (j + 2) % 3]]
        d01 = np.linalg.norm(nt[:, j, 0, 0] - v1, axis=1)
        d02 = np.linalg.norm(nt[:, j, 0, 0] - v2, axis=1)
        assert np.mean(d01 < d02) > 0.95
    # every cell contracts: collision length < flat bracket length
    assert np.all(d.cells["collision_length_top_mm"] < d.cells["bracket_length_mm"])
    assert np.all(d.cells["collision_length_bottom_mm"] < d.cells["bracket_length_mm"])


def test_rotations_map_flat_to_target(dome_design):
    d = dome_design
    bs = d.bases
    R = rotvec_to_matrix(np.c_[bs["rot_x_rad"], bs["rot_y_rad"], bs["rot_z_rad"]])
    N = np.c_[bs["normal_x"], bs["normal_y"], bs["normal_z"]]
    np.testing.assert_allclose(R[:, :, 2], N, atol=1e-8)  # flat +z -> normal
    ff = face_adjacency(d.F)
    nb = ff[np.arange(d.n_bases), bs["ref_slot"]]
    assert np.all(nb >= 0) and np.all(np.argmax(ff >= 0, axis=1) == bs["ref_slot"])
    C2 = np.c_[bs["flat_x_mm"], bs["flat_y_mm"], np.zeros(d.n_bases)]
    Fc = np.c_[bs["target_x_mm"], bs["target_y_mm"], bs["target_z_mm"]]
    u = np.einsum("kij,kj->ki", R, C2[nb] - C2)
    v = Fc[nb] - Fc
    v -= np.sum(v * N, 1)[:, None] * N
    cos = np.sum(u * v, 1) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)
    np.testing.assert_allclose(cos, 1.0, atol=1e-9)


# --------------------------------------------------------------------------------------
# checks


def star(shear=0.0, stretch=1.0):
    """A triangle with three neighbours (4 bases, 3 cells); flat layout = target xy with an
    optional (non-conformal) shear / stretch."""
    V = np.array([[0, 0, 0], [1, 0, 0], [0.5, H, 0], [0.5, -H, 0], [1.5, H, 0], [-0.5, H, 0]])
    F = np.array([[0, 1, 2], [1, 0, 3], [2, 1, 4], [0, 2, 5]])
    UV = V[:, :2] @ np.array([[stretch, 0], [shear, 1.0]])
    return V * 10, UV * 10, F


def test_check_refuses_long_cells_naming_them():
    from pysolver.design.checks import check_layout

    V, UV, F = star(stretch=2.4)
    lay = build_layout(V, UV, F)
    assert lay.central_length.max() > P.max_cell_length
    with pytest.raises(InputError,
                       match=r"longer than 9.5 mm .*on the target: cell \d+ at \(-?\d+\.\d, "):
        check_layout(lay)
    rep = check_layout(lay, raise_=False)
    assert not rep.ok and rep.figures["n_cells_over_limit"] >= 1


def test_check_refuses_flat_overlaps_and_gap_enforcement_fixes_them():
    from pysolver.design.checks import check_layout

    V, UV, F = star(shear=0.8)  # bumpers point off their flat neighbours
    lay = build_layout(V, UV, F, enforce_gap=False)  # closed-form 2D rule only
    assert lay.gaps is None
    from pysolver.design.layout import footprint_gaps

    lay.gaps = footprint_gaps(lay.bumpers, lay.C2)
    assert lay.gaps.gap.min() < P.min_gap
    with pytest.raises(InputError, match=r"in the flat layout .*bases \d+-\d+ \("):
        check_layout(lay)
    fixed = build_layout(V, UV, F)  # default: scale raised until the real gaps are >= min_gap
    assert 0 <= fixed.gaps.gap.min() - P.min_gap <= 1e-5  # (the loop overshoots by 1e-6 mm)
    assert fixed.scale2d > lay.scale2d
    check_layout(fixed)
