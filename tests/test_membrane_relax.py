"""Relaxation of a flat membrane's free nodes by the shell's Newton solver
(:class:`pysolver.temporal.membrane_model.FreeNodeProblem`, :func:`relax_contracted`).

Tolerances: gradient and Hessian to central finite differences (step 1e-6 mm) within 1e-6
relative; relaxed free-node forces below ``TOL.membrane_grad`` (1e-9 N); the relaxed energy
and tractions within 1e-9 relative of the values the membrane's hand-written Newton
iteration (replaced by the solver, commit 2ea23a2) gave; two starts of one membrane meet
within 1e-9 mm (the force tolerance over the smallest stiffness, ~0.3 N/mm, is 3e-9 mm; the
measured difference is 1e-12 mm).
"""

from __future__ import annotations

import numpy as np
import pytest

from pysolver.fitting.membrane_fit import patch_mesh
from pysolver.mechanics.energies import full_from_lower
from pysolver.mechanics.solver import newton
from pysolver.params import tol as TOL
from pysolver.temporal.membrane_model import (
    FreeNodeProblem,
    PlaneMembrane,
    _relax,
    cell_tractions,
    relax_contracted,
)

# the hand-written Newton's result on the patch below contracted by 0.9 (commit 2ea23a2)
REF_ENERGY = 125.14864226359023      # N mm
REF_TRACTION_SUM = 71.1265706411545  # N, all cells
COMPRESSED_TAU = 0.6                 # rest state 1/0.6 of the flat mesh: every element pushes


@pytest.fixture(scope="module")
def patch():
    pm = patch_mesh(6.0, rings=2, max_area=2.0)
    return pm, np.flatnonzero(pm.mesh.body < 0)


def _compressed_start(pm, free):
    """A compressed membrane and a start state whose exact Hessian is indefinite: its
    equilibrium from the flat layout with the free nodes moved by up to 0.2 mm (seeded)."""
    mem = PlaneMembrane(pm.mesh.xy, pm.mesh.tris, tau=COMPRESSED_TAU)
    x_eq = _relax(mem, pm.mesh.xy, free)
    x = x_eq.copy()
    x[free] += np.random.default_rng(1).uniform(-0.2, 0.2, (len(free), 2))
    return mem, x, x_eq


