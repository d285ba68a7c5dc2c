"""Conformal flattening of a disk-like stencil: CETM (the authors' choice) and LSCM (igl).

CETM (conformal equivalence of triangle meshes, Springborn, Schroeder & Pinkall 2008):
find per-vertex log scale factors ``u`` so that the metric ``l_ij exp((u_i + u_j)/2)``
is flat (angle sum 2 pi at every interior vertex), with ``u = 0`` on the boundary
(Dirichlet: boundary edge lengths kept), or the boundary values given (``u_boundary``: the
rim's scale free, :func:`pysolver.design.stencil.feasibility.rim_log_scale`).  The energy

    E(u) = sum_faces [ sum_k (alpha_k lam_k + 2 Lob(alpha_k)) - pi/2 sum_k lam_k ]
           + sum_i Theta_i u_i,       lam_k = 2 log(l_k) + u_a + u_b,

(``alpha_k`` = angle opposite edge k, ``Lob`` = Lobachevsky function) is convex with
gradient ``Theta_i - (angle sum at i)`` and Hessian the cotangent Laplacian of the
current metric; Newton with backtracking converges in a few steps.  Then the flat
triangles are laid out face by face (breadth-first walk).

``flattening="lscm"`` uses ``igl.lscm`` with two far-apart boundary vertices pinned.
:func:`compare_flattenings` runs both and records area/angle distortion, flips and the
resulting maximum cell length after the scaling rules.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field

import igl
import numpy as np
import scipy.sparse as sp
import scipy.special as sps
from scipy.sparse.linalg import spsolve

from ..errors import InputError
from ..geometry import face_adjacency, signed_areas_2d
from ..params import NEWTON, UNIT_CELL, UnitCell
from ..params import tol as TOL
from .layout import build_layout


@dataclass
class FlattenResult:
    """A flat layout and its figures."""

    UV: np.ndarray
    method: str
    metrics: dict = field(default_factory=dict)
    u: np.ndarray | None = None


# --------------------------------------------------------------------------------------
# CETM


_N = np.arange(1, 31)
_CL2_COEF = sps.zeta(2 * _N) / (_N * (2 * _N + 1))


def clausen2(theta: np.ndarray) -> np.ndarray:
    """Clausen function Cl2(theta) = -int_0^theta log|2 sin(t/2)| dt.

    Hand-written (scipy has no Clausen function; ``Im Li2(e^{i theta})`` through
    ``scipy.special.spence`` is ~500x slower): reduce to [0, pi] with
    Cl2(2 pi - t) = -Cl2(t), then the series
    ``t - t log t + t sum_n zeta(2n) / (n (2n+1)) (t / 2 pi)^(2n)`` (30 terms, < 1e-14).
    """
    th = np.mod(np.asarray(theta, float), 2 * np.pi)
    sg = np.where(th > np.pi, -1.0, 1.0)
    t = np.where(th > np.pi, 2 * np.pi - th, th)
    x = (t / (2 * np.pi)) ** 2
    acc = np.zeros_like(t)
    for c in _CL2_COEF[::-1]:
        acc = (acc + c) * x
    with np.errstate(divide="ignore", invalid="ignore"):
        r = t - t * np.log(t) + t * acc
    return sg * np.where(t > 0, r, 0.0)


def lobachevsky(x: np.ndarray) -> np.ndarray:
    """Lobachevsky function ``-int_0^x log|2 sin t| dt`` = Cl2(2x)/2."""
    x = np.asarray(x, float)
    return np.where((x <= 0) | (x >= np.pi), 0.0, 0.5 * clausen2(2 * x))


def _angles_from_lengths(L: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Corner angles from edge lengths (L[:, k] opposite corner k); degenerate -> (pi, 0, 0).

    Returns angles (m, 3) and a mask of valid (non-degenerate) triangles.
    """
    a, b, c = L[:, 0], L[:, 1], L[:, 2]
    valid = (a < b + c) & (b < a + c) & (c < a + b)
    A = np.zeros_like(L)
    with np.errstate(invalid="ignore", divide="ignore"):
        A[:, 0] = np.arccos(np.clip((b * b + c * c - a * a) / (2 * b * c), -1, 1))
        A[:, 1] = np.arccos(np.clip((a * a + c * c - b * b) / (2 * a * c), -1, 1))
    A[:, 2] = np.pi - A[:, 0] - A[:, 1]
    if not np.all(valid):
        bad = ~valid
        k = np.argmax(L[bad], axis=1)
        Ab = np.zeros((bad.sum(), 3))
        Ab[np.arange(len(k)), k] = np.pi
        A[bad] = Ab
    return A, valid


