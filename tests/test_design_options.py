"""Design options of issue #19: --min-bumper, --min-gap, --max-cell-length, --size, --time-file.

Each option is validated (exit code 2, a message naming it), recorded in ``design.json``
and has the effect it promises: the unit cell reaches the layout and the later stages
(read back from ``design.json``), ``--size`` scales exactly, ``--time-file`` is carried
onto the stencil exactly (a stencil OBJ: vertex-aligned) or by barycentric interpolation
(a remeshed surface: a field linear in the input coordinates stays linear).
"""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from _shared import quick_stencil_search

from pysolver.cli import main
from pysolver.design import run_design, unit_cell_options
from pysolver.design.mesh_input import load_input
from pysolver.errors import InputError
from pysolver.params import LIMITS, UNIT_CELL
from pysolver.tables import read_design, read_unit_cell, write_stencil


def hex_disk(rings=4):
    """Flat equilateral lattice (unit edge) of the hexagon with ``rings`` rings of triangles.

    Returns
    -------
    V : (n, 3) float -- z = 0, unitless
    F : (m, 3) int -- counter-clockwise
    """
    h = math.sqrt(3) / 2
    pts, index = [], {}
    for j in range(-rings, rings + 1):
        for i in range(-rings, rings + 1):
            if abs(i + j) <= rings:  # axial coordinates of a hexagon
                index[(i, j)] = len(pts)
                pts.append((i + 0.5 * j, h * j))
    F = []
    for (i, j), a in index.items():
        for tri in (((i + 1, j), (i, j + 1)), ((i, j + 1), (i - 1, j + 1))):
            if all(t in index for t in tri):
                F.append((a, index[tri[0]], index[tri[1]]))
    V = np.array(pts)
    return np.c_[V, np.zeros(len(V))], np.array(F)


@pytest.fixture(scope="module")
def stencil(tmp_path_factory):
    """A flat stencil OBJ (v = vt) of 61 vertices, unitless (2 x 4 units across)."""
    root = tmp_path_factory.mktemp("options")
    V, F = hex_disk()
    path = root / "hex.obj"
    write_stencil(path, V, V[:, :2], F)
    return path, V, F


@pytest.fixture(scope="module")
def grid(tmp_path_factory):
    """A curved height-field mesh (no vt, so it is remeshed), unitless, 2 x 2 units."""
    import trimesh

    root = tmp_path_factory.mktemp("grid")
    n = 16
    x = np.linspace(-1, 1, n + 1)
    X, Y = np.meshgrid(x, x)
    V = np.c_[X.ravel(), Y.ravel(), 0.15 * (X.ravel() ** 2 + Y.ravel() ** 2)]
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    F = np.array([t for j in range(n) for i in range(n) for t in (
        (idx[j, i], idx[j, i + 1], idx[j + 1, i + 1]),
        (idx[j, i], idx[j + 1, i + 1], idx[j + 1, i]))])
    path = root / "grid.obj"
    trimesh.Trimesh(V, F, process=False).export(path)
    return path, V, F


def _cli(args, capsys):
    try:
        rc = main(args)
    except SystemExit as e:  # argparse's own errors (usage, exclusive options): exit 2
        rc = e.code
    return rc, capsys.readouterr().err


# ------------------------------------------------------------------------------------------
# validation: exit code 2 and a message naming the option


