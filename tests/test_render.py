"""Render stage: STLs of a small regular patch measured against the design tables.

One module-scoped render of ``run_design(regular(rows=2, cols=3))`` (12 bases,
15 cells) with bracket thicknesses varied per cell and layer (as the temporal
stage would write them), cold cache in a temp folder.  Tolerances: bounding
boxes 0.05 mm (``tol.stl_bbox``), base centres and bracket thicknesses 0.02 mm,
node volume against an independent cadquery model 1 % (symmetric difference).
Faceting: circles are inscribed polygons with sagitta <= 0.005 mm.
"""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest
from _shared import section_width

from pysolver import tables
from pysolver.errors import ExternalToolError, InputError
from pysolver.geometry import apply_transform, print_transform
from pysolver.params import LAYERS, SIM, UNIT_CELL, layer_sign, tol
from pysolver.render import from_manifold, load_stl, render_design, solids, to_manifold
from pysolver.render import parts as render
from pysolver.render.scad_io import SCAD_DIR

U = UNIT_CELL
ALPHA = math.radians(U.alpha_deg)


def _design(folder):
    from pysolver.design import run_design
    from pysolver.design.surfaces import regular

    run_design(regular(rows=2, cols=3), folder, progress=False)
    cells = tables.read_table(folder, "cells")
    k = np.arange(len(cells["cell_id"]))
    cells["thickness_top_mm"] = 0.30 + 0.05 * (k % 8)
    cells["thickness_bottom_mm"] = 0.65 - 0.05 * (k % 8)
    tables.write_table(folder, "cells", cells)
    return folder


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("render")
    design = _design(root / "design")
    cache = root / "cache"
    summary = render_design(design, cache_dir=cache, progress=False)
    d = tables.read_design(design)
    stl = {k: load_stl(p) for k, p in summary["stl"].items()}
    return dict(dir=design, cache=cache, summary=summary, d=d, stl=stl)


# ------------------------------------------------------------------------------------------
# geometry helpers


def _to_print(P2, layer):
    P = np.c_[P2, np.zeros(len(P2))]
    return apply_transform(print_transform(layer), P)[:, :2]


def _slice(mesh, z):
    """Horizontal section at height z: (k, 2, 2) segments."""
    import trimesh

    seg = trimesh.intersections.mesh_plane(mesh, [0, 0, 1], [0, 0, z])
    return np.asarray(seg)[:, :, :2]


