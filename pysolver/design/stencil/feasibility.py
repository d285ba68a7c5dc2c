"""What a target surface needs of a unit cell, against what a cell can give: a measured bound.

Every stencil the design makes is conformal: a cell's flat length ``l`` is its target length
``D`` times ``K exp(u)``, ``u`` the conformal log-scale of the flattening at the cell and ``K``
one factor for the whole shell (``pipeline.md`` §2.5).  A cell can give only so much:

* **bending**: a cell of half fold ``t`` needs a target length of at least
  ``D_min(t) = 2 cos t (base_r + layer_h tan t + min_bumper)`` (the 3D rule), and on a
  surface of normal curvature ``k`` a cell ``D`` long folds by about ``t = k D / 2``;
* **contraction**: it must contract, ``l >= D / cos t + 2 layer_h tan t + min_gap`` (the 2D
  rule), and it can be at most ``max_cell_length`` long when printed.

So for any two places ``x`` and ``y`` of the target,
``max_cell_length >= l_x = K e^{u_x} D_x >= e^{u_x - u_y} rho_min(y) D_min(x)``: the longest
flat cell of *any* conformal stencil is at least

    L = max_x (e^{u_x} D_min(x)) / min_y (e^{u_y} / rho_min(y)),

with ``rho_min(y) = 1 / cos t_y + layer_h k_y + min_gap / max_cell_length`` the least
contraction a cell there needs.  The conformal log-scale is fixed by the surface up to a
harmonic function (its boundary values are free: Dirichlet data of the flattening), so
:func:`conformal_bound` minimises ``L`` over them, a linear programme in ``log L``.  When even
that minimum exceeds ``max_cell_length``, no conformal stencil of this target prints with
this unit cell: only a cut, a flatter target or another unit cell would.

Curvature and log-scale are measured at the scale of a cell (averaged over a ball of one
shortest cell length, :func:`cell_scale_curvature`), because a stencil of cells cannot
resolve finer detail, and the rim strip where no base centre lies is left out: the bound is
a measured estimate of what any stencil must reach, not a proof.
"""

from __future__ import annotations

import igl
import numpy as np
import scipy.sparse as sp
from scipy.optimize import linprog, minimize
from scipy.sparse.linalg import splu
from scipy.spatial import cKDTree
from scipy.special import logsumexp

from ...geometry import face_normals
from ...params import STENCIL, UNIT_CELL, StencilSearch, UnitCell
from ..flatten import cetm
from .remesh import needs_dense, resample_dense


def shortest_cell(params: UnitCell = UNIT_CELL) -> float:
    """Target length (mm) of the shortest cell, unfolded: ``2 (base_r + min_bumper)``."""
    return 2.0 * (params.base_r + params.min_bumper)


def cell_scale_curvature(V, F, radius: float):
    """Principal curvatures of the target averaged over balls of ``radius`` mm.

    The shape operator at each vertex is the least-squares fit of the face normals' change
    over the faces whose centroids lie within ``radius`` (``n_y - n_x ~ S (y - x)`` in the
    tangent plane): what a cell of that size folds by, not the mesh's finest detail.  (Hand
    written: libigl's quadric fit works in mesh rings, not in mm.)

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    radius : float, mm

    Returns
    -------
    k1, k2 : (n,) float, 1/mm
        Principal curvatures, ``|k1| >= |k2|``.
    d1 : (n, 3) float
        Unit direction of ``k1``.
    """
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    C = V[F].mean(axis=1)
    N = face_normals(V, F)
    Nv = igl.per_vertex_normals(V, F)
    tree = cKDTree(C)
    k1, k2 = np.zeros(len(V)), np.zeros(len(V))
    d1 = np.zeros((len(V), 3))
    for i, near in enumerate(tree.query_ball_point(V, radius)):
        n = Nv[i]
        a = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        a /= np.linalg.norm(a)
        b = np.cross(n, a)
        T = np.c_[a, b]                         # (3, 2) tangent frame
        if len(near) < 4:
            continue
        dx = (C[near] - V[i]) @ T               # (k, 2)
        dn = (N[near] - n) @ T                  # (k, 2)
        # dn = dx @ S (S symmetric): unknowns s11, s12, s22
        A = np.zeros((2 * len(near), 3))
        A[0::2, 0], A[0::2, 1] = dx[:, 0], dx[:, 1]
        A[1::2, 1], A[1::2, 2] = dx[:, 0], dx[:, 1]
        s = np.linalg.lstsq(A, dn.ravel(), rcond=None)[0]
        w, U = np.linalg.eigh(np.array([[s[0], s[1]], [s[1], s[2]]]))
        j = int(np.argmax(np.abs(w)))
        k1[i], k2[i] = w[j], w[1 - j]
        d1[i] = T @ U[:, j]
    return k1, k2, d1


