"""Robustness (issue #8): every bad input gets a clear error that NAMES the problem.

The catalogue, one test each: bad mesh files (missing, empty, corrupt, unsupported,
non-manifold, several pieces, holes, handles, closed, degenerate, NaN/inf, wrong
units), a surface too curved to build, bad time landscapes, hand-edited tables,
OpenSCAD missing or failing on one part, a diverging simulation, and bad Makefile
variables.  Every message is matched against the thing it must name (file, value,
place, rule) and a fix.  A few go through the real CLI in a subprocess to check the
exit code (2 bad input, 1 internal error) and that no traceback is shown.

Everything is small (at most the 60-base ``regular`` patch; OpenSCAD is replaced by a
stub where the test is about the error reporting), so the file runs in seconds.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh
from _shared import flat_grid, save_mesh

from pysolver import tables
from pysolver.cli import main
from pysolver.design import run_design
from pysolver.design.mesh_input import SizeWarning, load_input
from pysolver.errors import (
    EXIT_BAD_INPUT,
    EXIT_INTERNAL,
    ExternalToolError,
    InputError,
    MorphshellError,
)

REPO = Path(__file__).resolve().parent.parent
HAS_OPENSCAD = shutil.which("openscad") is not None


def _cli(args, cwd, env=None, timeout=120):
    """Run ``python -m pysolver.cli ARGS`` in a subprocess (the real front door)."""
    e = dict(os.environ, PYTHONPATH=str(REPO), **(env or {}))
    return subprocess.run([sys.executable, "-m", "pysolver.cli", "--quiet", *map(str, args)],
                          capture_output=True, text=True, env=e, cwd=cwd, timeout=timeout)


def _main(argv, capsys):
    """The CLI in-process: (exit code, stderr)."""
    rc = main(["--quiet", *map(str, argv)])
    return rc, capsys.readouterr().err


def _names(msg: str, *patterns: str) -> None:
    for p in patterns:
        assert re.search(p, msg), f"{p!r} not in message:\n{msg}"


# ------------------------------------------------------------------------------------------
# meshes: each bad mesh with the patterns its message must contain

MESH_CASES = {}
"""``{case: (builder, patterns)}``: ``builder(folder) -> path`` writes the bad mesh
``_m_<case>``; every pattern must be found in the message of the refusal."""


def bad_mesh(*patterns):
    """Register the decorated builder ``_m_<case>`` as the case ``<case>`` of
    :data:`MESH_CASES`."""
    def register(build):
        MESH_CASES[build.__name__.removeprefix("_m_")] = (build, list(patterns))
        return build
    return register


def _file(d, name: str, content) -> Path:
    """Write ``content`` (bytes or text) as the file ``name`` in ``d``; its path."""
    path = d / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    return path


def _grid_in_unit(d, name: str, unit_mm: float) -> Path:
    """A 100 mm flat grid written in a unit of ``unit_mm`` mm (metres: 1000), not in mm."""
    V, F = flat_grid(size=100.0)
    return save_mesh(d / name, V / unit_mm, F)


@bad_mesh(r"nope\.obj: file not found",
          r"Fix: check the path")
def _m_missing(d):
    return d / "nope.obj"


@bad_mesh(r"empty\.stl: empty file")
def _m_empty(d):
    return _file(d, "empty.stl", b"")


@bad_mesh(r"bad\.obj: cannot read the OBJ file, it is corrupt",
          r"index 8 is out of bounds")
def _m_corrupt_obj(d):
    return _file(d, "bad.obj", "v 0 0 0\nv 40 0 0\nv 0 40 0\nf 1 2 9\n")  # vertex 9 missing


@bad_mesh(r"noise\.stl: no triangles found: the file is empty, "
           r"truncated or corrupt")
def _m_corrupt_stl(d):
    return _file(d, "noise.stl", np.random.default_rng(0).bytes(300))


@bad_mesh(r"junk\.ply: cannot read the PLY file")
def _m_corrupt_ply(d):
    return _file(d, "junk.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n")


@bad_mesh(r"shape\.3ds: unsupported format '\.3ds'",
          r"\.obj, \.stl, \.ply, \.off")
def _m_unsupported(d):
    return _file(d, "shape.3ds", b"MM\x00\x00")


@bad_mesh(r"folder\.obj: is a directory, not a mesh file")
def _m_directory(d):
    (d / "folder.obj").mkdir()
    return d / "folder.obj"


@bad_mesh(r"fin\.obj: 1 non-manifold edge\(s\)",
          r"edge \(0, 1\) used by 3 triangles",
          r"at \(2\.9, 0\.0, 0\.0\) mm",
          r"Repair non Manifold Edges")
def _m_nonmanifold_edge(d):
    V, F = flat_grid()
    V = np.vstack([V, [[2.9, 0.0, 10.0]]])
    F = np.vstack([F, [[1, 0, len(V) - 1]]])  # a fin on the (interior-facing) edge 0-1
    F = np.vstack([F, [[0, 1, len(V) - 1]]])
    return save_mesh(d / "fin.obj", V, F)


@bad_mesh(r"bowtie\.obj: 1 non-manifold vertex",
          r"at \(0\.0, 0\.0, 0\.0\) mm")
def _m_nonmanifold_vertex(d):
    V, F = flat_grid()
    F = np.where(F == 63, 0, F)  # glue the far corner onto the first: a bow-tie vertex
    V[63] = [1e3, 1e3, 1e3]      # (now unreferenced, dropped on load)
    return save_mesh(d / "bowtie.obj", V, F)


@bad_mesh(r"two\.ply: 2 separate pieces \(faces per piece: \[98, 98\]\)",
          r"delete the small pieces")
def _m_components(d):
    V, F = flat_grid()
    return save_mesh(d / "two.ply", np.vstack([V, V + [60, 0, 0]]), np.vstack([F, F + len(V)]))


@bad_mesh(r"hole\.obj: the surface has 1 hole\(s\)",
          r"hole around \(20\.0, 20\.0, 0\.0\) mm",
          r"cut from each hole")
def _m_hole(d):
    V, F = flat_grid()
    q = 2 * (3 * 7 + 3)  # the two triangles of the quad in row 3, column 3
    return save_mesh(d / "hole.obj", V, np.delete(F, [q, q + 1], axis=0))


@bad_mesh(r"handle\.off: the surface has 1 handle\(s\) \(genus 1\)",
          r"cut through each handle")
def _m_handle(d):
    t = trimesh.creation.torus(30.0, 10.0)
    return save_mesh(d / "handle.off", t.vertices, t.faces[3:])


@bad_mesh(r"ball\.stl: the surface is closed \(no boundary\)",
          r"Fix: cut it open, e.g. delete the faces around \(0\.0, 0\.0, "
           r"-30\.0\) mm")
def _m_closed(d):
    s = trimesh.creation.icosphere(2, radius=30.0)
    return save_mesh(d / "ball.stl", s.vertices, s.faces)


@bad_mesh(r"ring\.obj: the surface is closed \(no boundary, "
           r"genus 1\)",
          r"cut it open")
def _m_closed_torus(d):
    t = trimesh.creation.torus(30.0, 10.0)
    return save_mesh(d / "ring.obj", t.vertices, t.faces)


@bad_mesh(r"repeat\.obj: 1 degenerate triangle",
          r"e\.g\. face 5 at \(",
          r"Remove Zero Area")
def _m_repeated_vertex(d):
    V, F = flat_grid()
    F[5] = [F[5, 0], F[5, 0], F[5, 2]]
    return save_mesh(d / "repeat.obj", V, F)


@bad_mesh(r"sliver\.obj: 1 degenerate triangle\(s\) \(zero area",
          r"face 3 at \(20\.0, 20\.0, 0\.0\) mm")
def _m_zero_area(d):
    # square split along its diagonal; one half split again at the diagonal's midpoint M,
    # and the T-junction closed by the zero-area triangle (A, M, C)
    V = np.array([[0, 0, 0], [40, 0, 0], [40, 40, 0], [0, 40, 0], [20, 20, 0]], float)
    F = np.array([[0, 1, 4], [1, 2, 4], [0, 2, 3], [0, 4, 2]])
    return save_mesh(d / "sliver.obj", V, F)


@bad_mesh(r"nan\.obj: 1 vertex coordinate\(s\) are NaN or infinite",
          r"first: vertex 3")
def _m_nan(d):
    return _file(d, "nan.obj", "v 0 0 0\nv 40 0 0\nv 0 40 0\nv nan 40 0\nf 1 2 3\nf 2 4 3\n")


@bad_mesh(r"inf\.obj: 1 vertex coordinate\(s\) are NaN or infinite")
def _m_inf(d):
    return _file(d, "inf.obj", "v 0 0 0\nv 40 0 0\nv 0 40 0\nv 40 inf 0\nf 1 2 3\nf 2 4 3\n")


@bad_mesh(r"nan\.stl: 6 triangle\(s\) with NaN or infinite vertex "
           r"coordinates \(first: triangle 20\)")
def _m_nan_stl(d):
    V, F = flat_grid()
    V[20] = [np.nan, 5.0, 0.0]      # (trimesh's STL processing would drop these triangles
    return save_mesh(d / "nan.stl", V, F)  # and the surface would show a misleading "hole")


@bad_mesh(r"flip\.obj: the faces are not consistently oriented",
          r"Re-Orient all faces")
def _m_orientation(d):
    V, F = flat_grid()
    F[10] = F[10, ::-1]
    return save_mesh(d / "flip.obj", V, F)


@bad_mesh(r"metres\.stl: the surface is only 0\.141 mm across",
          r"probably in metres",
          r"--scale 1000 .*it would be 141 mm across")
def _m_metres(d):
    return _grid_in_unit(d, "metres.stl", 1000.0)


@bad_mesh(r"inches\.obj: the surface is only 5\.57 mm across",
          r"probably in inches",
          r"--scale 25\.4 .*it would be 141 mm across")
def _m_inches(d):
    return _grid_in_unit(d, "inches.obj", 25.4)


@bad_mesh(r"um\.ply: the surface is 1\.414e\+05 mm across; that is "
           r"implausibly large",
          r"--scale 0\.001")
def _m_micrometres(d):
    return _grid_in_unit(d, "um.ply", 1e-3)


@pytest.mark.parametrize("case", list(MESH_CASES))
def test_bad_mesh_is_named(case, tmp_path):
    build, patterns = MESH_CASES[case]
    path = build(tmp_path)
    with pytest.raises(InputError) as e:
        load_input(path)
    msg = str(e.value)
    _names(msg, *patterns)
    assert "Fix:" in msg, msg


@pytest.mark.parametrize("case, patterns", [
    ("missing", [r"mesh file '.*nope\.obj' does not exist"]),
    ("closed", [r"the surface is closed", r"Fix: cut it open"]),
    ("metres", [r"--scale 1000"]),
])
def test_bad_mesh_via_cli_exit_2_no_traceback(case, patterns, tmp_path):
    path = MESH_CASES[case][0](tmp_path)
    r = _cli(["design", path, "--out", tmp_path / "out"], cwd=tmp_path)
    assert r.returncode == EXIT_BAD_INPUT, r.stderr
    assert "Traceback" not in r.stderr
    _names(r.stderr, r"^morphshell design: error: ", *patterns)
    assert not (tmp_path / "out").exists()          # nothing written


def test_metres_mesh_designs_with_scale_option(tmp_path, capsys):
    """The offered fix works: ``--scale 1000`` turns the metre mesh into a valid input."""
    path = _m_metres(tmp_path)
    m = load_input(path, scale=1000.0)
    assert np.ptp(m.V, axis=0)[:2] == pytest.approx([100.0, 100.0])
    rc, err = _main(["design", path, "--scale", "1000", "--stencil-order", "--out",
                     tmp_path / "out"], capsys)
    assert rc == 0, err
    assert (tmp_path / "out" / "cells.csv").is_file()


def test_suspicious_size_warns_and_offers_scale(tmp_path, capsys):
    """30 mm across is possible but suspicious (a 300 mm shell exported in cm): warn, go on."""
    V, F = flat_grid(size=21.2)
    path = save_mesh(tmp_path / "small.obj", V, F)
    with pytest.warns(SizeWarning, match=r"30 mm across.*--scale 10 .*centimetres.*300 mm"):
        load_input(path)
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        rc, err = _main(["design", path, "--stencil-order", "--out", tmp_path / "out"], capsys)
    assert rc == 0, err
    _names(err, r"morphshell design: warning: .*small\.obj: the surface is 30 mm across",
           r"--scale 10")
    assert "warnings.warn" not in err                # one clean line, no source echo


def test_directory_and_unknown_shape_via_cli(tmp_path, capsys):
    (tmp_path / "meshes").mkdir()
    rc, err = _main(["design", tmp_path / "meshes"], capsys)
    assert rc == EXIT_BAD_INPUT
    _names(err, r"meshes' is a directory, not a mesh file")


# ------------------------------------------------------------------------------------------
# a surface too curved to build


def _cap(tmp_path):
    """Sphere (radius 50 mm, centre (0, 0, 100)) above its equator: the flattening must
    stretch the rim so much that cells there exceed 9.5 mm."""
    s = trimesh.creation.icosphere(2, radius=50.0)
    keep = s.triangles_center[:, 2] > 0.0
    m = trimesh.Trimesh(s.vertices + [0, 0, 100.0], s.faces[keep], process=False)
    m.remove_unreferenced_vertices()
    return save_mesh(tmp_path / "cap.obj", m.vertices, m.faces)


def test_too_curved_names_the_region_in_target_mm(tmp_path):
    """Places are named in mm on the target (stencil.obj v: the input centred at its vertex
    mean and scaled by the 3D rule), to 0.1 mm, whatever the input's units (issue #19)."""
    from pysolver.build import design_only
    from pysolver.design.flatten import compare_flattenings
    from pysolver.design.layout import build_layout
    from pysolver.design.mesh_input import load_input

    out = tmp_path / "out"
    cap = _cap(tmp_path)
    with pytest.raises(InputError) as e:
        design_only(str(cap), out=out, stencil=True, progress=False)
    msg = str(e.value)
    _names(msg, r"unprintable design: \d+ unit cell\(s\) longer than 9\.5 mm \(max 1\d\.\d\d mm\)",
           r"on the target: cell \d+ at \(", r"region centred at \(",
           r"mostly along the rim", r"Fix: .*cut the surface through that region",
           r"--vertices N")
    # the places named, mapped back to the input, are on the user's sphere (centre
    # (0, 0, 100), radius 50), near its rim
    m = load_input(cap)
    lay = build_layout(m.V, compare_flattenings(m.V, m.F)["cetm"].UV, m.F)
    pts = np.array([[float(v) for v in p] for p in
                    re.findall(r"\d+ at \((-?\d+\.\d), (-?\d+\.\d), (-?\d+\.\d)\) mm", msg)])
    assert len(pts) == 4
    P = pts / lay.scale3d + m.V.mean(axis=0)
    r = np.linalg.norm(P - [0, 0, 100.0], axis=1)
    assert np.all(np.abs(r - 50.0) < 2.0), r           # cell midpoints: chords inside
    assert np.all(P[:, 2] < 115.0)                     # the rim, not the pole (z = 150)
    assert not out.exists()                            # nothing written