def _cetm_state(lam0, F, u):
    """Angles, energy terms for log-length-squared lam0 (m, 3) and u."""
    ua, ub = u[F[:, [1, 2, 0]]], u[F[:, [2, 0, 1]]]
    lam = lam0 + ua + ub
    L = np.exp(lam / 2)
    A, valid = _angles_from_lengths(L)
    return lam, L, A, valid


def _cetm_energy(lam0, F, u, theta, interior):
    lam, _, A, _ = _cetm_state(lam0, F, u)
    e = np.sum(A * lam) + 2 * np.sum(lobachevsky(A)) - 0.5 * np.pi * np.sum(lam)
    return e + np.sum(theta[interior] * u[interior])


def cetm(V, F, *, max_iter: int = 60, tol: float = TOL.cetm_stop, u_boundary=None):
    """CETM flattening with u = 0 on the boundary, or the boundary log-scale given.

    Parameters
    ----------
    V : (n, 3) float
    F : (m, 3) int
        A connected disk-like triangle mesh.
    u_boundary : (n,) float, optional
        Log-scale factors; the values on the boundary vertices are the Dirichlet data (a
        boundary edge's flat length is its 3D length times ``exp((u_a + u_b) / 2)``), the
        others are ignored.  Default 0: boundary edge lengths kept.

    Returns
    -------
    UV : (n, 2) float
        Flat layout (same scale as V: boundary edge lengths are kept unless
        ``u_boundary``).
    u : (n,) float
        Log scale factors (flat length = 3D length * exp((u_a + u_b)/2)).
    info : dict
        Iterations and final gradient norm.
    """
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    n = len(V)
    L0 = igl.edge_lengths(V, F)  # opposite corner k
    lam0 = 2 * np.log(L0)
    bnd = np.zeros(n, dtype=bool)
    bnd[igl.boundary_loop(F)] = True
    interior = np.flatnonzero(~bnd)
    theta = np.full(n, 2 * np.pi)
    u = np.zeros(n)
    if u_boundary is not None:
        u[bnd] = np.asarray(u_boundary, float).reshape(n)[bnd]
    # Hessian pattern: edges of each face (hand assembled so that degenerate triangles get
    # zero cotangent weight, which igl.cotmatrix_intrinsic would turn into inf/nan)
    I = F[:, [1, 2, 0]].ravel()
    J = F[:, [2, 0, 1]].ravel()
    it = 0
    gnorm = np.inf
    for it in range(1, max_iter + 1):  # noqa: B007
        lam, L, A, valid = _cetm_state(lam0, F, u)
        asum = np.bincount(F.ravel(), weights=A.ravel(), minlength=n)
        g = theta - asum
        gnorm = np.abs(g[interior]).max(initial=0.0)
        if gnorm < tol:
            break
        with np.errstate(divide="ignore"):
            cot = np.where(valid[:, None], 1.0 / np.tan(A), 0.0)
        w = 0.5 * cot.ravel()  # weight of edge opposite each corner
        W = sp.coo_matrix((np.r_[w, w], (np.r_[I, J], np.r_[J, I])), shape=(n, n)).tocsr()
        H = sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W
        H = H + sp.identity(n) * TOL.cetm_ridge
        Hi = H[interior][:, interior].tocsc()
        du = np.zeros(n)
        du[interior] = spsolve(Hi, -g[interior])
        e0 = _cetm_energy(lam0, F, u, theta, interior)
        slope = float(g[interior] @ du[interior])
        t = 1.0
        for _ in range(40):
            e1 = _cetm_energy(lam0, F, u + t * du, theta, interior)
            if e1 <= e0 + NEWTON.armijo_c1 * t * slope + TOL.energy_roundoff * abs(e0):
                break
            t *= 0.5
        u = u + t * du
    _, L, A, valid = _cetm_state(lam0, F, u)
    if not np.all(valid) or gnorm > TOL.cetm_grad:
        raise InputError(
            f"conformal flattening (CETM) did not converge (angle error {gnorm:.2e} rad, "
            f"{int((~valid).sum())} degenerate triangles)",
            fix="improve the triangle quality (remesh) or try flattening='lscm'")
    UV = layout_from_lengths(F, L, A)
    return UV, u, {"iterations": it, "angle_error_rad": float(gnorm)}