def worst_cell_curvature(k1, k2) -> np.ndarray:
    """(n,) float, 1/mm: the largest normal curvature ``|k1 cos^2 p + k2 sin^2 p|`` over the
    three directions of a triangle mesh's cells (60 deg apart), at their best orientation:
    some cell of any stencil folds at least this much per unit length."""
    k1, k2 = np.asarray(k1, float), np.asarray(k2, float)
    best = np.full(len(k1), np.inf)
    for p0 in np.radians(np.linspace(0.0, 60.0, 13)):
        worst = np.zeros(len(k1))
        for k in range(3):
            p = p0 + k * np.pi / 3
            worst = np.maximum(worst, np.abs(k1 * np.cos(p) ** 2 + k2 * np.sin(p) ** 2))
        best = np.minimum(best, worst)
    return best


def min_cell_length(kappa, params: UnitCell = UNIT_CELL, iterations: int = 50):
    """Shortest target length ``D`` (mm) of a cell on a surface of normal curvature
    ``kappa`` (1/mm): the fixed point of ``D = 2 cos t (base_r + layer_h tan t +
    min_bumper)``, ``t = kappa D / 2`` (inf where none exists: the surface bends too tightly
    for a cell to keep its bumpers)."""
    kappa = np.asarray(kappa, float)
    D = np.full(kappa.shape, shortest_cell(params))
    for _ in range(iterations):
        t = np.minimum(kappa * D / 2.0, np.radians(89.0))
        D = 2.0 * np.cos(t) * (params.base_r + params.layer_h * np.tan(t) + params.min_bumper)
    t = kappa * D / 2.0
    return np.where(t < np.radians(80.0), D, np.inf)


def harmonic_basis(V, F, modes: int = 24) -> np.ndarray:
    """(n, modes) float: harmonic extensions (cotangent Laplacian) of ``modes`` hat functions
    spaced evenly in arc length along the boundary (periodic, piecewise linear): a smooth
    family of boundary log-scales, enough for the bound and small enough for its linear
    programme."""
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    L = sp.csr_matrix(-igl.cotmatrix(V, F))
    bnd = np.asarray(igl.boundary_loop(F), dtype=np.int64)
    inner = np.setdiff1d(np.arange(len(V)), bnd)
    seg = np.linalg.norm(V[np.roll(bnd, -1)] - V[bnd], axis=1)
    s = np.r_[0.0, np.cumsum(seg)[:-1]] / seg.sum() * modes   # boundary arc length in modes
    k = np.arange(modes)
    d = np.abs(s[:, None] - k[None, :])
    B = np.maximum(1.0 - np.minimum(d, modes - d), 0.0)        # (b, modes) periodic hats
    H = np.zeros((len(V), modes))
    H[bnd] = B
    H[inner] = splu(sp.csc_matrix(L[inner][:, inner])).solve(
        -np.asarray(L[inner][:, bnd] @ B))
    return H


def _needs(V, F, params: UnitCell, rim_mm, u) -> dict:
    """What each point of the target needs (module docstring), measured at cell scale.

    Returns
    -------
    dict
        ``keep`` (k,) int (the points at least ``rim_mm``, default ``base_r``, from the
        rim), per point (n,): ``Dmin`` (mm, inf where no cell bends that far), ``t`` (half
        fold, rad), ``us`` (the log-scale ``u``, default CETM's, averaged over a ball of one
        shortest cell); per kept point (k,): ``a = log Dmin``, ``b = log rho_min``.
    """
    if u is None:
        _, u, _ = cetm(V, F)
    r = shortest_cell(params)
    k1, k2, _ = cell_scale_curvature(V, F, r)
    kap = worst_cell_curvature(k1, k2)
    Dmin = min_cell_length(kap, params)
    t = kap * np.where(np.isfinite(Dmin), Dmin, r) / 2.0
    rho = 1.0 / np.cos(np.minimum(t, np.radians(89.0))) + params.layer_h * kap \
        + params.min_gap / params.max_cell_length
    tree = cKDTree(V)
    us = np.array([u[nb].mean() for nb in tree.query_ball_point(V, r)])
    bnd = np.asarray(igl.boundary_loop(F), dtype=np.int64)
    d_rim, _ = cKDTree(V[bnd]).query(V)
    keep = np.flatnonzero(d_rim >= (params.base_r if rim_mm is None else rim_mm))
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = np.log(Dmin[keep]), np.log(rho[keep])
    return {"keep": keep, "Dmin": Dmin, "t": t, "us": us, "a": a, "b": b}


