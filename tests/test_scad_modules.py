"""The OpenSCAD library ``scad/``: defaults, functions, asserts and closed-form volumes.

Every test runs Debian's OpenSCAD (``openscad``) on a small file that ``use``s the
library; functions are checked through ``echo`` output (6 significant digits,
hence tolerances of 1e-4 mm), solids through their STL.

Faceting tolerance: a circle of radius r is a regular n-gon inscribed in it with
sagitta <= FACET_TOL = 0.005 mm, so a faceted cylinder's volume lies between
pi (r - 0.005)^2 h and pi r^2 h, i.e. at most 2 pi r 0.005 h below the ideal
volume (0.5 % for a base).  Volumes are compared with the ideal closed forms
within that bound, and with the exact faceted forms to 2e-5 (float32 STL coordinates).
"""

from __future__ import annotations

import json
import math
import re
import subprocess

import numpy as np
import pytest

from pysolver.geometry import rotvec_to_matrix
from pysolver.params import SUPPORT_FRAME, UNIT_CELL
from pysolver.params import tol as TOL
from pysolver.render import load_stl
from pysolver.render.scad_io import SCAD_DIR
from pysolver.render.scad_params import PARAMS_SCAD, params_scad_text

U = UNIT_CELL
GAP = 0.05       # APEX_GAP of scad/params.scad: gap between opened arms (actuated preview)
LIBS = ("util", "base", "bumper", "bracket", "holes", "support_frame", "unit_node")


def _run(code: str, tmp_path, suffix: str = "stl", name: str = "t"):
    """Run OpenSCAD on `code` (with every library file `use`d); return (rc, stderr, out path)."""
    head = "".join(f"use <{(SCAD_DIR / lib).as_posix()}.scad>\n" for lib in LIBS)
    head += f"include <{(SCAD_DIR / 'params.scad').as_posix()}>\n"
    src = tmp_path / f"{name}.scad"
    src.write_text(head + code)
    out = tmp_path / f"{name}.{suffix}"
    args = ["openscad", "-o", str(out), str(src)]
    if suffix == "stl":
        args[1:1] = ["--export-format", "binstl"]
    res = subprocess.run(args, capture_output=True, text=True, timeout=300)
    return res.returncode, res.stderr, out


def _echo(tmp_path, **exprs) -> dict:
    """Evaluate SCAD expressions; returns {name: parsed value}."""
    code = "".join(f"echo({k}={v});\n" for k, v in exprs.items())
    rc, err, out = _run(code, tmp_path, "echo", name="echo")
    assert rc == 0, err
    vals = {}
    for line in out.read_text().splitlines():
        m = re.match(r"ECHO: (\w+) = (.*)$", line)
        if m:
            txt = m.group(2).replace("undef", "null")
            vals[m.group(1)] = json.loads(txt)
    assert set(vals) == set(exprs), out.read_text()
    return vals


def _mesh(code: str, tmp_path, name="m"):
    rc, err, out = _run(code, tmp_path, "stl", name=name)
    assert rc == 0, err
    m = load_stl(out)
    assert m.is_watertight and m.is_volume
    return m


# ------------------------------------------------------------------------------------------
# defaults = pysolver.params


def test_params_scad_is_generated_from_params_py():
    """One source: scad/params.scad is the text generated from pysolver.params."""
    assert PARAMS_SCAD.read_text() == params_scad_text(), \
        "scad/params.scad is out of date: run make scad-params"


