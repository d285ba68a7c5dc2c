"""Fast renderer (openscad-evaluator) cross-checked against Debian OpenSCAD.

One module-scoped design: ``run_design(regular(rows=2, cols=3))`` (12 bases, 15 cells) with
bracket thicknesses varied per cell and layer (as in ``tests/test_render.py``), rendered
without the actuated preview (27 parts) by both backends into ONE cache folder.
Tolerances: part and layer volumes 1e-4 relative; symmetric difference of each part pair
(manifold3d booleans) below 1e-3 of the part volume (measured: ~2e-5 at most, on the
support frames, whose rounded offsets are faceted slightly differently).
"""

from __future__ import annotations

import shutil
import warnings

import numpy as np
import pytest

from pysolver import tables
from pysolver.errors import ExternalToolError, InputError
from pysolver.params import LAYERS
from pysolver.params import tol as TOL
from pysolver.render import fast as render_fast
from pysolver.render import load_stl, render_design, render_parts, to_manifold
from pysolver.render import parts as render
from pysolver.render.scad_io import Part

VOLUME_RTOL = 1e-4
SYMDIFF_RTOL = 1e-3


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    from pysolver.design import run_design
    from pysolver.design.surfaces import regular

    root = tmp_path_factory.mktemp("render_fast")
    design = root / "design"
    run_design(regular(rows=2, cols=3), design, progress=False, plots=False)
    cells = tables.read_table(design, "cells")
    k = np.arange(len(cells["cell_id"]))
    cells["thickness_top_mm"] = 0.30 + 0.05 * (k % 8)
    cells["thickness_bottom_mm"] = 0.65 - 0.05 * (k % 8)
    tables.write_table(design, "cells", cells)
    cache = root / "cache"
    out = {"root": root, "cache": cache}
    for name in ("openscad", "fast"):
        d = root / f"design_{name}"
        shutil.copytree(design, d)
        s = render_design(d, cache_dir=cache, actuated=False, progress=False, renderer=name)
        parts = [Part(p.stem, "?", None, -1, p) for p in sorted((d / "scad").glob("*.scad"))]
        res = render_parts(parts, cache_dir=cache, progress=False, renderer=name)
        out[name] = dict(dir=d, summary=s, parts=res,
                         layers={k: load_stl(p) for k, p in s["stl"].items()})
    return out


def test_each_renderer_has_its_own_cache_keys(both):
    so, sf = both["openscad"]["summary"], both["fast"]["summary"]
    assert so["renderer"] == "openscad" and sf["renderer"] == "fast"
    assert sf["renderer_version"].startswith("openscad-evaluator ")
    assert so["renderer_version"].startswith("OpenSCAD version")
    # same cache folder, same part files: the fast render shares nothing with OpenSCAD's
    assert so["rendered"] == so["parts"] == sf["rendered"] == sf["parts"] == 27
    assert sf["fallback_parts"] == []
    po, pf = both["openscad"]["parts"], both["fast"]["parts"]
    assert po["cached"] == pf["cached"] == 27             # second call: all from the cache
    assert set(po["stl"].values()).isdisjoint(pf["stl"].values())
    assert len(list(both["cache"].glob("*.stl"))) == 2 * 27


@pytest.mark.parametrize("name", ["openscad", "fast"])
def test_layers_are_watertight_single_volumes(both, name):
    s = both[name]["summary"]
    for key in (*LAYERS, "support_frame_top", "support_frame_bottom"):
        mesh = both[name]["layers"][key]
        assert mesh.is_watertight and mesh.is_volume, key
        assert s["watertight"][key] and s["bodies"][key] == 1, key


def test_part_volumes_and_shapes_agree(both):
    po, pf = both["openscad"]["parts"], both["fast"]["parts"]
    assert set(po["stl"]) == set(pf["stl"])
    for name in sorted(po["stl"]):
        a = to_manifold(load_stl(po["stl"][name]), f"{name} openscad")
        b = to_manifold(load_stl(pf["stl"][name]), f"{name} fast")
        va = a.volume()
        assert b.volume() == pytest.approx(va, rel=VOLUME_RTOL), name
        sym = (a - b).volume() + (b - a).volume()
        assert sym < SYMDIFF_RTOL * va, (name, sym / va)
        assert a.genus() == b.genus(), name


