"""The measured bound on the longest flat cell of any conformal stencil of a target
(:mod:`pysolver.design.stencil.feasibility`), against closed forms on a plate and a cylinder."""

from __future__ import annotations

from dataclasses import replace

import igl
import numpy as np
import pytest
from _shared import shared_file

from pysolver.design import surfaces
from pysolver.design.flatten import cetm
from pysolver.design.mesh_input import load_input
from pysolver.design.stencil.feasibility import (
    cell_scale_curvature,
    conformal_bound,
    describe_bound,
    min_cell_length,
    rim_log_scale,
    shortest_cell,
    target_bound,
    worst_cell_curvature,
)
from pysolver.design.stencil.remesh import resample_dense
from pysolver.params import STENCIL, UNIT_CELL

P = UNIT_CELL


def _plate(width=80.0, height=60.0):
    P2, F = surfaces._dense(np.array([[0, 0], [width, 0], [width, height], [0, height]],
                                     float))
    return np.c_[P2, np.zeros(len(P2))], F


def _cylinder(radius, width=70.0, height=60.0):
    """A plate rolled around the y axis; also its unrolled coordinates."""
    V, F = _plate(width, height)
    a = V[:, 0] / radius
    return np.c_[radius * np.sin(a), V[:, 1], radius * (1 - np.cos(a))], F, V


def _fixed_point(kappa):
    D = shortest_cell(P)
    for _ in range(200):
        t = kappa * D / 2
        D = 2 * np.cos(t) * (P.base_r + P.layer_h * np.tan(t) + P.min_bumper)
    return D, kappa * D / 2


def test_shortest_cell_grows_with_curvature():
    assert min_cell_length(np.array([0.0]))[0] == pytest.approx(2 * (P.base_r + P.min_bumper))
    k = np.array([0.0, 0.02, 0.05, 0.1])
    D = min_cell_length(k)
    assert np.all(np.diff(D) > 0)
    for kk, d in zip(k, D, strict=True):
        assert d == pytest.approx(_fixed_point(kk)[0], rel=1e-9)
    assert np.isinf(min_cell_length(np.array([1.0]))[0])  # a 1 mm radius: no cell fits


def test_worst_cell_curvature_of_sphere_and_cylinder():
    # three cell directions 60 deg apart at their best orientation: a sphere folds every
    # cell by k, a cylinder at least one by 3/4 k (directions at 30, 90, 150 deg)
    got = worst_cell_curvature(np.array([0.1, 0.1, 0.1]), np.array([0.1, 0.0, -0.1]))
    np.testing.assert_allclose(got[:2], [0.1, 0.075], rtol=1e-3)
    assert 0.05 <= got[2] <= 0.1  # a saddle: some direction keeps a fold


def test_curvature_at_cell_scale_of_a_cylinder():
    V, F, flat = _cylinder(40.0)
    k1, k2, d1 = cell_scale_curvature(V, F, shortest_cell(P))
    # away from the rim (a ball there is cut by it)
    inner = np.all((flat[:, :2] > 10) & (flat[:, :2] < [60, 50]), axis=1)
    np.testing.assert_allclose(np.abs(k1[inner]), 1 / 40.0, rtol=0.05)
    assert np.abs(k2[inner]).max() < 0.1 / 40.0
    assert np.abs(d1[inner][:, 1]).max() < 0.1  # the curved direction runs across y


def test_bound_on_a_flat_plate_is_the_shortest_cell():
    """No curvature, no conformal stretch: the shortest cell, contracted only by the gap."""
    V, F = _plate()
    b = conformal_bound(V, F, P)
    want = shortest_cell(P) * (1 + P.min_gap / P.max_cell_length)
    assert b["bound_mm"] == pytest.approx(want, rel=0.01)
    assert b["contraction"] == pytest.approx(1.0, abs=0.01) and b["printable"]
    assert b["fold_deg"] < 0.5