def _loops(seg):
    """Group section segments into closed loops; returns a list of (k, 2) point arrays."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    P = seg.reshape(-1, 2)
    keys, inv = np.unique(np.round(P / 1e-6).astype(np.int64), axis=0, return_inverse=True)
    inv = inv.ravel()
    e = inv.reshape(-1, 2)
    n = len(keys)
    A = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    ncomp, lab = connected_components(A, directed=False)
    pts = np.zeros((n, 2))
    pts[inv] = P
    return [pts[lab == c] for c in range(ncomp)]


def _fit_circle(P):
    """Algebraic (Kasa) least-squares circle: centre (2,), radius."""
    A = np.c_[2 * P, np.ones(len(P))]
    sol, *_ = np.linalg.lstsq(A, (P ** 2).sum(1), rcond=None)
    c = sol[:2]
    return c, math.sqrt(sol[2] + c @ c)


def _arms(d, layer):
    """Every printed arm: (cell row, flat midpoint (2,), unit direction (2,), thickness)."""
    C = np.c_[d.bases["flat_x_mm"], d.bases["flat_y_mm"]]
    out = []
    for c, (a, b) in enumerate(zip(d.cells["base_a"], d.cells["base_b"], strict=True)):
        h = d.cells[f"thickness_{layer}_mm"][c]
        l = d.cells["central_length_mm"][c]
        for i, j in ((a, b), (b, a)):
            v = C[j] - C[i]
            ang = math.atan2(v[1], v[0])
            for k in (-1, 1):
                u = np.array([math.cos(ang + k * ALPHA), math.sin(ang + k * ALPHA)])
                mid = C[i] + (U.base_r + l / (2 * math.cos(ALPHA))) / 2 * u
                out.append((c, mid, u, h))
    return out


# ------------------------------------------------------------------------------------------
# outputs


def test_summary_and_part_files(built):
    s, d = built["summary"], built["d"]
    n = d.n_bases
    assert s["parts_by_kind"] == {"node": 2 * n, "actuated": 2 * n, "frame": 2, "marker": 1}
    assert s["rendered"] == s["parts"] and s["cached"] == 0
    assert s["seconds_per_part"] > 0
    files = sorted((built["dir"] / "scad").glob("*.scad"))
    assert len(files) == s["parts"]
    for f in files:
        code = [ln for ln in f.read_text().splitlines() if ln and not ln.startswith("//")]
        assert code[0].startswith("use <" + SCAD_DIR.as_posix())   # library by path
        body = "\n".join(code[1:])
        assert body.count(");") == 1 and "module" not in body        # data + one call


def test_each_flat_bracket_has_one_owner(built):
    """Flat nodes list every cell once per layer, at the lower base id, pointing at the other
    base (its whole bracket); actuated nodes list every cell of their base (own arms)."""
    from pysolver.render.scad_io import bracket_owner, node_arguments

    d = built["d"]
    ids = [int(b) for b in d.bases["base_id"]]
    C = {b: np.array([d.bases["flat_x_mm"][r], d.bases["flat_y_mm"][r]]) for r, b in enumerate(ids)}
    cells = {frozenset((int(a), int(b))): (float(l), float(ht), float(hb))
             for a, b, l, ht, hb in zip(d.cells["base_a"], d.cells["base_b"],
                                       d.cells["central_length_mm"], d.cells["thickness_top_mm"],
                                       d.cells["thickness_bottom_mm"], strict=True)}
    assert bracket_owner(7, 3) == bracket_owner(3, 7) == 3
    for layer in LAYERS:
        drawn = []
        for b in ids:
            for dir_, l, h in node_arguments(d, b, layer)["brackets"]:
                ang = math.radians(dir_)
                far = C[b] + l * np.array([math.cos(ang), math.sin(ang)])
                dist = {j: np.linalg.norm(C[j] - far) for j in ids}
                nb = min(dist, key=dist.get)
                assert dist[nb] < 1e-3 and b < nb
                lc, ht, hb = cells[frozenset((b, nb))]
                assert (l, h) == pytest.approx((lc, ht if layer == "top" else hb), abs=1e-9)
                drawn.append(frozenset((b, nb)))
        assert sorted(map(sorted, drawn)) == sorted(map(sorted, cells))      # each cell once
        n_act = sum(len(node_arguments(d, b, layer, actuated=True)["brackets"]) for b in ids)
        assert n_act == 2 * len(cells)


def test_every_stl_is_watertight_and_single(built):
    s, d = built["summary"], built["d"]
    for key, mesh in built["stl"].items():
        assert mesh.is_watertight and mesh.is_volume, key
        assert s["watertight"][key], key
    for key in ("top", "bottom", "support_frame_top", "support_frame_bottom"):
        assert len(built["stl"][key].split(only_watertight=True)) == 1, key
        assert s["bodies"][key] == 1, key
    # the actuated preview: every node a separate solid (arms stop 0.05 mm short of each
    # other, layers a membrane thickness apart)
    assert len(built["stl"]["actuated"].split(only_watertight=True)) == 2 * d.n_bases
    assert s["bodies"]["actuated"] == 2 * d.n_bases
    n_dots = int((~d.bases["alignment"].astype(bool)).sum())
    for layer in LAYERS:   # one separate dot per non-alignment base
        assert s["bodies"][f"markers_{layer}"] == n_dots
        dot = math.pi * U.marker_r ** 2 * U.marker_depth
        facet_bound = 2 * math.pi * U.marker_r * tol.facet * U.marker_depth
        assert 0 < n_dots * dot - s["volumes_mm3"][f"markers_{layer}"] <= n_dots * facet_bound


def test_layer_bounding_box_matches_table(built):
    """bbox = base discs (flat centre +- r) and the outer corners of the bracket rhombi.

    A rhombus corner (the outer apex of a mitred V) lies on the cell's bisector at
    (l/2) tan(alpha) + (h/2)/cos(alpha) from the axis; on the patch's boundary it sticks
    out past the discs (vertical cells).
    """
    d = built["d"]
    C = np.c_[d.bases["flat_x_mm"], d.bases["flat_y_mm"]]
    for layer in LAYERS:
        pts = [C + U.base_r * np.array(e) for e in ((1, 0), (-1, 0), (0, 1), (0, -1))]
        for c, (a, b) in enumerate(zip(d.cells["base_a"], d.cells["base_b"], strict=True)):
            v = C[b] - C[a]
            l = np.linalg.norm(v)
            perp = np.array([-v[1], v[0]]) / l
            h = d.cells[f"thickness_{layer}_mm"][c]
            off = l / 2 * math.tan(ALPHA) + h / 2 / math.cos(ALPHA)
            pts.append((C[a] + v / 2)[None] + np.array([off, -off])[:, None] * perp)
        P = _to_print(np.vstack(pts), layer)
        lo, hi = np.r_[P.min(0), 0.0], np.r_[P.max(0), U.layer_h]
        b = built["stl"][layer].bounds
        assert b[0] == pytest.approx(lo, abs=tol.stl_bbox), layer
        assert b[1] == pytest.approx(hi, abs=tol.stl_bbox), layer
        assert np.array(built["summary"]["bbox_mm"][layer]) == pytest.approx(b, abs=1e-5)


def test_support_frame_bounding_box(built):
    out = built["d"].support
    for layer in LAYERS:
        P = _to_print(out, layer)
        b = built["stl"][f"support_frame_{layer}"].bounds
        off = 9.0   # FRAME_OFFSET_OUT
        assert b[0, :2] == pytest.approx(P.min(0) - off, abs=tol.stl_bbox)
        assert b[1, :2] == pytest.approx(P.max(0) + off, abs=tol.stl_bbox)
        assert b[:, 2] == pytest.approx([0, U.layer_h], abs=1e-4)


def test_base_centres_from_section(built):
    """Section through the 0.3 mm indent (only base discs there): fitted circles = bases.csv."""
    d = built["d"]
    C = np.c_[d.bases["flat_x_mm"], d.bases["flat_y_mm"]]
    z = U.layer_h - U.base_p / 2          # print frame: membrane face at z = 2.3
    for layer in LAYERS:
        fits = [_fit_circle(P) for P in _loops(_slice(built["stl"][layer], z))]
        discs = np.array([c for c, r in fits if abs(r - U.base_r) < 0.05])
        holes = [c for c, r in fits if abs(r - U.align_r) < 0.05]
        assert len(discs) == d.n_bases
        assert len(holes) == int(d.bases["alignment"].sum())
        P = _to_print(C, layer)
        dist = np.linalg.norm(P[:, None] - discs[None], axis=2)
        assert dist.min(1).max() < 0.02, layer
        assert len(set(dist.argmin(1))) == d.n_bases


def test_bracket_thickness_from_section(built):
    """Section at bracket mid-height; width across each arm at its midpoint = cells.csv."""
    d = built["d"]
    z = U.bracket_w / 2                   # print frame: far face (brackets) on the bed
    for layer in LAYERS:
        seg = _slice(built["stl"][layer], z)
        T = print_transform(layer)[:2, :2]
        for c, mid, u, h in _arms(d, layer):
            m = _to_print(mid[None], layer)[0]
            w = T @ np.array([-u[1], u[0]])
            width = section_width(seg, m, w)
            assert width == pytest.approx(h, abs=0.02), (layer, c)
        # above the bracket height only bases and bumpers remain: no arm there
        seg = _slice(built["stl"][layer], U.bracket_w + 0.1)
        _c, mid, u, _h = _arms(d, layer)[0]
        m = _to_print(mid[None], layer)[0]
        assert section_width(seg, m, T @ np.array([-u[1], u[0]])) is None


def test_actuated_preview_places_bases_on_target(built):
    """The regular patch's target is flat: indent section of each layer (0.15 mm off its
    membrane face, which is membrane_h/2 = 0.25 mm off the mid-plane)."""
    d = built["d"]
    mesh = built["stl"]["actuated"]
    m2 = SIM.membrane_h / 2
    for z in (m2 + U.base_p / 2, -(m2 + U.base_p / 2)):
        fits = [_fit_circle(P) for P in _loops(_slice(mesh, z))]
        discs = np.array([c for c, r in fits if abs(r - U.base_r) < 0.05])
        T = np.c_[d.bases["target_x_mm"], d.bases["target_y_mm"]]
        assert len(discs) == d.n_bases
        dist = np.linalg.norm(T[:, None] - discs[None], axis=2)
        assert dist.min(1).max() < 0.02
    assert mesh.bounds[:, 2] == pytest.approx([-U.layer_h - m2, U.layer_h + m2], abs=1e-4)


def test_node_agrees_with_independent_cadquery_model(built):
    """One node per layer rebuilt with cadquery from the tables: symmetric difference < 1 %."""
    import cadquery as cq

    from pysolver.render.scad_io import Part

    d = built["d"]
    # an interior base (3 neighbours) and an alignment base (through-hole, 2 neighbours)
    deg = np.bincount(np.r_[d.cells["base_a"], d.cells["base_b"]], minlength=d.n_bases)
    picks = [int(np.flatnonzero(deg == 3)[0]), int(np.flatnonzero(d.bases["alignment"])[0])]
    for base in picks:
        for layer in LAYERS:
            name = f"node_{layer}_{base:04d}"
            part = Part(name, "node", layer, base, built["dir"] / "scad" / f"{name}.scad")
            res = render.render_parts([part], cache_dir=built["cache"], progress=False)
            assert res["cached"] == 1                  # the part STL the layer was built from
            a = to_manifold(load_stl(res["stl"][name]))
            b = to_manifold(_cadquery_node(cq, d, base, layer))
            sym = (a - b).volume() + (b - a).volume()
            assert sym < 0.01 * a.volume(), (base, layer, sym, a.volume())
            # the faceted (inscribed) circles make the OpenSCAD node the smaller one
            assert a.volume() < b.volume()


def _cadquery_node(cq, d, base, layer):
    """Independent model of one node (flat shell frame) from the tables, as a trimesh."""
    import trimesh

    s = layer_sign(layer)
    c = np.array([d.bases["flat_x_mm"][base], d.bases["flat_y_mm"][base]])

    def zr(a, b):   # layer-local heights a < b -> flat-frame z range
        return (a, b) if s > 0 else (-b, -a)

    def prism(origin, udir, length, width, za, zb, start=0.0):
        z0, z1 = zr(za, zb)
        pl = cq.Plane(origin=(origin[0], origin[1], z0), xDir=(udir[0], udir[1], 0),
                      normal=(0, 0, 1))
        return (cq.Workplane(pl).center(start + length / 2, 0).rect(length, width)
                .extrude(z1 - z0))

    z0, z1 = zr(0, U.layer_h)
    node = cq.Workplane("XY").workplane(offset=z0).center(*c).circle(U.base_r).extrude(z1 - z0)
    bm = d.bumpers
    for k in np.flatnonzero((bm["base_id"] == base) & (bm["layer"] == layer)):
        ang = math.radians(bm["dir_deg"][k])
        u = np.array([math.cos(ang), math.sin(ang)])
        pr = prism(c, u, 20.0, U.base_th, U.base_p, U.layer_h)
        n = np.array([bm["plane_nx"][k], bm["plane_ny"][k], bm["plane_nz"][k]])
        n /= np.linalg.norm(n)
        p = np.array([bm["plane_px"][k] + c[0], bm["plane_py"][k] + c[1], bm["plane_pz"][k]])
        p = p - U.clearance * n
        xd = np.cross(n, [0, 0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0, 0])
        cutter = cq.Workplane(cq.Plane(origin=tuple(p), xDir=tuple(xd), normal=tuple(n))) \
            .rect(60, 60).extrude(60)
        node = node.union(pr.cut(cutter))
    C = np.c_[d.bases["flat_x_mm"], d.bases["flat_y_mm"]]
    zb0, zb1 = zr(U.layer_h - U.bracket_w, U.layer_h)
    for cid in np.flatnonzero((d.cells["base_a"] == base) | (d.cells["base_b"] == base)):
        a, b = int(d.cells["base_a"][cid]), int(d.cells["base_b"][cid])
        if base != min(a, b):
            continue                # the lower base id draws the whole bracket of the cell
        l = d.cells["central_length_mm"][cid]
        h = d.cells[f"thickness_{layer}_mm"][cid]
        # each base's two arms: strips of width h from h inside its rim, radial at +-alpha,
        # cut by the cell's perpendicular bisector (the mitre of each V)
        for p0, p1 in ((C[a], C[b]), (C[b], C[a])):
            v = (p1 - p0) / l
            ang = math.atan2(v[1], v[0])
            half = cq.Workplane(cq.Plane(origin=(*(p0 + v * l / 2), zb0), xDir=(-v[1], v[0], 0),
                                         normal=(0, 0, 1))).center(0, 10).rect(40, 20) \
                .extrude(zb1 - zb0)           # the half plane toward p0
            for k in (-1, 1):
                u = np.array([math.cos(ang + k * ALPHA), math.sin(ang + k * ALPHA)])
                arm = prism(p0, u, l, h, U.layer_h - U.bracket_w, U.layer_h,
                            start=U.base_r - h)
                node = node.union(arm.intersect(half))
    zp0, zp1 = zr(U.layer_h - U.marker_depth, U.layer_h + 0.1)
    node = node.cut(cq.Workplane("XY").workplane(offset=zp0).center(*c)
                    .circle(U.marker_r).extrude(zp1 - zp0))
    if d.bases["alignment"][base]:
        node = node.cut(cq.Workplane("XY").workplane(offset=-3).center(*c)
                        .circle(U.align_r).extrude(6))
    verts, tris = node.val().tessellate(0.001, 0.05)
    return trimesh.Trimesh(np.array([v.toTuple() for v in verts]), np.array(tris))


# ------------------------------------------------------------------------------------------
# cache, library edits, errors


def test_warm_render_uses_the_cache(built):
    s = render_design(built["dir"], cache_dir=built["cache"], progress=False)
    assert s["rendered"] == 0 and s["cached"] == s["parts"]
    assert s["volumes_mm3"] == pytest.approx(built["summary"]["volumes_mm3"], rel=1e-9)


def test_editing_a_module_default_changes_the_build(built, tmp_path):
    """A temp copy of scad/ with bracket() height 1.2 instead of 1: no Python edit involved."""
    lib = tmp_path / "scad"
    shutil.copytree(SCAD_DIR, lib)
    src = (lib / "bracket.scad").read_text()
    sig = "module bracket(dir, l, h, height=BRACKET_W,"
    assert sig in src
    (lib / "bracket.scad").write_text(src.replace(sig, "module bracket(dir, l, h, height=1.2,"))
    design = tmp_path / "design"
    design.mkdir()
    for f in ("bases.csv", "cells.csv", "bumpers.csv", "support_frame.csv", "stencil.obj",
              "time_landscape.csv", "design.json"):
        shutil.copy(built["dir"] / f, design / f)
    s = render_design(design, cache_dir=built["cache"], scad_dir=lib, actuated=False,
                      progress=False)
    assert s["cached"] == 0 and s["rendered"] == s["parts"]     # every key changed
    mesh = load_stl(s["stl"]["top"])
    seg = _slice(mesh, 1.1)                                      # between 1.0 and 1.2
    T = print_transform("top")[:2, :2]
    for c, mid, u, h in _arms(built["d"], "top")[:8]:
        m = _to_print(mid[None], "top")[0]
        assert section_width(seg, m, T @ np.array([-u[1], u[0]])) == pytest.approx(h, abs=0.02), c
    assert s["volumes_mm3"]["top"] > built["summary"]["volumes_mm3"]["top"]


def test_failing_part_is_named_and_others_stay_cached(built, tmp_path):
    lib = tmp_path / "scad"
    shutil.copytree(SCAD_DIR, lib)
    src = (lib / "unit_node.scad").read_text()
    anchor = "                 pose=undef, rim=undef) {\n"
    bad = anchor + '    assert(centre[0] < 0, "test: refusing x >= 0");\n'
    (lib / "unit_node.scad").write_text(src.replace(anchor, bad))
    cache = tmp_path / "cache"
    with pytest.raises(ExternalToolError) as e:
        render_design(built["dir"], cache_dir=cache, scad_dir=lib, actuated=False,
                      progress=False)
    d = built["d"]
    x = d.bases["flat_x_mm"]
    failing = np.flatnonzero(x >= 0)
    msg = str(e.value)
    assert f"failed on {2 * len(failing)} of" in msg
    assert f"base {failing[0]}, top layer" in msg and "test: refusing x >= 0" in msg
    # the parts that rendered are cached: nodes with x < 0 (both layers), 2 frames, 1 marker
    assert len(list(cache.glob("*.stl"))) == 2 * int((x < 0).sum()) + 3


def test_missing_openscad_says_how_to_install(built, monkeypatch):
    monkeypatch.setenv(render.OPENSCAD_ENV, "/nonexistent/openscad")
    with pytest.raises(ExternalToolError, match="apt-get install openscad"):
        render_design(built["dir"], cache_dir=built["cache"], progress=False)


def test_bad_thickness_is_an_input_error(built, tmp_path):
    design = tmp_path / "design"
    shutil.copytree(built["dir"], design, ignore=shutil.ignore_patterns("stl", "scad"))
    cells = tables.read_table(design, "cells")
    cells["thickness_bottom_mm"][3] = 0.0
    tables.write_table(design, "cells", cells)
    with pytest.raises(InputError, match="thickness_bottom_mm"):
        render_design(design, cache_dir=built["cache"], progress=False)


def test_union_helpers_round_trip(built):
    m = to_manifold(built["stl"]["top"])
    back = from_manifold(m)
    assert back.volume == pytest.approx(built["stl"]["top"].volume, rel=1e-9)


def test_count_bodies_matches_decompose():
    """``count_bodies`` (edge-connected triangles of the mesh) counts the solids that
    ``Manifold.decompose`` splits a union into: two touching cubes are one body, a third
    apart from them another, an empty solid none."""
    import manifold3d

    cube = manifold3d.Manifold.cube([1.0, 1.0, 1.0])
    cubes = [cube, cube.translate([0.5, 0.0, 0.0]), cube.translate([3.0, 0.0, 0.0]),
              manifold3d.Manifold.sphere(0.5, 24).translate([0.0, 5.0, 0.0])]
    m = solids.union(cubes)
    assert solids.count_bodies(m) == len(m.decompose()) == 3
    assert solids.count_bodies(solids.union([])) == 0


def test_stl_export_welds_what_float32_merges(tmp_path):
    """A closed mesh with two vertices 1e-9 mm apart (a tetrahedron with a vertex split in
    two, joined by two sliver triangles): written as it is, the STL's float32 merges them
    and the slivers leave edges of three or four triangles; :func:`as_float32` welds them
    and drops the slivers, and the file is watertight with the same volume."""
    import trimesh

    from pysolver.render.solids import as_float32
    A, B, C, D = [0.3, 0.2, 0.1], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 0.0, 10.0]
    A2 = [0.3 + 1e-9, 0.2, 0.1]
    V = np.array([A, B, C, D, A2])
    F = np.array([[0, 4, 1], [4, 2, 1], [4, 3, 2], [0, 3, 4], [0, 1, 3], [1, 2, 3]])
    raw = trimesh.Trimesh(V, F, process=False)
    assert raw.is_watertight  # in float64
    raw.export(tmp_path / "raw.stl")
    assert not trimesh.load(tmp_path / "raw.stl", force="mesh").is_watertight
    as_float32(raw).export(tmp_path / "welded.stl")
    m = trimesh.load(tmp_path / "welded.stl", force="mesh")
    assert m.is_watertight and m.is_volume and len(m.faces) == 4
    assert m.volume == pytest.approx(abs(raw.volume), rel=1e-6)
