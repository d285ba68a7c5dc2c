"""Compiled (numba) kernels for the hot loops of the energy, gradient and Hessian assembly.

Profiling the benchmark shell (~460 bases, ~8000 membrane triangles, ~9800 DOFs) showed the
numpy assembly at ~80 ms per Newton iteration, most of it in many small array operations on
(n, 3, 3) stacks (membrane element Hessians, rigid-body reduction of every 3x3 block, scatter).
These loops are written here once, element by element, and compiled with numba:

* :func:`membrane_kernel` -- energy, gradient (accumulated per point) and the 9x9 point-space
  Hessian of every incompressible neo-Hookean triangle (same formulas as
  :func:`pysolver.mechanics.energies.membrane_terms`, which stays the reference implementation);
* :func:`reduce_scatter` -- rigid-body reduction ``J_p^T K J_q`` (``J = [I, -[v]x]``) of every
  3x3 point block of a batch of elements and summation into the CSC data array of the reduced
  Hessian through precomputed positions (-1 = not stored: upper triangle or the rotation
  columns of a free vertex);
* :func:`discrete_terms` -- springs and cross pairs; :func:`cross_point_hessian`;
* :func:`rigid_positions`, :func:`rigid_gradient`, :func:`rigid_rotation_term` -- the
  points of the rigid bases from their poses, and the reduction of point gradients to the
  bases' degrees of freedom.

All are optional: without numba, :class:`.energies.ShellEnergy` uses the vectorised numpy
path (same results to round-off; tested).
"""

from __future__ import annotations

import numpy as np

try:  # soft dependency
    from numba import njit

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - depends on the installation
    HAVE_NUMBA = False

    def njit(*args, **kwargs):
        def wrap(f):
            return f
        return wrap if not (len(args) == 1 and callable(args[0])) else args[0]