def test_free_node_problem_derivatives_match_finite_differences(patch):
    pm, free = patch
    mem = PlaneMembrane(pm.mesh.xy, pm.mesh.tris)
    x = relax_contracted(pm.mesh, pm.centers, mem, 0.9)
    x[free] += np.random.default_rng(0).uniform(-0.05, 0.05, (len(free), 2))
    prob = FreeNodeProblem(mem, x, free)
    E, g, H = prob.evaluate()
    assert E == pytest.approx(mem.energy(x), rel=1e-14)
    assert prob.residual(g) == np.abs(mem.gradient(x)[free]).max()
    # lower-triangle CSC with sorted indices and a stored diagonal, as the solver factorises
    assert sp_lower(H) and H.shape == (prob.n, prob.n) and len(prob.rot_dofs) == 0
    Hf = full_from_lower(H).toarray()
    ref = mem.hessian(x).toarray()[prob.fdof][:, prob.fdof]
    assert np.allclose(Hf, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    rng = np.random.default_rng(2)
    step = 1e-6
    for _ in range(3):
        v = rng.standard_normal(prob.n)
        Ep, gp = prob.gradient_at(prob.trial(v, step))
        Em, gm = prob.gradient_at(prob.trial(v, -step))
        assert (Ep - Em) / (2 * step) == pytest.approx(g @ v, rel=1e-6)
        fd = (gp - gm) / (2 * step)
        assert np.linalg.norm(fd - Hf @ v) <= 1e-6 * np.linalg.norm(Hf @ v)
        assert prob.energy_at(prob.trial(v, step)) == Ep
    # an inverted element: infinite energy, as PlaneMembrane.energy
    y = x.copy()
    t = pm.mesh.tris[np.isin(pm.mesh.tris, free).all(axis=1)][0]
    y[t[0]] = y[t[1]] + y[t[2]] - y[t[0]]  # vertex 0 reflected across the opposite edge
    assert mem.energy(y) == np.inf
    assert prob.energy_at(y) == np.inf


def sp_lower(H) -> bool:
    """Whether ``H`` is lower-triangle CSC, sorted, with the diagonal first in each column."""
    if H.format != "csc" or not H.has_sorted_indices:
        return False
    cols = np.repeat(np.arange(H.shape[1]), np.diff(H.indptr))
    return bool(np.all(H.indices >= cols)
                and np.array_equal(H.indices[H.indptr[:-1]], np.arange(H.shape[0])))


def test_relaxed_patch_is_the_reference_equilibrium(patch):
    pm, free = patch
    mem = PlaneMembrane(pm.mesh.xy, pm.mesh.tris)
    x = relax_contracted(pm.mesh, pm.centers, mem, 0.9)
    assert np.abs(mem.gradient(x)[free]).max() < TOL.membrane_grad
    assert mem.energy(x) == pytest.approx(REF_ENERGY, rel=1e-9)
    T = cell_tractions(pm.mesh, pm.centers, pm.cell_bases, mem, x)
    assert T.sum() == pytest.approx(REF_TRACTION_SUM, rel=1e-9)
    # the attached nodes are where the contraction put them
    att = pm.mesh.body >= 0
    c = pm.centers[pm.mesh.body[att]]
    assert np.allclose(x[att], 0.9 * c + (pm.mesh.xy[att] - c), rtol=0, atol=1e-12)


def test_relaxation_handles_compressed_elements(patch):
    pm, free = patch
    mem, x, x_eq = _compressed_start(pm, free)
    assert np.isfinite(mem.energy(x))
    J = np.linalg.det(mem.deformation(x))
    assert np.all(J < 1)  # every element compressed
    prob = FreeNodeProblem(mem, x, free)
    _, _, H = prob.evaluate()
    w = np.linalg.eigvalsh(full_from_lower(H).toarray())
    assert w[0] < 0  # exact Hessian indefinite
    _, _, Hc = prob.evaluate(psd=True)  # the convexified one is positive semi-definite
    assert np.linalg.eigvalsh(full_from_lower(Hc).toarray())[0] >= -1e-12 * w[-1]

    psd_calls = []

    class Counting(FreeNodeProblem):
        def evaluate(self, hessian=True, psd=False):
            psd_calls.append(psd)
            return super().evaluate(hessian, psd)

    counting = Counting(mem, x, free)
    res = newton(counting, tol=TOL.membrane_grad)
    assert res.converged and res.regularised > 0
    assert any(psd_calls)  # the convexified (per-element PSD) Hessian was used
    assert np.abs(counting.x - x_eq).max() < 1e-9
    assert np.abs(mem.gradient(counting.x)[free]).max() < TOL.membrane_grad
    # and through the module's relaxation
    y = _relax(mem, x, free)
    assert np.abs(y - x_eq).max() < 1e-9
    assert np.array_equal(x[pm.mesh.body >= 0], y[pm.mesh.body >= 0])


def test_relaxation_failures_raise_with_the_force(patch):
    pm, free = patch
    mem, x, _ = _compressed_start(pm, free)
    with pytest.raises(RuntimeError, match=r"did not converge .*\|g\| = \d\.\d\de[+-]\d+ N"):
        _relax(mem, x, free, max_iter=1)
    y = pm.mesh.xy.copy()
    t = pm.mesh.tris[np.isin(pm.mesh.tris, free).all(axis=1)][0]
    y[t[0]] = y[t[1]] + y[t[2]] - y[t[0]]
    with pytest.raises(RuntimeError, match="inverted"):
        _relax(mem, y, free)
    assert TOL.membrane_grad == TOL.membrane_grad