def rim_log_scale(V, F, params: UnitCell = UNIT_CELL, settings: StencilSearch = STENCIL,
                  u=None) -> np.ndarray:
    """The boundary log-scale of the flattening that lowers the measured bound: the
    harmonic function ``h = H c`` (:func:`harmonic_basis`) minimising the bound's two
    extremes, each smoothed by a log-sum-exp of sharpness ``settings.rim_scale_sharpness``,
    plus ``settings.rim_scale_ridge |c|^2 / 2``.  (The bound itself is a linear programme,
    :func:`conformal_bound`; its minimiser is a vertex that may jump between equally good
    ones with the last bits, while this one is unique and smooth in the input.)

    Parameters
    ----------
    V : (n, 3) float, mm -- the target, finely meshed
    F : (m, 3) int
    params : UnitCell
    settings : StencilSearch
    u : (n,) float, optional -- CETM's log-scale with 0 on the rim

    Returns
    -------
    h : (n,) float
        Log-scale to add to the flattening's, harmonic, with mean 0 on the rim (its values
        on the rim are the Dirichlet data of :func:`pysolver.design.flatten.cetm`); zeros
        when some point bends too tightly for any cell (no boundary scale helps there), or
        when the bound it gives is no lower than the rim's lengths kept give.
    """
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    need = _needs(V, F, params, None, u)
    keep = need["keep"]
    if not np.all(np.isfinite(need["Dmin"][keep])) or not len(keep):
        return np.zeros(len(V))
    H = harmonic_basis(V, F)
    Hk, us, a, b = H[keep], need["us"][keep], need["a"], need["b"]
    beta, mu = settings.rim_scale_sharpness, settings.rim_scale_ridge

    def weights(c):  # the two log-sum-exps' softmax weights at c
        h = Hk @ c
        p, q = beta * (us + h + a), -beta * (us + h - b)
        lp, lq = logsumexp(p), logsumexp(q)
        return (lp + lq) / beta, np.exp(p - lp), np.exp(q - lq)

    def smoothed(c):  # log of the smoothed bound plus the ridge, and its gradient
        f, wp, wq = weights(c)
        return f + 0.5 * mu * c @ c, Hk.T @ (wp - wq) + mu * c

    def hessian(c):
        _, wp, wq = weights(c)
        gp, gq = Hk.T @ wp, Hk.T @ wq
        return beta * (Hk.T @ ((wp + wq)[:, None] * Hk) - np.outer(gp, gp)
                       - np.outer(gq, gq)) + mu * np.eye(len(c))

    # Newton's method with an exact Hessian (24 modes): converged to round-off, so that the
    # last bits of the input move the result by no more than they move the problem
    res = minimize(smoothed, np.zeros(H.shape[1]), jac=True, hess=hessian,
                   method="trust-exact", options={"gtol": 1e-12, "maxiter": 200})
    def spread(h):  # log of the bound
        return np.max(us + h + a) - np.min(us + h - b)

    if not np.all(np.isfinite(res.x)) or not spread(Hk @ res.x) < spread(0.0):
        return np.zeros(len(V))  # (the smoothed extremes' minimiser can miss the exact ones)
    h = H @ res.x
    bnd = np.asarray(igl.boundary_loop(F), dtype=np.int64)
    return h - h[bnd].mean()


