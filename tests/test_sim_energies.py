"""Energies of the simulator: finite-difference derivatives, invariances, rest states.

Tolerances: gradients and Hessians match central finite differences with relative error
(Frobenius / 2-norm over all entries) < 1e-5; invariances and rest forces hold to round-off
(1e-10 relative / 1e-9 N).
"""

from __future__ import annotations

import numpy as np
import pytest
from synthetic import StandInBracketModel, regular_stencil

from pysolver.design.cellnodes import model_arrays
from pysolver.mechanics import build_model
from pysolver.mechanics.energies import (
    ShellEnergy,
    State,
    cross_hessian,
    cross_terms,
    full_from_lower,
    membrane_terms,
    rodrigues,
    spring_terms,
)
from pysolver.mechanics.kernels import HAVE_NUMBA
from pysolver.params import SIM

REL = 1e-5


def _fd(fun, X, eps=1e-6):
    """Central differences of ``fun(X) -> (E, g, H)``: gradient from E, Hessian from g."""
    E, g, H = fun(X)
    x = X.ravel()
    gf = np.zeros(x.size)
    Hf = np.zeros((x.size, x.size))
    for i in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp[i] += eps
        xm[i] -= eps
        Ep, gp, _ = fun(xp.reshape(X.shape))
        Em, gm, _ = fun(xm.reshape(X.shape))
        gf[i] = (Ep - Em) / (2 * eps)
        Hf[:, i] = (gp.ravel() - gm.ravel()) / (2 * eps)
    eg = np.linalg.norm(gf - g.ravel()) / np.linalg.norm(g)
    eH = np.linalg.norm(Hf - H) / np.linalg.norm(H)
    return eg, eH


@pytest.mark.parametrize("seed", range(3))
def test_spring_fd(seed):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(2, 3)) * 2
    L = np.linalg.norm(X[1] - X[0])
    rest = np.array([L + rng.uniform(-0.5, 1.0)])
    coef = np.array([[rng.uniform(1, 5), rng.uniform(-1, 0), rng.uniform(-0.2, 0.2), 0.01]])
    if seed == 2:
        coef = np.array([[SIM.kappa_c, 0.0, 0.0, 0.0]])  # bumper contact spring

    def fun(X):
        E, g, K = spring_terms(X[None, 0], X[None, 1], rest, coef)
        return E.sum(), g[0], np.block([[K[0], -K[0]], [-K[0], K[0]]])

    eg, eH = _fd(fun, X)
    assert eg < REL and eH < REL


@pytest.mark.parametrize("seed", range(3))
def test_cross_pair_fd(seed):
    rng = np.random.default_rng(10 + seed)
    X = rng.normal(size=(4, 3)) * 2
    w, R0 = np.array([rng.uniform(0.5, 2)]), np.array([rng.uniform(-0.5, 0.5)])

    def fun(X):
        E, g, parts = cross_terms(*[X[None, i] for i in range(4)], w, R0)
        H = cross_hessian(w, parts)[0]
        return E.sum(), g[0], np.transpose(H, (0, 2, 1, 3)).reshape(12, 12)

    eg, eH = _fd(fun, X)
    assert eg < REL and eH < REL


@pytest.mark.parametrize("seed", range(3))
def test_membrane_fd(seed):
    rng = np.random.default_rng(20 + seed)
    P = np.array([[0.0, 0.0], [2.0, 0.3], [0.4, 1.8]])
    Dm = np.stack([P[1] - P[0], P[2] - P[0]], 1) / SIM.tau
    dmi = np.linalg.inv(Dm)[None]
    area = np.array([0.5 * abs(np.linalg.det(Dm))])
    X = np.c_[P, np.zeros(3)] + rng.normal(size=(3, 3)) * 0.4

    def fun(X):
        E, g, H = membrane_terms(X[None], dmi, area, SIM.mu, SIM.membrane_h)
        return E.sum(), g[0], np.transpose(H[0], (0, 2, 1, 3)).reshape(9, 9)

    eg, eH = _fd(fun, X)
    assert eg < REL and eH < REL


