"""The tools ``make`` installs are present: the test suite fails, never skips, without them.

OpenSCAD (Debian package ``openscad``, from ``make``'s ``system-deps``) and the Python packages
numba, scikit-sparse (CHOLMOD), cadquery and openscad-evaluator (``pyproject.toml``
dependencies) are requirements of the project, not options.  The tests that use them call them
directly (no ``skipif``); this file names what is missing in one place.
"""

from __future__ import annotations

import importlib
import shutil
import subprocess

import pytest

from pysolver.render import fast as render_fast


def test_openscad_runs():
    exe = shutil.which("openscad")
    assert exe, "OpenSCAD is not on PATH; 'make' installs it (sudo apt-get install openscad)"
    r = subprocess.run([exe, "--version"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "OpenSCAD version" in (r.stderr + r.stdout)


@pytest.mark.parametrize("module", ["numba", "sksparse.cholmod", "cadquery",
                                    "openscad_evaluator", "openscad_lalr_parser"])
def test_python_dependency_imports(module):
    importlib.import_module(module)  # ImportError = a broken install: run 'make' again


def test_project_backends_use_them():
    from pysolver.mechanics.kernels import HAVE_NUMBA
    from pysolver.mechanics.solver import HAVE_CHOLMOD

    assert HAVE_NUMBA and HAVE_CHOLMOD and render_fast.available()