def conformal_bound(V, F, params: UnitCell = UNIT_CELL, *, rim_mm: float | None = None,
                    u=None) -> dict:
    """The least longest flat cell any conformal stencil of a target can have (module
    docstring), with the flattening's boundary scale chosen to lower it.

    Parameters
    ----------
    V : (n, 3) float, mm -- the target, finely meshed (well-shaped triangles)
    F : (m, 3) int
    params : UnitCell
    rim_mm : float, mm, optional
        Points nearer the rim are left out (no base centre lies there); default ``base_r``.
    u : (n,) float, optional
        Conformal log-scale with 0 on the rim (default: CETM of the target).

    Returns
    -------
    dict
        ``bound_mm`` (the least longest flat cell, boundary scale optimised: any conformal
        stencil), ``bound_rim_fixed_mm`` (with the rim's scale kept, as CETM with u = 0 on
        the rim does, or with the log-scale ``u`` given), ``contraction`` (``e^{u_max - u_min}``
        over the region, cell-scale, boundary scale optimised), ``fold_deg`` (largest cell
        fold the curvature forces), ``shortest_cell_mm`` (``D_min`` range), ``limit_mm``,
        ``printable`` (``bound_rim_fixed_mm <= max_cell_length``: not excluded for a layout
        that keeps the rim's lengths; :func:`target_bound` gives the verdict for the
        layouts the search makes), ``where`` (the point, mm, that sets the bound).
    """
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    need = _needs(V, F, params, rim_mm, u)
    keep, Dmin, t = need["keep"], need["Dmin"], need["t"]
    if not np.all(np.isfinite(Dmin[keep])):
        i = keep[np.argmax(~np.isfinite(Dmin[keep]))]
        return {"bound_mm": float("inf"), "bound_rim_fixed_mm": float("inf"),
                "printable": False, "limit_mm": params.max_cell_length,
                "where": V[i].round(1).tolist(), "contraction": None,
                "fold_deg": 180.0, "shortest_cell_mm": [float(np.nanmin(Dmin)), float("inf")]}
    us, a, b = need["us"][keep], need["a"], need["b"]
    fixed = float(np.max(us + a) - np.min(us - b))
    # minimise over boundary data h = H c: t s.t. us + Hc + a <= s + t, us + Hc - b >= s
    Hk = harmonic_basis(V, F)[keep]
    m, nb = Hk.shape
    one = np.ones((m, 1))
    A = np.vstack([np.hstack([Hk, -one, -one]), np.hstack([-Hk, one, np.zeros((m, 1))])])
    rhs = np.r_[-(us + a), us - b]
    cost = np.r_[np.zeros(nb + 1), 1.0]
    res = linprog(cost, A_ub=A, b_ub=rhs, bounds=[(None, None)] * (nb + 2), method="highs-ds")
    best = float(res.fun) if res.status == 0 else fixed
    h = Hk @ res.x[:nb] if res.status == 0 else np.zeros(m)
    i = keep[int(np.argmax(us + h + a))]
    return {"bound_mm": round(float(np.exp(best)), 3),
            "bound_rim_fixed_mm": round(float(np.exp(fixed)), 3),
            "contraction": round(float(np.exp(np.ptp(us + h))), 3),
            "fold_deg": round(float(np.degrees(2 * t[keep].max())), 1),
            "shortest_cell_mm": [round(float(Dmin[keep].min()), 3),
                                 round(float(Dmin[keep].max()), 3)],
            "limit_mm": params.max_cell_length,
            "printable": bool(np.exp(fixed) <= params.max_cell_length),
            "where": V[i].round(1).tolist()}


def target_bound(V, F, params: UnitCell = UNIT_CELL, settings: StencilSearch = STENCIL) -> dict:
    """:func:`conformal_bound` of a target meshed as the stencil search meshes it (resampled
    finely when its triangles are poor or few); ``printable`` is that of the layouts the
    search makes: with ``settings.rim_scale`` other than ``"kept"`` the rim's scale may be
    free, and the best conformal layout's bound applies (``rim_scale`` records which)."""
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    if needs_dense(V, F, settings):
        V, F = resample_dense(V, F, settings.dense_faces)
    b = conformal_bound(V, F, params)
    b["rim_scale"] = "kept" if settings.rim_scale == "kept" else "free"
    if b["rim_scale"] == "free":
        b["printable"] = bool(b["bound_mm"] <= params.max_cell_length)
    return b


def describe_bound(b: dict, params: UnitCell = UNIT_CELL) -> str:
    """One sentence for a refusal: the measured bound against the limit."""
    if not np.isfinite(b["bound_mm"]):
        return (f"the target bends too tightly for any cell to keep its bumpers near "
                f"({', '.join(f'{x:.1f}' for x in b['where'])}) mm")
    most = params.max_cell_length / shortest_cell(params)
    free = (", as morphshell lays it out when the first does not print"
            if b.get("rim_scale") == "free" else "")
    head = (f"measured bound: every stencil of this target has a flat cell of at least "
            f"{b['bound_rim_fixed_mm']:.2f} mm in a conformal layout that keeps the rim's "
            f"lengths, {b['bound_mm']:.2f} mm in the best conformal layout (the rim's scale "
            f"free{free}); its cells must "
            f"contract {b['contraction']:.2f} times more in one place than in another and "
            f"fold by up to {b['fold_deg']:.0f} deg, and a cell can contract at most "
            f"{most:.2f} times at {params.min_bumper:g} mm bumpers")
    if b["printable"]:
        return head + "; the bound does not exclude a printable stencil"
    return head + f": over the {params.max_cell_length:g} mm limit, no stencil of it prints " \
        "with this unit cell"


__all__ = ["shortest_cell", "cell_scale_curvature", "worst_cell_curvature", "min_cell_length",
           "harmonic_basis", "rim_log_scale", "conformal_bound", "target_bound", "describe_bound"]