@njit(cache=True, fastmath=False)
def membrane_kernel(X, tri, dm_inv, rest_area, mu, h, G, H, want_hessian):  # pragma: no cover
    """Incompressible neo-Hookean CST: energy, gradient into ``G``, Hessians into ``H``.

    A one-body assembly: one compiled loop over the elements, with the energy, the gradient
    and the 9x9 Hessian of each element written out in it (longer than the project's 80
    lines on purpose: numba compiles it as one loop, and the formulas follow
    :func:`pysolver.mechanics.energies.membrane_terms` line by line).

    Parameters
    ----------
    X : (p, 3) float -- point positions
    tri : (t, 3) int -- point ids of each triangle
    dm_inv : (t, 2, 2) float
    rest_area : (t,) float
    mu, h : float
    G : (p, 3) float -- gradient accumulator (added to)
    H : (t, 9, 9) float -- point-space Hessians (written when ``want_hessian``)
    want_hessian : bool

    Returns
    -------
    E : float -- total membrane energy
    """
    E = 0.0
    nt = tri.shape[0]
    f0 = np.empty(3)
    f1 = np.empty(3)
    A = np.empty((2, 3))
    B = np.empty((3, 2))
    HF = np.empty((2, 2, 3, 3))
    Pm = np.empty((3, 3))
    for t in range(nt):
        i0, i1, i2 = tri[t, 0], tri[t, 1], tri[t, 2]
        d00, d01 = dm_inv[t, 0, 0], dm_inv[t, 0, 1]
        d10, d11 = dm_inv[t, 1, 0], dm_inv[t, 1, 1]
        for k in range(3):
            e1 = X[i1, k] - X[i0, k]
            e2 = X[i2, k] - X[i0, k]
            f0[k] = e1 * d00 + e2 * d10
            f1[k] = e1 * d01 + e2 * d11
        C00 = f0[0] * f0[0] + f0[1] * f0[1] + f0[2] * f0[2]
        C01 = f0[0] * f1[0] + f0[1] * f1[1] + f0[2] * f1[2]
        C11 = f1[0] * f1[0] + f1[1] * f1[1] + f1[2] * f1[2]
        det = C00 * C11 - C01 * C01
        gi = 1.0 / det
        Y00 = C11 * gi
        Y01 = -C01 * gi
        Y11 = C00 * gi
        ha = h * rest_area[t]
        E += ha * 0.5 * mu * (C00 + C11 + gi - 3.0)
        for k in range(3):
            A[0, k] = f0[k] * Y00 + f1[k] * Y01
            A[1, k] = f0[k] * Y01 + f1[k] * Y11
        B[0, 0] = -(d00 + d10)
        B[0, 1] = -(d01 + d11)
        B[1, 0] = d00
        B[1, 1] = d01
        B[2, 0] = d10
        B[2, 1] = d11
        for v in range(3):
            p = tri[t, v]
            for k in range(3):
                P0 = mu * (f0[k] - gi * A[0, k])
                P1 = mu * (f1[k] - gi * A[1, k])
                G[p, k] += ha * (B[v, 0] * P0 + B[v, 1] * P1)
        if not want_hessian:
            continue
        for i in range(3):
            for j in range(3):
                Pm[i, j] = A[0, i] * f0[j] + A[1, i] * f1[j]
        for a in range(2):
            for c in range(2):
                if a == 0 and c == 0:
                    y = Y00
                elif a == 1 and c == 1:
                    y = Y11
                else:
                    y = Y01
                dac = 1.0 if a == c else 0.0
                for i in range(3):
                    for j in range(3):
                        val = gi * y * Pm[i, j] + gi * (2.0 * A[a, i] * A[c, j]
                                                        + A[c, i] * A[a, j])
                        if i == j:
                            val += dac - gi * y
                        HF[a, c, i, j] = mu * val
        for v in range(3):
            for w in range(3):
                b00 = B[v, 0] * B[w, 0] * ha
                b01 = B[v, 0] * B[w, 1] * ha
                b10 = B[v, 1] * B[w, 0] * ha
                b11 = B[v, 1] * B[w, 1] * ha
                for i in range(3):
                    for j in range(3):
                        H[t, 3 * v + i, 3 * w + j] = (b00 * HF[0, 0, i, j] + b01 * HF[0, 1, i, j]
                                                      + b10 * HF[1, 0, i, j]
                                                      + b11 * HF[1, 1, i, j])
    return E


@njit(cache=True, fastmath=False)
def reduce_scatter(Hp, pts, V, pos, data, use):  # pragma: no cover
    """Rigid-body reduction of element point Hessians and summation into CSC data.

    Parameters
    ----------
    Hp : (n, 3k, 3k) float -- point-space element Hessians
    pts : (n, k) int -- point ids
    V : (p, 3) float -- rotated local offsets ``v = R t`` (0 for free points)
    pos : (n, 6k, 6k) int -- CSC data position of each reduced entry, -1 = dropped
    data : (nnz,) float -- accumulator
    use : (n, k, k) bool -- point pairs with a stored entry (:func:`stored_pairs`); the
        others (blocks in the upper triangle: half the pairs of points on different bases)
        are skipped
    """
    n, k = pts.shape
    R = np.empty((6, 6))
    TR = np.empty((3, 3))
    for e in range(n):
        for a in range(k):
            va0, va1, va2 = V[pts[e, a], 0], V[pts[e, a], 1], V[pts[e, a], 2]
            for b in range(k):
                if not use[e, a, b]:
                    continue
                vb0, vb1, vb2 = V[pts[e, b], 0], V[pts[e, b], 1], V[pts[e, b], 2]
                ra, rb = 3 * a, 3 * b
                # K = Hp block; TT = K, TR = -K [vb]x, RT = [va]x K, RR = [va]x TR
                for i in range(3):
                    K0 = Hp[e, ra + i, rb + 0]
                    K1 = Hp[e, ra + i, rb + 1]
                    K2 = Hp[e, ra + i, rb + 2]
                    R[i, 0] = K0
                    R[i, 1] = K1
                    R[i, 2] = K2
                    TR[i, 0] = -(vb2 * K1 - vb1 * K2)
                    TR[i, 1] = -(vb0 * K2 - vb2 * K0)
                    TR[i, 2] = -(vb1 * K0 - vb0 * K1)
                    R[i, 3] = TR[i, 0]
                    R[i, 4] = TR[i, 1]
                    R[i, 5] = TR[i, 2]
                for j in range(3):
                    K0 = Hp[e, ra + 0, rb + j]
                    K1 = Hp[e, ra + 1, rb + j]
                    K2 = Hp[e, ra + 2, rb + j]
                    R[3, j] = va1 * K2 - va2 * K1
                    R[4, j] = va2 * K0 - va0 * K2
                    R[5, j] = va0 * K1 - va1 * K0
                    T0, T1, T2 = TR[0, j], TR[1, j], TR[2, j]
                    R[3, 3 + j] = va1 * T2 - va2 * T1
                    R[4, 3 + j] = va2 * T0 - va0 * T2
                    R[5, 3 + j] = va0 * T1 - va1 * T0
                oa, ob = 6 * a, 6 * b
                for r in range(6):
                    for c in range(6):
                        p = pos[e, oa + r, ob + c]
                        if p >= 0:
                            data[p] += R[r, c]