def test_membrane_flat_energy_closed_form():
    """Pre-stretched flat membrane: Psi = mu/2 (2 tau^2 + 1/tau^4 - 3) per rest area."""
    rng = np.random.default_rng(1)
    P = rng.uniform(0, 3, size=(5, 3, 2))
    Dm = np.stack([P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]], 2) / SIM.tau
    dmi = np.linalg.inv(Dm)
    A_rest = 0.5 * np.abs(np.linalg.det(Dm))
    X = np.concatenate([P, np.zeros((5, 3, 1))], 2)
    E, g, _ = membrane_terms(X, dmi, A_rest, SIM.mu, SIM.membrane_h, hessian=False)
    t = SIM.tau
    psi = SIM.mu / 2 * (2 * t * t + t**-4 - 3)
    assert np.allclose(E, SIM.membrane_h * A_rest * psi, rtol=1e-12)
    # per flat area: 0.30025 N/mm (simulator.md 6.5)
    assert np.isclose(E.sum() / (A_rest.sum() * t * t), 0.30025, rtol=1e-4)


def test_psd_projection_is_psd():
    rng = np.random.default_rng(3)
    n = 50
    X = rng.normal(size=(n, 3, 3))
    P = np.array([[0.0, 0.0], [2.0, 0.3], [0.4, 1.8]])
    Dm = np.stack([P[1] - P[0], P[2] - P[0]], 1) / SIM.tau
    dmi = np.tile(np.linalg.inv(Dm), (n, 1, 1))
    area = np.full(n, 0.5 * abs(np.linalg.det(Dm)))
    *_, H = membrane_terms(X, dmi, area, SIM.mu, SIM.membrane_h, psd=True)
    w = np.linalg.eigvalsh(np.transpose(H, (0, 1, 3, 2, 4)).reshape(n, 9, 9))
    assert w.min() > -1e-9 * np.abs(w).max()
    xa, xb = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    coef = np.tile([3.0, -0.5, 0.0, 0.0], (n, 1))
    *_, K = spring_terms(xa, xb, np.full(n, 3.0), coef, psd=True)
    assert np.linalg.eigvalsh(K).min() > -1e-12


# ---------------------------------------------------------------------------------------------
# total reduced energy


@pytest.fixture(scope="module")
def patch_model():
    lay = regular_stencil(4, 3)
    th = np.full((len(lay.cells.faces), 2), 0.45)
    geometry = model_arrays(lay.V, lay.UV, lay.F, rotvec=lay.rotvec)
    return build_model(lay.V, lay.UV, lay.F, th, geometry, rotvec=lay.rotvec)


def _random_energy(model, seed, backend="auto"):
    rng = np.random.default_rng(seed)
    e = ShellEnergy(model, backend=backend)
    mat = StandInBracketModel()
    e.spring_coef = mat.coefficients(model.spring_thickness, model.spring_bracket_length, 20.0,
                                     eta=0.2)
    e.spring_rest = model.spring_rest0 - rng.uniform(0, 0.3, len(model.spring_rest0))
    contact = rng.random(len(e.spring_rest)) < 0.3
    e.spring_coef[contact] = (SIM.kappa_c, 0, 0, 0)
    e.spring_rest[contact] = model.spring_collision[contact]
    s = State.flat(model)
    s.R = rodrigues(rng.normal(size=(model.n_bases, 3)) * 0.2)  # rotated bases
    s.c = s.c + rng.normal(size=s.c.shape) * 0.1
    s.f = s.f + rng.normal(size=s.f.shape) * 0.1
    return e, s


@pytest.mark.parametrize("seed", [0, 1])
def test_reduced_gradient_and_hessian_fd(patch_model, seed):
    """Reduced gradient (centres, rotation vectors, free vertices) and Hessian vs finite
    differences of the energy through the exponential-map retraction used by the solver."""
    e, s = _random_energy(patch_model, seed)
    n = patch_model.n_dof
    E, g, H = e.evaluate(s)
    H = full_from_lower(H).toarray()
    eye = np.eye(n)
    eps = 1e-5
    gf = np.array([(e.energy(s.moved(eye[i], eps)) - e.energy(s.moved(eye[i], -eps))) / (2 * eps)
                   for i in range(n)])
    assert np.linalg.norm(gf - g) / np.linalg.norm(g) < REL
    # Hessian by second differences of the energy on a subset: two bases (all 12 DOFs) and
    # the last three free vertices
    idx = np.r_[0:12, n - 9:n]
    eps = 1e-4
    Hf = np.zeros((len(idx), len(idx)))
    for a, i in enumerate(idx):
        for b, j in enumerate(idx[a:], start=a):
            def f(si, sj, i=i, j=j):
                return e.energy(s.moved(si * eye[i] + sj * eye[j], eps))
            Hf[a, b] = Hf[b, a] = (f(1, 1) - f(1, -1) - f(-1, 1) + f(-1, -1)) / (4 * eps * eps)
    Hs = H[np.ix_(idx, idx)]
    assert np.linalg.norm(Hf - Hs) / np.linalg.norm(Hs) < REL