# ------------------------------------------------------------------------------------------
# time landscapes


@pytest.fixture(scope="module")
def regular_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("regular") / "design"
    run_design("regular", d, progress=False, plots=False)
    return d


def _fresh(regular_dir, tmp_path):
    d = tmp_path / "design"
    shutil.copytree(regular_dir, d)
    return d


@pytest.mark.parametrize("time, patterns", [
    ("nan", [r"time .nan.: NaN/inf is not a time", r"finite times in seconds"]),
    ("-5", [r"time .-5.: negative time -5 s", r">= 0"]),
    ("1/0", [r"time expression '1/0' cannot be evaluated: ZeroDivisionError"]),
    ("9**9**9", [r"cannot be evaluated: .*overflow"]),            # instant, not a hang
    ("30 + 0.5*w", [r"unknown name 'w'", r"names: x y z r"]),
    ("sqrt(-1 - r)", [r"NaN/inf at vertex 0 \(42 values\)"]),
    (np.arange(5.0), [r"time array has 5 values; the stencil has 42 vertices"]),
    (np.r_[np.full(20, 60.0), np.nan, np.full(21, 60.0)], [r"time array: NaN/inf at vertex 20"]),
    (np.r_[np.full(41, 60.0), -1.0], [r"negative time -1 s at vertex 41"]),
])
def test_bad_time_landscape_is_named(time, patterns, tmp_path):
    with pytest.raises(InputError) as e:
        run_design("regular", tmp_path / "d", time=time, progress=False, plots=False)
    _names(str(e.value), *patterns, "Fix:")
    assert not (tmp_path / "d").exists()