def test_params_scad_equals_params_py(tmp_path):
    v = _echo(tmp_path, BASE_R="BASE_R", BASE_TH="BASE_TH", BASE_P="BASE_P",
              BRACKET_W="BRACKET_W", CLEARANCE="CLEARANCE", ALIGN_R="ALIGN_R",
              MARKER_R="MARKER_R", MARKER_DEPTH="MARKER_DEPTH", ALPHA_MARGIN="ALPHA_MARGIN",
              LAYER_H="LAYER_H", ALPHA="ALPHA", FACET_TOL="FACET_TOL",
              FRAME_OFFSET_IN="FRAME_OFFSET_IN", FRAME_OFFSET_OUT="FRAME_OFFSET_OUT",
              CONNECTOR_W="CONNECTOR_W", CONNECTOR_R0="CONNECTOR_R0")
    expect = dict(BASE_R=U.base_r, BASE_TH=U.base_th, BASE_P=U.base_p, BRACKET_W=U.bracket_w,
                  CLEARANCE=U.clearance, ALIGN_R=U.align_r, MARKER_R=U.marker_r,
                  MARKER_DEPTH=U.marker_depth, ALPHA_MARGIN=U.alpha_margin_deg,
                  LAYER_H=U.layer_h, ALPHA=U.alpha_deg, FACET_TOL=TOL.facet,
                  FRAME_OFFSET_IN=SUPPORT_FRAME.offset_in,
                  FRAME_OFFSET_OUT=SUPPORT_FRAME.offset_out,
                  CONNECTOR_W=SUPPORT_FRAME.connector_w, CONNECTOR_R0=SUPPORT_FRAME.connector_r0)
    for k, e in expect.items():
        assert v[k] == pytest.approx(e, rel=1e-5), k


def test_module_defaults_are_the_paper_dimensions(tmp_path):
    """Rendered with their defaults, base/bracket/marker have the paper's sizes."""
    b = _mesh("base();", tmp_path, "base")
    assert b.bounds[:, 2] == pytest.approx([0, 2.3], abs=1e-5)          # height 2.3 mm
    # diameter 4 mm (the 48-gon is turned by half a facet: extents r cos(3.75 deg))
    assert b.bounds[:, 0] == pytest.approx([-2, 2], abs=TOL.facet)
    br = _mesh("bracket(0, 7, 0.4);", tmp_path, "bracket")
    assert br.bounds[:, 2] == pytest.approx([1.3, 2.3], abs=1e-5)        # 1 mm high, far face
    d = _mesh("marker_dot();", tmp_path, "dot")
    assert d.bounds[:, 2] == pytest.approx([1.8, 2.3], abs=1e-5)


# ------------------------------------------------------------------------------------------
# functions


def test_facets_meets_the_sagitta_tolerance(tmp_path):
    radii = [0.3, 0.75, 2.0, 6.0, 9.0]
    v = _echo(tmp_path, **{f"n{i}": f"facets({r})" for i, r in enumerate(radii)})
    for i, r in enumerate(radii):
        n = v[f"n{i}"]
        assert n % 4 == 0 and n >= 8
        assert r * (1 - math.cos(math.pi / n)) <= TOL.facet + 1e-12
        # the next smaller multiple of 4 would break the tolerance (n is minimal)
        assert n == 8 or r * (1 - math.cos(math.pi / (n - 4))) > TOL.facet
    assert v["n2"] == 48  # base discs


def test_rotvec_matrix_matches_frames(tmp_path):
    rng = np.random.default_rng(3)
    rvs = rng.normal(size=(4, 3))
    t = [1.5, -2.0, 3.25]
    v = _echo(tmp_path, **{f"m{i}": f"rotvec_matrix({rv.tolist()}, {t})"
                           for i, rv in enumerate(rvs)})
    for i, rv in enumerate(rvs):
        M = np.array(v[f"m{i}"])
        assert M[:3, :3] == pytest.approx(rotvec_to_matrix(rv), abs=1e-5)
        assert M[:3, 3] == pytest.approx(t, abs=1e-5)


