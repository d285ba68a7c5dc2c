"""Membrane traction on a unit cell (pysolver.fitting.cell_membrane), the input of temporal
programming.

Tolerances: closed form at d = 0 to 1e-4 relative; mesh refinement 0.5 -> 0.25 mm^2 changes
the traction by < 1 %; the (default, simulator) mesh agrees with the design stage's fitted
linear membrane model to 15 % (the fit was made on a 10x finer mesh, see the module doc).
"""

from __future__ import annotations

import numpy as np
import pytest

from pysolver.fitting.cell_membrane import membrane_traction
from pysolver.params import SIM, UNIT_CELL
from pysolver.temporal.membrane_model import load_membrane_model


@pytest.mark.parametrize("b0", [1.8, 3.8])
def test_uniform_prestress_closed_form(b0):
    T = membrane_traction(b0, 0.0)
    l0 = b0 + UNIT_CELL.bracket_offset
    exact = SIM.mu * SIM.membrane_h * (1 - SIM.tau**-6) * np.sqrt(3) * l0
    assert abs(T - exact) < 1e-4 * exact


def test_monotone_and_mesh_converged():
    d = np.array([0.0, 0.4, 0.8])
    T_short = membrane_traction(2.0, d)
    T_long = membrane_traction(4.0, d)
    assert np.all(np.diff(T_short) < 0) and np.all(np.diff(T_long) < 0)  # pre-stretch relaxes
    assert np.all(T_long > T_short)
    f1 = membrane_traction(2.0, 0.8, max_area=0.5)
    f2 = membrane_traction(2.0, 0.8, max_area=0.25)
    assert abs(f1 - f2) < 0.01 * f2


def test_agrees_with_design_membrane_model():
    model = load_membrane_model()  # the committed fit: it must load (no skip)
    b = np.array([1.8, 2.8, 4.8, 1.8, 2.8, 4.8])
    d = np.array([0.0, 0.0, 0.0, 0.8, 0.8, 0.8])
    T = membrane_traction(b, d)
    F = np.array([float(np.squeeze(model.force(bi, di))) for bi, di in zip(b, d, strict=True)])
    assert np.all(np.abs(T - F) < 0.15 * F)
