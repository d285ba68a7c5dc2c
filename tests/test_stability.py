"""Design results are a function of the geometry (issues #28 and #42).

The same target must give the same shell on any x86-64 machine, however its mesh is labelled
or placed: the same vertex count (within 3 %), 3D scaling (1 %), longest flat cell (0.15 mm)
and verdict, whatever the order of its vertices and faces (exactly: the same stencil to the
last bit), a rigid motion (those two in ``tests/test_labelling.py``), the input's last bits
(coordinates jittered by 1e-7 of the size),
the CPU's code path (numpy without AVX2/FMA3, OpenBLAS's Sandybridge kernels) or the number
of BLAS threads.  Small shapes here; every built-in, reference and peer shape in
``bench/bench_stability.py`` (``make bench``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pysolver.design import run_design, surfaces
from pysolver.errors import InputError

REPO = Path(__file__).resolve().parent.parent
SHAPE = "dome:size=0.7"
VERTEX_RTOL, SCALE_RTOL, CELL_ATOL_MM = 0.03, 0.01, 0.15
"""The issue's tolerances: bases, 3D scaling (relative), longest flat cell (mm)."""


def figures(source, out) -> dict:
    """The design's key figures: bases, 3D scaling, longest flat cell, verdict."""
    try:
        s = run_design(source, out, progress=False, plots=False)
    except InputError as e:
        return {"verdict": "refused", "why": e.problem}
    return {"verdict": "printable" if s["checks"]["ok"] else "unprintable",
            "bases": s["counts"]["bases"], "scale3d": s["scale"]["scale3d"],
            "max_cell_mm": s["cell_length_mm"]["max"]}


def assert_same(a: dict, b: dict) -> None:
    assert a["verdict"] == b["verdict"], (a, b)
    if a["verdict"] == "refused":
        return
    assert abs(a["bases"] - b["bases"]) <= VERTEX_RTOL * a["bases"], (a, b)
    assert abs(a["scale3d"] / b["scale3d"] - 1) <= SCALE_RTOL, (a, b)
    assert abs(a["max_cell_mm"] - b["max_cell_mm"]) <= CELL_ATOL_MM, (a, b)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    return figures(SHAPE, tmp_path_factory.mktemp("ref"))


def test_reference_design_is_printable_at_size(reference):
    assert reference["verdict"] == "printable"
    assert 0.98 <= reference["scale3d"] <= 1.02


@settings(max_examples=1, deadline=None, derandomize=True)  # (more: bench_stability)
@given(seed=st.integers(0, 2**31 - 1))
def test_design_is_stable_under_input_jitter(reference, tmp_path_factory, seed):
    """Verdict, bases, 3D scaling and longest flat cell within the issue's tolerances.
    (Before each round of the stencil optimisation had a trust region, a jitter could send
    it into another local minimum: 8.486 mm for most jitters, 8.34 mm for some.  Measured
    with it on six jitters: 7.453-7.464 mm.)"""
    s = surfaces.builtin(SHAPE)
    rng = np.random.default_rng(seed)
    s.V = s.V + 1e-7 * np.ptp(s.V, axis=0).max() * rng.standard_normal(s.V.shape)
    assert_same(reference, figures(s, tmp_path_factory.mktemp("jitter")))


PROBE = (
    "import json, sys\n"
    "sys.path.insert(0, {tests!r})\n"
    "from test_stability import figures\n"
    "print(json.dumps(figures({shape!r}, {out!r})))\n")


@pytest.mark.parametrize("env", [
    {"NPY_DISABLE_CPU_FEATURES": "AVX2 FMA3", "OPENBLAS_CORETYPE": "Sandybridge"},
    {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"},
    {"OPENBLAS_NUM_THREADS": "2", "OMP_NUM_THREADS": "2"},
], ids=["no-avx2-fma3-sandybridge", "1-blas-thread", "2-blas-threads"])
def test_design_is_stable_across_code_paths_and_threads(reference, tmp_path, env):
    code = PROBE.format(tests=str(REPO / "tests"), shape=SHAPE, out=str(tmp_path / "d"))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=REPO, env={**os.environ, **env}, timeout=900)
    assert r.returncode == 0, r.stderr
    assert_same(reference, json.loads(r.stdout.strip().splitlines()[-1]))