def stored_pairs(pos) -> np.ndarray:
    """``use`` of :func:`reduce_scatter`: which point pairs of each element have a stored entry
    in a position map ``pos (n, 6k, 6k)``."""
    n, k6 = pos.shape[0], pos.shape[1]
    k = k6 // 6
    return np.ascontiguousarray((pos.reshape(n, k, 6, k, 6) >= 0).any(axis=(2, 4)))


@njit(cache=True, fastmath=False)
def cross_point_hessian(weight, G, Ka, Kb, out):  # pragma: no cover
    """Point-space Hessians (n, 12, 12) of cross pairs: ``w G G^T`` plus ``[[K,-K],[-K,K]]``
    with ``Ka`` on points (0, 1) and ``Kb`` on points (2, 3) (see
    ``pysolver.mechanics.energies.cross_terms``).
    """
    n = G.shape[0]
    for e in range(n):
        w = weight[e]
        for a in range(4):
            for i in range(3):
                gi = w * G[e, a, i]
                for b in range(4):
                    for j in range(3):
                        out[e, 3 * a + i, 3 * b + j] = gi * G[e, b, j]
        for a in range(2):
            for b in range(2):
                sgn = 1.0 if a == b else -1.0
                for i in range(3):
                    for j in range(3):
                        out[e, 3 * a + i, 3 * b + j] += sgn * Ka[e, i, j]
                        out[e, 6 + 3 * a + i, 6 + 3 * b + j] += sgn * Kb[e, i, j]


