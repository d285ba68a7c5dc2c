"""A single unit cell: the 3D simulation reduces to a 1-D force balance.

Two equilateral triangles (one cell, straight target) are symmetric about the cell axis, the
perpendicular bisector and the mid-plane, so the bases only translate along the axis, all 4
bracket springs have the same length ``b = l - 2 r cos 37`` and the cross pairs are at rest.
Equilibrium is then ``4 F_b(rest - b) = T(l)`` with ``T = dW_mem/dl`` the membrane pull.
The test integrates this 1-D problem independently (its own plastic rest-length update and
bumper switch) and compares the bracket length frame by frame.

Tolerance: |b_sim - b_1D| < 1e-5 mm (Newton stops at 1e-6 N; the 1-D membrane force is a
central difference with step 1e-5 mm).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq
from synthetic import StandInBracketModel, single_cell_stencil

from pysolver.design.cellnodes import model_arrays
from pysolver.mechanics import build_model
from pysolver.mechanics.energies import ShellEnergy, State
from pysolver.params import SIM
from sim.model.collisions import completion_times
from sim.model.simulate import simulate_model


def test_single_cell_matches_1d_force_balance():
    V, UV, F = single_cell_stencil(flat_length=6.0, target_length=4.8)
    h = 0.35
    model = build_model(V, UV, F, np.full((1, 2), h), model_arrays(V, UV, F))
    assert model.n_free == 0  # membrane = the quad between the bases: W(l) is explicit
    mat = StandInBracketModel()
    t_end = 60.0
    fr = simulate_model(model, mat, t_end=t_end, dt=0.5)
    b_sim = fr["bracket_length"][:, 0, :]  # (n_frames, 4)
    assert np.ptp(b_sim, axis=1).max() < 1e-7  # the four springs stay equal
    assert np.abs(fr["base_center"][:, :, 2]).max() < 1e-9  # stays flat
    Rdev = np.abs(fr["base_rotation"] - np.eye(3)).max()
    assert Rdev < 1e-7  # no rotation

    # 1-D model
    e = ShellEnergy(model)
    ca, cb = model.base_flat
    mid, u = 0.5 * (ca + cb), (cb - ca) / np.linalg.norm(cb - ca)
    off = model.unit.bracket_offset

    def W(l):
        s = State.flat(model)
        s.c = np.stack([mid - 0.5 * l * u, mid + 0.5 * l * u])
        return e.energy_parts(s)["membrane"]

    def T(l, d=1e-5):  # membrane pull on the cell = dW/dl
        return (W(l + d) - W(l - d)) / (2 * d)

    L0 = model.spring_rest0[0]
    Lc = model.spring_collision[0]
    bmat = model.cell_bracket_length[0]
    rest, contact, b_prev = L0, False, None
    b1 = []
    for k, t in enumerate(fr["t"]):
        eta = 0.0 if k == 0 else SIM.eta
        c = mat.coefficients(h, bmat, t, eta=eta)
        if k > 0:
            rest = min(rest, L0 - eta * (L0 - b_prev))
            contact = b_prev <= Lc
            if contact:
                rest = Lc
        if contact:
            def bal(b, rest=rest):
                return 4 * SIM.kappa_c * (rest - b) - T(b + off)
        else:
            def bal(b, c=c, rest=rest):
                x = rest - b
                return 4 * (x * (c[0] + x * (c[1] + x * (c[2] + x * c[3])))) - T(b + off)
        b = brentq(bal, Lc - 0.3, L0 + 0.2, xtol=1e-13)  # F is monotone on this range
        b1.append(b)
        b_prev = b
    b1 = np.array(b1)
    assert np.abs(b_sim[:, 0] - b1).max() < 1e-5
    # the cell reaches its bumpers within the run
    assert b1.min() < Lc + 1e-3
    assert np.isfinite(completion_times(fr)[0])
