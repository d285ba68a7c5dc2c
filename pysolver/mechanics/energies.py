"""Energies of the shell with analytic gradients and Hessians, vectorised over elements.

Element energies (point space, each point 3 coordinates; ``shared/design/simulator.md`` §6):

* :func:`spring_terms` -- polynomial spring ``E = sum_k c_k x^(k+1)/(k+1)``, ``x = rest - L``
  (compression positive).  Bracket springs use the material model's force coefficients;
  a bumper contact is the same spring with coefficients ``(kappa_c, 0, 0, 0)`` and rest
  length ``L_c`` (``E = kappa_c/2 (L - L_c)^2``).
* :func:`cross_terms` -- shear-resisting crossed pair ``E = w/2 (L_a - L_b - R0)^2`` with
  ``w = kappa_s * Lambda``.
* :func:`membrane_terms` -- incompressible neo-Hookean CST
  ``E = h A_rest mu/2 (tr C + 1/det C - 3)``, rest = flat / tau.

:class:`ShellEnergy` evaluates their sum over a :class:`State` (rigid bases + free membrane
vertices) and reduces gradient and Hessian to the reduced DOFs by the chain rule through the
rigid-body map ``x = c + exp([theta]x) R t`` **at theta = 0** (the rotation is folded into
``R`` after every accepted step): ``dx/dtheta = -[v]x`` and the second-order term
``sum_p g_p . d2x_p/dtheta2`` with ``d2x_i/dtheta_a dtheta_b = (d_ia v_b + d_ib v_a)/2
- d_ab v_i`` (``v = R t``).  The Hessian is scattered into a sparse lower-triangle CSC matrix
whose pattern (and every element entry's position in it) is computed once
(:class:`SparsePattern`).  Two assembly backends give the same matrix to round-off: compiled
element loops (:mod:`.kernels`, numba; default when installed, ~4x faster) and vectorised
numpy (per-cell blocks for springs and cross pairs, per-point-pair blocks for the membrane).

``psd=True`` returns a convexified Hessian instead: per-element projection onto the positive
semidefinite cone (closed form for springs and cross pairs, 6x6 eigen-decomposition in
deformation-gradient space for the membrane) and the per-base second-order rotation term
projected likewise.  The solver uses it only when shifting the exact Hessian does not help.

The functions here are the reference implementation used by the finite-difference tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from pysolver.errors import InputError
from pysolver.params import tol as TOL

from .kernels import (
    HAVE_NUMBA,
    cross_point_hessian,
    discrete_terms,
    membrane_kernel,
    reduce_scatter,
    rigid_gradient,
    rigid_positions,
    rigid_rotation_term,
    stored_pairs,
)
from .model import ShellModel

# ------------------------------------------------------------------------------------------------
# small vector helpers


def skew(v):
    """Cross-product matrices ``[v]x`` of ``v : (..., 3)`` -> (..., 3, 3)."""
    v = np.asarray(v, float)
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1),
                     np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def rodrigues(theta):
    """Rotation matrices ``exp([theta]x)`` of rotation vectors ``theta : (n, 3)`` (rad)."""
    theta = np.asarray(theta, float)
    a = np.linalg.norm(theta, axis=-1)
    small = a < TOL.small_angle
    a_safe = np.where(small, 1.0, a)
    s = np.where(small, 1.0 - a * a / 6.0, np.sin(a) / a_safe)
    c = np.where(small, 0.5 - a * a / 24.0, (1.0 - np.cos(a)) / a_safe**2)
    K = skew(theta)
    return np.eye(3) + s[..., None, None] * K + c[..., None, None] * (K @ K)


def _poly(coef, x):
    """Energy, force and stiffness of force coefficients ``coef (n, 4)`` (x^1..x^4) at x."""
    c1, c2, c3, c4 = coef[:, 0], coef[:, 1], coef[:, 2], coef[:, 3]
    f = x * (c1 + x * (c2 + x * (c3 + x * c4)))
    e = x * x * (c1 / 2 + x * (c2 / 3 + x * (c3 / 4 + x * c4 / 5)))
    k = c1 + x * (2 * c2 + x * (3 * c3 + x * 4 * c4))
    return e, f, k


# ------------------------------------------------------------------------------------------------
# element energies (point space)


def spring_terms(xa, xb, rest, coef, *, hessian=True, psd=False):
    """Polynomial springs between points ``xa`` and ``xb``.

    Parameters
    ----------
    xa, xb : (n, 3) float, mm
    rest : (n,) float, mm
        Rest length; compression ``x = rest - |xb - xa|``.
    coef : (n, 4) float, N mm^-k
        Force coefficients of x^1..x^4 (force = dE/dx).
    hessian, psd : bool
        Return the Hessian block; project it to PSD.

    Returns
    -------
    E : (n,) float, N mm
    g : (n, 2, 3) float, N -- gradient w.r.t. (xa, xb)
    K : (n, 3, 3) float, N/mm or None -- Hessian is ``[[K, -K], [-K, K]]``
    """
    d = xb - xa
    L = np.sqrt(np.einsum("ni,ni->n", d, d))
    u = d / L[:, None]
    e, f, k = _poly(coef, rest - L)
    gb = -f[:, None] * u
    g = np.stack([-gb, gb], axis=1)
    if not hessian:
        return e, g, None
    axial = k
    trans = -f / L
    if psd:
        axial = np.maximum(axial, 0.0)
        trans = np.maximum(trans, 0.0)
    uu = u[:, :, None] * u[:, None, :]
    K = (axial - trans)[:, None, None] * uu + trans[:, None, None] * np.eye(3)
    return e, g, K


def cross_terms(x0, x1, x2, x3, weight, rest, *, hessian=True, psd=False):
    """Crossed pairs ``E = w/2 (|x1 - x0| - |x3 - x2| - R0)^2``.

    Parameters
    ----------
    x0, x1, x2, x3 : (n, 3) float, mm
        Segment a = x0-x1, segment b = x2-x3.
    weight : (n,) float, N/mm
        ``kappa_s * Lambda``.
    rest : (n,) float, mm
        R0.

    Returns
    -------
    E : (n,) float
    g : (n, 4, 3) float
    parts : tuple or None
        ``(G, Ka, Kb)``: the Hessian is ``w G G^T`` (``G : (n, 4, 3)`` = dD/dx) plus a spring
        block ``[[K, -K], [-K, K]]`` with ``Ka : (n, 3, 3)`` on (x0, x1) and ``Kb`` on (x2, x3)
        (see :func:`cross_hessian`).
    """
    da = x1 - x0
    db = x3 - x2
    La = np.sqrt(np.einsum("ni,ni->n", da, da))
    Lb = np.sqrt(np.einsum("ni,ni->n", db, db))
    ua = da / La[:, None]
    ub = db / Lb[:, None]
    D = La - Lb - rest
    E = 0.5 * weight * D * D
    G = np.stack([-ua, ua, ub, -ub], axis=1)  # dD/dx
    wD = weight * D
    g = wD[:, None, None] * G
    if not hessian:
        return E, g, None
    ca, cb = wD, -wD
    if psd:
        ca, cb = np.maximum(ca, 0.0), np.maximum(cb, 0.0)
    I3 = np.eye(3)
    Ka = (I3 - ua[:, :, None] * ua[:, None, :]) * (ca / La)[:, None, None]
    Kb = (I3 - ub[:, :, None] * ub[:, None, :]) * (cb / Lb)[:, None, None]
    return E, g, (G, Ka, Kb)


def cross_hessian(weight, parts):
    """Full point-space Hessian (n, 4, 4, 3, 3) of cross pairs from :func:`cross_terms` parts."""
    G, Ka, Kb = parts
    H = weight[:, None, None, None, None] * G[:, :, None, :, None] * G[:, None, :, None, :]
    for (i, j), s in (((0, 0), 1), ((1, 1), 1), ((0, 1), -1), ((1, 0), -1)):
        H[:, i, j] += s * Ka
        H[:, 2 + i, 2 + j] += s * Kb
    return H


def membrane_terms(X, dm_inv, rest_area, mu, h, *, hessian=True, psd=False):
    """Incompressible neo-Hookean constant-strain triangles.

    ``Psi = mu/2 (tr C + 1/det C - 3)``, ``C = F^T F``, ``F = [x1-x0, x2-x0] Dm^-1`` (3x2);
    energy ``h * A_rest * Psi``.  With ``Y = C^-1``, ``g = 1/det C``, ``A = F Y`` (columns
    ``A_a``) and ``P = F Y F^T``: ``dPsi/dF = mu (F - g A)`` and the 3x3 blocks of
    ``d2Psi/dF_a dF_c`` (columns a, c of F) are
    ``mu [(d_ac - g Y_ac) I + 2g A_a A_c^T + g A_c A_a^T + g Y_ac P]``.

    Parameters
    ----------
    X : (n, 3, 3) float, mm
        Current vertex positions per triangle.
    dm_inv : (n, 2, 2) float, 1/mm
    rest_area : (n,) float, mm^2
    mu : float, MPa
    h : float, mm

    Returns
    -------
    E : (n,) float, N mm
    g : (n, 3, 3) float, N
    H : (n, 3, 3, 3, 3) float or None -- [tri, vertex, vertex, xyz, xyz]
    """
    Ds = np.stack([X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]], axis=2)  # (n, 3, 2)
    Fd = Ds @ dm_inv
    f0, f1 = Fd[:, :, 0], Fd[:, :, 1]
    C00 = np.einsum("ni,ni->n", f0, f0)
    C01 = np.einsum("ni,ni->n", f0, f1)
    C11 = np.einsum("ni,ni->n", f1, f1)
    det = C00 * C11 - C01 * C01
    gi = 1.0 / det
    Y00, Y01, Y11 = C11 * gi, -C01 * gi, C00 * gi
    ha = h * rest_area
    E = ha * 0.5 * mu * (C00 + C11 + gi - 3.0)
    A0 = f0 * Y00[:, None] + f1 * Y01[:, None]
    A1 = f0 * Y01[:, None] + f1 * Y11[:, None]
    P0 = mu * (f0 - gi[:, None] * A0)
    P1 = mu * (f1 - gi[:, None] * A1)
    B = np.stack([-(dm_inv[:, 0] + dm_inv[:, 1]), dm_inv[:, 0], dm_inv[:, 1]], axis=1)  # (n,3,2)
    g = ha[:, None, None] * (B[:, :, 0, None] * P0[:, None, :] + B[:, :, 1, None] * P1[:, None, :])
    if not hessian:
        return E, g, None
    Pm = A0[:, :, None] * f0[:, None, :] + A1[:, :, None] * f1[:, None, :]  # F Y F^T
    A = (A0, A1)
    Yac = ((Y00, Y01), (Y01, Y11))
    I3 = np.eye(3)
    HF = np.empty((len(X), 2, 2, 3, 3))
    for a in (0, 1):
        for c in (0, 1):
            y = Yac[a][c]
            HF[:, a, c] = (((1.0 if a == c else 0.0) - gi * y)[:, None, None] * I3
                           + (gi * y)[:, None, None] * Pm
                           + gi[:, None, None] * (2 * A[a][:, :, None] * A[c][:, None, :]
                                                  + A[c][:, :, None] * A[a][:, None, :]))
    HF *= mu
    if psd:
        M = np.transpose(HF, (0, 1, 3, 2, 4)).reshape(-1, 6, 6)
        M = 0.5 * (M + np.transpose(M, (0, 2, 1)))
        w = np.linalg.eigvalsh(M)
        neg = w[:, 0] < 0
        if np.any(neg):
            wq, Q = np.linalg.eigh(M[neg])
            M[neg] = (Q * np.maximum(wq, 0.0)[:, None, :]) @ np.transpose(Q, (0, 2, 1))
            HF = np.transpose(M.reshape(-1, 2, 3, 2, 3), (0, 1, 3, 2, 4))
    # H[v, w] = ha sum_ac B[v, a] B[w, c] HF[a, c]
    # two batched matmuls: T[w, a] = sum_c B[w, c] HF[a, c], then H[v, w] = sum_a B[v, a] T[w, a]
    n = len(X)
    Bh = B * np.sqrt(ha)[:, None, None]
    T = Bh @ np.transpose(HF.reshape(n, 2, 2, 9), (0, 2, 1, 3)).reshape(n, 2, 18)
    T = np.transpose(T.reshape(n, 3, 2, 9), (0, 2, 1, 3)).reshape(n, 2, 27)
    H = (Bh @ T).reshape(n, 3, 3, 3, 3)
    return E, g, H


# ------------------------------------------------------------------------------------------------
# reduction helpers (J = [I, -[v]x] at theta = 0)


def _right_cross(M, v):
    """``M [v]x`` for stacks ``M (..., 3, 3)``, ``v (..., 3)``."""
    out = np.empty_like(M)
    v0, v1, v2 = (v[..., k, None] for k in range(3))
    out[..., :, 0] = v2 * M[..., :, 1] - v1 * M[..., :, 2]
    out[..., :, 1] = v0 * M[..., :, 2] - v2 * M[..., :, 0]
    out[..., :, 2] = v1 * M[..., :, 0] - v0 * M[..., :, 1]
    return out


def _left_cross(v, M):
    """``[v]x M`` for stacks ``M (..., 3, 3)``, ``v (..., 3)``."""
    out = np.empty_like(M)
    v0, v1, v2 = (v[..., k, None] for k in range(3))
    out[..., 0, :] = v1 * M[..., 2, :] - v2 * M[..., 1, :]
    out[..., 1, :] = v2 * M[..., 0, :] - v0 * M[..., 2, :]
    out[..., 2, :] = v0 * M[..., 1, :] - v1 * M[..., 0, :]
    return out


def jtkj(K, vp, vq):
    """``J_p^T K J_q`` (n, 6, 6) with ``J = [I, -[v]x]``: rigid-body reduction of a 3x3 block."""
    TR = -_right_cross(K, vq)
    out = np.empty(K.shape[:-2] + (6, 6))
    out[..., :3, :3] = K
    out[..., :3, 3:] = TR
    out[..., 3:, :3] = _left_cross(vp, K)
    out[..., 3:, 3:] = _left_cross(vp, TR)
    return out


def segment_blocks(K, v0, v1):
    """Reduced Hessian (n, 12, 12) of 2-point elements with point Hessian ``[[K,-K],[-K,K]]``.

    Point 0 lies on the first body (DOFs 0..5), point 1 on the second (DOFs 6..11).
    """
    out = np.empty(K.shape[:-2] + (12, 12))
    out[..., :6, :6] = jtkj(K, v0, v0)
    R01 = jtkj(K, v0, v1)
    out[..., :6, 6:] = -R01
    out[..., 6:, :6] = -np.swapaxes(R01, -1, -2)
    out[..., 6:, 6:] = jtkj(K, v1, v1)
    return out


# ------------------------------------------------------------------------------------------------
# state of the reduced model


@dataclass
class State:
    """Configuration of the shell.

    Attributes
    ----------
    c : (m, 3) float, mm -- base centres
    R : (m, 3, 3) float -- accumulated base rotations (flat pose -> current)
    f : (n_free, 3) float, mm -- free membrane vertices
    """

    c: np.ndarray
    R: np.ndarray
    f: np.ndarray

    @classmethod
    def flat(cls, model: ShellModel) -> State:
        """The flat, as-printed configuration."""
        m = model.n_bases
        return cls(model.base_flat.copy(), np.tile(np.eye(3), (m, 1, 1)),
                   model.point_local[model.free_points].copy())

    def copy(self) -> State:
        return State(self.c.copy(), self.R.copy(), self.f.copy())

    def moved(self, dx, alpha: float = 1.0) -> State:
        """The state displaced by ``alpha * dx`` (reduced DOFs; rotation applied on the left)."""
        m = len(self.c)
        body = np.asarray(dx[: 6 * m]).reshape(m, 6) * alpha
        f = self.f + alpha * np.asarray(dx[6 * m:]).reshape(-1, 3)
        return State(self.c + body[:, :3], rodrigues(body[:, 3:]) @ self.R, f)

    def orthonormalize(self) -> None:
        """Project the accumulated rotations back onto SO(3) (polar decomposition)."""
        U, _, Vt = np.linalg.svd(self.R)
        self.R = U @ Vt


# ------------------------------------------------------------------------------------------------
# sparse pattern with cached scatter maps


class SparsePattern:
    """Lower-triangle CSC pattern of the reduced Hessian and cached scatter maps into it.

    Parameters
    ----------
    n : int
        Matrix size.
    groups : list of (rows, cols)
        Per group, ``rows : (k, a)`` and ``cols : (k, b)`` int: the reduced DOF indices of each
        element block's rows and columns (``-1`` = dropped).  Blocks are ``(k, a, b)``; only
        entries with row >= col are stored (pass each off-diagonal block once in each
        orientation).  A single array ``(k, d)`` means ``rows = cols``.
    """

    def __init__(self, n: int, groups):
        self.n = n
        keys, self._maps, self._shapes = [], [], []
        for grp in groups:
            rows, cols = grp if isinstance(grp, tuple) else (grp, grp)
            r = np.asarray(rows, dtype=np.int64)[:, :, None]
            c = np.asarray(cols, dtype=np.int64)[:, None, :]
            keep = (r >= 0) & (c >= 0) & (r >= c)
            rr = np.broadcast_to(r, keep.shape)[keep]
            cc = np.broadcast_to(c, keep.shape)[keep]
            keys.append(cc * n + rr)
            self._maps.append([np.flatnonzero(keep.ravel()), None])
            self._shapes.append(keep.shape)
        diag = np.arange(n, dtype=np.int64)
        allk = np.unique(np.concatenate(keys + [diag * n + diag]))
        self._allk = allk
        self.nnz = len(allk)
        self.indices = (allk % n).astype(np.int32)
        cols = allk // n
        self.indptr = np.r_[0, np.cumsum(np.bincount(cols, minlength=n))].astype(np.int32)
        for mp, k in zip(self._maps, keys, strict=True):
            mp[1] = np.searchsorted(allk, k)
        self.diag_pos = np.searchsorted(allk, diag * n + diag)

    def assemble_data(self, blocks) -> np.ndarray:
        """CSC data array: sum of element blocks (list aligned with ``groups``, None = skip)."""
        data = np.zeros(self.nnz)
        for (sel, pos), B in zip(self._maps, blocks, strict=True):
            if B is None:
                continue
            data += np.bincount(pos, weights=B.reshape(-1)[sel], minlength=self.nnz)
        return data

    def matrix(self, data) -> sp.csc_matrix:
        """The lower-triangle CSC matrix with this pattern and ``data``."""
        return sp.csc_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))

    def assemble(self, blocks) -> sp.csc_matrix:
        """Sum element blocks (list aligned with ``groups``) into a lower-triangle CSC matrix."""
        return self.matrix(self.assemble_data(blocks))

    def positions(self, rows, cols) -> np.ndarray:
        """CSC data positions of entries ``(rows, cols)`` (int arrays, row >= col), which must
        be in the pattern."""
        key = np.asarray(cols, dtype=np.int64) * self.n + np.asarray(rows, dtype=np.int64)
        pos = np.searchsorted(self._allk, key)
        if np.any(pos >= self.nnz) or np.any(self._allk[np.minimum(pos, self.nnz - 1)] != key):
            raise ValueError("entries outside the sparsity pattern")
        return pos

    def position_map(self, i: int) -> np.ndarray:
        """(k, a, b) int: CSC data position of every entry of group ``i``'s blocks, -1 = dropped."""
        sel, pos = self._maps[i]
        out = -np.ones(self._shapes[i], dtype=np.int32 if self.nnz < 2**31 else np.int64)
        out.reshape(-1)[sel] = pos
        return out