def test_bracket_arms_form_a_rhombus(tmp_path):
    """Roots on the rim at dir +- 37 deg, apexes on the bisector at (l/2) tan(alpha)."""
    dir_, l, h = 25.0, 7.3, 0.45
    v = _echo(tmp_path, a=f"bracket_arms({dir_}, {l}, {h})",
              s=f"bracket_arms({dir_}, {l}, {h}, span=5.9)")
    a = np.radians(U.alpha_deg)
    R = np.array([[math.cos(math.radians(dir_)), -math.sin(math.radians(dir_))],
                  [math.sin(math.radians(dir_)), math.cos(math.radians(dir_))]])
    for k, arm in zip((-1, 1), v["a"], strict=True):
        root, tip, start, end = (R.T @ np.array(p) for p in arm)   # cell frame
        assert root == pytest.approx(U.base_r * np.array([math.cos(a), k * math.sin(a)]), abs=1e-4)
        assert tip == pytest.approx([l / 2, k * (l / 2) * math.tan(a)], abs=1e-4)
        # flat: the printed arm starts h inside the base, radially, and ends at the apex
        u = (tip - root) / np.linalg.norm(tip - root)
        assert u == pytest.approx([math.cos(a), k * math.sin(a)], abs=1e-4)
        assert np.linalg.norm(root - start) == pytest.approx(h, abs=1e-4)
        assert end == pytest.approx(tip, abs=1e-4)
    for arm in v["s"]:   # actuated: same roots and arm length, tips at span/2 along the axis
        root, tip, start, end = (R.T @ np.array(p) for p in arm)
        assert tip[0] == pytest.approx(5.9 / 2, abs=1e-4)
        assert np.linalg.norm(tip - root) == pytest.approx(l / (2 * math.cos(a)) - U.base_r,
                                                           abs=1e-4)
        # the box's farthest corner stops APEX_GAP/2 before the bisector
        u = (tip - root) / np.linalg.norm(tip - root)
        corner = end[0] + (h / 2) * abs(u[1])
        assert corner == pytest.approx(5.9 / 2 - GAP / 2, abs=1e-4)


def _v_outline(l, h, k):
    """Independent closed form of one flat V (cell frame: own base at 0, neighbour at (l, 0))."""
    a, r = np.radians(U.alpha_deg), U.base_r
    u = np.array([math.cos(a), k * math.sin(a)])               # own arm k, radial
    n = k * np.array([-u[1], u[0]])                             # away from the axis
    s = (r - h) * u                                             # root end, h inside the rim
    y_out = k * ((l / 2) * math.tan(a) + (h / 2) / math.cos(a))
    y_in = k * ((l / 2) * math.tan(a) - (h / 2) / math.cos(a))
    mirror = np.array([-1.0, 1.0])                              # x -> l - x
    return np.array([s - h / 2 * n, s + h / 2 * n, [l / 2, y_out],
                     [l, 0] + mirror * (s + h / 2 * n), [l, 0] + mirror * (s - h / 2 * n),
                     [l / 2, y_in]])