def test_bound_on_a_cylinder_is_its_folded_cell():
    """Developable: no conformal stretch; every cell folds by the curvature at 3/4."""
    R = 15.0
    V, F, _ = _cylinder(R, width=60.0)
    b = conformal_bound(V, F, P)
    D, t = _fixed_point(0.75 / R)
    want = D * (1 / np.cos(t) + P.layer_h * 0.75 / R + P.min_gap / P.max_cell_length)
    assert b["bound_mm"] == pytest.approx(want, rel=0.03)
    assert b["contraction"] < 1.05  # (the rim's scale moves it a little)
    assert b["fold_deg"] == pytest.approx(np.degrees(2 * t), rel=0.15)  # (a max: rim noise)
    # a smaller bumper lowers it; a limit under it makes the target unprintable, and says so
    assert conformal_bound(V, F, replace(P, min_bumper=0.1))["bound_mm"] < b["bound_mm"]
    low = replace(P, max_cell_length=b["bound_rim_fixed_mm"] * 0.95)
    lb = conformal_bound(V, F, low)
    assert not lb["printable"]
    assert "no stencil of it prints" in describe_bound(lb, low)
    assert "does not exclude" in describe_bound(b, P)


def test_boundary_scale_only_lowers_the_bound():
    """The flattening's free boundary scale is a minimum over a family that contains the
    fixed rim (u = 0): never above it; on a dome it is strictly lower."""
    s = surfaces.builtin("dome")
    b = conformal_bound(s.V, s.F, P)
    assert b["bound_mm"] <= b["bound_rim_fixed_mm"] + 1e-9
    assert b["bound_mm"] < b["bound_rim_fixed_mm"]
    assert b["contraction"] > 1.05  # a cap must be stretched to lie flat


def _off_centre_bowl():
    """A paraboloid (radius 50 mm at its apex) over a 100 x 60 mm rectangle whose centre is
    25 mm from the apex: its cells need more contraction at one end than at the other."""
    P2, F = surfaces._dense(np.array([[0, 0], [100, 0], [100, 60], [0, 60]], float))
    P2 = P2 - [25.0, 30.0]
    return np.c_[P2, (P2**2).sum(axis=1) / 100.0], F


def test_rim_log_scale_is_harmonic_lowers_the_bound_and_ignores_last_bits():
    """The rim's log-scale the free layout takes: harmonic, of mean 0 on the rim; the bound
    it gives lies between the linear programme's minimum and the rim kept (measured 5.587 <=
    5.626 < 5.652 mm); and 1e-9 of the size on the input moves it by under 1e-6."""
    V, F = _off_centre_bowl()
    _, u, _ = cetm(V, F)
    h = rim_log_scale(V, F, P)
    bnd = igl.boundary_loop(F)
    inner = np.setdiff1d(np.arange(len(V)), bnd)
    assert np.abs((-igl.cotmatrix(V, F) @ h)[inner]).max() < 1e-9
    assert abs(h[bnd].mean()) < 1e-12
    b = conformal_bound(V, F, P)
    with_h = conformal_bound(V, F, P, u=u + h)["bound_rim_fixed_mm"]
    assert b["bound_mm"] - 1e-3 <= with_h < b["bound_rim_fixed_mm"] - 0.02
    rng = np.random.default_rng(0)
    for _ in range(2):
        Vj = V + rng.uniform(-1.0, 1.0, V.shape) * 1e-9 * np.ptp(V)
        assert np.abs(rim_log_scale(Vj, F, P) - h).max() < 1e-6


def test_rim_scale_free_admits_the_peer_beetle():
    """The peer beetle at 150 mm with 0.1 mm bumpers, read as the design stage reads it:
    its rim's scale free lowers the measured bound well below the rim kept (8.71 against
    9.35 mm), so that a limit between the two (9.0 mm) admits it only free; the smoothed
    choice of the rim's scale comes within 0.15 mm of the free bound."""
    m = load_input(shared_file("peer-shapes", "beetle.obj"), size=150.0)
    V = m.V - m.V.mean(axis=0)
    p = replace(P, min_bumper=0.1, max_cell_length=9.0)
    b = target_bound(V, m.F, p)
    assert b["bound_mm"] < p.max_cell_length < b["bound_rim_fixed_mm"]
    assert b["bound_rim_fixed_mm"] - b["bound_mm"] > 0.3
    assert b["printable"] and b["rim_scale"] == "free"
    assert not target_bound(V, m.F, p, replace(STENCIL, rim_scale="kept"))["printable"]
    Vd, Fd = resample_dense(V, m.F, STENCIL.dense_faces)
    _, u, _ = cetm(Vd, Fd)
    with_h = conformal_bound(Vd, Fd, p, u=u + rim_log_scale(Vd, Fd, p))["bound_rim_fixed_mm"]
    assert b["bound_mm"] - 1e-3 <= with_h < b["bound_mm"] + 0.15