def test_layer_volumes_agree(both):
    vo = both["openscad"]["summary"]["volumes_mm3"]
    vf = both["fast"]["summary"]["volumes_mm3"]
    assert set(vo) == set(vf)
    for key in vo:
        assert vf[key] == pytest.approx(vo[key], rel=VOLUME_RTOL), key
    assert both["fast"]["summary"]["bodies"] == both["openscad"]["summary"]["bodies"]


def test_failed_fast_part_falls_back_to_openscad(both, monkeypatch):
    """A part the fast renderer fails on is rendered by OpenSCAD (here from the cache) and
    named in a warning and in the result."""
    d = both["fast"]["dir"]
    parts = [Part(n, "node", "top", i, d / "scad" / f"{n}.scad")
             for i, n in enumerate(("node_top_0000", "node_top_0001"))]
    real = render_fast.render_files

    def flaky(items, **kw):
        ans = real(items, **kw)
        ans[1] = {"ok": False, "seconds": 0.0, "error": "ERROR: simulated evaluator failure"}
        return ans

    monkeypatch.setattr(render_fast, "render_files", flaky)
    cache = both["root"] / "cache_fallback"
    shutil.copytree(both["cache"], cache)
    for p in both["fast"]["parts"]["stl"].values():   # drop the fast renders only
        (cache / p.name).unlink()
    with pytest.warns(render.RendererFallbackWarning, match="node_top_0001"):
        res = render_parts(parts, cache_dir=cache, progress=False, renderer="fast")
    assert res["renderer"] == "fast"
    assert list(res["fallback"]) == ["node_top_0001"]
    assert "simulated evaluator failure" in res["fallback"]["node_top_0001"]
    assert res["stl"]["node_top_0001"].name == both["openscad"]["parts"]["stl"][
        "node_top_0001"].name                       # the OpenSCAD render, from the cache
    assert res["stl"]["node_top_0000"].name == both["fast"]["parts"]["stl"][
        "node_top_0000"].name


def test_stuck_part_times_out_and_a_fresh_worker_continues(tmp_path):
    slow = tmp_path / "slow.scad"
    slow.write_text("for (i = [0:10000], j = [0:10000]) if (i < 0) cube(1);\n")
    ok = tmp_path / "ok.scad"
    ok.write_text("cube([1, 2, 3]);\n")
    ans = render_fast.render_files([(slow, tmp_path / "slow.stl"), (ok, tmp_path / "ok.stl")],
                                   jobs=1, timeout=2.0)
    assert not ans[0]["ok"] and "timed out after 2 s" in ans[0]["error"]
    assert ans[1]["ok"]
    assert load_stl(tmp_path / "ok.stl").volume == pytest.approx(6.0, rel=1e-6)


def test_evaluator_errors_are_part_failures(tmp_path):
    bad = {"assert.scad": ('assert(false, "refusing this part");\ncube(1);\n', "refusing"),
           "unknown.scad": ("cube(undefined_size);\n", "unknown variable"),
           "empty.scad": ("translate([1, 0, 0]) children();\n", "no geometry"),
           "syntax.scad": ("cube(1\n", "syntax")}
    items = []
    for name, (text, _) in bad.items():
        (tmp_path / name).write_text(text)
        items.append((tmp_path / name, tmp_path / (name + ".stl")))
    ans = render_fast.render_files(items, jobs=1)
    for (name, (_, why)), a in zip(bad.items(), ans, strict=True):
        assert not a["ok"], name
        assert why in a["error"], (name, a["error"])


def test_mirror_by_zero_vector_is_identity_as_in_openscad(tmp_path):
    """The library writes mirror([0, 0, layer == "top" ? 0 : 1]); without the shim every
    top-layer part of openscad-evaluator 1.8.1 is empty."""
    f = tmp_path / "m.scad"
    f.write_text("mirror([0, 0, 0]) translate([0, 0, 1]) cube([1, 2, 3]);\n"
                 "mirror([0, 0, 1]) cube(1);\n")
    solid, _ = render_fast.evaluate_file(f)
    assert solid.volume() == pytest.approx(7.0, rel=1e-9)
    lo, hi = np.asarray(solid.bounding_box()).reshape(2, 3)
    assert lo == pytest.approx([0, 0, -1]) and hi == pytest.approx([1, 2, 4])