def test_numba_and_numpy_assembly_agree(patch_model):
    assert HAVE_NUMBA, "numba is not importable; 'make' installs it (pyproject dependency)"
    for psd in (False, True):
        (e1, s), (e2, _) = _random_energy(patch_model, 5, "numpy"), _random_energy(patch_model, 5,
                                                                                   "numba")
        E1, g1, H1 = e1.evaluate(s, psd=psd)
        E2, g2, H2 = e2.evaluate(s, psd=psd)
        assert abs(E1 - E2) < 1e-12 * abs(E1)
        assert np.abs(g1 - g2).max() < 1e-12 * np.abs(g1).max()
        assert abs(full_from_lower(H1) - full_from_lower(H2)).max() < 1e-12 * abs(H1).max()


def test_psd_hessian_is_psd(patch_model):
    e, s = _random_energy(patch_model, 7)
    _, _, H = e.evaluate(s, psd=True)
    w = np.linalg.eigvalsh(full_from_lower(H).toarray())
    assert w.min() > -1e-9 * w.max()


def test_rigid_motion_invariance(patch_model):
    """Energy unchanged by a global rotation + translation; net force and torque vanish."""
    e, s = _random_energy(patch_model, 2)
    E0, g = e.gradient(s)
    Q = rodrigues(np.array([[0.3, -1.1, 0.7]]))[0]
    t = np.array([12.0, -5.0, 3.0])
    moved = State(s.c @ Q.T + t, Q @ s.R, s.f @ Q.T + t)
    assert abs(e.energy(moved) - E0) < 1e-12 * abs(E0)
    m = patch_model.n_bases
    body = g[: 6 * m].reshape(m, 6)
    free = g[6 * m:].reshape(-1, 3)
    force = body[:, :3].sum(0) + free.sum(0)
    torque = (body[:, 3:].sum(0) + np.cross(s.c, body[:, :3]).sum(0)
              + np.cross(s.f, free).sum(0))
    assert np.abs(force).max() < 1e-9 and np.abs(torque).max() < 1e-8


def test_zero_force_at_rest(patch_model):
    """Springs at their rest length and cross pairs at their flat rest difference exert no
    force: in the flat state only the membrane pulls."""
    e = ShellEnergy(patch_model)
    e.spring_coef = StandInBracketModel().coefficients(patch_model.spring_thickness,
                                                       patch_model.spring_bracket_length, 0.0)
    s = State.flat(patch_model)
    parts = e.energy_parts(s)
    assert parts["springs"] == 0.0 and abs(parts["cross"]) < 1e-20
    X, _ = e.positions(s)
    sp_ = patch_model.spring_points
    _, gs, _ = spring_terms(X[sp_[:, 0]], X[sp_[:, 1]], e.spring_rest, e.spring_coef)
    cp = patch_model.cross_points
    _, gx, _ = cross_terms(*(X[cp[:, i]] for i in range(4)), patch_model.cross_weight,
                           patch_model.cross_rest)
    assert np.abs(gs).max() < 1e-12 and np.abs(gx).max() < 1e-9


def test_model_geometry(patch_model):
    """Bracket springs: flat length = b (equilateral cells), bumper length = target distance;
    membrane vertices attached to a base lie on its outline (radius base_r corners)."""
    md = patch_model
    assert np.allclose(md.spring_rest0, md.spring_bracket_length, atol=1e-6)
    assert np.all(md.spring_collision < md.spring_rest0)
    att = md.mem_body >= 0
    r = np.linalg.norm(md.mem_flat[att] - md.base_flat[md.mem_body[att]], axis=1)
    assert r.max() <= md.unit.base_r + 1e-9 and r.min() > 0.8 * md.unit.base_r
    free = ~att
    d = np.linalg.norm(md.mem_flat[free][:, None, :2] - md.base_flat[None, :, :2], axis=2)
    assert d.min() >= md.unit.base_r * np.cos(md.unit.alpha_rad) - 1e-9  # outside every base
    assert np.all(md.tri_rest_area > 0)
