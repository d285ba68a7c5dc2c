"""Conformal flattening: CETM energy/gradient, similarity on flat input, spherical cap."""

from __future__ import annotations

import igl
import numpy as np
import pytest
from scipy.integrate import quad
from scipy.spatial.transform import Rotation

from pysolver.design.flatten import (
    _cetm_energy,
    _cetm_state,
    cetm,
    compare_flattenings,
    corner_angles,
    distortion_metrics,
    lobachevsky,
    lscm,
)
from pysolver.design.surfaces import _disk_mesh
from pysolver.geometry import signed_areas_2d


def disk(radius=30.0, area=12.0):
    t = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    return _disk_mesh(np.c_[radius * np.cos(t), radius * np.sin(t)], area)


def test_lobachevsky_matches_integral():
    for x in (0.1, 0.5, 1.0, np.pi / 2, 2.5, 3.0):
        ref = -quad(lambda t: np.log(abs(2 * np.sin(t))), 0, x, limit=200)[0]
        assert lobachevsky(np.array([x]))[0] == pytest.approx(ref, abs=1e-9)
    assert lobachevsky(np.array([0.0, np.pi]))[0] == 0.0


def test_cetm_gradient_is_angle_defect():
    """dE/du_i = 2 pi - (angle sum at i), checked by central finite differences."""
    P, F = disk(20.0, 20.0)
    rng = np.random.default_rng(0)
    V = np.c_[P, 0.02 * (P[:, 0] ** 2 - P[:, 1] ** 2) / 20]
    n = len(V)
    lam0 = 2 * np.log(igl.edge_lengths(V, F))
    bnd = np.zeros(n, bool)
    bnd[igl.boundary_loop(F)] = True
    interior = np.flatnonzero(~bnd)
    theta = np.full(n, 2 * np.pi)
    u = np.zeros(n)
    u[interior] = 0.05 * rng.normal(size=len(interior))
    _, _, A, _ = _cetm_state(lam0, F, u)
    grad = theta - np.bincount(F.ravel(), weights=A.ravel(), minlength=n)
    h = 1e-6
    for i in rng.choice(interior, 8, replace=False):
        e = np.zeros(n)
        e[i] = h
        fd = (_cetm_energy(lam0, F, u + e, theta, interior)
              - _cetm_energy(lam0, F, u - e, theta, interior)) / (2 * h)
        assert fd == pytest.approx(grad[i], abs=1e-6)


@pytest.mark.parametrize("method", ["cetm", "lscm"])
def test_flat_input_gives_a_similarity(method):
    """Flattening an (arbitrarily placed) planar mesh returns it up to a similarity."""
    P, F = disk()
    R = Rotation.from_rotvec([0.3, -0.7, 0.2]).as_matrix()
    V = np.c_[P, np.zeros(len(P))] @ R.T + [5.0, -3.0, 12.0]
    UV = cetm(V, F)[0] if method == "cetm" else lscm(V, F)
    # best similarity UV -> P (complex least squares: P = a UV + b)
    z = UV[:, 0] + 1j * UV[:, 1]
    w = P[:, 0] + 1j * P[:, 1]
    M = np.c_[z, np.ones_like(z)]
    coef, *_ = np.linalg.lstsq(M, w, rcond=None)
    resid = np.abs(M @ coef - w).max()
    assert resid < 1e-7 * np.ptp(P)
    if method == "cetm":
        assert abs(abs(coef[0]) - 1) < 1e-9  # u = 0 everywhere: an isometry
    ang = np.degrees(np.abs(corner_angles(UV, F) - corner_angles(V, F))).max()
    assert ang < 1e-6


def cap(R=40.0, deg=55.0, area=6.0):
    rho = R * np.radians(deg)
    P, F = disk(rho, area)
    g = np.hypot(P[:, 0], P[:, 1]) / R
    az = np.arctan2(P[:, 1], P[:, 0])
    V = np.c_[R * np.sin(g) * np.cos(az), R * np.sin(g) * np.sin(az), R * np.cos(g)]
    return V, F


def test_spherical_cap_distortion_bounds():
    """A 55 deg spherical cap: CETM converges, keeps boundary lengths, no flips, corner
    angles within 1 deg on average and 5 deg at worst (discrete conformal maps change
    angles through the curvature of the mesh), conformal scale spread close to the smooth
    map's 1/cos^2(27.5 deg) = 1.27."""
    V, F = cap()
    UV, u, info = cetm(V, F)
    assert info["angle_error_rad"] < 1e-8
    assert np.all(signed_areas_2d(UV, F) > 0)
    loop = igl.boundary_loop(F)
    l3 = np.linalg.norm(V[loop] - V[np.roll(loop, -1)], axis=1)
    l2 = np.linalg.norm(UV[loop] - UV[np.roll(loop, -1)], axis=1)
    np.testing.assert_allclose(l2, l3, rtol=1e-9)
    m = distortion_metrics(V, UV, F)
    assert m["flips"] == 0
    assert m["angle_mean_deg"] < 1.0 and m["angle_max_deg"] < 5.0
    smooth = 1 / np.cos(np.radians(55 / 2)) ** 2
    assert abs(m["scale_spread"] - smooth) < 0.08
    # with the boundary lengths kept, the positively curved interior must shrink: u < 0
    assert u.min() < -0.1 and u.max() <= 1e-12


def test_compare_flattenings_records_both():
    V, F = cap(area=20.0)
    res = compare_flattenings(V, F)
    assert set(res) == {"cetm", "lscm"}
    for r in res.values():
        m = r.metrics
        for k in ("angle_mean_deg", "area_ratio_spread", "max_cell_length_mm", "flips"):
            assert k in m
        assert m["flips"] == 0


def test_cetm_with_a_boundary_scale_is_the_conformal_map_it_names():
    """On a flat disk, boundary data ``u = a x`` are the log-scale of the conformal map
    ``f(z) = exp(a z) / a`` (``|f'| = exp(a x)``): CETM must give that map, up to a rigid
    motion (measured: 5e-5 of the disk's size; 0.08 with the rim's lengths kept), and that
    log-scale inside (measured: 1.3e-4 of its range)."""
    P, F = disk()
    V = np.c_[P, np.zeros(len(P))]
    a = 0.01  # 1/mm: the scale varies by e^(+-0.3) over the disk
    UV, u, info = cetm(V, F, u_boundary=a * P[:, 0])
    bnd = igl.boundary_loop(F)
    assert np.allclose(u[bnd], a * P[bnd, 0], atol=1e-15)  # the Dirichlet data, as given
    assert np.abs(u - a * P[:, 0]).max() < 1e-3 * np.ptp(a * P[:, 0])
    z = P[:, 0] + 1j * P[:, 1]
    w = np.exp(a * z) / a
    M = np.c_[UV[:, 0] + 1j * UV[:, 1], np.ones(len(P))]
    coef, *_ = np.linalg.lstsq(M, w, rcond=None)
    assert abs(abs(coef[0]) - 1) < 1e-4  # no scaling left: a rigid motion
    assert np.abs(M @ coef - w).max() < 1e-3 * np.ptp(P)
    # every boundary edge is its 3D length times exp of its ends' mean log-scale
    L3 = np.linalg.norm(V[np.roll(bnd, -1)] - V[bnd], axis=1)
    L2 = np.linalg.norm(UV[np.roll(bnd, -1)] - UV[bnd], axis=1)
    assert np.allclose(L2, L3 * np.exp(a * (P[bnd, 0] + P[np.roll(bnd, -1), 0]) / 2),
                       rtol=1e-9)