@njit(cache=True, fastmath=False)
def discrete_terms(X, sp, rest, coef, cp, weight, cross_rest, want_hessian,
                   es, gs, Ks, ex, gx, Gx, Ka, Kb):  # pragma: no cover
    """Springs and crossed pairs element by element: the outputs of
    :func:`pysolver.mechanics.energies.spring_terms` (``es, gs, Ks``) and
    :func:`pysolver.mechanics.energies.cross_terms` (``ex, gx`` and the parts ``Gx, Ka, Kb``),
    same formulas, written into the given arrays (``Ks, Gx, Ka, Kb`` only when ``want_hessian``;
    no PSD projection).  The numpy versions build a dozen (n, 3, 3) temporaries per call
    (2 ms per evaluation on the benchmark, 1500 evaluations per run).
    """
    for e in range(sp.shape[0]):
        a, b = sp[e, 0], sp[e, 1]
        d0 = X[b, 0] - X[a, 0]
        d1 = X[b, 1] - X[a, 1]
        d2 = X[b, 2] - X[a, 2]
        L = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        u0, u1, u2 = d0 / L, d1 / L, d2 / L
        x = rest[e] - L
        c1, c2, c3, c4 = coef[e, 0], coef[e, 1], coef[e, 2], coef[e, 3]
        f = x * (c1 + x * (c2 + x * (c3 + x * c4)))
        es[e] = x * x * (c1 / 2 + x * (c2 / 3 + x * (c3 / 4 + x * c4 / 5)))
        gs[e, 1, 0] = -f * u0
        gs[e, 1, 1] = -f * u1
        gs[e, 1, 2] = -f * u2
        gs[e, 0, 0] = -gs[e, 1, 0]
        gs[e, 0, 1] = -gs[e, 1, 1]
        gs[e, 0, 2] = -gs[e, 1, 2]
        if want_hessian:
            k = c1 + x * (2 * c2 + x * (3 * c3 + x * 4 * c4))
            trans = -f / L
            ak = k - trans
            u = (u0, u1, u2)
            for i in range(3):
                for j in range(3):
                    Ks[e, i, j] = ak * (u[i] * u[j]) + (trans if i == j else 0.0)
    for e in range(cp.shape[0]):
        p0, p1, p2, p3 = cp[e, 0], cp[e, 1], cp[e, 2], cp[e, 3]
        a0 = X[p1, 0] - X[p0, 0]
        a1 = X[p1, 1] - X[p0, 1]
        a2 = X[p1, 2] - X[p0, 2]
        b0 = X[p3, 0] - X[p2, 0]
        b1 = X[p3, 1] - X[p2, 1]
        b2 = X[p3, 2] - X[p2, 2]
        La = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        Lb = np.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
        ua = (a0 / La, a1 / La, a2 / La)
        ub = (b0 / Lb, b1 / Lb, b2 / Lb)
        D = La - Lb - cross_rest[e]
        w = weight[e]
        ex[e] = 0.5 * w * D * D
        wD = w * D
        for i in range(3):
            gx[e, 0, i] = wD * -ua[i]
            gx[e, 1, i] = wD * ua[i]
            gx[e, 2, i] = wD * ub[i]
            gx[e, 3, i] = wD * -ub[i]
        if want_hessian:
            sa, sb = wD / La, -wD / Lb
            for i in range(3):
                Gx[e, 0, i] = -ua[i]
                Gx[e, 1, i] = ua[i]
                Gx[e, 2, i] = ub[i]
                Gx[e, 3, i] = -ub[i]
                for j in range(3):
                    dij = 1.0 if i == j else 0.0
                    Ka[e, i, j] = (dij - ua[i] * ua[j]) * sa
                    Kb[e, i, j] = (dij - ub[i] * ub[j]) * sb


@njit(cache=True, fastmath=False)
def rigid_positions(c, R, f, attached, body, local, free, X, V):  # pragma: no cover
    """Point positions of the rigid map (same sums as :meth:`ShellEnergy.positions`).

    ``V[i] = R[body[i]] local[i]`` and ``X[attached[i]] = c[body[i]] + V[i]`` for attached
    points, ``X[free[j]] = f[j]`` for free ones.  (The numpy gather of one 3x3 rotation per
    point plus ``einsum`` took 0.7 ms per call on the 7230-DOF benchmark, 2500 calls per run.)
    """
    for i in range(attached.shape[0]):
        b = body[i]
        p = attached[i]
        t0, t1, t2 = local[i, 0], local[i, 1], local[i, 2]
        for r in range(3):
            s = R[b, r, 0] * t0 + R[b, r, 1] * t1 + R[b, r, 2] * t2
            V[i, r] = s
            X[p, r] = c[b, r] + s
    for j in range(free.shape[0]):
        p = free[j]
        X[p, 0] = f[j, 0]
        X[p, 1] = f[j, 1]
        X[p, 2] = f[j, 2]