def test_bad_time_via_cli_is_bad_input(tmp_path, capsys):
    rc, err = _main(["design", "regular", "--time", "1/0", "--out", tmp_path / "d"], capsys)
    assert rc == EXIT_BAD_INPUT
    _names(err, r"morphshell design: error: time expression '1/0' cannot be evaluated")


@pytest.mark.parametrize("value, pattern", [
    ("nan", r"time_landscape\.csv:7: column time_s = 'nan': NaN not allowed"),
    ("-3", r"time_landscape\.csv:7: column time_s = '-3': must be >= 0"),
])
def test_hand_edited_time_landscape_csv(value, pattern, regular_dir, tmp_path):
    from pysolver.temporal import program_design

    d = _fresh(regular_dir, tmp_path)
    p = d / "time_landscape.csv"
    lines = p.read_text().splitlines()
    lines[6] = lines[6].split(",")[0] + "," + value
    p.write_text("\n".join(lines) + "\n")
    before = (d / "cells.csv").read_bytes()
    with pytest.raises(InputError, match=pattern):
        program_design(d, progress=False, picture=False)
    assert (d / "cells.csv").read_bytes() == before


def test_time_landscape_wrong_length_csv(regular_dir, tmp_path):
    d = _fresh(regular_dir, tmp_path)
    p = d / "time_landscape.csv"
    p.write_text("\n".join(p.read_text().splitlines()[:-5]) + "\n")   # 5 vertices lost
    with pytest.raises(InputError, match=r"time_landscape\.csv: 37 rows for 42 stencil vertices"):
        tables.read_design(d)


