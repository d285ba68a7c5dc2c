"""Built-in shapes, time landscapes, user meshes and stencils, bad-input catalogue."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from _shared import designed, flat_grid, quick_stencil_search, save_mesh

from pysolver import tables
from pysolver.design import run_design, surfaces
from pysolver.design.mesh_input import load_input, validate_surface
from pysolver.design.time_landscape import evaluate_expression, resolve_time
from pysolver.errors import InputError

# golden figures of the default built-in designs: (bases, max cell length mm); the remeshed
# shapes come from the automatic vertex-count search (nothing tuned per shape).  Compared
# within issue #42's tolerances for the same surface on another machine: bases 3 %, longest
# flat cell 0.15 mm, which every built-in shape keeps under five relabellings, a rigid motion
# and a 1e-7 jitter here (``bench/bench_stability.py``, ``docs/results.md``).
GOLDEN = {
    "regular": (60, 7.0),
    "mechtest": (120, 7.0),
    "dome": (110, 7.39),
    "saddle": (113, 7.11),
    "petal": (175, 9.22),
    "spiral": (214, 7.83),
    "weave": (255, 5.85),
}
BASES_RTOL, CELL_ATOL_MM = 0.03, 0.15


@pytest.mark.parametrize("name", list(surfaces.BUILTIN))
def test_builtin_surface_is_a_disk(name):
    s = surfaces.builtin(name)
    validate_surface(s.V, s.F, name)  # one connected, manifold, oriented disk in mm
    assert s.time is not None
    t = s.time(s.V)
    assert t.shape == (len(s.V),) and np.all(np.isfinite(t)) and t.min() >= 0
    assert t.max() <= 120


@pytest.mark.parametrize("name", list(surfaces.BUILTIN))
def test_builtin_designs_and_passes_checks(name, tmp_path_factory):
    folder = designed(name, tmp_path_factory)   # run_design(name, plots=False), shared
    summary = json.loads((folder / "design.json").read_text())["summary"]
    assert summary["checks"]["ok"], summary["checks"]
    bases, lmax = GOLDEN[name]
    assert summary["counts"]["bases"] == pytest.approx(bases, rel=BASES_RTOL)
    assert summary["cell_length_mm"]["max"] == pytest.approx(lmax, abs=CELL_ATOL_MM)
    assert summary["cell_length_mm"]["max"] <= 9.5
    assert summary["checks"]["figures"].get("min_flat_gap_mm", 0.1) >= 0.1 - 1e-6
    d = tables.read_design(folder)
    assert d.n_bases == summary["counts"]["bases"]
    assert 1 <= summary["counts"]["alignment_bases"] <= 4
    # every cell contracts from flat to target
    assert np.all(d.cells["target_length_mm"] < d.cells["central_length_mm"])
    assert np.all((d.time >= 0) & (d.time <= 120))


def test_shape_options_and_errors():
    assert surfaces.is_builtin("weave:large") and not surfaces.is_builtin("teapot")
    big = surfaces.builtin("dome:size=1.5")
    small = surfaces.builtin("dome")
    assert np.ptp(big.V, axis=0)[0] == pytest.approx(1.5 * np.ptp(small.V, axis=0)[0], rel=0.02)
    with pytest.raises(InputError, match="unknown shape"):
        surfaces.builtin("teapot")
    with pytest.raises(InputError, match="bad option"):
        surfaces.builtin("dome:colour=3")
    with pytest.raises(InputError, match="must be a number"):
        surfaces.builtin("dome:size=big")
    large = surfaces.builtin("weave:large")
    assert len(large.F) == 551 and large.UV is not None  # lattice stencil: no remeshing
    assert np.ptp(large.V[:, 2]) == pytest.approx(2 * 58.0, abs=1e-6)  # top arm: radius 58


# --------------------------------------------------------------------------------------
# default time landscapes encode the intended order


def test_petal_small_petals_close_first():
    s = surfaces.builtin("petal")
    az = np.arctan2(s.V[:, 1], s.V[:, 0])
    tip = np.hypot(s.V[:, 0], s.V[:, 1]) > 0  # all
    t = s.time(s.V)
    w_large = 0.5 + 0.5 * np.cos(3 * az)
    lifted = s.V[:, 2] > 10
    assert t[lifted & (w_large > 0.9) & tip].min() > t[lifted & (w_large < 0.1)].max()
    assert t[s.V[:, 2] == 0].min() <= t.min() + 1e-9  # the flat centre first


def test_weave_arms_in_order():
    s = surfaces.builtin("weave")
    t = s.time(s.V)
    # the returning parts lie exactly at z = 2 R_k (R = 30, 39, 48 mm): arm 0 lowest
    ret = [np.abs(s.V[:, 2] - 2 * R) < 1e-9 for R in (30.0, 39.0, 48.0)]
    assert all(r.sum() > 10 for r in ret)
    np.testing.assert_allclose([t[r].mean() for r in ret], [45, 65, 85], atol=1e-6)
    assert t.min() == pytest.approx(30.0)


def test_weave_is_an_isometric_lattice():
    """The weave's stencil is the lattice itself: equilateral faces in the flat layout,
    lengths kept by the (developable) lift within the chord error of the bends."""
    s = surfaces.builtin("weave")
    E = np.r_[s.F[:, [0, 1]], s.F[:, [1, 2]], s.F[:, [2, 0]]]
    l2 = np.linalg.norm(s.UV[E[:, 0]] - s.UV[E[:, 1]], axis=1)
    l3 = np.linalg.norm(s.V[E[:, 0]] - s.V[E[:, 1]], axis=1)
    np.testing.assert_allclose(l2, 13.0, rtol=1e-9)
    # a chord of arc length 13 mm on the tightest bend (R = 30 mm): 2 R sin(13 / 2R)
    assert l3.min() >= 2 * 30.0 * np.sin(13.0 / 60.0) - 1e-9 and l3.max() <= 13.0 + 1e-9
    # the stacked returning parts keep 2 x 9 mm between them
    z = np.unique(np.round(s.V[:, 2][s.V[:, 2] > 59.9], 9))
    assert {60.0, 78.0, 96.0} <= set(z)


# --------------------------------------------------------------------------------------
# time landscape sources


def test_time_expression_and_safety():
    V = np.array([[0.0, 0, -10], [3, 4, 0], [0, 0, 10]])
    np.testing.assert_allclose(evaluate_expression("30 + 0.5*z", V), [25, 30, 35])
    np.testing.assert_allclose(evaluate_expression("40 + clip(r, 0, 4)", V), [40, 44, 40])
    np.testing.assert_allclose(evaluate_expression("where(z > 0, 60, 30)", V), [30, 30, 60])
    for bad, msg in [("__import__('os')", "only the listed functions"),
                     ("x.__class__", "Attribute is not allowed"),
                     ("open('f')", "only the listed functions"),
                     ("[1, 2]", "List is not allowed"),
                     ("'a'", "only numbers are allowed"), ("30 +", "syntax error")]:
        with pytest.raises(InputError, match=msg):
            evaluate_expression(bad, V)
    t, desc = resolve_time("45", V)
    assert np.all(t == 45) and "constant" in desc
    with pytest.raises(InputError, match="negative time"):
        resolve_time("10*z", V)
    with pytest.raises(InputError, match="NaN"):
        resolve_time([1.0, np.nan, 2.0], V)
    with pytest.raises(InputError, match="2 values"):
        resolve_time([1.0, 2.0], V)
    with pytest.raises(InputError, match="needs an input mesh"):
        resolve_time("vertex", V)


@pytest.fixture(scope="module")
def dome_ply(tmp_path_factory):
    """The procedural dome exported as PLY with a per-vertex 'quality' = 30 + |z| and
    grey vertex colours = how far from the centre."""
    from trimesh.exchange.ply import export_ply

    s = surfaces.builtin("dome")
    m = trimesh.Trimesh(s.V, s.F, process=False)
    m.vertex_attributes["quality"] = 30 + np.abs(s.V[:, 2])
    r = np.hypot(s.V[:, 0], s.V[:, 1])
    g = (255 * r / r.max()).astype(np.uint8)
    m.visual.vertex_colors = np.c_[g, g, g, np.full_like(g, 255)]
    p = tmp_path_factory.mktemp("in") / "dome.ply"
    p.write_bytes(export_ply(m, include_attributes=True))
    return p


def test_user_mesh_with_vertex_times(dome_ply, tmp_path, monkeypatch):
    quick_stencil_search(monkeypatch)   # the subject is the landscape, not the optimisation
    summary = run_design(dome_ply, tmp_path / "a", time="vertex:quality", vertices=60, seed=0,
                         progress=False, plots=False)
    assert summary["checks"]["ok"] and summary["source_kind"] == "mesh"
    d = tables.read_design(tmp_path / "a")
    # quality = 30 + depth below the rim; the stencil is centred and scaled (scale3d)
    s3 = summary["scale"]["scale3d"]
    depth = (d.V[:, 2].max() - d.V[:, 2]) / s3
    assert np.corrcoef(depth, d.time)[0, 1] > 0.999
    assert d.time.min() >= 30 - 1e-6
    summary = run_design(dome_ply, tmp_path / "b", time="color:30:90", vertices=60, seed=0,
                         progress=False, plots=False)
    d = tables.read_design(tmp_path / "b")
    r = np.hypot(d.V[:, 0], d.V[:, 1])
    assert np.corrcoef(r, d.time)[0, 1] > 0.99 and 29 < d.time.min() and d.time.max() < 91
    with pytest.raises(InputError, match="no vertex property 'speed'"):
        run_design(dome_ply, tmp_path / "c", time="vertex:speed", vertices=60, seed=0,
                   progress=False, plots=False)


def _obj_with_uv(path, V, UV, F, marker: bool = False):
    """An OBJ as modelling tools export it: ``v``, ``vt`` and ``f v/vt`` corners."""
    lines = [tables.STENCIL_MARKER + ": test"] if marker else ["# exported"]
    lines += ["v {:.9g} {:.9g} {:.9g}".format(*p) for p in V]
    lines += ["vt {:.9g} {:.9g}".format(*p) for p in UV]
    lines += ["f " + " ".join(f"{i + 1}/{i + 1}" for i in f) for f in F]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_mesh_with_a_uv_map_is_a_target_surface(tmp_path):
    """A UV map is a texture layout: the mesh is a target unless --stencil or the marker."""
    s = surfaces.builtin("dome")
    # a texture layout that is a valid flat layout too: the UV map alone decides nothing
    src = _obj_with_uv(tmp_path / "textured.obj", s.V, s.V[:, :2] / 100 + 0.5, s.F)
    m = load_input(src)
    assert m.kind == "mesh" and m.UV is None and len(m.F) == len(s.F)
    assert any("UV map (vt) ignored" in n and "--stencil" in n for n in m.notes)
    m = load_input(src, stencil=True)
    assert m.kind == "stencil" and np.allclose(m.UV, s.V[:, :2] / 100 + 0.5, atol=1e-8)
    m = load_input(_obj_with_uv(tmp_path / "own.obj", s.V, s.V[:, :2], s.F, marker=True))
    assert m.kind == "stencil" and np.allclose(m.UV, s.V[:, :2], atol=1e-6)


def test_stencil_with_an_invalid_flat_layout_names_the_target_route(tmp_path):
    s = surfaces.builtin("dome")
    UV = s.V[:, :2].copy()
    UV[:len(UV) // 2, 0] *= -1  # half of the layout mirrored: triangles of both orientations
    src = _obj_with_uv(tmp_path / "textured.obj", s.V, UV, s.F)
    with pytest.raises(InputError, match=r"flat triangles are inverted") as e:
        run_design(src, tmp_path / "out", stencil=True, progress=False, plots=False)
    assert "without --stencil" in e.value.fix
    with pytest.raises(InputError, match=r"stencil marker") as e:
        run_design(_obj_with_uv(tmp_path / "own.obj", s.V, UV, s.F, True), tmp_path / "o2",
                   progress=False, plots=False)
    assert "marker" in e.value.fix
    assert not (tmp_path / "out").exists() and not (tmp_path / "o2").exists()


def test_user_stencil_keeps_vertex_and_face_order(tmp_path, tmp_path_factory):
    """A stencil OBJ (v target, vt flat) is used as is: same vertex and face order."""
    out = designed("dome", tmp_path_factory)
    V, UV, F = tables.read_stencil(out / "stencil.obj")
    rng = np.random.default_rng(7)
    pv = rng.permutation(len(V))  # new vertex k = old vertex pv[k]
    inv = np.argsort(pv)
    pf = rng.permutation(len(F))
    F2 = inv[F[pf]]
    F2 = np.roll(F2, 1, axis=1)  # also rotate the corners
    src = tmp_path / "mine.obj"
    tables.write_stencil(src, V[pv], UV[pv], F2)
    summary = run_design(src, tmp_path / "mine", progress=False, plots=False)
    assert summary["source_kind"] == "stencil"
    V3, UV3, F3 = tables.read_stencil(tmp_path / "mine" / "stencil.obj")
    assert np.array_equal(F3, F2)
    np.testing.assert_allclose(V3, V[pv] - V[pv].mean(0), atol=1e-5)  # already at scale
    # the flat layout is the same up to a uniform scale: rotating the face corners changes
    # the reference neighbours, hence the bumper directions and the critical flat gap
    U0 = UV[pv] - UV[pv].mean(0)
    k = np.sum(UV3 * U0) / np.sum(U0 * U0)
    assert abs(k - 1) < 0.01
    np.testing.assert_allclose(UV3, k * U0, atol=1e-5)
    d = tables.read_design(tmp_path / "mine")
    assert np.array_equal(np.c_[d.bases["v0"], d.bases["v1"], d.bases["v2"]], F2)


# --------------------------------------------------------------------------------------
# bad input catalogue


def _bad_meshes(tmp):
    V, F = flat_grid()
    n = 8
    cases = {}
    (tmp / "empty.obj").write_text("")
    cases["empty"] = (tmp / "empty.obj", "empty file")
    (tmp / "junk.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n")
    cases["corrupt"] = (tmp / "junk.ply", "cannot read|no triangles")
    (tmp / "shape.xyz").write_text("1 2 3\n")
    cases["format"] = (tmp / "shape.xyz", "unsupported format '.xyz'")
    Vn = np.vstack([V, [[20, 20, 10]]])
    Fn = np.vstack([F, [[0, 1, len(V)]]])  # a third face on boundary edge (0,1)... fin
    Fn = np.vstack([Fn, [[1, 0, len(V)]]])
    cases["nonmanifold"] = (save_mesh(tmp / "nm.obj", Vn, Fn), "non-manifold edge")
    V2 = np.vstack([V, V + [100, 0, 0]])
    F2 = np.vstack([F, F + len(V)])
    cases["components"] = (save_mesh(tmp / "two.obj", V2, F2), "2 separate pieces")
    hole = np.array([k for k, f in enumerate(F) if not np.all(np.isin(f, [27, 28, 35, 36]))])
    keep = np.ones(len(F), bool)
    keep[[k for k, f in enumerate(F) if np.isin(f, [27, 28, 35, 36]).sum() >= 2]] = False
    del hole
    cases["hole"] = (save_mesh(tmp / "hole.obj", V, F[keep]), "1 hole")
    sphere = trimesh.creation.icosphere(2, radius=30.0)
    cases["closed"] = (save_mesh(tmp / "sphere.stl", sphere.vertices, sphere.faces), "closed")
    torus = trimesh.creation.torus(30.0, 10.0)
    cases["genus"] = (save_mesh(tmp / "torus.off", torus.vertices, torus.faces[3:]), "handle")
    Fd = F.copy()
    Fd[5] = [Fd[5, 0], Fd[5, 0], Fd[5, 2]]
    cases["degenerate"] = (save_mesh(tmp / "deg.obj", V, Fd), "degenerate triangle")
    cases["tiny"] = (save_mesh(tmp / "tiny.stl", V / 1000, F), "scale=1000")
    cases["cm"] = (save_mesh(tmp / "cm.obj", V / 10, F), "scale=10")
    cases["huge"] = (save_mesh(tmp / "huge.obj", V * 1000, F), "implausibly large")
    Fo = F.copy()
    Fo[10] = Fo[10, ::-1]
    cases["orientation"] = (save_mesh(tmp / "flip.obj", V, Fo), "consistently oriented")
    # pinch: merge the two far ends of a strip -> one vertex with two fans
    Vs, Fs = flat_grid(n)
    Fs = np.where(Fs == n * n - 1, 0, Fs)  # identify the last corner with the first
    Vs[n * n - 1] = [1e3, 1e3, 1e3]  # now unreferenced (dropped on load)
    cases["pinch"] = (save_mesh(tmp / "pinch.obj", Vs, Fs), "non-manifold vertex")
    (tmp / "nan.obj").write_text("v 0 0 0\nv 40 0 0\nv 0 40 0\nv nan 40 0\nf 1 2 3\nf 2 4 3\n")
    cases["nan"] = (tmp / "nan.obj", "NaN")
    return cases


def test_bad_input_catalogue(tmp_path):
    for name, (path, msg) in _bad_meshes(tmp_path).items():
        with pytest.raises(InputError, match=msg):
            load_input(path)
        assert name  # each case named in the failure message via pytest's match


def test_good_mesh_formats_load(tmp_path):
    V, F = flat_grid()
    for ext in ("obj", "stl", "ply", "off"):
        m = load_input(save_mesh(tmp_path / f"g.{ext}", V, F))
        assert m.kind == "mesh" and len(m.F) == len(F)
    m = load_input(save_mesh(tmp_path / "g.obj", V / 10, F), scale=10)
    np.testing.assert_allclose(np.ptp(m.V, axis=0)[:2], 40.0)


def test_mesh_as_stencil_and_lscm(tmp_path, tmp_path_factory):
    """``stencil=True`` keeps a user mesh's own triangulation (order kept, flattened
    here); ``flattening='lscm'`` is selectable and recorded."""
    out = designed("dome", tmp_path_factory)
    V, _, F = tables.read_stencil(out / "stencil.obj")
    src = save_mesh(tmp_path / "mine.ply", V, F)
    summary = run_design(src, tmp_path / "mine", stencil=True, flattening="lscm",
                         progress=False, plots=False)
    assert summary["flattening"]["method"] == "lscm"
    assert set(summary["flattening"]["comparison"]) == {"cetm", "lscm"}
    V2, _, F2 = tables.read_stencil(tmp_path / "mine" / "stencil.obj")
    assert np.array_equal(F2, F)
    np.testing.assert_allclose(V2, V - V.mean(0), atol=1e-4)
    with pytest.raises(InputError, match="flattening='bff'"):
        run_design(src, tmp_path / "x", flattening="bff", progress=False)