def layout_from_lengths(F, L, A) -> np.ndarray:
    """Lay out a flat metric face by face (breadth-first), faces CCW.

    Parameters
    ----------
    F : (m, 3) int
    L : (m, 3) float
        Edge lengths opposite each corner.
    A : (m, 3) float
        Corner angles.
    """
    F = np.asarray(F, dtype=np.int64)
    n = int(F.max()) + 1

    ff = face_adjacency(F)
    P = np.full((n, 2), np.nan)
    placed = np.zeros(n, dtype=bool)
    seen = np.zeros(len(F), dtype=bool)
    v0, v1 = F[0, 0], F[0, 1]
    P[v0] = (0.0, 0.0)
    P[v1] = (L[0, 2], 0.0)
    placed[[v0, v1]] = True
    queue = deque([0])
    seen[0] = True
    while queue:
        f = queue.popleft()
        miss = np.flatnonzero(~placed[F[f]])
        if len(miss) == 1:
            k = int(miss[0])  # unknown corner k; known corners k+1, k+2 (CCW)
            a, b = F[f, (k + 1) % 3], F[f, (k + 2) % 3]
            # corner k lies left of a->b?  CCW order (a, b, k): k is left of a->b
            d = P[b] - P[a]
            d /= np.linalg.norm(d)
            ang = A[f, (k + 1) % 3]  # angle at a
            rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
            P[F[f, k]] = P[a] + L[f, (k + 2) % 3] * (rot @ d)  # edge a-k is opposite b
            placed[F[f, k]] = True
        for g in ff[f]:
            if g >= 0 and not seen[g]:
                seen[g] = True
                queue.append(g)
    if not placed.all():
        raise InputError("flattening: some vertices are not reachable (several components?)")
    return P


# --------------------------------------------------------------------------------------
# LSCM


def lscm(V, F) -> np.ndarray:
    """LSCM flattening (``igl.lscm``) with the two farthest boundary vertices pinned."""
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    loop = igl.boundary_loop(F)
    P = V[loop]
    D = np.linalg.norm(P[:, None] - P[None], axis=2)
    i, j = np.unravel_index(np.argmax(D), D.shape)
    b = np.array([loop[i], loop[j]], dtype=np.int64)
    bc = np.array([[0.0, 0.0], [D[i, j], 0.0]])
    out = igl.lscm(V, F, b, bc)
    UV = out[0] if isinstance(out, tuple) else out
    return np.asarray(UV, float)


# --------------------------------------------------------------------------------------
# metrics and comparison


def corner_angles(X, F) -> np.ndarray:
    """(m, 3) float, rad: corner angles of a 2D or 3D triangle mesh."""
    X = np.asarray(X, float)
    if X.shape[1] == 2:
        X = np.c_[X, np.zeros(len(X))]
    return igl.internal_angles(X, np.asarray(F, dtype=np.int64))


