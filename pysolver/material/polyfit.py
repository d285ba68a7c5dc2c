"""Multivariate monomial bases and least squares with linear derivative constraints (SI eq. 11).

A polynomial is a list of exponent rows ``E : (m, d) int`` and coefficients ``beta : (m,)``;
``p(X) = sum_j beta_j prod_k X[:, k] ** E[j, k]``.  The constrained fit solves

    minimise 1/2 ||W^(1/2) (X beta - y)||^2   subject to   A beta >= 0

with quadprog (Goldfarb-Idnani) through qpsolvers, after scaling the columns of X to unit norm and
the rows of A to unit norm (neither changes the minimiser; both are needed: the raw degree-4
design has a condition number of ~1e12).  Reductions use ``einsum`` (fixed order, no BLAS
threads) so the results do not depend on the thread count.
"""

from __future__ import annotations

import itertools

import numpy as np
import qpsolvers

from ..errors import MorphshellError
from ..params import tol as TOL


def mv(M, v) -> np.ndarray:
    """Matrix-vector product with a fixed summation order.

    ``M @ v`` goes through a multi-threaded BLAS whose summation order depends on the thread
    count; the ill-conditioned p_wet fit amplifies those last-bit differences to 1e-7 in the
    force coefficients, which would make the written model depend on the machine's thread
    settings.  ``einsum`` without ``optimize`` uses its own single-threaded loops.
    """
    return np.einsum("ij,j->i", M, v)


def monomial_exponents(max_deg, total_deg: int, factor=None) -> np.ndarray:
    """Exponent rows of all monomials with per-variable and total degree limits.

    Parameters
    ----------
    max_deg : (d,) int
        Highest power of each variable.
    total_deg : int
        Highest total degree.
    factor : (d,) int, optional
        Exponents added to every monomial afterwards (e.g. ``(0, 0, 1)`` multiplies by F).

    Returns
    -------
    E : (m, d) int
        Sorted by total degree, then lexicographically (deterministic).
    """
    rows = [e for e in itertools.product(*(range(k + 1) for k in max_deg)) if sum(e) <= total_deg]
    rows.sort(key=lambda e: (sum(e), tuple(-v for v in e)))
    E = np.array(rows, dtype=np.int64)
    if factor is not None:
        E = E + np.asarray(factor, dtype=np.int64)
    return E


def design_matrix(E: np.ndarray, X: np.ndarray, wrt: int | None = None) -> np.ndarray:
    """Monomial values (or their partial derivatives) at points.

    Parameters
    ----------
    E : (m, d) int
    X : (n, d) float
    wrt : int, optional
        Differentiate each monomial once with respect to variable ``wrt``.

    Returns
    -------
    (n, m) float
    """
    X = np.asarray(X, dtype=float)
    E = np.asarray(E)
    coef = np.ones(len(E))
    if wrt is not None:
        coef = E[:, wrt].astype(float)
        E = E.copy()
        E[:, wrt] = np.maximum(E[:, wrt] - 1, 0)
    out = np.ones((X.shape[0], E.shape[0]))
    for k in range(E.shape[1]):
        pk = E[:, k]
        if np.any(pk):
            # powers via a small table: faster and exact for the integer exponents used here
            tab = X[:, k:k + 1] ** np.arange(pk.max() + 1)
            out *= tab[:, pk]
    return out * coef


def evaluate(E: np.ndarray, beta: np.ndarray, X: np.ndarray, wrt: int | None = None) -> np.ndarray:
    """``p(X)`` or ``dp/dX[:, wrt]`` for the polynomial ``(E, beta)``; (n,) float."""
    return mv(design_matrix(E, X, wrt), beta)


def constrained_lstsq(X, y, A=None, w=None, ridge=0.0, viol_tol: float = TOL.qp_violation):
    """Weighted least squares ``X beta ~ y`` subject to ``A beta >= 0``.

    Parameters
    ----------
    X : (n, m) float
    y : (n,) float
    A : (k, m) float, optional
        Constraint rows (each ``A_i beta >= 0``).
    w : (n,) float, optional
        Row weights (default 1).
    ridge : float or (m,) float
        Tikhonov term ``sum_j ridge_j * trace(P)/m * gamma_j^2`` added in the scaled variables
        ``gamma``, for rank-deficient problems; 0 requires ``X`` to have full column rank.
    viol_tol : float
        Accepted constraint violation (unit-norm rows, scaled variables).

    Returns
    -------
    beta : (m,) float
    info : dict
        ``max_violation`` (max of ``-A beta`` in unit-norm-row scale, >= 0), ``n_active``,
        ``rounds`` (cutting-plane rounds).
    """
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    w = np.ones(len(y)) if w is None else np.asarray(w, dtype=float)
    N = np.einsum("ij,ik->jk", X * w[:, None], X)
    r = np.einsum("ij,i->j", X, w * y)
    return constrained_normal_lstsq(N, r, A, ridge, viol_tol)