def test_all_infeasible_landscape_names_the_achievable_range(regular_dir, tmp_path):
    from pysolver.temporal import program_design

    d = _fresh(regular_dir, tmp_path)
    tl = tables.read_table(d, "time_landscape")
    tl["time_s"][:] = 5000.0                     # far beyond any bracket
    tables.write_table(d, "time_landscape", tl)
    before = (d / "cells.csv").read_bytes()
    with pytest.raises(InputError) as e:
        program_design(d, progress=False, picture=False)
    _names(str(e.value), r"infeasible", r"79 of 79 cells",
           r"\d+ would need to finish later than their thickest brackets \(0\.65 mm\) allow",
           r"shift or scale the time landscape into the achievable range",
           r"\d+\.\d and \d+\.\d s")
    assert (d / "cells.csv").read_bytes() == before     # nothing half-written


# ------------------------------------------------------------------------------------------
# hand-edited cells.csv


def _edit_cells(d, fn):
    p = d / "cells.csv"
    rows = [r.split(",") for r in p.read_text().splitlines()]
    fn(rows)
    p.write_text("\n".join(",".join(r) for r in rows) + "\n")


def _set(rows, cell, col, value):
    rows[cell + 1][rows[0].index(col)] = value      # row 0 is the header: cell k is line k + 2