def distortion_metrics(V, UV, F, params: UnitCell = UNIT_CELL, layout=None) -> dict:
    """Distortion figures of a flat layout against the target.

    Returns a dict with ``angle_mean_deg``, ``angle_max_deg`` (corner angle differences),
    ``area_ratio_spread`` (max/min of the per-face area scale after the best global
    scale), ``scale_spread`` (its square root: the conformal length-scale spread),
    ``area_log_std``, ``flips`` and, with a layout, the cell length figures.
    """
    V = np.asarray(V, float)
    UV = np.asarray(UV, float)
    F = np.asarray(F, dtype=np.int64)
    A3 = 0.5 * igl.doublearea(V, F)
    A2 = signed_areas_2d(UV, F)
    flips = int(np.sum(A2 <= 0))
    if np.sum(A2 < 0) > np.sum(A2 > 0):
        A2 = -A2
        flips = int(np.sum(A2 <= 0))
    ok = A2 > 0
    r = np.full(len(F), np.nan)
    r[ok] = A2[ok] / A3[ok]
    lr = np.log(r[ok])
    lr -= np.average(lr, weights=A3[ok])
    dang = np.abs(corner_angles(UV, F) - corner_angles(V, F))
    out = {
        "angle_mean_deg": round(float(np.degrees(dang.mean())), 4),
        "angle_max_deg": round(float(np.degrees(dang.max())), 4),
        "area_ratio_spread": round(float(np.exp(lr.max() - lr.min())), 4),
        "scale_spread": round(float(np.exp(0.5 * (lr.max() - lr.min()))), 4),
        "area_log_std": round(float(np.sqrt(np.average(lr**2, weights=A3[ok]))), 4),
        "flips": flips,
    }
    if layout is not None:
        l = layout.central_length
        out["max_cell_length_mm"] = round(float(l.max()), 4)
        out["min_cell_length_mm"] = round(float(l.min()), 4)
        out["n_cells_over_limit"] = int(np.sum(l > params.max_cell_length))
    return out


def canonical_orientation(UV) -> np.ndarray:
    """Rotate a flat layout about its vertex mean so its long (principal) axis is x.

    The sign of each axis is fixed by making the third moment along it non-negative, so the
    result does not depend on where the layout walk started.  A rotation, no mirror.
    """
    UV = np.asarray(UV, float)
    c = UV.mean(axis=0)
    X = UV - c
    w, E = np.linalg.eigh(X.T @ X)
    E = E[:, ::-1]  # largest first
    if np.sum((X @ E[:, 0]) ** 3) < 0:
        E[:, 0] *= -1
    E[:, 1] = [-E[1, 0], E[0, 0]]  # proper rotation
    return X @ E + c


def flatten(V, F, method: str = "cetm", u_boundary=None) -> FlattenResult:
    """Flatten with ``method`` in {"cetm", "lscm"}; the result's long axis is x.
    ``u_boundary`` (n,) float: CETM's boundary log-scale (:func:`cetm`; LSCM's boundary is
    free)."""
    if method == "cetm":
        UV, u, info = cetm(V, F, u_boundary=u_boundary)
        return FlattenResult(canonical_orientation(UV), "cetm", dict(info), u)
    if method == "lscm":
        return FlattenResult(canonical_orientation(lscm(V, F)), "lscm", {})
    raise InputError(f"flattening={method!r}", fix="use 'cetm' or 'lscm'")


def compare_flattenings(V, F, params: UnitCell = UNIT_CELL,
                        methods=("cetm", "lscm"), u_boundary=None) -> dict[str, FlattenResult]:
    """Run every method and fill its metrics (distortion + max cell length after layout).

    A method that fails records ``{"error": message}`` and has ``UV = None``.
    ``u_boundary`` (n,) float: CETM's boundary log-scale (:func:`cetm`).
    """
    res = {}
    for m in methods:
        t0 = time.perf_counter()
        try:
            r = flatten(V, F, m, u_boundary=u_boundary)
        except InputError as e:
            res[m] = FlattenResult(None, m, {"error": e.problem})
            continue
        t1 = time.perf_counter()
        met = dict(r.metrics)
        try:
            lay = build_layout(V, r.UV, F, params, enforce_gap=False)
            met.update(distortion_metrics(lay.V, lay.UV, lay.F, params, layout=lay))
        except InputError as e:
            met.update(distortion_metrics(V, r.UV, F, params))
            met["layout_error"] = e.problem
        met["time_s"] = round(t1 - t0, 4)
        r.metrics = met
        res[m] = r
    return res


__all__ = ["FlattenResult", "clausen2", "lobachevsky", "cetm", "layout_from_lengths", "lscm",
           "corner_angles", "distortion_metrics", "canonical_orientation", "flatten",
           "compare_flattenings"]
