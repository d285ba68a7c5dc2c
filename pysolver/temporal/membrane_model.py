"""Linearised membrane model F_mem(b, d): the membrane's pull on one unit cell.

Temporal programming (Supplementary Note 4) needs, for every unit cell, the force
with which the pre-stretched membrane compresses the cell's brackets when the
cell reaches its target shape.  The paper models the membrane of a cell as one
linear spring between the centroids of the bracket end points (the two
"mid-side" points of the cell, whose distance is the bracket length ``b``) and
sets ``F_mem(b, d)`` to a first-order polynomial in each variable, fitted by
sampling FEM membrane simulations over initial bracket lengths and deformations.

This module does that sampling itself (the reference's fit is not available):

* **Patch.** A hexagonal patch of a regular (equilateral) stencil with flat
  central length ``l0`` between neighbouring base centres; bracket length
  ``b0 = l0 - 4 cos 37 deg``.  Bases are rigid, bounded by their bracket corner
  nodes (radius ``base_r``, +-37 deg around each neighbour direction; the design
  stage's ``model_arrays``).  The membrane mesh is the simulator's own
  (:func:`pysolver.mechanics.membrane_mesh`, ``simulator.md`` §6.6: corners attached
  to their base, free boundary segments between the corners of neighbouring bases
  at boundary vertices), which conforms to the stencil edges (clipped at the free
  boundary) so the force across each cell can be read exactly element by element.
* **Loading.** The patch contracts uniformly: every base centre is moved to
  ``s * c`` with ``s = (l0 - d) / l0`` (bases translate, do not rotate, do not
  shrink), so every cell's bracket length goes from ``b0`` to ``b0 - d``.  The
  free membrane nodes are relaxed (incompressible neo-Hookean CST, rest state
  = flat / tau, as the simulator's ``MEM_FINE`` membrane).
* **Traction of a cell.** The force that the membrane of one face (base) exerts
  across the shared stencil edge on the membrane of the other face, projected
  on the cell axis (positive = pulls the bases together = compresses the
  brackets): ``T = u . sum_seg h P N dS`` with the first Piola-Kirchhoff stress
  ``P`` averaged over the two elements at each edge segment.  This is the force
  the cell's four brackets must carry: summed over all cells it satisfies the
  virtual-work identity ``dE_mem/ds = l0 * sum_c T_c`` (tested).
* **Fit.** Interior cells (two stencil rings away from the patch boundary)
  give the samples; ``F_mem(b, d) = c0 + c1 b + c2 d + c3 b d`` (first order in
  each variable, SI Note 4) by least squares.  Boundary cells (an end of the
  shared edge on the boundary, the ``boundary`` column of ``cells.csv``) are
  compared with the model to measure the boundary weakening factor.

``F_mem`` is the **total** force of the cell (all four brackets, two per
layer); the per-bracket target used for the thickness design is ``F_mem / 4``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..design.cellnodes import model_arrays
from ..errors import InputError
from ..material.validate import (
    MEMBRANE_FIX,
    MEMBRANE_KIND,
    _describe,
    _File,
    _get,
    _is_number,
    _vector,
    validate_model_file,
)
from ..mechanics import MembraneMesh, membrane_mesh
from ..mechanics.energies import SparsePattern, membrane_terms
from ..mechanics.rim import margin_rest, rim_margin
from ..mechanics.solver import LinearSolver, newton
from ..params import MEMBRANE_MODEL_FILE, MODEL_FILES, NEWTON, PROGRAMMING, SIM, UNIT_CELL
from ..params import tol as TOL

TERMS = {
    "1": lambda b, d: np.ones_like(b),
    "b": lambda b, d: b,
    "d": lambda b, d: d,
    "b*d": lambda b, d: b * d,
    "d/b": lambda b, d: d / b,
}
"""Monomials a membrane model may use (b = flat bracket length b0, d = shortening, mm)."""

MODEL_TERMS = ("1", "b", "d", "d/b")
"""Chosen form: F = c0 + c1 b + (c2 + c3 / b) d -- linear in d (a linear spring per cell, as in
SI Note 4) whose offset is linear in b and whose stiffness has a 1/b part (the membrane strip in
the bracket gap is a spring of length ~b).  The SI's strictly bilinear form (``b*d`` instead of
``d/b``) leaves 2.5x the rms residual and up to 10 % error on short cells (b0 < 2.5 mm); both
fits are recorded in the model file."""

SI_TERMS = ("1", "b", "d", "b*d")
"""First order in each variable (SI Note 4's wording), fitted for comparison."""


def form_string(terms) -> str:
    return " + ".join(f"c{i}" + ("" if t == "1" else f"*{t}") for i, t in enumerate(terms))


FORM = form_string(MODEL_TERMS)


# ----------------------------------------------------------------------------------------------
# the model
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MembraneModel:
    """Linearised membrane traction of one unit cell.

    Attributes
    ----------
    coef : (k,) float
        Coefficients of ``terms`` (N, N/mm, ...).
    terms : tuple of str
        Monomials (keys of :data:`TERMS`), default :data:`MODEL_TERMS`:
        ``F_mem(b, d) = c0 + c1 b + c2 d + c3 d / b``.
    boundary_factor : float
        Factor on ``F_mem`` of boundary cells used for the thickness design.
    residual_rms_N, residual_max_N : float, N
        Fit residual on the FEM samples (interior cells).
    samples : dict
        The FEM samples (``b0_mm``, ``d_mm``, ``force_N``) the model was fitted to.
    meta : dict
        Everything else in the model file (provenance).
    """

    coef: np.ndarray
    terms: tuple = MODEL_TERMS
    boundary_factor: float = SIM.boundary_weakening
    residual_rms_N: float = float("nan")
    residual_max_N: float = float("nan")
    samples: dict = field(default_factory=dict)
    meta: dict = field(default_factory=dict)

    def force(self, b_mm, d_mm, boundary=None):
        """Membrane pull on a whole unit cell (all 4 brackets), N.

        Parameters
        ----------
        b_mm : (n,) float, mm
            Initial (flat) bracket length ``b0`` of the cell.
        d_mm : (n,) float, mm
            Shortening of the cell's membrane spring, ``b0 - b`` (compression positive).
        boundary : (n,) bool, optional
            Boundary cells; their force is multiplied by :attr:`boundary_factor`.

        Returns
        -------
        F : (n,) float, N
            Total membrane traction carried by the cell's 4 brackets.
        """
        b, d = np.broadcast_arrays(np.asarray(b_mm, dtype=float), np.asarray(d_mm, dtype=float))
        f = _design_matrix(b.ravel(), d.ravel(), self.terms) @ self.coef
        f = f.reshape(b.shape)
        if boundary is not None:
            f = np.where(np.asarray(boundary, dtype=bool), self.boundary_factor * f, f)
        return f

    def force_per_bracket(self, b_mm, d_mm, boundary=None):
        """Target force of one single bracket: ``force(...) / 4`` (N)."""
        return self.force(b_mm, d_mm, boundary) / 4.0


def check_membrane_model(d: dict, path=None) -> dict:
    """Check the content of a membrane model file (rules in :mod:`pysolver.material.validate`).

    Returns
    -------
    dict
        ``terms`` tuple of str, ``coef`` (k,) float, ``boundary_factor`` float,
        ``residual_rms_N``, ``residual_max_N`` float (N), ``samples`` dict of (n,) float.
    """
    f = _File(path if path is not None else "<model>", MEMBRANE_KIND, MEMBRANE_FIX)
    terms = _get(f, d, "terms", "terms")
    if not (isinstance(terms, list) and terms and all(isinstance(t, str) for t in terms)):
        f.fail("terms", f"is {_describe(terms)}; expected a list of monomial names "
                        f"({', '.join(TERMS)}).")
    for i, t in enumerate(terms):
        if t not in TERMS:
            f.fail(f"terms[{i}]", f"= {t!r} is not a known monomial ({', '.join(TERMS)}).")
    if len(set(terms)) != len(terms):
        f.fail("terms", f"{terms} repeats a monomial.")
    coef = _vector(f, _get(f, d, "coefficients", "coefficients"), "coefficients", len(terms))
    fit = _get(f, d, "fit", "fit")
    res = {}
    for k in ("residual_rms_N", "residual_max_N"):
        v = _get(f, fit, k, f"fit.{k}")
        if not (_is_number(v) and math.isfinite(v) and v >= 0):
            f.fail(f"fit.{k}", f"is {_describe(v)}; it must be a finite number >= 0 (N).")
        res[k] = float(v)
    lo, hi = MODEL_FILES.boundary_factor_range
    bf = d.get("boundary_factor", None)
    if bf is not None and not (_is_number(bf) and lo < bf <= hi):
        f.fail("boundary_factor", f"is {_describe(bf)}; it must be a number in ({lo:g}, {hi:g}].")
    samples = {}
    s = d.get("samples", {})
    if not isinstance(s, dict):
        f.fail("samples", f"is {_describe(s)}, expected an object.")
    for k in ("b0_mm", "d_mm", "force_N"):
        if k in s:
            samples[k] = _vector(f, s[k], f"samples.{k}")
    if len({len(v) for v in samples.values()}) > 1:
        f.fail("samples", "b0_mm, d_mm and force_N have different lengths "
                          f"({', '.join(f'{k} {len(v)}' for k, v in samples.items())}).")
    b_lo, b_hi = MODEL_FILES.membrane_b_range_mm
    n = MODEL_FILES.membrane_samples
    b = np.linspace(b_lo, b_hi, n)
    frac = np.linspace(0.0, MODEL_FILES.membrane_d_fraction, n)
    B, Fr = np.meshgrid(b, frac, indexing="ij")
    D = Fr * B
    with np.errstate(all="ignore"):
        F = (_design_matrix(B.ravel(), D.ravel(), tuple(terms)) @ coef).reshape(B.shape)
    if not np.all(F > 0):
        i = np.unravel_index(np.argmin(F), F.shape)
        f.fail("coefficients", f"give a membrane force F_mem = {F[i]:.4g} N at b0 = "
                               f"{B[i]:.3g} mm, d = {D[i]:.3g} mm; the membrane must pull (F_mem "
                               f"> 0) for b0 in [{b_lo:g}, {b_hi:g}] mm and d up to "
                               f"{MODEL_FILES.membrane_d_fraction:g} b0.")
    grow = np.diff(F, axis=1)
    if np.any(grow > 0):
        i = np.unravel_index(np.argmax(grow), grow.shape)
        f.fail("coefficients", f"give a membrane force that grows from {F[i]:.4g} N to "
                               f"{F[i[0], i[1] + 1]:.4g} N as a cell with b0 = {B[i]:.3g} mm "
                               f"shortens from d = {D[i]:.3g} to {D[i[0], i[1] + 1]:.3g} mm; the "
                               "pre-stretched membrane must relax as it contracts.")
    return dict(res, terms=tuple(terms), coef=coef,
                boundary_factor=None if bf is None else float(bf), samples=samples)


def validate_membrane_model_file(path) -> dict:
    """Read and check a membrane model file; returns :func:`check_membrane_model`'s dict plus
    ``data`` (the JSON object).

    Raises
    ------
    InputError
        The first rule the file breaks, naming the file, key and rule.
    """
    return validate_model_file(path, MEMBRANE_KIND, MEMBRANE_FIX, check_membrane_model)


def load_membrane_model(path=None) -> MembraneModel:
    """Load a membrane model file (default: the committed ``pysolver/data/membrane_model.json``).

    Raises
    ------
    InputError
        If the file is missing, is not a membrane model, or breaks a rule of
        :mod:`pysolver.material.validate` (the message names the key and the rule).
    """
    if isinstance(path, MembraneModel):
        return path
    p = Path(path) if path is not None else MEMBRANE_MODEL_FILE
    v = validate_membrane_model_file(p)
    bf = v["boundary_factor"]
    return MembraneModel(coef=v["coef"], terms=v["terms"],
                         boundary_factor=SIM.boundary_weakening if bf is None else bf,
                         residual_rms_N=v["residual_rms_N"], residual_max_N=v["residual_max_N"],
                         samples=v["samples"], meta=v["data"])


# ----------------------------------------------------------------------------------------------
# The simulator's membrane energy (pysolver.mechanics.energies.membrane_terms) in the plane
# ----------------------------------------------------------------------------------------------


class PlaneMembrane:
    """Energy, gradient and Hessian of a flat pre-stretched membrane patch, in-plane.

    The energy is the simulator's, :func:`pysolver.mechanics.energies.membrane_terms`
    (incompressible neo-Hookean CST, ``Psi = mu/2 (tr C + 1/det C - 3)`` per unit rest
    volume, rest state = flat mesh / tau, thickness ``h``; ``simulator.md`` §6.5), evaluated
    with ``z = 0`` and restricted to the in-plane degrees of freedom (the sampling patches
    stay flat: by symmetry the out-of-plane gradient is zero there).  Positions ``x`` are
    ``(n, 2)`` mm; degrees of freedom are ordered ``2 * node + axis``.
    """

    def __init__(self, X, tri, tau=SIM.tau, mu=SIM.mu, h=SIM.membrane_h, area_factor=1.0):
        self.tri = np.asarray(tri)
        X = np.asarray(X, dtype=float)
        Dm = np.stack([X[self.tri[:, 1]] - X[self.tri[:, 0]],
                       X[self.tri[:, 2]] - X[self.tri[:, 0]]], axis=-1)  # (m, 2, 2), flat
        if np.ndim(tau) == 0:
            Dm = Dm / tau
        else:  # a pre-stretch per triangle (the rim margin, pysolver.mechanics.rim)
            Dm = Dm / np.asarray(tau, float)[:, None, None]
        self.Dm = Dm
        self.Dm_inv = np.linalg.inv(Dm)
        # rest area (the rim margin holds less latex than its rest shape: margin_rest)
        self.area = 0.5 * np.abs(np.linalg.det(Dm)) * np.asarray(area_factor, float)
        self.mu, self.h = mu, h
        n = len(X)
        self.dofs = np.stack([2 * self.tri, 2 * self.tri + 1], axis=-1).reshape(len(tri), 6)
        self.rows = np.repeat(self.dofs, 6, axis=1).ravel()
        self.cols = np.tile(self.dofs, (1, 6)).ravel()
        self.ndof = 2 * n

    def deformation(self, x):
        """In-plane deformation gradient per element, (m, 2, 2)."""
        Ds = np.stack([x[self.tri[:, 1]] - x[self.tri[:, 0]],
                       x[self.tri[:, 2]] - x[self.tri[:, 0]]], axis=-1)
        return Ds @ self.Dm_inv

    def _terms(self, x, hessian, psd=False):
        X3 = np.c_[np.asarray(x, float), np.zeros(len(x))][self.tri]          # (m, 3, 3)
        return membrane_terms(X3, self.Dm_inv, self.area, self.mu, self.h, hessian=hessian,
                              psd=psd)

    def stress(self, x):
        """First Piola-Kirchhoff stress per element, (m, 2, 2) MPa.

        Read from the element gradient of :func:`membrane_terms`: the forces on an element's
        vertices 1 and 2 are ``h A P Dm^-T`` (columns), so ``P = [g1 g2] Dm^T / (h A)``.
        """
        _, g, _ = self._terms(x, hessian=False)
        G = np.stack([g[:, 1, :2], g[:, 2, :2]], axis=-1)                     # (m, 2, 2)
        return G @ np.transpose(self.Dm, (0, 2, 1)) / (self.h * self.area)[:, None, None]

    def element_terms(self, x, hessian=False, psd=False):
        """Element energies, in-plane gradients and Hessians in one evaluation.

        Parameters
        ----------
        x : (n, 2) float, mm
        hessian : bool
        psd : bool -- project each element Hessian to positive semi-definite

        Returns
        -------
        E : (m,) float, N mm
        g : (m, 3, 2) float, N -- per element vertex
        H : (m, 6, 6) float, N/mm, or None without ``hessian`` -- rows and columns ordered
            ``2 * k + axis`` over the element's vertices ``k`` (the columns of :attr:`dofs`)
        """
        E, g, H = self._terms(x, hessian=hessian, psd=psd)
        if H is not None:                                                     # (m, 3, 3, 3, 3)
            H = np.transpose(H[..., :2, :2], (0, 1, 3, 2, 4)).reshape(len(self.tri), 6, 6)
        return E, g[:, :, :2], H

    def inverted(self, x) -> bool:
        """Whether an element is inverted (``det F <= 0``)."""
        return bool(np.any(np.linalg.det(self.deformation(x)) <= 0))

    def assemble_gradient(self, g):
        """Node gradient (n, 2) N of element gradients ``g`` (m, 3, 2) N."""
        out = np.zeros((self.ndof // 2, 2))
        np.add.at(out, self.tri, g)
        return out

    def energy(self, x):
        """Total energy, N mm; ``inf`` if an element is inverted (``det F <= 0``)."""
        if self.inverted(x):
            return np.inf
        return float(np.sum(self.element_terms(x)[0]))

    def gradient(self, x):
        """Gradient, (n, 2) N."""
        return self.assemble_gradient(self.element_terms(x)[1])

    def hessian(self, x, psd=False):
        """Hessian, sparse (2n, 2n) N/mm; ``psd``: each element's projected to PSD."""
        He = self.element_terms(x, hessian=True, psd=psd)[2]
        return sp.csr_matrix((He.ravel(), (self.rows, self.cols)), shape=(self.ndof,) * 2)


class FreeNodeProblem:
    """Equilibrium of the free nodes of a :class:`PlaneMembrane`, for the shell's Newton solver.

    The static problem of :func:`pysolver.mechanics.solver.newton` (the protocol of its
    ``StaticProblem``) for a flat membrane whose attached nodes stay where the start state
    has them: the degrees of freedom are the in-plane translations of the free nodes, ordered
    ``2 * k + axis`` over ``free``; there are no rotations.  The Hessian is assembled into the
    lower-triangle CSC pattern the solver factorises (:class:`.energies.SparsePattern`).

    Parameters
    ----------
    mem : PlaneMembrane
    x : (v, 2) float, mm
        Start state (copied); the attached nodes keep these positions.
    free : (f,) int
        Free nodes.
    """

    def __init__(self, mem: PlaneMembrane, x, free):
        self.mem = mem
        self.x = np.array(x, dtype=float)
        free = np.asarray(free, dtype=np.int64)
        self.fdof = np.stack([2 * free, 2 * free + 1], axis=-1).ravel()
        self.n = len(self.fdof)
        self.dof_scale = np.ones(self.n)
        self.trans_dofs = np.arange(self.n)
        self.rot_dofs = np.zeros(0, dtype=np.int64)
        reduced = np.full(mem.ndof, -1, dtype=np.int64)
        reduced[self.fdof] = np.arange(self.n)
        self.pattern = SparsePattern(self.n, [reduced[mem.dofs]])
        self._scale = None  # (state, sum of element energies) of the last evaluation

    def _evaluate(self, x, hessian=False, psd=False):
        """Energy (N mm; ``inf`` if an element is inverted), free-node gradient (n,) N,
        reduced Hessian (lower-triangle CSC, N/mm; None without ``hessian``) and the sum of
        the element energies' magnitudes (N mm)."""
        mem = self.mem
        Ee, ge, He = mem.element_terms(x, hessian=hessian, psd=psd)
        E = np.inf if mem.inverted(x) else float(np.sum(Ee))
        g = mem.assemble_gradient(ge).reshape(-1)[self.fdof]
        H = None if He is None else self.pattern.assemble([He])
        return E, g, H, float(np.sum(np.abs(Ee)))

    def evaluate(self, hessian=True, psd=False):
        """Energy (N mm), gradient (n,) N and Hessian (lower-triangle CSC, N/mm, ``psd``:
        convexified per element; None without ``hessian``) at the current state."""
        E, g, H, scale = self._evaluate(self.x, hessian=hessian, psd=psd)
        self._scale = (self.x, scale)
        return E, g, H

    def trial(self, dx, alpha):
        """The state moved by ``alpha * dx`` (free nodes only), (v, 2) mm."""
        x = self.x.copy()
        x.reshape(-1)[self.fdof] += alpha * dx
        return x

    def energy_at(self, trial) -> float:
        """Energy at a trial state, N mm (``inf`` if an element is inverted)."""
        return self._evaluate(trial)[0]

    def gradient_at(self, trial):
        """Energy (N mm) and free-node gradient (n,) N at a trial state."""
        return self._evaluate(trial)[:2]

    def accept(self, trial) -> None:
        self.x = trial

    def residual(self, g) -> float:
        """Largest force on a free node component, N."""
        return float(np.abs(g).max(initial=0.0))

    def roundoff(self) -> float:
        """Round-off of the energy at the current state, N mm (as ``StaticProblem``'s)."""
        if self._scale is None or self._scale[0] is not self.x:
            self.evaluate(hessian=False)
        return TOL.energy_roundoff * max(self._scale[1], 1.0)


def _relax(mem: PlaneMembrane, x, free, tol=TOL.membrane_grad, linear: LinearSolver | None = None,
           max_iter: int = NEWTON.max_iter_wet):
    """Relax the free nodes with the shell's Newton solver (:func:`.solver.newton`).

    Elements in compression make the exact Hessian indefinite (seen on cover's
    40 000-triangle membrane); the solver then shifts it or takes the per-element PSD
    projection, which gives a descent direction to the same minimum.

    Parameters
    ----------
    mem : PlaneMembrane
    x : (v, 2) float, mm -- start state (not modified)
    free : (f,) int -- free nodes
    tol : float, N -- largest free-node force component at convergence
    linear : LinearSolver, optional -- reused between calls on the same free nodes
    max_iter : int -- most Newton iterations

    Returns
    -------
    x : (v, 2) float, mm

    Raises
    ------
    RuntimeError
        The start state has an inverted triangle, or the solve stopped with a force above
        ``TOL.newton_grad``.
    """
    problem = FreeNodeProblem(mem, x, free)
    if not np.isfinite(problem.evaluate(hessian=False)[0]):
        raise RuntimeError("membrane start state has inverted triangles")
    res = newton(problem, tol=tol, max_iter=max_iter, linear=linear)
    if not res.residual <= TOL.newton_grad:
        raise RuntimeError(f"membrane relaxation did not converge ({res.status}, "
                           f"|g| = {res.residual:.2e} N)")
    return problem.x


def _move_bodies(mem: PlaneMembrane, x, free, att, x_att_new, linear=None):
    """Move the attached nodes and predict the free nodes with one linear (tangent) solve.

    The load step is halved until the predicted state has no inverted triangle; the state of
    a partial step is relaxed (:func:`_relax`, with ``linear``) before the rest follows.
    """
    fdof = np.stack([2 * free, 2 * free + 1], axis=-1).ravel()
    adof = np.stack([2 * att, 2 * att + 1], axis=-1).ravel()
    H = mem.hessian(x)
    Hff = H[fdof][:, fdof].tocsc()
    Hfa = H[fdof][:, adof]
    delta = (x_att_new - x[att]).ravel()
    pred = -spla.spsolve(Hff, Hfa @ delta)
    for frac in (1.0, 0.5, 0.25, 0.125, 0.0625):
        xt = x.copy()
        xt[att] += frac * delta.reshape(-1, 2)
        xt.reshape(-1)[fdof] += frac * pred
        if np.isfinite(mem.energy(xt)):
            if frac == 1.0:
                return xt
            xt = _relax(mem, xt, free, linear=linear)
            return _move_bodies(mem, xt, free, att, x_att_new, linear)
    raise RuntimeError("membrane load step failed")  # pragma: no cover


def cell_tractions(mesh: MembraneMesh, centers, cell_bases, mem: PlaneMembrane, x,
                   tau=SIM.tau) -> np.ndarray:
    """Force the membrane transmits across each cell's stencil edge, along the cell axis (N).

    ``T_c = u . sum_seg h P N dS`` over the mesh edges of the cell's stencil edge
    (``mesh.edge_segments``), with the first Piola-Kirchhoff stress ``P`` averaged over the
    (one or two) triangles at each edge, ``N dS`` the rest normal times rest length
    (flat / ``tau``) pointing from base b towards base a, and ``u`` the unit flat axis from
    base b to base a.  Positive = tension = the membrane pulls the cell's two bases together.

    Parameters
    ----------
    mesh : MembraneMesh
        The layout's membrane (:func:`pysolver.mechanics.membrane_mesh`); ``mem`` was built
        on its vertices and triangles (the triangles may be followed by rim triangles).
    centers : (m, 2) float, mm -- flat base centres
    cell_bases : (c, 2) int -- bases (a, b) of each cell
    mem : PlaneMembrane
    x : (v, 2) float, mm -- current membrane vertices
    tau : float -- pre-stretch of the triangles along the stencil edges

    Returns
    -------
    T : (c,) float, N
    """
    P = mem.stress(x) * mem.h                                   # (t, 2, 2), N/mm
    tri = mesh.tris
    nv = len(mesh.xy)
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    key = np.minimum(e[:, 0], e[:, 1]) * nv + np.maximum(e[:, 0], e[:, 1])
    tid = np.tile(np.arange(len(tri)), 3)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    S = mesh.edge_segments
    sk = S.min(axis=1) * nv + S.max(axis=1)
    lo, hi = np.searchsorted(ks, sk, "left"), np.searchsorted(ks, sk, "right")
    if np.any(hi == lo):
        raise RuntimeError("a stencil edge segment is not a mesh edge")  # pragma: no cover
    Pm = 0.5 * (P[tid[order[lo]]] + P[tid[order[hi - 1]]])      # one or two triangles
    C = np.asarray(centers, float)[:, :2]
    cb = np.asarray(cell_bases)
    u = C[cb[:, 0]] - C[cb[:, 1]]
    u /= np.linalg.norm(u, axis=1)[:, None]
    ue = u[mesh.edge_cell]
    E = (mesh.xy[S[:, 1]] - mesh.xy[S[:, 0]]) / tau
    N = np.c_[E[:, 1], -E[:, 0]]                                 # rest normal * rest length
    N *= np.where(np.einsum("ij,ij->i", N, ue) < 0, -1.0, 1.0)[:, None]
    t = np.einsum("ij,ij->i", np.einsum("eij,ej->ei", Pm, N), ue)
    return np.bincount(mesh.edge_cell, weights=t, minlength=len(cb))


def relax_contracted(mesh: MembraneMesh, centers, mem: PlaneMembrane, s: float, x=None):
    """Relaxed membrane of a layout whose base centres are moved to ``s * c`` (mm).

    Bases translate with the contraction (rigid, not rotating); the free vertices follow by a
    tangent predictor and Newton (:func:`_move_bodies`, :func:`_relax`).

    Parameters
    ----------
    mesh : MembraneMesh -- vertices ``xy`` (v, 2) mm and ``body`` (v,)
    centers : (m, 2) float, mm -- flat base centres
    mem : PlaneMembrane -- built on ``mesh`` (and its rim, if any)
    s : float -- contraction factor (1 = flat layout)
    x : (v, 2) float, mm, optional -- start state (default the flat layout)

    Returns
    -------
    x : (v, 2) float, mm
    """
    free = np.flatnonzero(mesh.body < 0)
    att = np.flatnonzero(mesh.body >= 0)
    cb = np.asarray(centers, float)[mesh.body[att], :2]
    x = mesh.xy.copy() if x is None else x
    linear = LinearSolver()  # one symbolic analysis for every solve on these free nodes
    x = _move_bodies(mem, x, free, att, s * cb + (mesh.xy[att] - cb), linear)
    return _relax(mem, x, free, linear=linear)


def layout_membrane(UV, F, max_area: float, geometry: dict | None = None):
    """The membrane mesh of a flat layout (:func:`pysolver.mechanics.membrane_mesh`).

    Parameters
    ----------
    UV : (n, 2) float, mm -- flat stencil vertices
    F : (m, 3) int
    max_area : float, mm^2
    geometry : dict, optional
        The design's ``model.npz`` arrays; default the design stage's own arrays of the flat
        stencil (:func:`pysolver.design.cellnodes.model_arrays`, target = flat layout).

    Returns
    -------
    mesh : MembraneMesh
    geometry : dict
    centers : (m, 2) float, mm -- flat base centres
    """
    UV = np.asarray(UV, float)[:, :2]
    F = np.asarray(F, np.int64)
    if geometry is None:
        geometry = model_arrays(np.c_[UV, np.zeros(len(UV))], UV, F)
    mesh = membrane_mesh(UV, F, geometry, max_area=max_area)
    return mesh, geometry, UV[F].mean(axis=1)


def cell_membrane_factors(UV, F, cells, b0, d1, model: MembraneModel | None = None,
                          max_area: float = PROGRAMMING.membrane_factor_max_area, rim=None,
                          geometry: dict | None = None) -> dict:
    """Per-cell correction of ``F_mem`` from an FEM membrane on the design's own flat stencil.

    The linear model describes an interior cell of a regular lattice.  Here the
    design's flat layout is meshed like the sampling patches and the simulator
    (:func:`pysolver.mechanics.membrane_mesh`) and contracted
    uniformly by the factor ``s`` that gives its cells their median target
    shortening; each cell's FEM traction divided by ``F_mem(b0, (1 - s) l)`` is its
    factor: about 1 inside, about 0.6 at a straight boundary, much less for a cell
    whose stencil edge has both ends on the boundary, and above/below 1 where the
    stencil edge is longer/shorter than in a regular lattice.

    Parameters
    ----------
    UV : (nv, 2) float, mm -- flat stencil vertices
    F : (nf, 3) int -- stencil faces
    cells : dict -- ``cells.csv`` columns (``base_a``, ``base_b``, ``vertex_a``,
        ``vertex_b``, ``central_length_mm``)
    b0, d1 : (n_cells,) float, mm -- flat bracket length, target shortening
    model : MembraneModel, optional (default: the committed model)
    max_area : float, mm^2 -- membrane mesh size (flat)
    rim : (float, float), optional
        ``(margin_mm, stretch)``: the membrane as fabricated at the rim
        (:func:`pysolver.mechanics.rim.rim_margin`, ``PhysicsOptions.rim``), as in the simulator.
    geometry : dict, optional
        The design's ``model.npz`` arrays (its bracket nodes, as the simulator reads them);
        default computed from the flat stencil.

    Returns
    -------
    dict
        ``factor`` (n_cells,), ``s`` (contraction), ``d_mm`` (n_cells,), ``force_N``
        (n_cells,) FEM tractions, ``n_triangles``.
    """
    model = load_membrane_model() if model is None else model
    mesh, geometry, C = layout_membrane(UV, F, max_area, geometry)
    mine = np.c_[geometry["cell_bases"], geometry["cell_verts"]]
    theirs = np.column_stack([cells["base_a"], cells["base_b"], cells["vertex_a"],
                              cells["vertex_b"]])
    if mine.shape[0] != len(theirs) or not np.array_equal(mine, theirs):
        raise InputError("cells.csv does not list the stencil's interior edges in the "
                         "design-folder order.", fix="re-run the design stage.")
    lc = np.asarray(cells["central_length_mm"], float)
    s = 1.0 - float(np.median(np.asarray(d1, float) / lc))
    s = min(max(s, PROGRAMMING.membrane_contraction_min), 1.0)
    if rim is None:
        mem = PlaneMembrane(mesh.xy, mesh.tris)
        run = mesh
    else:
        X, tri, body, margin = rim_margin(mesh.xy, mesh.tris, mesh.body, C,
                                          UNIT_CELL.base_r, float(rim[0]))
        run = dataclasses.replace(mesh, xy=X, tris=tri, body=body)
        stretch, area_factor = margin_rest(margin, SIM.tau, float(rim[1]))
        mem = PlaneMembrane(X, tri, tau=stretch, area_factor=area_factor)
    x = relax_contracted(run, C, mem, s)
    T = cell_tractions(run, C, geometry["cell_bases"], mem, x)
    d = (1.0 - s) * lc
    ref = model.force(np.asarray(b0, float), d)
    return {"factor": T / ref, "s": s, "d_mm": d, "force_N": T,
            "n_triangles": int(len(mesh.tris))}


# ----------------------------------------------------------------------------------------------
# fit
# ----------------------------------------------------------------------------------------------


def _design_matrix(b, d, terms=MODEL_TERMS):
    b, d = np.asarray(b, dtype=float), np.asarray(d, dtype=float)
    return np.column_stack([TERMS[t](b, d) for t in terms])


__all__ = ["check_membrane_model", "validate_membrane_model_file",
           "TERMS", "MODEL_TERMS", "SI_TERMS", "FORM", "MembraneModel",
           "load_membrane_model", "layout_membrane", "PlaneMembrane", "FreeNodeProblem",
           "cell_tractions", "relax_contracted", "cell_membrane_factors"]