def test_cells_csv_missing_column(regular_dir, tmp_path):
    d = _fresh(regular_dir, tmp_path)

    def drop(rows):
        k = rows[0].index("thickness_top_mm")
        for r in rows:
            del r[k]

    _edit_cells(d, drop)
    with pytest.raises(InputError) as e:
        tables.read_design(d)
    _names(str(e.value), r"cells\.csv: header does not match the cells table; missing "
                         r"\['thickness_top_mm'\]", r"Fix: the header must be exactly: cell_id,")


@pytest.mark.parametrize("value", ["0.9", "0.1"])
def test_cells_csv_thickness_out_of_range(value, regular_dir, tmp_path):
    d = _fresh(regular_dir, tmp_path)
    _edit_cells(d, lambda rows: _set(rows, 10, "thickness_bottom_mm", value))
    pattern = (rf"cells\.csv:12 \(cell 10\): thickness_bottom_mm = {value} mm is outside the "
               r"bracket thickness range 0\.3-0\.65 mm")
    with pytest.raises(InputError, match=pattern):
        tables.read_design(d)
    from pysolver.mechanics import load_model  # the simulator refuses it as well

    with pytest.raises(InputError, match=pattern):
        load_model(d)


def test_cells_csv_cell_refers_to_missing_base(regular_dir, tmp_path):
    d = _fresh(regular_dir, tmp_path)
    _edit_cells(d, lambda rows: _set(rows, 3, "base_b", "999"))
    with pytest.raises(InputError) as e:
        tables.read_design(d)
    _names(str(e.value), r"cells\.csv:5 \(cell 3\): base_b = 999 refers to a base that does not "
                         r"exist \(the design has 60, ids 0\.\.59\)", r"undo the hand edit")