@njit(cache=True, fastmath=False)
def rigid_gradient(G, attached, body, V, free, m, g):  # pragma: no cover
    """Reduced gradient: force and torque ``v x G`` per base, summed over its attached points
    in point order (as ``np.bincount`` does), then the free points' forces; into ``g``
    ``(6 m + 3 n_free,)``."""
    for k in range(6 * m):
        g[k] = 0.0
    for i in range(attached.shape[0]):
        b = body[i]
        p = attached[i]
        G0, G1, G2 = G[p, 0], G[p, 1], G[p, 2]
        v0, v1, v2 = V[i, 0], V[i, 1], V[i, 2]
        o = 6 * b
        g[o] += G0
        g[o + 1] += G1
        g[o + 2] += G2
        g[o + 3] += v1 * G2 - v2 * G1
        g[o + 4] += v2 * G0 - v0 * G2
        g[o + 5] += v0 * G1 - v1 * G0
    o = 6 * m
    for j in range(free.shape[0]):
        p = free[j]
        g[o + 3 * j] = G[p, 0]
        g[o + 3 * j + 1] = G[p, 1]
        g[o + 3 * j + 2] = G[p, 2]


@njit(cache=True, fastmath=False)
def rigid_rotation_term(G, attached, body, V, out):  # pragma: no cover
    """Second-order term of the rigid map per base, ``sum_p sym(g_p v_p^T) - (g_p . v_p) I``
    over its attached points, into ``out (m, 3, 3)`` (see ``ShellEnergy._rotation_term``)."""
    out[:] = 0.0
    for i in range(attached.shape[0]):
        b = body[i]
        p = attached[i]
        gv = G[p, 0] * V[i, 0] + G[p, 1] * V[i, 1] + G[p, 2] * V[i, 2]
        for r in range(3):
            for c in range(3):
                x = 0.5 * (G[p, r] * V[i, c] + G[p, c] * V[i, r])
                if r == c:
                    x -= gv
                out[b, r, c] += x


def warm_up() -> None:
    """Compile the kernels on a tiny input (numba caches them on disk)."""
    if not HAVE_NUMBA:
        return
    X = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    tri = np.array([[0, 1, 2]])
    dmi = np.eye(2)[None] * 3.0
    G = np.zeros((3, 3))
    H = np.zeros((1, 9, 9))
    membrane_kernel(X, tri, dmi, np.ones(1), 0.72, 0.5, G, H, True)
    pos = -np.ones((1, 18, 18), dtype=np.int32)
    reduce_scatter(H, tri, X, pos, np.zeros(1), stored_pairs(pos))
    att, body, free = np.array([0, 1]), np.array([0, 0]), np.array([2])
    Rb = np.eye(3)[None]
    V = np.zeros((2, 3))
    rigid_positions(np.zeros((1, 3)), Rb, np.zeros((1, 3)), att, body, X[:2], free, X.copy(), V)
    rigid_gradient(G, att, body, V, free, 1, np.zeros(9))
    rigid_rotation_term(G, att, body, V, np.zeros((1, 3, 3)))
    sp, cp = np.array([[0, 1]]), np.array([[0, 1, 2, 0]])
    one, m33 = np.ones(1), np.zeros((1, 3, 3))
    discrete_terms(X, sp, one, np.ones((1, 4)), cp, one, np.zeros(1), True, np.zeros(1),
                   np.zeros((1, 2, 3)), m33, np.zeros(1), np.zeros((1, 4, 3)),
                   np.zeros((1, 4, 3)), m33.copy(), m33.copy())


__all__ = ["HAVE_NUMBA", "membrane_kernel", "reduce_scatter", "stored_pairs", "cross_point_hessian",
           "discrete_terms", "rigid_positions", "rigid_gradient", "rigid_rotation_term", "warm_up"]