@pytest.mark.parametrize("args, message", [
    (["--min-bumper", "-0.1"], r"--min-bumper -0.1 mm is outside 0-2 mm"),
    (["--min-bumper", "2.5"], r"--min-bumper 2.5 mm is outside 0-2 mm"),
    (["--min-bumper", "nan"], r"--min-bumper nan mm is outside"),
    (["--min-gap", "-1"], r"--min-gap -1.0 mm is outside 0-2 mm"),
    (["--min-gap", "inf"], r"--min-gap inf mm is outside"),
    (["--max-cell-length", "4.5"], r"--max-cell-length 4.5 mm is outside 4.7-9.5 mm"),
    (["--max-cell-length", "9.6"], r"--max-cell-length 9.6 mm is outside 4.7-9.5 mm"),
    (["--min-bumper", "1", "--max-cell-length", "6"],
     r"--max-cell-length 6.0 mm is outside 6.1-9.5 mm"),
    (["--size", "10"], r"--size 10.0 must be a length in mm from 20 to 2000"),
    (["--size", "nan"], r"--size nan must be"),
    (["--size", "100", "--scale", "2"], r"not allowed with argument"),
    (["--time", "30", "--time-file", "t.csv"], r"not allowed with argument"),
    (["--min-bumper", "abc"], r"invalid float value"),
])
def test_bad_options_exit_2_naming_them(args, message, tmp_path, capsys):
    for cmd in ("design", "build"):
        rc, err = _cli([cmd, "petal", "--out", str(tmp_path / "o"), *args], capsys)
        assert rc == 2, (cmd, args, err)
        assert __import__("re").search(message, err), (cmd, err)
        assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("content, message", [
    ("time_s\n30\n40\n", r"2 values, but the input mesh .* has 61 vertices"),
    ("time_s\n" + "30,1\n" * 61, r"t.csv:2: 2 columns"),
    ("time_s\n" + "30\n" * 30 + "abc\n" + "30\n" * 30, r"t.csv:32: 'abc' is not a number"),
    ("time_s\n" + "30\n" * 60 + "-1\n", r"negative time -1 s at vertex 60"),
    ("time_s\n" + "30\n" * 60 + "nan\n", r"NaN/inf at vertex 60"),
    ("time_s\n" + "30\n" * 60 + f"{LIMITS.max_t_end + 1}\n", r"beyond the longest simulation"),
    ("", r"no values"),
    ("time_s\n", r"no values"),
])
def test_bad_time_files_exit_2_naming_the_line(content, message, stencil, tmp_path, capsys):
    path, _V, _F = stencil
    tf = tmp_path / "t.csv"
    tf.write_text(content)
    rc, err = _cli(["design", str(path), "--size", "60", "--out", str(tmp_path / "o"),
                    "--time-file", str(tf)], capsys)
    assert rc == 2, err
    assert __import__("re").search(message, err), err
    assert not (tmp_path / "o").exists()


def test_time_file_refused_for_a_missing_file_and_a_builtin_shape(tmp_path, capsys):
    rc, err = _cli(["design", "petal", "--out", str(tmp_path / "o"), "--time-file",
                    str(tmp_path / "none.csv")], capsys)
    assert rc == 2 and "none.csv: no such file" in err
    tf = tmp_path / "t.csv"
    tf.write_text("30\n")
    with pytest.raises(InputError, match="petal is a built-in shape"):
        run_design("petal", tmp_path / "p", time_file=tf, plots=False, progress=False)


def test_unit_cell_options_replace_only_what_is_given():
    assert unit_cell_options() == UNIT_CELL
    p = unit_cell_options(min_bumper=0.1, min_gap=0.2, max_cell_length=9.0)
    assert (p.min_bumper, p.min_gap, p.max_cell_length) == (0.1, 0.2, 9.0)
    assert p.base_r == UNIT_CELL.base_r and p.clearance == UNIT_CELL.clearance
    assert p.shortest_cell() == pytest.approx(2 * (2.0 + 0.1) + 0.2)


# ------------------------------------------------------------------------------------------
# effects, recorded in design.json and read back by the later stages


def test_unit_cell_options_reach_the_layout_and_design_json(stencil, tmp_path):
    path, V, F = stencil
    out = {}
    for mb in (0.1, 0.6):
        params = unit_cell_options(min_bumper=mb, min_gap=0.3, max_cell_length=9.4)
        run_design(path, tmp_path / str(mb), params=params, size=60.0, plots=False,
                   progress=False)
        d = read_design(tmp_path / str(mb))
        meta = json.loads((tmp_path / str(mb) / "design.json").read_text())
        assert meta["options"]["params"]["min_bumper"] == mb
        assert meta["options"]["params"]["min_gap"] == 0.3
        assert meta["options"]["params"]["max_cell_length"] == 9.4
        assert d.params == params and read_unit_cell(tmp_path / str(mb)) == params
        out[mb] = d
    # flat stencil: the 3D rule makes the shortest centroid distance 2 (base_r + min_bumper)
    for mb, d in out.items():
        l3 = d.cells["target_length_mm"]
        assert l3.min() == pytest.approx(2 * (UNIT_CELL.base_r + mb), rel=1e-6)
        # ... and the 2D rule (flat: ideal tips min_gap apart) the flat one 2 bumpers + gap
        assert d.cells["central_length_mm"].min() == pytest.approx(l3.min() + 0.3, rel=1e-6)


