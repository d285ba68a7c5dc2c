"""Small helpers shared by several test files (meshes, section measurements, fits)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

SHARED = Path(__file__).resolve().parents[2] / "shared"
"""``../shared`` beside the checkout: test inputs that are not project data (present in CI)."""


def run_cli(argv, capsys) -> tuple[int, str]:
    """``morphshell --quiet ARGV`` in this process: (exit code, what it printed)."""
    from pysolver.cli import main

    rc = main(["--quiet", *map(str, argv)])
    cap = capsys.readouterr()
    return rc, cap.err + cap.out


def shared_file(*parts: str) -> Path:
    """A file of ``../shared``; the test is skipped, saying so, where it is absent."""
    p = SHARED.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"needs {p} (../shared beside the checkout, as in CI)")
    return p


def flat_grid(n: int = 8, size: float = 40.0):
    """Flat n x n grid of right triangles, size x size mm, CCW (normals +z).

    Returns
    -------
    V : (n*n, 3) float, mm
    F : (2 (n-1)^2, 3) int
    """
    X, Y = np.meshgrid(np.linspace(0, size, n), np.linspace(0, size, n))
    V = np.c_[X.ravel(), Y.ravel(), np.zeros(n * n)]
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1
            F += [[a, b, d], [a, d, c]]
    return V, np.array(F)


def save_mesh(path, V, F):
    """Write a mesh as-is (no merging or repair) in the format of ``path``'s suffix."""
    trimesh.Trimesh(V, F, process=False).export(path)
    return path


def section_width(seg, m, w):
    """Width of a 2D section around point m along direction w: nearest wall crossings either side.

    seg : (k, 2, 2) float, mm -- the section's boundary segments; m : (2,) mm; w : (2,) unit.
    Returns the width in mm, or None if m is not enclosed along w.
    """
    p, d = seg[:, 0], seg[:, 1] - seg[:, 0]
    den = w[0] * d[:, 1] - w[1] * d[:, 0]
    ok = np.abs(den) > 1e-12
    r = p - m
    s = (r[:, 0] * d[:, 1] - r[:, 1] * d[:, 0]) / np.where(ok, den, 1)
    t = (r[:, 0] * w[1] - r[:, 1] * w[0]) / np.where(ok, den, 1)
    s = s[ok & (t >= -1e-9) & (t <= 1 + 1e-9)]
    if not (np.any(s > 0) and np.any(s < 0)):
        return None
    return s[s > 0].min() - s[s < 0].max()


FIT_RTOL = 1e-6
"""A fresh material fit against the committed one, relative to the largest |coefficient| of
each part.  The fit's last bits move with the CPU's code path and the BLAS kernel (measured:
about 1e-8 relative); 1e-6 is far below the fit's own error (residual RMS 0.05-0.1 mm) and far
above those bits."""


def assert_fit_matches(fresh: dict, committed: dict, rtol: float = FIT_RTOL) -> None:
    """A fresh bracket-model file dict reproduces the committed one: same grid and options,
    force polynomials (per power of x) and creep coefficients within ``rtol``."""
    assert fresh["grid"] == committed["grid"]
    assert fresh["fit"]["options"] == committed["fit"]["options"]
    a = np.asarray(fresh["force_coefficients"]["data"], float)
    b = np.asarray(committed["force_coefficients"]["data"], float)
    assert a.shape == b.shape
    k = a.shape[-1]
    err = np.abs(a - b).reshape(-1, k).max(axis=0)            # per power of x, N mm^-k
    scale = np.abs(b).reshape(-1, k).max(axis=0)
    assert np.all(err <= rtol * scale), (err, scale)
    for part in ("dry", "wet"):
        c0 = np.asarray(committed["creep_model"][part]["coefficients"], float)
        c1 = np.asarray(fresh["creep_model"][part]["coefficients"], float)
        assert np.abs(c1 - c0).max() <= rtol * np.abs(c0).max(), part


def designed(shape: str, tmp_path_factory) -> Path:
    """The design folder of a built-in shape at its defaults (``run_design(shape,
    plots=False)``), made once per test session and shared by every test that needs it,
    across the workers of ``pytest -n`` (a file lock; the workers' temporary folders share a
    parent).  Copy it (``shutil.copytree``) before running a stage on it: the design itself
    is what the tests check, a redesign of the same shape would give the same bytes
    (``tests/test_reproducibility.py`` checks that, against a fresh design)."""
    import fcntl
    import os

    from pysolver.design import run_design

    base = tmp_path_factory.getbasetemp()
    root = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "designed"
    root.mkdir(parents=True, exist_ok=True)
    out = root / shape.replace(":", "_").replace("=", "-").replace(",", "_")
    # one lock per shape: two workers wanting two shapes design them side by side
    with open(root / f".{out.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (out / "design.json").is_file():
            run_design(shape, out, progress=False, plots=False)
    return out


QUICK_SEARCH = {"opt_rounds": 1, "opt_iterations": 30, "opt_timing_iterations": 30,
                "opt_converge_rounds": 1, "opt_converge_iterations": 30, "opt_pin_weight": 0.0,
                "opt_prox_iterations": 30}
"""A smaller stencil-optimisation budget (one round of 30 L-BFGS iterations, proximal or
not, one more for the pick, no polish at scale 1) for tests whose subject is not the
optimisation (a landscape carried onto the stencil, an option recorded): about 10x less
time in the design stage (24 -> 2 s CPU for a 60-vertex dome with a vertex-property
landscape).  The optimisation itself is tested at the full budget (the built-in shapes'
designs, ``tests/test_stencil.py``)."""


def quick_stencil_search(monkeypatch) -> None:
    """Make :func:`pysolver.design.run_design` search stencils with :data:`QUICK_SEARCH`."""
    import dataclasses
    import functools

    from pysolver.design import pipeline
    from pysolver.params import STENCIL

    settings = dataclasses.replace(STENCIL, **QUICK_SEARCH)
    monkeypatch.setattr(pipeline, "remesh_surface",
                        functools.partial(pipeline.remesh_surface, settings=settings))