def constrained_normal_lstsq(N, r, A=None, ridge=0.0, viol_tol: float = TOL.qp_violation):
    """:func:`constrained_lstsq` given the normal equations ``N = X'WX`` (m, m), ``r = X'Wy``.

    Lets callers with block-structured designs assemble ``N`` cheaply.
    """
    N = np.asarray(N, dtype=float)
    m = N.shape[0]
    scale = np.sqrt(np.maximum(np.diag(N), 0.0))
    scale[scale == 0.0] = 1.0
    P = N / np.outer(scale, scale)
    q = -np.asarray(r, dtype=float) / scale
    ridge = np.broadcast_to(np.asarray(ridge, dtype=float), (m,))
    if np.any(ridge > 0.0):
        P = P + np.diag(ridge * np.trace(P) / m)
    P = 0.5 * (P + P.T)
    G = None
    if A is not None and len(A):
        As = np.asarray(A, dtype=float) / scale
        rn = np.linalg.norm(As, axis=1)
        keep = rn > 0.0
        G = -As[keep] / rn[keep, None]
    gamma, n_rounds = _solve_cutting_plane(P, q, G, viol_tol)
    info = {"max_violation": 0.0, "n_active": 0, "rounds": n_rounds}
    if G is not None:
        g = mv(G, gamma)
        info["max_violation"] = float(max(0.0, g.max()))
        info["n_active"] = int(np.sum(g > -TOL.active_set))
    return gamma / scale, info


def _solve_cutting_plane(P, q, G, tol: float, max_rounds: int = 100):
    """Solve ``min 1/2 g'Pg + q'g, G g <= 0`` by adding violated rows to a working set.

    Dense sampled derivative constraints (e.g. p'(x) >= 0 every 0.01 mm) are nearly parallel
    neighbours; handed all at once, quadprog's dual active-set method can cycle on them (observed:
    a 32-variable, 1 863-row problem never returned).  Starting from an evenly thinned subset
    and adding the most violated rows (at most ``len(q)`` per round) until every row holds to
    ``tol`` gives the same minimiser with small, well-separated working sets.  ``tol`` must
    exceed the 2e-11 relaxation below.
    """
    def qp(rows):
        if rows is None or len(rows) == 0:
            return qpsolvers.solve_qp(P, q, solver="quadprog")
        return qpsolvers.solve_qp(P, q, G[rows], relax[rows], solver="quadprog")

    if G is not None:
        # Every row passes through the origin (homogeneous derivative constraints), a degenerate
        # configuration on which quadprog was seen to cycle forever; relaxing row i by a
        # distinct 1e-11 * (1 + frac(i * golden ratio)) breaks the degeneracy (deterministic,
        # far below the accepted violation ``tol``).
        relax = TOL.qp_relax * (1.0 + (np.arange(len(G)) * 0.6180339887498949) % 1.0)

    if G is None:
        gamma = qp(None)
        if gamma is None:
            raise MorphshellError("the polynomial least-squares problem (quadprog) has no "
                                  "solution; the design is rank-deficient.")
        return gamma, 1
    m = len(q)
    stride = max(1, len(G) // (8 * m))
    rows = np.arange(0, len(G), stride)
    for k in range(1, max_rounds + 1):
        gamma = qp(rows)
        if gamma is None:
            raise MorphshellError("the constrained polynomial fit (quadprog) found no solution; "
                                  "the constraints may be infeasible or the design "
                                  "rank-deficient.")
        v = mv(G, gamma)
        bad = np.flatnonzero(v > tol)
        if bad.size == 0:
            return gamma, k
        add = bad[np.argsort(-v[bad], kind="stable")][:m]
        rows = np.union1d(rows, add)
    raise MorphshellError(f"the constrained polynomial fit did not converge in {max_rounds} "
                          f"cutting-plane rounds (max violation {v.max():.3g}).")


# ----------------------------------------------------------------------------------------------
# the bracket force polynomial in the compression x (degree 4, no constant term)


def poly_force(c, x):
    """``sum_k c[..., k-1] x^k`` for k = 1..4: force (N) of coefficient rows ``c`` (..., 4) at x."""
    c = np.asarray(c, float)
    x = np.asarray(x, float)
    return x * (c[..., 0] + x * (c[..., 1] + x * (c[..., 2] + x * c[..., 3])))


def poly_energy(c, x):
    """Energy ``sum_k c_k x^(k+1) / (k+1)`` (N mm) of force coefficients ``c`` (..., 4) at x."""
    c = np.asarray(c, float)
    x = np.asarray(x, float)
    return x * x * (c[..., 0] / 2 + x * (c[..., 1] / 3 + x * (c[..., 2] / 4 + x * c[..., 3] / 5)))


def poly_stiffness(c, x):
    """``dF/dx = sum_k k c_k x^(k-1)`` (N/mm) of force coefficients ``c`` (..., 4) at x."""
    c = np.asarray(c, float)
    x = np.asarray(x, float)
    return c[..., 0] + x * (2 * c[..., 1] + x * (3 * c[..., 2] + x * 4 * c[..., 3]))