def test_render_refuses_hand_edited_thickness(regular_dir, tmp_path):
    from pysolver.render import render_design

    d = _fresh(regular_dir, tmp_path)
    _edit_cells(d, lambda rows: _set(rows, 0, "thickness_top_mm", "1.5"))
    with pytest.raises(InputError, match=r"cells\.csv:2 \(cell 0\): thickness_top_mm = 1\.5 mm"):
        render_design(d, cache_dir=tmp_path / "cache", progress=False)
    assert not (d / "stl").exists() and not (tmp_path / "cache").exists()


# ------------------------------------------------------------------------------------------
# OpenSCAD missing or failing


def test_openscad_missing_named_with_install_fix(regular_dir, tmp_path, monkeypatch):
    from pysolver import render

    monkeypatch.setenv(render.OPENSCAD_ENV, str(tmp_path / "no-openscad"))
    with pytest.raises(ExternalToolError) as e:
        render.render_design(_fresh(regular_dir, tmp_path), cache_dir=tmp_path / "c",
                             progress=False)
    _names(str(e.value), r"OpenSCAD executable '.*no-openscad' was not found",
           r"apt-get install openscad", r"MORPHSHELL_OPENSCAD=")
    assert e.value.exit_code == EXIT_BAD_INPUT


def test_openscad_missing_build_fails_before_design(tmp_path):
    """PATH without openscad: ``build`` says so at once (exit 2), before any stage runs."""
    r = _cli(["build", "regular", "--no-sim"], cwd=tmp_path,
             env={"PATH": str(tmp_path / "empty-bin")})
    assert r.returncode == EXIT_BAD_INPUT, r.stderr
    assert "Traceback" not in r.stderr
    _names(r.stderr, r"morphshell build: error: OpenSCAD executable 'openscad' was not found",
           r"apt-get install openscad")
    assert not (tmp_path / "build" / "regular").exists()
    assert not (tmp_path / "build" / ".staging" / "regular").exists()


FAKE_OPENSCAD = """\
#!{python}
# Stand-in for OpenSCAD: fails on one part file like OpenSCAD does, renders a small
# tetrahedron for every other part.
import struct, sys
from pathlib import Path
if sys.argv[1:] == ["--version"]:
    sys.stderr.write("OpenSCAD version 2021.01 (stub)\\n")
    sys.exit(0)
out, scad = Path(sys.argv[sys.argv.index("-o") + 1]), Path(sys.argv[-1])
if scad.name == {fail!r} and not Path({healed!r}).exists():
    sys.stderr.write('ERROR: Assertion \\'(h >= 0.3)\\' failed: "bracket too thin" in file '
                     '../../scad/bracket.scad, line 42\\nExecution aborted\\n')
    sys.exit(1)
P = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
T = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
with open(out, "wb") as f:
    f.write(b"stub".ljust(80, b" ") + struct.pack("<I", len(T)))
    for t in T:
        f.write(struct.pack("<3f", 0, 0, 0))
        for i in t:
            f.write(struct.pack("<3f", *P[i]))
        f.write(b"\\0\\0")
"""


