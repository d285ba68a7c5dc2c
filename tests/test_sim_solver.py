"""Newton solver: linear solvers, convergence, line search on negative curvature.

Tolerances: Newton stops at the residual tolerance ``tol.newton_grad`` = 1e-6 N; backends agree
to 1e-10 relative; equilibria reached from different starts agree to 1e-9 relative in energy.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from synthetic import StandInBracketModel, regular_stencil

from pysolver.design.cellnodes import model_arrays
from pysolver.mechanics import build_model
from pysolver.mechanics.energies import ShellEnergy, State, rodrigues
from pysolver.mechanics.solver import (
    HAVE_CHOLMOD,
    LinearSolver,
    NotPositiveDefinite,
    StaticProblem,
    newton,
)
from pysolver.params import tol


def _spd(n=60, seed=0, shift=1.0):
    rng = np.random.default_rng(seed)
    A = sp.random(n, n, density=0.08, random_state=rng)
    A = (A @ A.T + shift * sp.eye(n)).tocsc()
    return sp.tril(A).tocsc(), A


@pytest.mark.parametrize("backend", ["cholmod", "superlu"])
def test_linear_solver(backend):
    if backend == "cholmod":
        assert HAVE_CHOLMOD, "scikit-sparse is not importable; 'make' installs it"
    L, A = _spd()
    b = np.arange(A.shape[0], dtype=float)
    s = LinearSolver(backend)
    s.factorize(L)
    x = s.solve(b)
    assert np.linalg.norm(A @ x - b) < 1e-10 * np.linalg.norm(b)
    L2, _ = _spd(shift=-50.0)  # indefinite
    with pytest.raises(NotPositiveDefinite):
        s.factorize(L2)
    s.factorize(L)  # usable again after a failure
    assert np.allclose(s.solve(b), x, rtol=1e-10)


@pytest.fixture(scope="module")
def patch():
    lay = regular_stencil(5, 4)
    th = np.full((len(lay.cells.faces), 2), 0.45)
    geometry = model_arrays(lay.V, lay.UV, lay.F, rotvec=lay.rotvec)
    m = build_model(lay.V, lay.UV, lay.F, th, geometry, rotvec=lay.rotvec)
    return m


def _energy(model):
    e = ShellEnergy(model)
    e.spring_coef = StandInBracketModel().coefficients(model.spring_thickness,
                                                       model.spring_bracket_length, 0.0)
    return e


def test_newton_dry_step_converges_quadratically(patch):
    e = _energy(patch)
    res = newton(StaticProblem(e, State.flat(patch)), max_iter=50)
    assert res.converged and res.residual < tol.newton_grad
    E = np.array([h[0] for h in res.history])
    r = np.array([h[1] for h in res.history])
    assert np.all(np.diff(E) <= 1e-10 * abs(E[0]))  # monotone energy decrease
    assert res.iterations <= 8
    k = np.flatnonzero(r < 1e-2)
    assert len(k) >= 2 and r[k[-1]] < 10 * r[k[-1] - 1] ** 2  # quadratic tail


def test_newton_same_equilibrium_from_perturbed_start(patch):
    e = _energy(patch)
    p0 = StaticProblem(e, State.flat(patch))
    r0 = newton(p0, max_iter=50)
    rng = np.random.default_rng(4)
    s = State.flat(patch)
    s.R = rodrigues(rng.normal(size=(patch.n_bases, 3)) * 0.05)
    s.c = s.c + rng.normal(size=s.c.shape) * 0.2
    s.f = s.f + rng.normal(size=s.f.shape) * 0.2
    r1 = newton(StaticProblem(e, s), max_iter=200)
    assert r0.converged and r1.converged
    assert abs(r1.energy - r0.energy) < 1e-9 * abs(r0.energy)


class _Toy:
    """E(x, y) = x^4/4 - x^2/2 + y^2 (+ coupling): a saddle at the origin, minima at x = +-1."""

    n = 2
    dof_scale = np.ones(2)
    trans_dofs = np.arange(2)
    rot_dofs = np.zeros(0, dtype=int)

    def __init__(self, x):
        self.state = np.asarray(x, float)

    @staticmethod
    def _eg(z):
        x, y = z
        E = x**4 / 4 - x * x / 2 + y * y + 0.1 * x * y
        g = np.array([x**3 - x + 0.1 * y, 2 * y + 0.1 * x])
        return E, g

    def evaluate(self, hessian=True, psd=False):
        E, g = self._eg(self.state)
        x = self.state[0]
        hxx = 3 * x * x - 1
        if psd:
            hxx = max(hxx, 0.0)
        # lower triangle, CSC with a stored diagonal (the solver's contract)
        H = sp.csc_matrix((np.array([hxx, 0.1, 2.0]), np.array([0, 1, 1]), np.array([0, 2, 3])),
                          shape=(2, 2))
        return E, g, H

    def trial(self, dx, alpha):
        return self.state + alpha * dx

    def energy_at(self, z):
        return self._eg(z)[0]

    def gradient_at(self, z):
        return self._eg(z)

    def accept(self, z):
        self.state = z

    def residual(self, g):
        return float(np.abs(g).max())

    def roundoff(self):
        return 1e-15


def test_line_search_escapes_saddle():
    """Started next to a saddle (negative curvature), the shifted Newton directions with the
    strong Wolfe search (which expands steps) reach a minimum quadratically."""
    pb = _Toy([1e-3, 0.5])
    res = newton(pb, tol=1e-12, max_iter=50, linear=LinearSolver("superlu"))
    assert res.converged and res.iterations < 25
    assert res.regularised >= 1
    x = pb.state
    assert abs(abs(x[0]) - 1.0) < 0.01
    E = np.array([h[0] for h in res.history])
    assert np.all(np.diff(E) <= 1e-15)