def _unique_pairs(pts):
    """Point pairs of elements ``pts (k, q)``: (i <= j) local pairs ordered so that the global
    point ids satisfy p <= q.

    Returns
    -------
    pairs : (np, 2) int -- unique (p, q), p <= q
    li, lj : (k, q (q + 1) / 2) int -- local indices giving block (p, q) = H[el, li, lj]
    pid : (k, q (q + 1) / 2) int -- pair id of each element's local pair
    """
    k, q = pts.shape
    iu, ju = np.triu_indices(q)
    P = pts[:, iu]
    Q = pts[:, ju]
    swap = P > Q
    li = np.where(swap, ju, iu)
    lj = np.where(swap, iu, ju)
    p, qq = np.minimum(P, Q), np.maximum(P, Q)
    key = p.astype(np.int64) * (int(pts.max()) + 1) + qq
    uk, pid = np.unique(key.ravel(), return_inverse=True)
    n1 = int(pts.max()) + 1
    pairs = np.c_[uk // n1, uk % n1]
    return pairs, li, lj, pid.reshape(k, -1)


def full_from_lower(L: sp.spmatrix) -> sp.csc_matrix:
    """Symmetric matrix from its lower triangle."""
    L = sp.csc_matrix(L)
    return (L + L.T - sp.diags(L.diagonal())).tocsc()


# ------------------------------------------------------------------------------------------------
# the total energy


class ShellEnergy:
    """Total energy of a :class:`~.model.ShellModel` with reduced gradient and Hessian.

    The bracket springs' state (rest length, force coefficients, contact switch) is held in
    :attr:`spring_rest` and :attr:`spring_coef` and set by the time stepper before each solve.

    Parameters
    ----------
    model : ShellModel
    backend : {"auto", "numba", "numpy"}
        Hessian assembly: compiled kernels (:mod:`.kernels`) or vectorised numpy; ``auto``
        uses numba when it is installed.  Both give the same matrix to round-off.
    """

    def __init__(self, model: ShellModel, backend: str = "auto"):

        if backend not in ("auto", "numba", "numpy"):
            raise ValueError(f"backend must be auto, numba or numpy, got {backend!r}")
        if backend == "numba" and not HAVE_NUMBA:

            raise InputError("backend 'numba' needs numba", fix="pip install numba")
        self.backend = "numba" if backend == "auto" and HAVE_NUMBA else backend
        if self.backend == "auto":
            self.backend = "numpy"
        self.model = model
        self.consts = model.consts
        self.last_energy_scale = None  # energy_scale of the state last evaluated (N mm)
        # physics options (sim.model.physics): membrane modulus factor (relaxation) and external
        # terms (weight, plane); 1.0 and None reproduce the reference model bit for bit
        self.mu_scale = 1.0
        self.external = None
        self.contact = None  # sim.model.contact.BaseContact: barrier between non-neighbour bases
        self.bending = None  # sim.model.physics.BracketBending: brackets bent out of plane
        self._ext_pos = None
        m, c = model.n_bases, model.n_cells
        self.m = m
        self.n = model.n_dof
        ns = len(model.spring_points)
        self.spring_rest = model.spring_rest0.copy()
        self.spring_coef = np.zeros((ns, 4))
        self.attached = np.flatnonzero(model.point_body >= 0)
        self.att_body = model.point_body[self.attached]
        self.att_local = np.ascontiguousarray(model.point_local[self.attached], dtype=float)
        self.free_pts = model.free_points
        pd = model.point_dofs()
        self.point_dofs = pd
        rot_dofs = 6 * np.arange(m)[:, None] + 3 + np.arange(3)
        if self.backend == "numpy":
            # per cell (bases a, b) for springs + cross pairs; membrane point pairs (diagonal,
            # off-diagonal in both orientations); per base rotation block
            a, b = model.cell_bases[:, 0], model.cell_bases[:, 1]
            cell_dofs = np.c_[6 * a[:, None] + np.arange(6), 6 * b[:, None] + np.arange(6)]
            pairs, li, lj, pid = _unique_pairs(model.tri_points)
            self.tri_li, self.tri_lj, self.tri_pid = li, lj, pid
            self.pairs = pairs
            self.pair_diag = pairs[:, 0] == pairs[:, 1]
            dpair, opair = pairs[self.pair_diag], pairs[~self.pair_diag]
            self.pattern = SparsePattern(self.n, [
                rot_dofs, cell_dofs, pd[dpair[:, 0]], (pd[opair[:, 0]], pd[opair[:, 1]]),
                (pd[opair[:, 1]], pd[opair[:, 0]])])
        else:
            # whole elements; positions of every reduced entry for the compiled scatter
            groups = [rot_dofs] + [pd[P].reshape(len(P), -1) for P in
                                   (model.spring_points, model.cross_points, model.tri_points)]
            self.pattern = SparsePattern(self.n, groups)
            self.pos_spring = self.pattern.position_map(1)
            self.pos_cross = self.pattern.position_map(2)
            self.pos_tri = self.pattern.position_map(3)
            self.use_spring, self.use_cross, self.use_tri = (
                stored_pairs(p) for p in (self.pos_spring, self.pos_cross, self.pos_tri))
            self._Hm = np.zeros((len(model.tri_points), 9, 9))
        tr, rot = model.dof_slices()
        self.trans_dofs, self.rot_dofs = tr, rot
        # check that every spring / cross point sits on base a (even) or b (odd) of its cell
        cb = np.repeat(model.cell_bases, 4, axis=0)
        assert np.all(model.point_body[model.spring_points] == cb)
        assert np.all(model.point_body[model.cross_points] == cb[:, [0, 1, 0, 1]])
        self.dof_scale = np.ones(self.n)
        self.dof_scale[rot] = model.unit.base_r**2  # rotation DOFs: N mm / rad ~ r^2 N/mm
        self.n_cells = c

    # -- kinematics --------------------------------------------------------------------------------
    def positions(self, state: State):
        """Point positions ``(p, 3)`` and rotated local offsets ``v = R t`` of attached points."""
        md = self.model
        if self.backend == "numba":
            X, v = np.empty((md.n_points, 3)), np.empty((len(self.attached), 3))
            rigid_positions(state.c, state.R, state.f, self.attached, self.att_body,
                            self.att_local, self.free_pts, X, v)
            return X, v
        t = md.point_local[self.attached]
        v = np.einsum("nij,nj->ni", state.R[self.att_body], t)
        X = np.empty((md.n_points, 3))
        X[self.attached] = state.c[self.att_body] + v
        X[self.free_pts] = state.f
        return X, v

    # -- element terms -----------------------------------------------------------------------------
    def _discrete(self, X, hessian, psd):
        """Springs and cross pairs (:func:`.kernels.discrete_terms` with the numba backend,
        else numpy)."""
        md = self.model
        sp_ = md.spring_points
        if self.backend == "numba" and not psd:
            ns, nc = len(sp_), len(md.cross_points)
            es, gs, ex, gx = np.empty(ns), np.empty((ns, 2, 3)), np.empty(nc), np.empty((nc, 4, 3))
            Ks, G, Ka, Kb = ((np.empty((ns, 3, 3)), np.empty((nc, 4, 3)), np.empty((nc, 3, 3)),
                              np.empty((nc, 3, 3))) if hessian else
                             (np.empty((0, 3, 3)), np.empty((0, 4, 3)), np.empty((0, 3, 3)),
                              np.empty((0, 3, 3))))
            discrete_terms(X, sp_, self.spring_rest, self.spring_coef, md.cross_points,
                           md.cross_weight, md.cross_rest, hessian, es, gs, Ks, ex, gx, G, Ka, Kb)
            return (es, gs, Ks if hessian else None), (ex, gx, (G, Ka, Kb) if hessian else None)
        es, gs, Ks = spring_terms(X[sp_[:, 0]], X[sp_[:, 1]], self.spring_rest, self.spring_coef,
                                  hessian=hessian, psd=psd)
        cp = md.cross_points
        ex, gx, parts = cross_terms(X[cp[:, 0]], X[cp[:, 1]], X[cp[:, 2]], X[cp[:, 3]],
                                    md.cross_weight, md.cross_rest, hessian=hessian, psd=psd)
        return (es, gs, Ks), (ex, gx, parts)

    def _membrane(self, X, G, hessian, psd):
        """Membrane energy; adds its point gradient to ``G``; returns (E, H (t,3,3,3,3)/(t,9,9))."""
        md, k = self.model, self.consts
        if self.backend == "numba" and not psd:

            E = membrane_kernel(X, md.tri_points, md.tri_dm_inv, md.tri_rest_area, self.mu,
                                k.membrane_h, G, self._Hm, hessian)
            return float(E), (self._Hm if hessian else None)
        em, gm, Hm = membrane_terms(X[md.tri_points], md.tri_dm_inv, md.tri_rest_area, self.mu,
                                    k.membrane_h, hessian=hessian, psd=psd)
        _accumulate(G, md.tri_points, gm)
        if Hm is not None and self.backend == "numba":
            Hm = np.transpose(Hm, (0, 1, 3, 2, 4)).reshape(-1, 9, 9)
        return float(em.sum()), Hm

    @property
    def mu(self) -> float:
        """Membrane shear modulus in use, MPa (``consts.mu`` times the relaxation factor)."""
        return self.consts.mu if self.mu_scale == 1.0 else self.consts.mu * self.mu_scale

    def energy_parts(self, state: State) -> dict:
        """Energy per kind (N mm): ``springs``, ``cross``, ``membrane``, ``total`` (and
        ``external`` when weight or a plane is on)."""
        X, _ = self.positions(state)
        (es, _, _), (ex, _, _) = self._discrete(X, False, False)
        G = np.zeros((self.model.n_points, 3))
        em, _ = self._membrane(X, G, False, False)
        d = {"springs": float(es.sum()), "cross": float(ex.sum()), "membrane": em}
        d["total"] = d["springs"] + d["cross"] + d["membrane"]
        if self.external is not None:
            d["external"] = self.external.energy(state, X)
            d["total"] += d["external"]
        if self.contact is not None:
            d["contact"] = self.contact.evaluate(state, False)[0]
            d["total"] += d["contact"]
        if self.bending is not None:
            d["bending"] = self.bending.evaluate(state, False)[0]
            d["total"] += d["bending"]
        return d

    def energy(self, state: State) -> float:
        """Total energy (N mm)."""
        return self.energy_parts(state)["total"]

    def energy_scale(self, state: State) -> float:
        """Sum of absolute element energies: the scale of the energy's round-off error."""
        d = self.energy_parts(state)
        return (abs(d["springs"]) + abs(d["cross"]) + abs(d["membrane"])
                + abs(d.get("external", 0.0)) + abs(d.get("contact", 0.0))
                + abs(d.get("bending", 0.0)))

    def _reduce_gradient(self, G, v):
        m = self.m
        if self.backend == "numba":
            g = np.empty(6 * m + 3 * len(self.free_pts))
            rigid_gradient(G, self.attached, self.att_body, v, self.free_pts, m, g)
            return g
        Ga = G[self.attached]
        force = np.stack([np.bincount(self.att_body, weights=Ga[:, d], minlength=m)
                          for d in range(3)], 1)
        tq = np.cross(v, Ga)
        torque = np.stack([np.bincount(self.att_body, weights=tq[:, d], minlength=m)
                           for d in range(3)], 1)
        return np.r_[np.c_[force, torque].ravel(), G[self.free_pts].ravel()]

    def gradient(self, state: State):
        """Energy (N mm) and reduced gradient (N and N mm) at ``state`` (theta = 0)."""
        E, g, _ = self.evaluate(state, hessian=False)
        return E, g

    def evaluate(self, state: State, *, hessian: bool = True, psd: bool = False):
        """Energy, reduced gradient and (lower-triangle CSC) reduced Hessian at ``state``.

        Parameters
        ----------
        state : State
        hessian : bool
        psd : bool
            Convexified Hessian (per-element PSD projection).

        Returns
        -------
        E : float, N mm
        g : (n_dof,) float -- N for centres and free vertices, N mm for rotations
        H : scipy.sparse.csc_matrix or None -- lower triangle
        """
        md = self.model
        X, v = self.positions(state)
        (es, gs, Ks), (ex, gx, parts) = self._discrete(X, hessian, psd)
        G = np.zeros((md.n_points, 3))
        em, Hm = self._membrane(X, G, hessian, psd)
        _accumulate(G, md.spring_points, gs)
        _accumulate(G, md.cross_points, gx)
        E = float(es.sum() + ex.sum()) + em
        # the round-off scale of this energy, as energy_scale(state) computes it
        self.last_energy_scale = abs(float(es.sum())) + abs(float(ex.sum())) + abs(em)
        ext = None
        if self.external is not None:
            ext = self.external.evaluate(state, X, G, hessian)
            E += ext[0]
            self.last_energy_scale += abs(ext[0])
        g = self._reduce_gradient(G, v)
        if ext is not None:
            g[: 6 * self.m] += ext[1].ravel()
        con = None
        if self.contact is not None:
            con = self.contact.evaluate(state, hessian)
            E += con[0]
            self.last_energy_scale += abs(con[0])
            if con[1] is not None:
                g += con[1]
        bend = None
        if self.bending is not None:
            bend = self.bending.evaluate(state, hessian, self.pattern)
            E += bend[0]
            self.last_energy_scale += abs(bend[0])
            g[: 6 * self.m] += bend[1].ravel()
        if not hessian:
            return E, g, None
        V = np.zeros((md.n_points, 3))
        V[self.attached] = v  # rotated offsets; 0 for free points (their rotation dofs drop)
        rot = self._rotation_term(G, v, psd)
        if self.backend == "numba":
            H = self._assemble_numba(V, Ks, parts, Hm, rot)
        else:
            H = self._assemble_numpy(V, Ks, parts, Hm, rot)
        if ext is not None:
            H.data[self._external_positions()] += ext[2][:, self._lo[0], self._lo[1]].ravel()
        if bend is not None:
            bend[2](H.data)
        if con is not None and con[2] is not None:
            H = (H + con[2]).tocsc()
            H.sort_indices()
        return E, g, H

    def step_limit(self, state: State, p, alpha_max: float) -> float:
        """Largest safe multiple of the step ``p``: ``alpha_max``, or less when a contact
        barrier (:mod:`sim.model.contact`) would be crossed."""
        if self.contact is None:
            return alpha_max
        return self.contact.step_limit(state, p, alpha_max)

    def _external_positions(self) -> np.ndarray:
        """CSC positions of the lower triangle of every base's 6x6 diagonal block."""
        if self._ext_pos is None:
            self._lo = np.tril_indices(6)
            base = 6 * np.arange(self.m)[:, None]
            self._ext_pos = self.pattern.positions((base + self._lo[0]).ravel(),
                                                   (base + self._lo[1]).ravel())
        return self._ext_pos

    def _rotation_term(self, G, v, psd):
        """Second-order term of the rigid map per base: sum_p g_p . d2x_p / dtheta2 (m, 3, 3)."""
        if self.backend == "numba" and not psd:
            rot = np.empty((self.m, 3, 3))
            rigid_rotation_term(G, self.attached, self.att_body, v, rot)
            return rot
        Ga = G[self.attached]
        gv = Ga[:, :, None] * v[:, None, :]
        term = 0.5 * (gv + np.transpose(gv, (0, 2, 1)))
        term -= np.einsum("ni,ni->n", Ga, v)[:, None, None] * np.eye(3)
        rot = np.zeros((self.m, 9))
        tf = term.reshape(-1, 9)
        for d in range(9):
            rot[:, d] = np.bincount(self.att_body, weights=tf[:, d], minlength=self.m)
        rot = rot.reshape(-1, 3, 3)
        if psd:
            w, Q = np.linalg.eigh(rot)
            rot = (Q * np.maximum(w, 0.0)[:, None, :]) @ np.transpose(Q, (0, 2, 1))
        return rot

    def _assemble_numba(self, V, Ks, parts, Hm9, rot):

        md = self.model
        data = self.pattern.assemble_data([rot, None, None, None])
        Hs = np.empty((len(Ks), 6, 6))
        Hs[:, :3, :3] = Ks
        Hs[:, 3:, 3:] = Ks
        Hs[:, :3, 3:] = -Ks
        Hs[:, 3:, :3] = -Ks
        reduce_scatter(Hs, md.spring_points, V, self.pos_spring, data, self.use_spring)
        Hx = np.empty((len(md.cross_points), 12, 12))
        cross_point_hessian(md.cross_weight, *parts, Hx)
        reduce_scatter(Hx, md.cross_points, V, self.pos_cross, data, self.use_cross)
        reduce_scatter(Hm9, md.tri_points, V, self.pos_tri, data, self.use_tri)
        return self.pattern.matrix(data)

    def _assemble_numpy(self, V, Ks, parts, Hm, rot):
        md, c = self.model, self.n_cells
        # springs: [[K, -K], [-K, K]] between base a and base b
        sp_ = md.spring_points
        cell = segment_blocks(Ks, V[sp_[:, 0]], V[sp_[:, 1]]).reshape(c, 4, 12, 12).sum(1)
        # cross pairs: w G G^T + segment blocks Ka on (x0, x1) and Kb on (x2, x3)
        G, Ka, Kb = parts
        cp = md.cross_points
        Vc = V[cp]
        X_ = segment_blocks(Ka, Vc[:, 0], Vc[:, 1]) + segment_blocks(Kb, Vc[:, 2], Vc[:, 3])
        u = np.empty((len(cp), 2, 6))
        u[:, 0, :3] = G[:, 0] + G[:, 2]
        u[:, 1, :3] = G[:, 1] + G[:, 3]
        u[:, 0, 3:] = np.cross(Vc[:, 0], G[:, 0]) + np.cross(Vc[:, 2], G[:, 2])
        u[:, 1, 3:] = np.cross(Vc[:, 1], G[:, 1]) + np.cross(Vc[:, 3], G[:, 3])
        u = u.reshape(-1, 12)
        X_ += md.cross_weight[:, None, None] * u[:, :, None] * u[:, None, :]
        cell += X_.reshape(c, 4, 12, 12).sum(1)
        # membrane: sum element blocks per point pair, then reduce each pair
        nt = len(md.tri_points)
        blk = Hm[np.arange(nt)[:, None], self.tri_li, self.tri_lj].reshape(-1, 9)
        npair = len(self.pairs)
        Pb = np.empty((npair, 9))
        pidf = self.tri_pid.ravel()
        for d in range(9):
            Pb[:, d] = np.bincount(pidf, weights=blk[:, d], minlength=npair)
        Pb = Pb.reshape(-1, 3, 3)
        R = jtkj(Pb, V[self.pairs[:, 0]], V[self.pairs[:, 1]])
        Rd = R[self.pair_diag]
        Ro = R[~self.pair_diag]
        return self.pattern.assemble([rot, cell, Rd, Ro, np.swapaxes(Ro, 1, 2)])

    def residual(self, g) -> float:
        """Convergence measure (N): ``max(|g_translation|_inf, |g_rotation|_inf / base_r)``.

        Forces on base centres and free membrane vertices are in N; torques (N mm) are
        divided by the base radius so that both are forces at the base rim.
        """
        g = np.asarray(g)
        return float(max(np.abs(g[self.trans_dofs]).max(initial=0.0),
                         np.abs(g[self.rot_dofs]).max(initial=0.0) / self.model.unit.base_r))


def _accumulate(G, pts, g):
    """``G[pts] += g`` for element gradients ``g (n, k, 3)`` (repeated points summed)."""
    n = len(G)
    idx = pts.ravel()
    gg = g.reshape(-1, 3)
    for d in range(3):
        G[:, d] += np.bincount(idx, weights=gg[:, d], minlength=n)


__all__ = ["skew", "rodrigues", "spring_terms", "cross_terms", "cross_hessian", "membrane_terms",
           "jtkj", "segment_blocks", "State", "SparsePattern", "full_from_lower", "ShellEnergy"]
