"""The stencil objective, written once: numpy forward passes and their reverse passes.

:class:`pysolver.design.stencil.optimise.StencilObjective` minimises, round after round, the
longest flat cell after the layout rules (:mod:`pysolver.design.layout`: the 3D rule, then
the 2D rule) plus penalties, over the flat stencil vertices.  Every term it evaluates, for
the optimiser's gradient or for the exact checks between rounds, is computed by the classes
and functions here:

* :class:`CellGeometry` -- per cell, the half fold's cosine and tangent and the target and
  flat centroid distances;
* :class:`Scalings` -- the logs of the 3D scaling, the flat scaling and the longest flat
  centroid distance, smoothed (log-sum-exp) or exact;
* :func:`timing` -- the timing misfit, with the achievable times of :func:`log_time_range`;
* :class:`FlatTriangles` -- signed areas, corner angles and centre clearances.

Each forward pass keeps what its ``backward`` needs; the backward functions accumulate into
the gradient arrays they are given.  autograd differentiated the same composition at about
20 us per operation each way (4.7 ms per evaluation on petal's 132-vertex stencil against
0.7 ms here), so the passes are written out by hand; ``tests/stencil_oracle.py`` states the
rules again with autograd, and ``tests/test_stencil.py`` checks value and gradient against
it (1e-12 and 1e-9 relative) and against finite differences.
"""

from __future__ import annotations

import numpy as np

from ...params import STENCIL, UNIT_CELL, StencilSearch, UnitCell
from ...params import tol as TOL

_NEXT, _PREV = [1, 2, 0], [2, 0, 1]


def _scatter(idx, values, n: int):
    """(n, k) float: the rows of ``values`` (..., k) summed into rows ``idx`` (...)."""
    v = values.reshape(-1, values.shape[-1])
    i = np.asarray(idx).ravel()
    return np.stack([np.bincount(i, v[:, j], minlength=n) for j in range(v.shape[1])], axis=1)


def smax(v, sharpness, lse=None):
    """Log of the smoothed maximum of positive ``v`` (c,) (log-sum-exp of ``sharpness log v``
    over ``sharpness``; None: the exact maximum) and its gradient (c,) in ``v`` (at an
    exact maximum reached by several entries, shared evenly among them, as autograd does).

    ``lse``, optional: the log-sum-exp to take the value with instead of this function's own
    (the exact checks between rounds take scipy's, whose last bit differs from this one's in
    about 0.5 % of cases; the stencils chosen depend on those checks, so they keep it)."""
    lv = np.log(v)
    if sharpness is None:
        top = lv.max()
        at = lv == top
        return float(top), at / (at.sum() * v)
    z = sharpness * lv
    top = z.max()
    e = np.exp(z - top)
    total = e.sum()
    value = top + np.log(total) if lse is None else lse(z)
    return float(value / sharpness), e / total / v


