"""Security, third pass (issue #43): no code from the working directory runs in a child
interpreter, no path read from a stamp reaches outside its folder, the studio's token is
seen by no other process or user, the studio refuses before it reads, and the low-severity
holes of the audit.  Each test fails on the code before the fix (``docs/threat-model.md``
lists them per boundary)."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import pytest

from pysolver.child import PACKAGE_ROOT, python_argv

# ------------------------------------------------------------------------------ child Pythons

PLANTED = ("pyvista.py", "numpy.py", "runpy.py", "pysolver/__init__.py", "sim/__init__.py",
           "openscad_evaluator.py", "trimesh.py")
"""Modules a hostile working directory could hold: each writes a marker when imported."""


@pytest.fixture
def hostile_cwd(tmp_path, monkeypatch):
    """A working directory full of planted modules; yields the marker file they write."""
    cwd = tmp_path / "cwd"
    marker = tmp_path / "imported-from-cwd.txt"
    for name in PLANTED:
        p = cwd / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(f"open({str(marker)!r}, 'a').write({name!r} + '\\n')\n")
    monkeypatch.chdir(cwd)
    monkeypatch.setenv("PYTHONPATH", str(cwd))      # ignored by an isolated child too
    return marker


def _planted(marker: Path) -> list[str]:
    return marker.read_text().split() if marker.exists() else []


def test_a_child_python_imports_nothing_from_the_working_directory(hostile_cwd):
    code = ("import sys, numpy, pysolver, sim, runpy\n"
            "print(pysolver.__file__); print(repr(sys.path))")
    r = subprocess.run(python_argv(code=code), capture_output=True, text=True, check=True)
    assert _planted(hostile_cwd) == []
    first, path = r.stdout.splitlines()
    assert first == str(Path(PACKAGE_ROOT) / "pysolver" / "__init__.py")
    assert str(Path.cwd()) not in path and "''" not in path
    with pytest.raises(ValueError):
        python_argv("pysolver.x; import os")
    with pytest.raises(ValueError):
        python_argv()


def test_the_pyvista_probe_runs_no_planted_module(hostile_cwd):
    from sim.report.plots import _pyvista_status

    ok, why = _pyvista_status.__wrapped__()
    assert _planted(hostile_cwd) == []
    assert ok or "pyvista" in why


def test_a_fast_render_worker_runs_no_planted_module(hostile_cwd, tmp_path):
    from pysolver.render.fast import render_files

    scad = tmp_path / "part.scad"
    scad.write_text("cube([1, 2, 3]);\n")
    ans = render_files([(scad, tmp_path / "part.stl")], jobs=1)
    assert _planted(hostile_cwd) == []
    assert ans[0]["ok"], ans[0]["error"]            # the real worker ran
    assert (tmp_path / "part.stl").stat().st_size > 84


def test_a_studio_run_runs_no_planted_module(hostile_cwd, tmp_path):
    from pysolver.studio.server import Build, Job

    job = Job()
    job.state.update(state="running", started=time.time(), log=[])
    folder = tmp_path / "no-such-build"
    req = json.dumps({"folder": str(folder), "landscape": [1.0], "source": {}})
    job._run(Build(folder), req, ["start", "program", "report"], dict(Job.DEFAULT_S))
    assert _planted(hostile_cwd) == []
    state = job.snapshot()
    # the real rerun module answered: a named error about the folder, not an import failure
    assert state["state"] == "error" and f"{folder}/summary.json" in state["error"], state