def test_openscad_failing_on_one_part_names_it_and_keeps_the_rest(tmp_path, monkeypatch):
    from pysolver import render

    d = tmp_path / "design"
    run_design("regular:rows=1,cols=2", d, progress=False, plots=False)    # 4 bases
    fake = tmp_path / "openscad"
    healed = tmp_path / "healed"
    fake.write_text(FAKE_OPENSCAD.format(python=sys.executable, fail="node_top_0002.scad",
                                         healed=str(healed)))
    fake.chmod(0o755)
    monkeypatch.setenv(render.OPENSCAD_ENV, str(fake))
    cache = tmp_path / "cache"
    with pytest.raises(ExternalToolError) as e:
        render.render_design(d, cache_dir=cache, actuated=False, jobs=2, progress=False)
    msg = str(e.value)
    _names(msg, r"OpenSCAD failed on 1 of 11 parts \(10 rendered and cached",
           r"base 2, top layer \(node_top_0002\.scad\)",
           r"Assertion '\(h >= 0\.3\)' failed: \"bracket too thin\"",
           r"Parts that rendered stay cached")
    assert len(list(cache.glob("*.stl"))) == 10
    assert not (d / "stl").exists()
    healed.touch()                                     # "fix" the part: only it re-renders
    s = render.render_design(d, cache_dir=cache, actuated=False, jobs=2, progress=False)
    assert (s["rendered"], s["cached"]) == (1, 10)


# ------------------------------------------------------------------------------------------
# a diverging simulation


class _SofteningMaterial:
    """The committed bracket model until 2.5 s, then brackets with absurd negative stiffness
    (a broken material fit): the quasi-static solve runs away."""

    path = "softening-test-material"

    def __init__(self):
        from pysolver.material.model import load_bracket_model

        self.base = load_bracket_model()

    def coefficients(self, h, b, t, eta=0.0):
        c = np.asarray(self.base.coefficients(h, b, t, eta=eta), float)
        return c if np.max(t) <= 2.5 else -1e9 * c


def test_diverging_simulation_stops_keeps_frames_names_step_and_cause(tmp_path):
    from sim.model.simulate import simulate_design

    d = tmp_path / "design"
    run_design("regular:rows=2,cols=3", d, progress=False, plots=False)
    with pytest.raises(MorphshellError) as e:
        simulate_design(d, material=_SofteningMaterial(), t_end=10.0, progress=False)
    msg = str(e.value)
    m = re.search(r"simulation diverged at step (\d+) \(t = ([\d.]+) s\): (.*)", msg)
    assert m, msg
    step, t = int(m.group(1)), float(m.group(2))
    assert t > 2.5 and t == pytest.approx(0.5 * step)
    _names(msg, r"runaway motion|energy blow-up|NaN", r"likely cause", r"Fix: ")
    with np.load(d / "sim" / "frames.npz") as z:       # the frames so far are kept
        assert len(z["t"]) == step
        np.testing.assert_allclose(z["t"], 0.5 * np.arange(step))
        assert np.all(np.isfinite(z["base_center"]))
    assert not (d / "sim" / "summary.json").exists()


# ------------------------------------------------------------------------------------------
# bad Makefile variables (make shape=... VERTICES=... -> the CLI)