def test_later_stages_read_the_designs_unit_cell(stencil, tmp_path):
    """pysolver.mechanics.load_model takes the unit cell of design.json (not the defaults)."""
    from pysolver.mechanics import load_model

    path, _V, _F = stencil
    params = unit_cell_options(min_bumper=0.2, max_cell_length=9.3)
    run_design(path, tmp_path / "d", params=params, size=60.0, plots=False, progress=False)
    assert load_model(tmp_path / "d").unit == params
    meta = json.loads((tmp_path / "d" / "design.json").read_text())
    meta["options"]["params"]["min_gap"] = 5.0  # a hand edit outside the range
    (tmp_path / "d" / "design.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"design.json: --min-gap 5.0 mm is outside"):
        read_unit_cell(tmp_path / "d")


def test_size_scales_the_largest_extent_exactly(stencil, grid, tmp_path):
    for path, V, _F in (stencil, grid):
        m = load_input(path, size=106.0)
        assert np.ptp(m.V, axis=0).max() == pytest.approx(106.0, rel=1e-12)
        assert m.scale == pytest.approx(106.0 / np.ptp(V, axis=0).max(), rel=1e-12)
        np.testing.assert_allclose(m.V, V * m.scale, rtol=1e-8)  # (OBJ: 9 digits)
    # unitless (4.2 units across) is refused without --size, accepted with it
    path, V, _F = stencil
    with pytest.raises(InputError, match=r"--size MM"):
        load_input(path)
    run_design(path, tmp_path / "d", size=75.0, plots=False, progress=False)
    opts = json.loads((tmp_path / "d" / "design.json").read_text())["options"]
    assert opts["size_mm"] == 75.0
    assert opts["input_scale"] == pytest.approx(75.0 / np.ptp(V, axis=0).max(), rel=1e-12)


def test_messages_give_target_mm(stencil, tmp_path):
    """A cell that is too long is named at its position on the (scaled) target, in mm."""
    _path, V, F = stencil
    path = tmp_path / "stretched.obj"
    write_stencil(path, V, V[:, :2] * [1.3, 1.0], F)  # flat layout stretched along x
    params = unit_cell_options(max_cell_length=5.3)
    with pytest.raises(InputError, match=r"longer than 5.3 mm .*on the target: cell \d+ at "
                                         r"\(-?\d+\.\d, -?\d+\.\d, 0\.0\) mm"):
        run_design(path, tmp_path / "d", params=params, size=60.0, plots=False,
                   progress=False)


def test_time_file_on_a_stencil_is_used_as_given(stencil, tmp_path):
    path, V, _F = stencil
    t = 30.0 + np.arange(len(V)) * 0.731  # not a smooth field: any interpolation would show
    tf = tmp_path / "t.csv"
    tf.write_text("time_s\n" + "".join(f"{float(v)!r}\n" for v in t))
    run_design(path, tmp_path / "d", size=60.0, time_file=tf, plots=False, progress=False)
    d = read_design(tmp_path / "d")
    np.testing.assert_array_equal(d.time, np.array([float(f"{v:.9g}") for v in t]))
    tfi = json.loads((tmp_path / "d" / "design.json").read_text())["options"]["time_file"]
    import hashlib

    assert tfi["sha256"] == hashlib.sha256(tf.read_bytes()).hexdigest()
    assert tfi["path"] == str(tf) and tfi["values"] == len(V)


def test_time_file_on_a_remeshed_surface_is_interpolated(grid, tmp_path, monkeypatch):
    """t = 30 + 10 x + 5 y on the input vertices (unitless): the stencil vertices lie on the
    input surface and barycentric interpolation reproduces a linear field, so the stencil's
    landscape is affine in its target x, y with slopes 10 and 5 per input unit."""
    quick_stencil_search(monkeypatch)   # the subject is the landscape, not the optimisation
    path, V, _F = grid
    tf = tmp_path / "t.csv"
    tf.write_text("time_s\n" + "".join(f"{float(30 + 10 * x + 5 * y)!r}\n" for x, y, _z in V))
    summary = run_design(path, tmp_path / "d", size=70.0, vertices=60, time_file=tf,
                         plots=False, progress=False)
    assert summary["remesh"]["remeshed"] is not False
    d = read_design(tmp_path / "d")
    assert len(d.V) != len(V)  # a new vertex set, not the input's
    opts = json.loads((tmp_path / "d" / "design.json").read_text())["options"]
    k = opts["input_scale"] * opts["scale3d"]  # target mm per input unit
    A = np.c_[np.ones(len(d.V)), d.V[:, 0], d.V[:, 1]]
    coef, *_ = np.linalg.lstsq(A, d.time, rcond=None)
    assert coef[1:] == pytest.approx([10 / k, 5 / k], rel=1e-6)
    # s, against a 30 s span: within 5e-5 mm of the surface, the slope 0.3 s/mm
    assert np.abs(A @ coef - d.time).max() < 1e-4
    assert "interpolation" in summary["time"]["source"]


def test_make_passes_the_options_as_data(stencil, tmp_path):
    """``make design ... TIMEFILE=f ARGS="--min-bumper 0.1 ..."``: the options arrive as words,
    a hostile TIMEFILE is a file name, not a command."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    path, V, _F = stencil
    tf = tmp_path / "t s.csv"  # (a space: one word all the same)
    tf.write_text("time_s\n" + "".join(f"{40.0 + i % 7}\n" for i in range(len(V))))

    def make(*var):
        return subprocess.run(
            ["make", "-s", "-f", str(repo / "Makefile"), "-o", ".venv/.installed",
             f"PY={sys.executable}", "design", f"shape={path}", *var],
            cwd=tmp_path, capture_output=True, text=True, timeout=300,
            env=dict(os.environ, PYTHONPATH=str(repo)))

    r = make(f"TIMEFILE={tf}",
             "ARGS=--quiet --no-program --size 60 --min-bumper 0.1 --min-gap 0.2 --out out")
    assert r.returncode == 0, r.stderr
    opts = json.loads((tmp_path / "out" / "design.json").read_text())["options"]
    assert opts["params"]["min_bumper"] == 0.1 and opts["params"]["min_gap"] == 0.2
    assert opts["time_file"]["path"] == str(tf) and opts["size_mm"] == 60.0
    pwn = tmp_path / "pwned"
    r = make(f'TIMEFILE=x"; touch {pwn}; echo "$(shell touch {pwn}-2)`touch {pwn}-3`',
             "ARGS=--quiet --size 60 --out out2")
    assert r.returncode == 2 and "no such file" in r.stderr, r.stderr
    assert list(tmp_path.glob("pwned*")) == []


# ------------------------------------------------------------------------------------------
# a stencil printed elsewhere: --stencil and --thickness-file (issue #32)


def _thickness_csv(path, a, b, th, header="cell,face_a,face_b,thickness_plus_normal_mm,"
                   "thickness_minus_normal_mm,t_star_s"):
    path.write_text(header + "\n" + "".join(
        f"{i},{x},{y},{float(p)!r},{float(m)!r},30.0\n" for i, (x, y, p, m) in
        enumerate(zip(a, b, th[:, 0], th[:, 1], strict=True))))
    return path


def test_thickness_file_gives_every_cell_its_thickness(stencil, tmp_path, capsys):
    """Rows in any order, each cell's two faces in either order: every cell gets its own
    row's thickness (+normal = top), and design.json records the file's hash."""
    path, _V, _F = stencil
    run_design(path, tmp_path / "d0", size=60.0, plots=False, progress=False)
    cells = read_design(tmp_path / "d0").cells
    rng = np.random.default_rng(3)
    th = np.round(rng.uniform(0.3, 0.65, (len(cells["cell_id"]), 2)), 6)
    order = rng.permutation(len(th))
    swap = rng.random(len(th)) < 0.5
    a, b = cells["base_a"][order], cells["base_b"][order]
    tf = _thickness_csv(tmp_path / "th.csv", np.where(swap, b, a), np.where(swap, a, b),
                        th[order])
    rc, err = _cli(["design", str(path), "--stencil", "--size", "60", "--thickness-file",
                    str(tf), "--out", str(tmp_path / "d"), "--quiet"], capsys)
    assert rc == 0, err
    d = read_design(tmp_path / "d")
    np.testing.assert_allclose(np.c_[d.cells["thickness_top_mm"], d.cells["thickness_bottom_mm"]],
                               th, rtol=1e-8)
    np.testing.assert_array_equal(d.cells["base_a"], cells["base_a"])
    opts = json.loads((tmp_path / "d" / "design.json").read_text())["options"]
    import hashlib

    assert opts["stencil"] is True
    assert opts["thickness_file"]["sha256"] == hashlib.sha256(tf.read_bytes()).hexdigest()


@pytest.mark.parametrize("edit, message", [
    ("drop", r"no row for cell"),
    ("extra", r"is not a unit cell of the design"),
    ("twice", r"appears 2 times"),
    ("thick", r"outside the bracket thickness range"),
    ("text", r":3: not a number"),
    ("header", r"no thickness columns"),
])
def test_bad_thickness_files_exit_2_naming_the_problem(stencil, tmp_path, capsys, edit,
                                                       message):
    path, _V, _F = stencil
    run_design(path, tmp_path / "d0", size=60.0, plots=False, progress=False)
    cells = read_design(tmp_path / "d0").cells
    a, b = cells["base_a"].copy(), cells["base_b"].copy()
    th = np.full((len(a), 2), 0.5)
    if edit == "drop":
        a, b, th = a[1:], b[1:], th[1:]
    elif edit == "extra":  # faces 0 and the last one are not neighbours
        a, b, th = np.r_[a, 0], np.r_[b, b.max()], np.r_[th, [[0.5, 0.5]]]
    elif edit == "twice":
        a, b, th = np.r_[a, b[0]], np.r_[b, a[0]], np.r_[th, [[0.5, 0.5]]]
    elif edit == "thick":
        th[4, 1] = 0.8
    tf = _thickness_csv(tmp_path / "th.csv", a, b, th,
                        header="cell,face_a,face_b,h_top,h_bottom,t" if edit == "header"
                        else "cell,face_a,face_b,thickness_plus_normal_mm,"
                             "thickness_minus_normal_mm,t_star_s")
    if edit == "text":
        lines = tf.read_text().splitlines()
        lines[2] = lines[2].replace("0.5", "half", 1)
        tf.write_text("\n".join(lines) + "\n")
    rc, err = _cli(["design", str(path), "--stencil", "--size", "60", "--thickness-file",
                    str(tf), "--out", str(tmp_path / "d"), "--quiet"], capsys)
    assert rc == 2 and re.search(message, err), err
    assert not (tmp_path / "d").exists()


def test_stencil_flag_refuses_a_built_in_shape(tmp_path, capsys):
    """``--stencil`` names a finished stencil file; a built-in shape is not one.  (A mesh
    without ``vt`` given with ``--stencil`` keeps its own triangles and is flattened:
    ``tests/test_surfaces.py::test_mesh_as_stencil_and_lscm``.)"""
    rc, err = _cli(["design", "petal", "--stencil", "--out", str(tmp_path / "c")], capsys)
    assert rc == 2 and "built-in shape" in err, err
    assert not (tmp_path / "c").exists()


def test_a_build_refuses_a_thickness_file_before_any_work(tmp_path):
    """The program stage would overwrite the file's thicknesses (and the output claim does
    not hash it): a build refuses it, naming the design-stage route, and writes nothing."""
    from pysolver.build import build
    from pysolver.errors import InputError

    tf = tmp_path / "cells.csv"
    tf.write_text("cell,thickness_plus_normal_mm\n")
    with pytest.raises(InputError) as e:
        build("regular", out=tmp_path / "b", thickness_file=tf, render=False, progress=False)
    assert "design stage only" in e.value.problem and "--thickness-file" in e.value.fix
    assert not (tmp_path / "b").exists()
