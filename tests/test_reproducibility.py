"""Reproducible builds (issue #8): the same input and options give byte-identical tables
and geometrically identical STLs, and ``summary.json`` records what a build depended on
(versions of the project, OpenSCAD and key libraries; a hash of the inputs).

Shapes: ``regular`` (a given stencil) and ``dome`` (CVT remeshing + CETM flattening, the
parts where nondeterminism would hide) for the tables; the 4-base
``regular:rows=1,cols=2`` for the CLI build and the renders (``--no-program``: its three
cells are all boundary cells; the programming stage is checked on ``regular``).
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _shared import designed

from pysolver.build import inputs_hash
from pysolver.core.provenance import lock_record
from pysolver.design import run_design

REPO = Path(__file__).resolve().parent.parent
SMALL = "regular:rows=1,cols=2"
TABLES = ("stencil.obj", "bases.csv", "cells.csv", "bumpers.csv", "time_landscape.csv",
          "support_frame.csv")


@pytest.mark.parametrize("shape", ["regular", "dome"])
def test_two_designs_are_byte_identical(shape, tmp_path, tmp_path_factory):
    a, b = designed(shape, tmp_path_factory), tmp_path / "b"   # (a: the session's design)
    run_design(shape, b, progress=False, plots=False)
    for name in TABLES:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    # design.json too, except the wall-clock timings it records
    ja, jb = (_untimed(json.loads((d / "design.json").read_text())) for d in (a, b))
    assert ja == jb


def _untimed(obj):
    if isinstance(obj, dict):
        return {k: _untimed(v) for k, v in obj.items() if k not in ("timings_s", "time_s")}
    if isinstance(obj, list):
        return [_untimed(v) for v in obj]
    return obj


def _canonical(path, decimals=4):
    """An STL as a comparable object: its sorted unique vertices rounded to 1e-4 mm, its
    triangles as sorted rows of sorted vertex ranks, and its volume."""
    import trimesh

    m = trimesh.load_mesh(str(path), file_type="stl", process=True)
    V = np.round(np.asarray(m.vertices), decimals) + 0.0
    keys, inv = np.unique(V, axis=0, return_inverse=True)
    T = np.sort(inv.ravel()[np.asarray(m.faces)], axis=1)
    T = T[np.lexsort(T.T[::-1])]
    return keys, T, float(m.volume)


@pytest.fixture(scope="module")
def cli_build(tmp_path_factory):
    """``morphshell build regular:rows=1,cols=2 --no-program --no-sim`` (design, render)."""
    cwd = tmp_path_factory.mktemp("cli")
    args = [sys.executable, "-m", "pysolver.cli", "--quiet", "build", SMALL, "--no-program"]
    r = subprocess.run(args + ["--no-sim"], capture_output=True, text=True, cwd=cwd,
                       env=dict(os.environ, PYTHONPATH=str(REPO)), timeout=600)
    assert r.returncode == 0, r.stderr
    return cwd / "build" / SMALL


def test_summary_records_versions_and_inputs_hash(cli_build):
    s = json.loads((cli_build / "summary.json").read_text())
    v = s["versions"]
    for lib in ("morphshell", "python", "numpy", "scipy", "libigl", "trimesh", "manifold3d",
                "triangle", "matplotlib", "openscad"):
        assert v.get(lib) and v[lib] != "not installed", lib
    assert re.match(r"OpenSCAD version \d{4}\.\d\d", v["openscad"]), v["openscad"]
    # the lock make installs: its hash, and no installed package off it
    assert v["lock_sha256"] == hashlib.sha256((REPO / "uv.lock").read_bytes()).hexdigest()
    assert v["lock_mismatched"] == []
    assert re.fullmatch(r"[0-9a-f]{64}", s["inputs_sha256"])
    # the hash is that of the recorded source + options, and changes with any option
    assert s["inputs_sha256"] == inputs_hash(s["source"], s["options"])
    other = dict(s["options"], vertices=30)
    assert inputs_hash(s["source"], other) != s["inputs_sha256"]
    assert s["figures"]["n_bases"] == 4 and s["figures"]["n_cells"] == 3
    assert set(s["stages"]) == {"design", "render"}
    assert not (cli_build / ".inputs_sha256").exists()


def test_lock_record_names_packages_installed_off_the_lock(tmp_path):
    lock = tmp_path / "uv.lock"
    scipy_version = importlib.metadata.version("scipy")
    lock.write_text('version = 1\n\n[[package]]\nname = "numpy"\nversion = "0.0.1"\n'
                    f'\n[[package]]\nname = "scipy"\nversion = "{scipy_version}"\n'
                    '\n[[package]]\nname = "no-such-package-here"\nversion = "1.0"\n')
    rec = lock_record(lock)
    assert rec["sha256"] == hashlib.sha256(lock.read_bytes()).hexdigest()
    assert rec["mismatched"] == [f"numpy {np.__version__} (lock: 0.0.1)"]
    assert lock_record(tmp_path / "absent.lock") == {"sha256": None, "mismatched": []}


def test_build_tables_match_an_independent_design(cli_build, tmp_path):
    """A second design of the same input reproduces the build's tables."""
    d = tmp_path / "again"
    run_design(SMALL, d, progress=False, plots=False)
    for name in TABLES:
        assert (d / name).read_bytes() == (cli_build / name).read_bytes(), name


def test_two_programs_are_byte_identical(tmp_path):
    """The temporal stage (thickness per cell) is deterministic too."""
    from pysolver.temporal import program_design

    out = []
    for k in "ab":
        d = tmp_path / k
        run_design("regular", d, progress=False, plots=False)
        program_design(d, progress=False, picture=False)
        out.append((d / "cells.csv").read_bytes())
    assert out[0] == out[1]


def test_two_renders_are_geometrically_identical(cli_build, tmp_path):
    """Render an independent copy of the design with a cold cache of its own (every part
    through OpenSCAD again, then union and export): the STLs match the build's."""
    from pysolver.render import STL_FILES, render_design

    d = tmp_path / "design"
    shutil.copytree(cli_build, d, ignore=shutil.ignore_patterns("stl", "scad", "*.png"))
    s = render_design(d, cache_dir=tmp_path / "cold-cache", progress=False)
    assert s["cached"] == 0 and s["rendered"] == s["parts"]
    for key, name in STL_FILES.items():
        ka, ta, va = _canonical(cli_build / "stl" / name)
        kb, tb, vb = _canonical(d / "stl" / name)
        assert ka.shape == kb.shape and np.array_equal(ka, kb), key
        assert np.array_equal(ta, tb), key
        assert va == pytest.approx(vb, rel=1e-9), key