class CellGeometry:
    """Per-cell half-fold cosine and tangent and centroid distances (forward), and their
    backward pass into the flat and target positions.

    Parameters
    ----------
    Q : (n, 2) float -- flat stencil vertices
    X : (n, 3) float, mm -- target stencil vertices
    F : (m, 3) int
    fa, fb, o1, o2 : (c,) int -- each cell's two bases and the vertices opposite its edge
    tiny : float -- the guard under the tangent's square root

    Attributes
    ----------
    cos_t, tan_t : (c,) float -- of each cell's half fold angle on the target
    D : (c,) float, mm -- target centroid distance; d : (c,) float -- flat, in Q's units
    g_cos, g_tan, g_D, g_d : (c,) float -- the gradients gathered for :meth:`backward`
    """

    def __init__(self, Q, X, F, fa, fb, o1, o2, tiny: float):
        self.F, self.fa, self.fb, self.o1, self.o2 = F, fa, fb, o1, o2
        self.e1 = X[F[:, 1]] - X[F[:, 0]]
        self.e2 = X[F[:, 2]] - X[F[:, 0]]
        N = np.cross(self.e1, self.e2)
        self.nn = np.sqrt(np.sum(N * N, axis=1))
        self.Nh = N / self.nn[:, None]
        c = np.sum(self.Nh[fa] * self.Nh[fb], axis=1)
        cphi = np.clip(c, -0.99, 1.0)
        self.live = (cphi != -0.99) & (cphi != 1.0)  # (the clip passes no gradient at bounds)
        self.cphi = cphi
        self.cos_t = np.sqrt((1.0 + cphi) / 2.0)
        self.tan_t = np.sqrt(np.maximum(1.0 - cphi, 0.0) / (1.0 + cphi) + tiny)
        self.dX = X[o1] - X[o2]
        self.Dl = np.sqrt(np.sum(self.dX**2, axis=1))
        self.D = self.Dl / 3.0
        self.dQ = Q[o1] - Q[o2]
        self.dl = np.sqrt(np.sum(self.dQ**2, axis=1))
        self.d = self.dl / 3.0
        self.g_cos = np.zeros_like(self.D)
        self.g_tan = np.zeros_like(self.D)
        self.g_D = np.zeros_like(self.D)
        self.g_d = np.zeros_like(self.D)

    def backward(self, gX, gQ) -> None:
        """Add the gradients gathered in ``g_cos``, ``g_tan``, ``g_D``, ``g_d`` (c,) to
        ``gX`` (n, 3) and ``gQ`` (n, 2)."""
        n = len(gX)
        c = self.cphi
        g_c = self.g_cos / (4.0 * self.cos_t)
        g_c += self.g_tan / (2.0 * self.tan_t) * (-2.0 / (1.0 + c) ** 2)
        g_c *= self.live  # (cphi < 1 there, so the maximum under the tangent is 1 - cphi)
        g_Nh = (_scatter(self.fa, g_c[:, None] * self.Nh[self.fb], len(self.Nh))
                + _scatter(self.fb, g_c[:, None] * self.Nh[self.fa], len(self.Nh)))
        g_N = (g_Nh - self.Nh * np.sum(g_Nh * self.Nh, axis=1, keepdims=True)) / self.nn[:, None]
        g_e1 = np.cross(self.e2, g_N)
        g_e2 = np.cross(g_N, self.e1)
        F = self.F
        gX += (_scatter(F[:, 1], g_e1, n) + _scatter(F[:, 2], g_e2, n)
               - _scatter(F[:, 0], g_e1 + g_e2, n))
        g_dX = (self.g_D / (3.0 * self.Dl))[:, None] * self.dX
        gX += _scatter(self.o1, g_dX, n) - _scatter(self.o2, g_dX, n)
        g_dQ = (self.g_d / (3.0 * self.dl))[:, None] * self.dQ
        gQ += _scatter(self.o1, g_dQ, n) - _scatter(self.o2, g_dQ, n)


class Scalings:
    """Logs of the 3D scaling, the flat scaling and the longest flat centroid distance from a
    :class:`CellGeometry`, with their backward pass into it.

    The 3D rule scales the target by ``s3 = max_c (base_r + layer_h tan t_c + min_bumper)
    2 cos t_c / D_c``; the 2D rule the flat layout by ``s2 = max_c (s3 D_c / (2 cos t_c) +
    layer_h tan t_c + min_gap / 2) / (d_c / 2)``; the longest flat cell is ``s2 max_c d_c``.

    Parameters
    ----------
    geo : CellGeometry
    params : UnitCell
    sharpness : float or None
        Log-sum-exp sharpness on the log quantities (a max over c cells is over-estimated by
        at most ``log(c) / sharpness``); None takes the exact maxima (not smooth).
    like : Scalings, optional
        Scalings of the same geometry whose per-cell 3D rule is reused.
    lse : callable, optional
        The log-sum-exp of the smoothed maxima' values (:func:`smax`).

    Attributes
    ----------
    log_s3, log_s2, log_d : float
        ``log(s3)`` (the shell's size over the target's), ``log(s2)`` (mm per unit of Q),
        ``log(max_c d_c)``; ``log_s2 + log_d`` is the log of the longest flat cell, mm.
    """

    def __init__(self, geo: CellGeometry, params: UnitCell, sharpness, like=None, lse=None):
        self.geo, self.h = geo, params.layer_h
        if like is None:  # (the per-cell 3D rules; ``like``: Scalings of the same geometry)
            self.K = 2.0 * (params.base_r + params.min_bumper + self.h * geo.tan_t)
            self.r3 = self.K * geo.cos_t / geo.D
        else:
            self.K, self.r3 = like.K, like.r3
        self.log_s3, self.w3 = smax(self.r3, sharpness, lse)
        self.s3 = np.exp(self.log_s3)
        num = self.s3 * geo.D / (2.0 * geo.cos_t) + self.h * geo.tan_t + params.min_gap / 2.0
        self.r2 = 2.0 * num / geo.d
        self.log_s2, self.w2 = smax(self.r2, sharpness, lse)
        self.log_d, self.wd = smax(geo.d, sharpness, lse)

    def backward(self, g_s3: float, g_s2: float, g_d: float) -> None:
        """Add the gradients of ``log_s3``, ``log_s2``, ``log_d`` to the geometry's."""
        geo = self.geo
        g_r2 = g_s2 * self.w2
        g_num = 2.0 * g_r2 / geo.d
        geo.g_d -= g_r2 * self.r2 / geo.d
        half = geo.D / (2.0 * geo.cos_t)
        g_s3 += float(np.sum(g_num * half)) * self.s3
        geo.g_D += g_num * self.s3 / (2.0 * geo.cos_t)
        geo.g_cos -= g_num * self.s3 * half / geo.cos_t
        geo.g_tan += g_num * self.h
        g_r3 = g_s3 * self.w3
        geo.g_tan += 2.0 * self.h * g_r3 * geo.cos_t / geo.D
        geo.g_cos += g_r3 * self.K / geo.D
        geo.g_D -= g_r3 * self.r3 / geo.D
        geo.g_d += g_d * self.wd