def test_bracket_outline_is_the_mitred_v(tmp_path):
    """Each V: root ends h inside both rims, apexes = crossings of the edge lines, on the
    bisector at (l/2) tan(alpha) +- (h/2)/cos(alpha); edges h/2 off the bracket_arms() lines."""
    dir_, l, h = 25.0, 7.3, 0.45
    v = _echo(tmp_path, m=f"bracket_outline({dir_}, {l}, {h}, -1)",
              p=f"bracket_outline({dir_}, {l}, {h}, 1)", a=f"bracket_arms({dir_}, {l}, {h})",
              b=f"bracket_arms({dir_ + 180}, {l}, {h})")
    c, s = math.cos(math.radians(dir_)), math.sin(math.radians(dir_))
    R = np.array([[c, -s], [s, c]])
    far = np.array([l * c, l * s])
    for k, key in ((-1, "m"), (1, "p")):
        P = np.array(v[key]) @ R                                # cell frame
        assert P == pytest.approx(_v_outline(l, h, k), abs=1e-4)
        # consistent with the arm centre lines: own arm k and the neighbour's arm -k
        own = np.array(v["a"][(k + 1) // 2])
        nb = np.array(v["b"][(1 - k) // 2]) + far
        for line, idx in ((own, (0, 1, 2, 5)), (nb, (2, 3, 4, 5))):
            u = (line[1] - line[0]) / np.linalg.norm(line[1] - line[0])
            off = [(np.array(v[key][i]) - line[0]) @ np.array([-u[1], u[0]]) for i in idx]
            assert np.abs(off) == pytest.approx(np.full(4, h / 2), abs=1e-4)


def test_bumper_points_lie_on_the_moved_plane(tmp_path):
    p, n = [3.0, 1.0, 2.3], [0.9, 0.3, -0.2]
    v = _echo(tmp_path, pts=f"bumper_points(20, {p}, {n})",
              pl=f"bumper_trim_plane({p}, {n})")
    pts = np.array(v["pts"])
    nn = np.array(n) / np.linalg.norm(n)
    assert np.array(v["pl"][0]) == pytest.approx(np.array(p) - U.clearance * nn, abs=1e-5)
    assert (pts[4:] - p) @ nn == pytest.approx(-U.clearance * np.ones(4), abs=1e-4)
    assert pts[:4, 2] == pytest.approx([0.3, 0.3, 2.3, 2.3], abs=1e-6)
    side = np.linalg.norm(pts[1] - pts[0])
    assert side == pytest.approx(U.base_th, abs=1e-5)
    u = np.array([math.cos(math.radians(20)), math.sin(math.radians(20)), 0])
    assert np.cross(pts[4:] - pts[:4], u) == pytest.approx(np.zeros((4, 3)), abs=1e-4)


def test_support_frame_bar_has_the_given_length(tmp_path):
    v = _echo(tmp_path, b="support_frame_bar([1, 2], 90, 12.5)")
    p0, p1 = np.array(v["b"])
    assert p0 == pytest.approx([1, 3], abs=1e-6)
    assert p1 == pytest.approx([1, 14.5], abs=1e-5)


# ------------------------------------------------------------------------------------------
# closed-form volumes


def _cyl_bound(r, h):
    """Largest volume deficit of a faceted cylinder: the annulus of width FACET_TOL."""
    return 2 * math.pi * r * TOL.facet * h


def test_base_volume(tmp_path):
    m = _mesh("base();", tmp_path)
    ideal = math.pi * U.base_r ** 2 * U.layer_h
    n = 48
    faceted = n / 2 * U.base_r ** 2 * math.sin(2 * math.pi / n) * U.layer_h
    assert m.volume == pytest.approx(faceted, rel=2e-5)
    assert 0 <= ideal - m.volume <= _cyl_bound(U.base_r, U.layer_h)


def test_base_with_pocket_and_hole_volume(tmp_path):
    m = _mesh("difference() { base(); marker_pocket(); alignment_hole(); }", tmp_path)
    ideal = math.pi * (U.base_r ** 2 - U.align_r ** 2) * U.layer_h
    bound = _cyl_bound(U.base_r, U.layer_h) + _cyl_bound(U.align_r, U.layer_h)
    assert abs(m.volume - ideal) <= bound
    m = _mesh("difference() { base(); marker_pocket(); }", tmp_path, "p")
    ideal = math.pi * (U.base_r ** 2 * U.layer_h - U.marker_r ** 2 * U.marker_depth)
    assert abs(m.volume - ideal) <= _cyl_bound(U.base_r, U.layer_h) + _cyl_bound(
        U.marker_r, U.marker_depth)


@pytest.mark.parametrize("l, h", [(5.0, 0.3), (7.0, 0.45), (9.0, 0.65)])
def test_bracket_volume(tmp_path, l, h):
    """Flat bracket = two V's, each two strips of width h whose centre lines run lng + h from
    the root end to the mitre: 4 h (lng + h) x height (exact); = bracket_volume()."""
    m = _mesh(f"bracket(33, {l}, {h});", tmp_path)
    assert len(m.split(only_watertight=True)) == 2              # the two V's, one solid each
    a = np.radians(U.alpha_deg)
    lng = l / (2 * math.cos(a)) - U.base_r
    expect = 4 * h * U.bracket_w * (lng + h)
    assert m.volume == pytest.approx(expect, rel=2e-5)
    # the same from the V polygon (shoelace), and the library's closed form
    P = _v_outline(l, h, 1)
    area = 0.5 * abs(np.dot(P[:, 0], np.roll(P[:, 1], -1)) - np.dot(P[:, 1], np.roll(P[:, 0], -1)))
    assert 2 * area * U.bracket_w == pytest.approx(expect, rel=1e-12)
    assert _echo(tmp_path, v=f"bracket_volume({l}, {h})")["v"] == pytest.approx(expect, rel=1e-5)


def test_actuated_bracket_is_two_separate_boxes(tmp_path):
    """With a span a base draws only its own two arms (boxes of width h and length t_end + h)."""
    l, h, span = 7.0, 0.45, 5.9
    m = _mesh(f"bracket(33, {l}, {h}, span={span});", tmp_path)
    v = _echo(tmp_path, a=f"bracket_arms(33, {l}, {h}, span={span})")
    assert len(m.split(only_watertight=True)) == 2
    lengths = [np.linalg.norm(np.array(arm[3]) - np.array(arm[2])) for arm in v["a"]]
    assert m.volume == pytest.approx(h * U.bracket_w * sum(lengths), rel=2e-5)


def test_bumper_volume_straight_and_tilted(tmp_path):
    # vertical plane perpendicular to the axis at 2.8 mm: side^2 (2.8 - clearance)
    m = _mesh("bumper(0, [2.8, 0, 2.3], [1, 0, 0]);", tmp_path, "s")
    assert m.volume == pytest.approx(U.base_th ** 2 * (2.8 - U.clearance), rel=2e-5)
    # tilted plane: side^2 times the mean of the 4 axial edge lengths (closed form)
    p, n, d = np.array([3.0, 1.0, 2.3]), np.array([0.9, 0.3, -0.2]), 20.0
    m = _mesh(f"bumper({d}, {p.tolist()}, {n.tolist()});", tmp_path, "t")
    nn = n / np.linalg.norm(n)
    u = np.array([math.cos(math.radians(d)), math.sin(math.radians(d)), 0])
    v = np.array([-u[1], u[0], 0])
    q = p - U.clearance * nn
    ts = [((q - (w * v + np.array([0, 0, z]))) @ nn) / (u @ nn)
          for w in (-1, 1) for z in (0.3, 2.3)]
    assert m.volume == pytest.approx(U.base_th ** 2 * np.mean(ts), rel=2e-5)


def test_unit_node_layers_and_volume(tmp_path):
    """A flat node of the top and bottom layer: z ranges, and volume by inclusion-exclusion."""
    bump = "[[0, [2.8, 0, 2.3], [1, 0, 0]], [120, [-1.4, 2.42487113, 2.3], [-0.5, 0.866025404, 0]]]"
    brk = "[[0, 7, 0.45], [120, 7, 0.3]]"
    top = _mesh(f'unit_node([3, 4], "top", {bump}, {brk}, marker=false);', tmp_path, "top")
    bot_bump = bump.replace("2.3]", "-2.3]")
    bot = _mesh(f'unit_node([3, 4], "bottom", {bot_bump}, {brk}, marker=false);', tmp_path, "b")
    assert top.bounds[:, 2] == pytest.approx([0, 2.3], abs=1e-5)
    assert bot.bounds[:, 2] == pytest.approx([-2.3, 0], abs=1e-5)
    assert top.volume == pytest.approx(bot.volume, rel=2e-5)
    # pieces rendered alone: node = base + bumpers + brackets - overlaps with the base
    parts = _mesh(f"union() {{ for (b = {bump}) bumper(b[0], b[1], b[2]); "
                  f"for (b = {brk}) bracket(b[0], b[1], b[2]); }}", tmp_path, "p")
    cut = _mesh(f"intersection() {{ base(); union() {{ for (b = {bump}) bumper(b[0], b[1], b[2]); "
                f"for (b = {brk}) bracket(b[0], b[1], b[2]); }} }}", tmp_path, "c")
    base = _mesh("base();", tmp_path, "base")
    assert top.volume == pytest.approx(base.volume + parts.volume - cut.volume, rel=2e-5)


# ------------------------------------------------------------------------------------------
# argument checks


@pytest.mark.parametrize("code, message", [
    ("bracket(0, 3.0, 0.4);", "central length"),
    ("bracket(0, 7, 0);", "thickness"),
    ("bracket(0, 7, 0.4, height=3);", "height"),
    ("bumper(0, [2.8, 0, 2.3], [-1, 0, 0]);", "face away"),
    ('unit_node([0, 0], "middle");', "layer"),
    ("base(r=-1);", "r must be"),
    ("alignment_hole(r=3);", "below the base radius"),
    ("support_frame([[0, 0], [1, 0]]);", "at least 3"),
])
def test_asserts_reject_bad_arguments(tmp_path, code, message):
    rc, err, _ = _run(code, tmp_path)
    assert rc != 0
    assert "Assertion" in err and message in err, err


def test_actuated_arms_of_a_folded_cell_stop_short(tmp_path):
    """A folded cell's opened arms stop 2 layer_h tan(|fold|/2) shorter along the axis
    (the end faces of facing arms would otherwise close over the layer height)."""
    l, h, span, fold = 7.0, 0.45, 5.9, 16.0
    v = _echo(tmp_path, a=f"bracket_arms(0, {l}, {h}, span={span})",
              b=f"bracket_arms(0, {l}, {h}, span={span}, "
                f"gap=bracket_preview_gap(APEX_GAP, {fold}))")
    extra = 2 * U.layer_h * math.tan(math.radians(fold / 2))
    for a, b in zip(v["a"], v["b"], strict=True):
        # tips' axial reach: shorter by half the extra gap (each side gives half)
        assert a[3][0] - b[3][0] == pytest.approx(extra / 2, abs=1e-5)  # echo: 6 digits
    m0 = _mesh(f"bracket(0, {l}, {h}, span={span});", tmp_path, "f0")
    m1 = _mesh(f"bracket(0, {l}, {h}, span={span}, fold={fold});", tmp_path, "f1")
    m2 = _mesh(f"bracket(0, {l}, {h}, span={span}, fold={-fold});", tmp_path, "f2")
    assert m1.volume < m0.volume and m1.volume == pytest.approx(m2.volume, rel=1e-9)


def test_base_phase_keeps_rim_crossings_away_from_vertices(tmp_path):
    """base_phase() picks the polygon rotation whose nearest vertex is farthest from every
    given rim angle: optimal on a fine grid to within the candidate spacing, and above the
    stated worst-case bound."""
    n = 48
    step = 360.0 / n
    rng = np.random.default_rng(3)
    angles = rng.uniform(0, 360, 36)

    def clearance(phase, a):
        x = np.mod(np.asarray(a) - phase, step)
        return np.minimum(x, step - x).min()

    lst = "[" + ", ".join(f"{a:.6f}" for a in angles) + "]"
    v = _echo(tmp_path, empty="base_phase([])", axes="base_phase([0, 30, 90, -30])",
              rnd=f"base_phase({lst})")
    assert v["empty"] == pytest.approx(step / 2)
    assert clearance(v["axes"], [0, 30, 90, -30]) == pytest.approx(step / 2, abs=step / 96)
    best = max(clearance(p, angles) for p in np.linspace(0, step, 4801))
    got = clearance(v["rnd"], angles)
    assert got >= best - step / 96 - 1e-6
    assert got >= step * (1 / (2 * len(angles)) - 1 / (2 * 96))


def test_rim_angles_of_brackets_and_bumpers(tmp_path):
    """Side edges of a flat radial arm (centre line at dir +- alpha, h/2 off it) cross the
    rim at dir +- alpha +- asin(h / (2 r)); bumper walls at dir +- asin(base_th / (2 r))."""
    h, d = 0.45, 20.0
    v = _echo(tmp_path, br=f"bracket_rim_angles({d}, 7, {h})", bu=f"bumper_rim_angles({d})")
    da = math.degrees(math.asin(h / (2 * U.base_r)))
    a = U.alpha_deg
    expect = sorted([d - a - da, d - a + da, d + a - da, d + a + da])
    np.testing.assert_allclose(sorted(v["br"]), expect, atol=1e-4)
    w = math.degrees(math.asin(U.base_th / (2 * U.base_r)))
    np.testing.assert_allclose(v["bu"], [d - w, d + w], atol=1e-4)