def test_auto_runs_the_self_check_and_picks_fast(both):
    render._SELF_CHECKS.clear()
    check = render.fast_self_check(cache_dir=both["cache"])
    assert check["ok"], check["summary"]
    assert set(check["parts"]) == {"ref_node_top", "ref_node_bottom", "ref_actuated_top",
                                   "ref_frame_top", "ref_frame_bottom", "ref_marker",
                                   "ref_specimen"}
    assert check["max_volume_rel"] <= TOL.self_check_volume_rtol
    assert check["max_symdiff_rel"] <= TOL.self_check_symdiff_rtol
    d = both["fast"]["dir"]
    part = Part("marker", "marker", None, -1, d / "scad" / "marker.scad")
    res = render_parts([part], cache_dir=both["cache"], progress=False, renderer="auto")
    assert res["renderer"] == "fast" and res["renderer_requested"] == "auto"
    assert res["self_check"]["ok"] and res["cached"] == 1
    assert not list(both["cache"].glob("ref_*"))          # the check keeps to selfcheck/


def test_self_check_in_the_background_is_the_foreground_check(both, tmp_path):
    """The build's background self-check (a fresh cache) gives the result of the check run
    in the foreground; a render started meanwhile waits for it instead of running its own;
    only the ``auto`` renderer starts one."""
    render._SELF_CHECKS.clear()
    fg = render.fast_self_check(cache_dir=both["cache"])
    render._SELF_CHECKS.clear()
    design = tmp_path / "build" / "shell"
    design.mkdir(parents=True)
    assert render.start_self_check(design, renderer="fast") is None
    assert render.start_self_check(design, renderer="openscad") is None
    thread = render.start_self_check(design, renderer="auto")
    assert thread is not None and thread.is_alive()
    cache = render.default_cache_dir(design)
    assert cache == tmp_path / "build" / ".cache" / "parts"
    d = both["fast"]["dir"]
    part = Part("marker", "marker", None, -1, d / "scad" / "marker.scad")
    res = render_parts([part], cache_dir=cache, progress=False, renderer="auto")
    assert not thread.is_alive()  # the render waited for the background check
    assert res["renderer"] == "fast"
    bg = res["self_check"]
    assert bg["ok"] and bg["parts"] == fg["parts"] and bg["summary"] == fg["summary"]
    assert len(list((cache / "selfcheck").glob("*.stl"))) == 2 * len(fg["parts"])


def test_without_the_evaluator_auto_uses_openscad_and_fast_says_how_to_install(both,
                                                                                monkeypatch):
    monkeypatch.setattr(render_fast, "version", lambda: None)
    d = both["openscad"]["dir"]
    part = Part("marker", "marker", None, -1, d / "scad" / "marker.scad")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = render_parts([part], cache_dir=both["cache"], progress=False, renderer="auto")
    assert res["renderer"] == "openscad" and not res["self_check"]["ok"]
    with pytest.raises(ExternalToolError, match="pip install openscad-evaluator"):
        render_parts([part], cache_dir=both["cache"], progress=False, renderer="fast")


def test_unknown_renderer_is_an_input_error(both):
    with pytest.raises(InputError, match="renderer must be one of"):
        render_design(both["fast"]["dir"], cache_dir=both["cache"], renderer="cgal",
                      progress=False)


def test_cli_has_the_renderer_option():
    from pysolver.cli.parser import make_parser

    ap = make_parser()
    assert ap.parse_args(["render", "d", "--renderer", "fast"]).renderer == "fast"
    assert ap.parse_args(["build", "petal", "--renderer", "auto"]).renderer == "auto"
    assert ap.parse_args(["render", "d"]).renderer is None
    with pytest.raises(SystemExit):
        ap.parse_args(["render", "d", "--renderer", "cgal"])