@pytest.mark.parametrize("argv, patterns", [
    (["build", "nosuch"], [r"unknown shape 'nosuch'",
                           *(rf"\b{n}\b" for n in ("regular", "petal", "saddle", "dome"))]),
    (["build", "dome:bogus=1"], [r"bad option: unknown option\(s\) \['bogus'\] for 'dome'",
                                 r"dome takes: size, radius, cap_deg"]),
    (["build", "dome:size=big"], [r"'size=big': value must be a number"]),
    (["build", "no/such/mesh.stl"], [r"mesh file 'no/such/mesh.stl' does not exist"]),
    (["build", "regular", "--vertices", "abc"], [r"argument --vertices: invalid int value"]),
    (["build", "regular", "--vertices", "2"], [r"--vertices 2 must be a whole number from 4"]),
    (["build", "regular", "--scale", "-1"], [r"--scale -1\.0 must be a positive number"]),
    (["build", "regular", "--time", "t+1"], [r"unknown name 't'"]),
    (["build", "regular", "--material", "nosuch.json"],
     [r"material model file 'nosuch\.json' does not exist"]),
    (["build", "regular", "--refine", "-1"], [r"--refine must be a whole number from 0 to "
                                              r"\d+, got -1"]),
    (["build", "regular", "--jobs", "0"], [r"--jobs must be a whole number from 1 to \d+, "
                                           r"got 0"]),
    (["build", "regular", "--no-sim", "--no-render", "--t-end", "-3"],
     [r"--t-end must be a number of seconds from 0 to \d+, got -3\.0"]),
    (["build", "regular", "--t-end", "10.2", "--no-render"],
     [r"t_end = 10\.2 s is not a non-negative multiple of dt = 0\.5 s"]),
    (["build", "regular", "--flattening", "bff"], [r"invalid choice: 'bff'"]),
])
def test_bad_make_variables_are_named_before_any_stage(argv, patterns, tmp_path, monkeypatch,
                                                       capsys):
    monkeypatch.chdir(tmp_path)
    try:
        rc, err = _main(argv, capsys)
    except SystemExit as e:                             # argparse's own errors
        rc, err = e.code, capsys.readouterr().err
    assert rc == EXIT_BAD_INPUT, err
    _names(err, *patterns)
    assert not (tmp_path / "build").exists()           # refused before any stage (or lock)


def test_make_shape_nosuch_subprocess_exit_2(tmp_path):
    r = _cli(["build", "nosuch"], cwd=tmp_path)
    assert r.returncode == EXIT_BAD_INPUT
    assert "Traceback" not in r.stderr
    assert r.stderr.startswith("morphshell build: error: unknown shape 'nosuch'.")
    assert "Fix: use one of the built-in shapes" in r.stderr


def test_builtin_spec_with_dot_is_a_shape_not_a_file(tmp_path, capsys):
    """``dome:size=1.5`` has a '.' (a "suffix") but names a built-in shape, not a file."""
    from pysolver.build import shape_name

    assert shape_name("dome:size=1.5") == "dome:size=1.5"
    rc, err = _main(["design", "regular:rows=1,cols=2", "--out", tmp_path / "r"], capsys)
    assert rc == 0, err                                  # integer options stay integers


def test_internal_error_exit_1_no_traceback(tmp_path):
    code = textwrap.dedent(f"""
        import sys
        import pysolver.stages.runners as d
        def boom(*a, **k):
            raise RuntimeError("boom in the design stage")
        d.run_design = boom
        from pysolver.cli import main
        sys.exit(main(["--quiet", "design", "regular", "--out", {str(tmp_path / "o")!r}]))
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=str(REPO)), cwd=tmp_path, timeout=120)
    assert r.returncode == EXIT_INTERNAL, r.stderr
    assert "Traceback" not in r.stderr
    _names(r.stderr, r"morphshell design: internal error \(RuntimeError: boom in the design "
                     r"stage\)\. This is a bug; re-run with --debug")
    assert not (tmp_path / "o").exists()


def test_stage_failure_in_build_names_the_stage_and_what_was_kept(tmp_path, capsys,
                                                                   monkeypatch):
    monkeypatch.chdir(tmp_path)
    rc, err = _main(["build", "regular", "--no-render", "--no-sim", "--time", "5000"], capsys)
    assert rc == EXIT_BAD_INPUT
    _names(err, r"morphshell build: error: program stage: .*infeasible",
           r"nothing was written to .*build/regular",
           r"this build's partial files were removed \(add --debug to keep them\)",
           r"Fix: shift or scale the time landscape")
    assert not (tmp_path / "build" / "regular").exists()


def test_disk_full_is_named_not_called_a_bug(tmp_path, capsys, monkeypatch):
    import errno

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "cells.csv"))

    monkeypatch.setattr("pysolver.stages.runners.run_design", full)
    rc, err = _main(["design", "regular", "--out", tmp_path / "o"], capsys)
    assert rc == EXIT_BAD_INPUT
    _names(err, r"error: no space left on the device \(the disk is full\) \(.*cells\.csv\)",
           r"Fix: free some space or write elsewhere")
    assert "This is a bug" not in err
