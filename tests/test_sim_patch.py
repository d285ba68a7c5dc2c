"""A flat regular patch: symmetry, bending direction, reaching the designed (flat) shape.

Tolerances: a symmetric patch stays flat to 1e-6 mm (out of plane) and 1e-8 (tilt); the
asymmetric patch bends with a mean fold angle above 0.5 deg at its most bent frame, never
below -0.05 deg; at the end the base centres match the target within 0.01 mm RMS after rigid
alignment (contact springs of 199.8 N/mm under ~1 N leave a few micrometres).
"""

from __future__ import annotations

import numpy as np
import pytest
from synthetic import StandInBracketModel, regular_stencil

from pysolver.design.cellnodes import model_arrays
from pysolver.mechanics import build_model
from sim.model.collisions import completion_times
from sim.model.simulate import simulate_model


def _model(top, bottom):
    lay = regular_stencil(5, 4)
    nc = len(lay.cells.faces)
    th = np.c_[np.full(nc, top), np.full(nc, bottom)]
    geometry = model_arrays(lay.V, lay.UV, lay.F, rotvec=lay.rotvec)
    return build_model(lay.V, lay.UV, lay.F, th, geometry, rotvec=lay.rotvec)


def _fold_deg(fr, model):
    """Mean signed fold angle per frame (deg, + = concave on the top side)."""
    a, b = model.cell_bases[:, 0], model.cell_bases[:, 1]
    n = fr["base_rotation"][:, :, :, 2]  # R e_z: current normal of each base
    c = fr["base_center"]
    d = c[:, b] - c[:, a]
    dn = n[:, b] - n[:, a]
    s = -np.einsum("fci,fci->fc", dn, d) / np.linalg.norm(d, axis=2) ** 2  # ~ fold / length
    return np.degrees(s * np.linalg.norm(d, axis=2)).mean(axis=1)


def _rigid_rms(A, B):
    a0, b0 = A.mean(0), B.mean(0)
    U, _, Vt = np.linalg.svd((A - a0).T @ (B - b0))
    d = np.sign(np.linalg.det(U @ Vt))
    Q = (U @ np.diag([1, 1, d]) @ Vt).T
    return float(np.sqrt(np.mean(np.sum((A @ Q.T + b0 - Q @ a0 - B) ** 2, axis=1))))


@pytest.fixture(scope="module")
def sym_run():
    m = _model(0.4, 0.4)
    return m, simulate_model(m, StandInBracketModel(), t_end=120.0)


def test_symmetric_patch_stays_flat(sym_run):
    m, fr = sym_run
    assert fr["converged"].all()
    assert np.abs(fr["base_center"][:, :, 2]).max() < 1e-6
    assert np.abs(fr["membrane_vertices"][:, :, 2]).max() < 1e-6
    tilt = np.abs(fr["base_rotation"][:, :, :, 2] - [0, 0, 1]).max()
    assert tilt < 1e-8


def test_symmetric_patch_reaches_design(sym_run):
    m, fr = sym_run
    tc = completion_times(fr)
    assert np.isfinite(tc).all()  # every cell reached its bumpers
    assert _rigid_rms(fr["base_center"][-1], m.base_target) < 0.01
    # early stop once everything is in contact and nothing moves any more
    assert fr["summary"]["stopped_early"] and fr["t"][-1] < 120.0


def test_thinner_top_bends_toward_top():
    """Thinner (softer) top brackets contract first: the top layer gets shorter, so the
    patch folds with the top on the concave side (positive fold angle, the design-folder
    convention), then unfolds as the bottom catches up with its bumpers."""
    m = _model(0.3, 0.6)
    fr = simulate_model(m, StandInBracketModel(), t_end=90.0)
    fold = _fold_deg(fr, m)
    assert fold.max() > 0.5
    assert fold.min() > -0.05
    # bending is out of plane: base centres leave z = 0
    assert np.abs(fr["base_center"][:, :, 2]).max() > 0.1
    # the opposite asymmetry bends the other way (mirror symmetry of the model)
    m2 = _model(0.6, 0.3)
    fr2 = simulate_model(m2, StandInBracketModel(), t_end=90.0)
    assert np.allclose(_fold_deg(fr2, m2), -fold, atol=1e-6)
