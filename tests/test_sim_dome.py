"""A designed dome morphs into its target shape (design -> program -> simulate). Tolerances: every
step converges (1e-6 N); at least 95 % of the cells reach their bumpers (all 4 brackets, within
the 0.05 mm printing clearance) by t = 120 s; the final base centres are within 1 % of the
target size (bounding box diagonal, ~100 mm) RMS of the designed 3D centres after a rigid
(Kabsch) alignment. The residual (~0.4 % with the fitted model) comes from the two brackets of
a layer having slightly different contact lengths and from the contact springs' compliance.
"""

from __future__ import annotations

import shutil

import numpy as np
from _shared import designed

from pysolver.material.model import load_bracket_model
from pysolver.tables import read_table
from pysolver.temporal import program_design
from sim.model.collisions import completion_times
from sim.model.simulate import simulate_design


def _kabsch_rms(A, B):
    a0, b0 = A.mean(0), B.mean(0)
    U, _, Vt = np.linalg.svd((A - a0).T @ (B - b0))
    d = np.sign(np.linalg.det(U @ Vt))
    Q = (U @ np.diag([1, 1, d]) @ Vt).T
    err = np.linalg.norm((A - a0) @ Q.T + b0 - B, axis=1)
    return float(np.sqrt(np.mean(err**2))), float(err.max())


def test_dome_reaches_target(tmp_path, tmp_path_factory):
    """Designed, programmed with the committed model (programming must work: no stand-in
    material), simulated with the same model, before the build's refinement round: at least
    94 % of the cells complete (the dome of issue #42's search: 94.8 %, its landscape mapped
    onto 0-114 s, so the latest cells end near the 120 s the bath lasts; after the build's
    refinement round all 155 cells complete, ``docs/results.md``)."""
    d = tmp_path / "dome"
    shutil.copytree(designed("dome", tmp_path_factory), d)
    material = load_bracket_model()
    program_design(d, material=material, progress=False, picture=False, fit_landscape=True)
    summary = simulate_design(d, material=material, progress=False)
    assert summary["nonconverged_steps"] == []
    with np.load(d / "sim" / "frames.npz") as z:
        C = z["base_center"][-1]
        tc = completion_times({k: z[k] for k in ("t", "collided", "bracket_length",
                                                  "collision_length")})
    b = read_table(d, "bases")
    T = np.c_[b["target_x_mm"], b["target_y_mm"], b["target_z_mm"]]
    rms, _ = _kabsch_rms(C, T)
    size = np.linalg.norm(np.ptp(T, axis=0))
    assert np.isfinite(tc).mean() >= 0.94
    assert rms < 0.01 * size