def time_terms(central, contact, params: UnitCell = UNIT_CELL,
               settings: StencilSearch = STENCIL):
    """Each cell's bracket length ``b0 = central - bracket_offset`` (floored at
    ``settings.opt_tiny``) and its compression ``x = central - contact``, floored smoothly
    (softplus) at ``settings.timing_compression_floor``.

    Parameters
    ----------
    central, contact : (c,) float, mm
        Flat central length of each cell and its length at bumper contact.
    params : UnitCell
    settings : StencilSearch

    Returns
    -------
    b0, x : (c,) float, mm
    """
    xm = settings.timing_compression_floor
    return (np.maximum(central - params.bracket_offset, settings.opt_tiny),
            xm * np.logaddexp(0.0, (central - contact) / xm))


def log_time_terms(central, contact, params: UnitCell = UNIT_CELL,
                   settings: StencilSearch = STENCIL):
    """The logs of :func:`time_terms`: ``log_b0, log_x`` (c,) float."""
    b0, x = time_terms(central, contact, params, settings)
    return np.log(b0), np.log(x)


def log_time_range(central, contact, boundary, params: UnitCell = UNIT_CELL,
                   settings: StencilSearch = STENCIL):
    """Estimated log of the fastest and slowest completion time of each cell.

    ``log t ~ c + a log b0 + e log x + k [boundary]`` (:func:`time_terms`) with the
    coefficients ``settings.timing_fastest`` / ``timing_slowest`` (thinnest / thickest
    bracket).

    Parameters
    ----------
    central, contact : (c,) float, mm
        Flat central length of each cell and its length at bumper contact.
    boundary : (c,) float
        1 for cells with a base on the stencil's rim, else 0.
    params : UnitCell
    settings : StencilSearch

    Returns
    -------
    lo, hi : (c,) float
        Log of the times (s).
    """
    return _log_range(*log_time_terms(central, contact, params, settings), boundary, settings)


def _log_range(lb0, lx, boundary, settings):
    fast, slow = settings.timing_fastest, settings.timing_slowest
    return (fast[0] + fast[1] * lb0 + fast[2] * lx + fast[3] * boundary,
            slow[0] + slow[1] * lb0 + slow[2] * lx + slow[3] * boundary)


def timing(geo: CellGeometry, sharp: Scalings, boundary, log_t_star, params: UnitCell,
           settings):
    """The timing misfit at the smoothed scalings, and its backward pass.

    The fastest and slowest times a cell can reach follow :func:`log_time_range`: the
    bracket length and compression (flat central length ``s2 d`` minus the contact length
    ``s3 D / cos t``).  A cell whose requested time ``t*`` falls outside that range is
    clamped; the misfit is the mean over cells of the squared distance (in log time) from
    ``log t*`` to the range narrowed by ``settings.timing_margin`` at both ends (the
    estimate's own error is about 0.22).

    Parameters
    ----------
    geo : CellGeometry
    sharp : Scalings -- the smoothed ones
    boundary : (c,) float -- 1 for cells with a base on the rim
    log_t_star : (c,) float -- log of each cell's requested time (s)

    Returns
    -------
    value : float
    backward : callable ``(g) -> (g_log_s3, g_log_s2)``, adding the rest to ``geo``.
    """
    s2, s3 = np.exp(sharp.log_s2), sharp.s3
    L = s2 * geo.d
    C = s3 * geo.D / geo.cos_t
    tiny, xm = settings.opt_tiny, settings.timing_compression_floor
    b0, x = time_terms(L, C, params, settings)
    lo, hi = _log_range(np.log(b0), np.log(x), boundary, settings)
    fast, slow = settings.timing_fastest, settings.timing_slowest
    m = settings.timing_margin
    early = np.maximum(lo - log_t_star + m, 0.0)
    late = np.maximum(log_t_star - hi + m, 0.0)
    value = float(np.mean(early**2 + late**2))

    def backward(g: float):
        k = 2.0 * g / len(early)
        g_lo, g_hi = k * early, -k * late
        g_lb0 = fast[1] * g_lo + slow[1] * g_hi
        g_lx = fast[2] * g_lo + slow[2] * g_hi
        x_raw = L - C
        g_x = g_lx / x * np.exp(-np.logaddexp(0.0, -x_raw / xm))  # (x's slope: a sigmoid)
        g_L = np.where(L - params.bracket_offset > tiny, g_lb0 / b0, 0.0) + g_x
        g_C = -g_x
        geo.g_d += g_L * s2
        geo.g_D += g_C * s3 / geo.cos_t
        geo.g_cos -= g_C * C / geo.cos_t
        return float(np.sum(g_C * geo.D / geo.cos_t)) * s3, float(np.sum(g_L * geo.d)) * s2

    return value, backward


def _edges(Q, F):
    """(m, 3, 2) float: edge k of each flat triangle, from corner k to corner k + 1."""
    T = Q[F]
    return T[:, _NEXT] - T


def _area(E):
    """(m,) float: signed areas (positive: counter-clockwise) from the edges ``E``."""
    return 0.5 * (E[:, 2, 0] * E[:, 0, 1] - E[:, 0, 0] * E[:, 2, 1])


def signed_areas(Q, F):
    """(m,) float: the signed areas of the flat triangles ``F`` (m, 3) of ``Q`` (n, 2), in
    Q's units squared (positive: counter-clockwise), as :class:`FlatTriangles` has them."""
    return _area(_edges(Q, F))


class FlatTriangles:
    """Signed areas, squared edge lengths, corner cosines and angles and centre clearances
    of the flat triangles, with the backward pass into the flat positions.

    Attributes
    ----------
    A : (m,) float -- signed areas, in Q's units squared
    L2 : (m, 3) float -- squared length of edge k (corner k to k + 1)
    angles : (m, 3) float, rad -- corner angles
    clearance : (m, 3) float -- centroid to edge k, in Q's units
    g_A, g_angles, g_clearance -- the gradients gathered for :meth:`backward`
    """

    def __init__(self, Q, F):
        self.F, self.n = F, len(Q)
        self.E = _edges(Q, F)
        self.L2 = np.sum(self.E**2, axis=2)
        E = self.E
        self.A = _area(E)
        self.dot = -np.sum(E * E[:, _PREV], axis=2)
        self.den = np.sqrt(self.L2 * self.L2[:, _PREV])
        cos = self.dot / self.den
        self.cc = np.clip(cos, -1.0 + TOL.exact, 1.0 - TOL.exact)
        self.angles = np.arccos(self.cc)
        self.sqL = np.sqrt(self.L2)
        self.clearance = 2.0 * self.A[:, None] / (3.0 * self.sqL)
        self.g_A = np.zeros_like(self.A)
        self.g_angles = np.zeros_like(self.L2)
        self.g_clearance = np.zeros_like(self.L2)

    def backward(self, gQ) -> None:
        """Add the gradients gathered in ``g_A``, ``g_angles``, ``g_clearance`` to ``gQ``."""
        E = self.E
        g_A = self.g_A + np.sum(self.g_clearance * 2.0 / (3.0 * self.sqL), axis=1)
        g_L2 = -self.g_clearance * self.clearance / (2.0 * self.L2)
        inside = (self.cc != -1.0 + TOL.exact) & (self.cc != 1.0 - TOL.exact)
        g_cos = np.where(inside, -self.g_angles / np.sqrt(1.0 - self.cc**2), 0.0)
        g_dot = g_cos / self.den
        g_den = -g_cos * self.dot / self.den**2
        g_L2 += g_den * self.L2[:, _PREV] / (2.0 * self.den)
        g_L2[:, _PREV] += g_den * self.L2 / (2.0 * self.den)
        g_E = -g_dot[..., None] * E[:, _PREV] + 2.0 * E * g_L2[..., None]
        g_E[:, _PREV] += -g_dot[..., None] * E
        g_E[:, 2, 0] += 0.5 * g_A * E[:, 0, 1]
        g_E[:, 0, 1] += 0.5 * g_A * E[:, 2, 0]
        g_E[:, 0, 0] -= 0.5 * g_A * E[:, 2, 1]
        g_E[:, 2, 1] -= 0.5 * g_A * E[:, 0, 0]
        g_T = -g_E
        g_T[:, _NEXT] += g_E
        gQ += _scatter(self.F, g_T, self.n)


__all__ = ["smax", "CellGeometry", "Scalings", "time_terms", "log_time_terms", "log_time_range",
           "timing", "signed_areas", "FlatTriangles"]
