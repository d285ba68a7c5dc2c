"""Stencil optimisation: move stencil vertices on the target to shorten the longest flat cell.

The layout rules (:mod:`pysolver.design.layout`) turn a stencil into a shell in closed form:

* the **3D rule** scales the target by ``s3 = max_c (base_r + layer_h tan t_c + min_bumper)
  2 cos t_c / D_c`` (``D_c`` target centroid distance of cell ``c``, ``t_c`` half its fold),
* the **2D rule** scales the flat layout by ``s2 = max_c (s3 D_c / (2 cos t_c) + layer_h
  tan t_c + min_gap / 2) / (d_c / 2)`` (``d_c`` flat centroid distance),

and the longest flat cell is ``s2 max_c d_c``.  A cell's centroid distance is a third of the
distance between the two vertices opposite its edge, so every quantity is a smooth function
of the stencil vertices away from the max.  :func:`optimize_stencil` minimises that longest
flat cell over the interior vertex positions in the conformal plane of the dense target (so
the vertices stay on the target) and the rim vertices' places along the rim curve, with
the three maxima smoothed by log-sum-exp, penalties that keep flat corners within 30-90 deg
and every base centre clear of its triangle's edges, and a log barrier that keeps every flat
triangle positively oriented.  Given a time landscape that varies, a fourth term moves each
cell's achievable completion times (estimated from its bracket length and compression,
:func:`timing_misfit`) toward its requested time: the paper's cover carrying the
reference's landscape clamps 8.7 % of its cells (``bench/bench_design_cover.py``).  The
target positions are the exact lift of the flat points, linearised per vertex (the Jacobian
of the dense piecewise linear map) inside each of a few outer rounds and lifted again after
each.

The functions here state the rules once, autograd-friendly.  The optimiser evaluates them
with the hand-written forward and reverse passes of :mod:`.objective` (0.7 ms per
evaluation on petal's 132-vertex stencil; autograd's differentiation of these functions,
``StencilObjective.linearised(..., autodiff=True)``, took 4.7 ms, its cost being per
operation), which ``tests/test_stencil.py`` checks against autograd to 1e-9 and against
finite differences.  The rules themselves are checked against
:func:`pysolver.design.layout.build_layout` by ``tests/test_stencil.py``.
"""

from __future__ import annotations

import autograd.numpy as anp
import igl
import numpy as np
from autograd import value_and_grad
from autograd.scipy.special import logsumexp
from scipy.optimize import minimize

from ...geometry import face_adjacency, unit_cells
from ...params import STENCIL, UNIT_CELL, StencilSearch, UnitCell
from ...params import tol as TOL
from ..time_landscape import cell_target_times
from . import objective as og


def opposite_vertices(F, cells=None):
    """The two vertices opposite each unit cell's edge.

    Parameters
    ----------
    F : (m, 3) int
    cells : Cells, optional

    Returns
    -------
    o : (c, 2) int
        ``o[c, k]`` is the vertex of base ``cells.faces[c, k]`` not on the shared edge; the
        cell's centroid distance is ``|X[o[:, 0]] - X[o[:, 1]]| / 3`` in any embedding X.
    """
    F = np.asarray(F, dtype=np.int64)
    if cells is None:
        cells = unit_cells(F, face_adjacency(F))
    return np.c_[F[cells.faces[:, 0], cells.slots[:, 0]], F[cells.faces[:, 1], cells.slots[:, 1]]]


def _flat_triangles(Q, F):
    """Signed areas, squared edge lengths and corner cosines of the flat triangles, from one
    gather of ``Q`` (autograd-friendly; the objective's cost is autograd's per-operation
    overhead, so every flat term shares these few operations).

    Returns
    -------
    A : (m,) float
        Signed areas (positive: counter-clockwise), in the units of Q squared.
    L2 : (m, 3) float
        Squared length of edge k, from corner k to corner k + 1.
    cos : (m, 3) float
        Cosine of the corner angle at corner k.
    """
    T = Q[F]                                              # (m, 3, 2)
    E = T[:, [1, 2, 0]] - T                               # edge k: corner k -> k + 1
    L2 = anp.sum(E * E, axis=2)
    A = _area(E)
    # corner k lies between edge k and edge k - 1 reversed
    cos = -anp.sum(E * E[:, [2, 0, 1]], axis=2) / anp.sqrt(L2 * L2[:, [2, 0, 1]])
    return A, L2, cos


def _area(E):
    """(m,) signed areas from the edges ``E`` (m, 3, 2) of :func:`_flat_triangles`."""
    return 0.5 * (E[:, 2, 0] * E[:, 0, 1] - E[:, 0, 0] * E[:, 2, 1])


def _corner_angles(cos):
    return anp.arccos(anp.clip(cos, -1.0 + TOL.exact, 1.0 - TOL.exact))


def _clearances(A, L2):
    return 2.0 * A[:, None] / (3.0 * anp.sqrt(L2))


def centroid_edge_distances(Q, F):
    """(m, 3) float: distance from each flat triangle's centroid to its three edges
    (``2 A / (3 |e|)``, edge k from corner k to k + 1), in the units of Q."""
    A, L2, _ = _flat_triangles(Q, F)
    return _clearances(A, L2)


def _np(x):
    return np.asarray(x, dtype=float)


def _angles_np(Q, F):
    return _np(flat_corner_angles(np.asarray(Q, float), F))


def _signed_areas(Q, F):
    T = Q[F]
    return _area(T[:, [1, 2, 0]] - T)


def flat_corner_angles(Q, F):
    """(m, 3) float, rad: the flat triangles' corner angles (autograd-friendly; numpy
    version: :func:`pysolver.design.flatten.corner_angles`)."""
    return _corner_angles(_flat_triangles(Q, F)[2])


def _cell_geometry(Q, X, F, fa, fb, o1, o2, tiny: float = STENCIL.opt_tiny):
    """Per-cell half-fold cosine and tangent, target and flat centroid distances
    (autograd-friendly).

    Returns
    -------
    cos_t, tan_t : (c,) float
        Of the half fold angle on the target.
    D : (c,) float, mm
        Target centroid distance.
    d : (c,) float
        Flat centroid distance, in the units of Q.
    """
    N = anp.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
    N = N / anp.sqrt(anp.sum(N * N, axis=1, keepdims=True))
    # (the layout refuses folds over 178 deg; -0.99 keeps tan finite before that)
    cphi = anp.clip(anp.sum(N[fa] * N[fb], axis=1), -0.99, 1.0)
    cos_t = anp.sqrt((1.0 + cphi) / 2.0)
    tan_t = anp.sqrt(anp.maximum(1.0 - cphi, 0.0) / (1.0 + cphi) + tiny)
    D = anp.sqrt(anp.sum((X[o1] - X[o2]) ** 2, axis=1)) / 3.0
    d = anp.sqrt(anp.sum((Q[o1] - Q[o2]) ** 2, axis=1)) / 3.0
    return cos_t, tan_t, D, d


def layout_logs(Q, X, F, fa, fb, o1, o2, params: UnitCell, sharpness: float | None):
    """Smoothed logs of the 3D scaling and of the longest flat cell after both scaling rules.

    Parameters
    ----------
    Q : (n, 2) float
        Flat stencil vertices (any scale).
    X : (n, 3) float, mm
        Target stencil vertices.
    F : (m, 3) int
    fa, fb : (c,) int
        The two bases of each cell.
    o1, o2 : (c,) int
        Vertices opposite each cell's edge (:func:`opposite_vertices`).
    params : UnitCell
    sharpness : float or None
        Log-sum-exp sharpness on log quantities (a max over c cells is over-estimated by
        at most ``log(c) / sharpness``); None takes the exact maxima (not smooth).

    Returns
    -------
    log_s3 : float
        ``~ log(s3)``, the 3D scaling (the shell's size over the target's).
    log_s2 : float
        ``~ log(s2)``, the flat scaling (mm per unit of Q).
    log_dmax : float
        ``~ log(max_c d_c)``; ``log_s2 + log_dmax`` is the log of the longest flat cell, mm.
    """
    return _scaling_logs(_cell_geometry(Q, X, F, fa, fb, o1, o2), params, sharpness)


def _scaling_logs(geometry, params: UnitCell, sharpness: float | None):
    """:func:`layout_logs` from the cells' ``geometry`` (:func:`_cell_geometry`)."""
    cos_t, tan_t, D, d = geometry

    def smax(v):  # log of the (smoothed) maximum of positive v
        return anp.max(anp.log(v)) if sharpness is None else \
            logsumexp(sharpness * anp.log(v)) / sharpness

    r3 = (params.base_r + params.layer_h * tan_t + params.min_bumper) * 2.0 * cos_t / D
    log_s3 = smax(r3)
    r2 = (anp.exp(log_s3) * D / (2.0 * cos_t) + params.layer_h * tan_t
          + params.min_gap / 2.0) / (d / 2.0)
    return log_s3, smax(r2), smax(d)


def log_time_terms(central, contact, params: UnitCell = UNIT_CELL,
                   settings: StencilSearch = STENCIL):
    """The logs of each cell's bracket length ``b0 = central - bracket_offset`` and of its
    compression ``x = central - contact``, floored smoothly (softplus) at
    ``settings.timing_compression_floor``: the terms of :func:`log_time_range`
    (autograd-friendly).

    Parameters
    ----------
    central, contact : (c,) float, mm

    Returns
    -------
    log_b0, log_x : (c,) float
    """
    log_b0 = anp.log(anp.maximum(central - params.bracket_offset, settings.opt_tiny))
    xm = settings.timing_compression_floor
    return log_b0, anp.log(xm * anp.logaddexp(0.0, (central - contact) / xm))


def log_time_range(central, contact, boundary, params: UnitCell = UNIT_CELL,
                   settings: StencilSearch = STENCIL):
    """Estimated log of the fastest and slowest completion time of each cell (autograd-friendly).

    ``log t ~ c + a log b0 + e log x + k [boundary]`` with the coefficients
    ``settings.timing_fastest`` / ``timing_slowest`` (thinnest / thickest bracket); the
    bracket length is ``b0 = central - bracket_offset`` and the compression
    ``x = central - contact``, floored smoothly (softplus) at
    ``settings.timing_compression_floor``.

    Parameters
    ----------
    central, contact : (c,) float, mm
        Flat central length of each cell and its length at bumper contact.
    boundary : (c,) float
        1 for cells with a base on the stencil's rim, else 0.

    Returns
    -------
    lo, hi : (c,) float
        Log of the times (s).
    """
    log_b0, log_x = log_time_terms(central, contact, params, settings)

    def estimate(m):
        return m[0] + m[1] * log_b0 + m[2] * log_x + m[3] * boundary

    return estimate(settings.timing_fastest), estimate(settings.timing_slowest)


def layout_timing_terms(lay):
    """What :func:`log_time_range` reads of a laid-out stencil, as the optimiser states it
    (:func:`timing_misfit`).

    Parameters
    ----------
    lay : pysolver.design.layout.Layout

    Returns
    -------
    central, contact : (c,) float, mm
        Flat central length; the length at bumper contact, ``s3 D / cos t`` (the 3D
        centroid distance over the cosine of the half fold).
    boundary : (c,) float
        1 for cells with an end of their edge on the rim (temporal programming's flag).
    """
    contact = lay.target_length / np.cos(np.radians(lay.fold_angle_deg) / 2.0)
    return (np.asarray(lay.central_length, float), contact,
            np.asarray(lay.cells.boundary, float))


def estimated_clamping(central, contact, boundary, t_star, params: UnitCell = UNIT_CELL,
                       settings: StencilSearch = STENCIL) -> float:
    """Fraction of cells whose time ``t_star`` (s) lies outside :func:`log_time_range`.

    Only a guide for the vertex-count search (the estimate's error is about 0.22 in log
    time); temporal programming computes each cell's range from the material and membrane
    models.  It is optimistic on stencils the optimiser suited to the landscape (their
    cells sit where the estimate says they just reach): measured on cover with the
    reference's landscape, 0 % estimated against 8.7 % programmed at 319 vertices.
    """
    lo, hi = log_time_range(np.asarray(central, float), np.asarray(contact, float),
                            np.asarray(boundary, float), params, settings)
    log_t = np.log(np.maximum(np.asarray(t_star, float), settings.opt_tiny))
    return float(np.mean((log_t < lo) | (log_t > hi)))


def timing_misfit(Q, X, F, fa, fb, o1, o2, boundary, log_t_star, log_s3, log_s2,
                  params: UnitCell, settings: StencilSearch):
    """How far the cells' achievable times miss the time landscape (autograd-friendly).

    The fastest and slowest times a cell can reach (thinnest and thickest bracket) follow,
    closely, ``log t ~ c + a log b0 + e log x + k [boundary cell]``
    (``settings.timing_fastest``, ``settings.timing_slowest``): ``b0`` is the cell's bracket
    length and ``x`` its compression (flat central length minus the contact length
    ``s3 D / cos t``), both mm.  A cell whose requested time ``t*`` falls outside that
    range is clamped; the misfit is the mean over cells of the squared distance (in log
    time) from ``log t*`` to the range narrowed by ``settings.timing_margin`` at both ends
    (the estimate's own error is about 0.22).

    Parameters
    ----------
    boundary : (c,) float
        1 for cells with a base on the stencil's rim, else 0.
    log_t_star : (c,) float
        Log of each cell's requested time (s).
    log_s3, log_s2 : float
        The scalings (:func:`layout_logs`).

    Returns
    -------
    float
    """
    return _misfit(_cell_geometry(Q, X, F, fa, fb, o1, o2), boundary, log_t_star, log_s3,
                   log_s2, params, settings)


def _misfit(geometry, boundary, log_t_star, log_s3, log_s2, params: UnitCell,
            settings: StencilSearch):
    """:func:`timing_misfit` from the cells' ``geometry`` (:func:`_cell_geometry`)."""
    cos_t, _, D, d = geometry
    L = anp.exp(log_s2) * d
    lo, hi = log_time_range(L, anp.exp(log_s3) * D / cos_t, boundary, params, settings)
    m = settings.timing_margin
    early = anp.maximum(lo - log_t_star + m, 0.0)
    late = anp.maximum(log_t_star - hi + m, 0.0)
    return anp.mean(early**2 + late**2)


class RimCurve:
    """A closed flat curve along which the stencil's rim vertices slide (the boundary the
    CVT put them on: the target's rim, or the inset curve), by arc length.

    Fixed rim vertices made each candidate's longest cell depend on where its rim points
    happened to fall: on the stand, the longest flat cell is a rim cell at every count, and
    moves by 1.7 mm between neighbouring counts.  Sliding keeps them on the curve, so the
    stencil still covers the same part of the target.

    Parameters
    ----------
    C : (r, 2) float, mm
        The curve, closed (last row = first).
    """

    def __init__(self, C):
        C = np.asarray(C, float)
        if np.linalg.norm(C[-1] - C[0]) > 0:
            C = np.vstack([C, C[:1]])
        seg = np.diff(C, axis=0)
        keep = np.linalg.norm(seg, axis=1) > 0
        self.A, self.D = C[:-1][keep], seg[keep]          # segment starts and vectors
        self.len = np.linalg.norm(self.D, axis=1)
        self.s = np.r_[0.0, np.cumsum(self.len)]          # arc length at segment starts
        self.total = float(self.s[-1])

    def project(self, P):
        """Arc length (mm) of the nearest curve point of each of ``P`` (k, 2) and the
        distance (mm) to it."""
        P = np.asarray(P, float)
        w = P[:, None, :] - self.A[None]                  # (k, r, 2)
        t = np.clip(np.einsum("krj,rj->kr", w, self.D) / self.len**2, 0.0, 1.0)
        d = np.linalg.norm(w - t[..., None] * self.D[None], axis=2)
        j = np.argmin(d, axis=1)
        k = np.arange(len(P))
        return self.s[j] + t[k, j] * self.len[j], d[k, j]

    def point(self, s):
        """(k, 2) float, mm: the curve points at arc lengths ``s`` (k,) (periodic)."""
        s = np.mod(np.asarray(s, float), self.total)
        j = np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.len) - 1)
        return self.A[j] + ((s - self.s[j]) / self.len[j])[:, None] * self.D[j]

    def tangent(self, s):
        """(k, 2) float: unit tangents at arc lengths ``s``."""
        s = np.mod(np.asarray(s, float), self.total)
        j = np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.len) - 1)
        return self.D[j] / self.len[j][:, None]

    def shortest(self, s0, s1):
        """Signed arc length (mm) from ``s0`` to ``s1`` the short way round."""
        return np.mod(np.asarray(s1) - np.asarray(s0) + self.total / 2, self.total) \
            - self.total / 2


class StencilObjective:
    """The objective of :func:`optimize_stencil` for one stencil: its fixed data and terms.

    Built once per call (a class because the cells, the free/fixed split, the starting
    angles and clearances and the landscape are reused by every round and every check).

    Parameters
    ----------
    domain : pysolver.design.stencil.remesh.FlatDomain
    P : (n, 2) float, mm
        The starting flat stencil (its angles and clearances set the penalties' floors).
    F : (m, 3) int
    params : UnitCell
    settings : StencilSearch
    t_vertex : (n,) float, s, optional
    pin : bool
    rim : (r, 2) float, mm, optional
        The closed curve the rim vertices lie on (:class:`RimCurve`); they then slide along
        it.  Rim vertices off it (an ear's or a flap's removal made them rim) stay fixed.
    pin_scale3d : float
        The 3D scaling the pin holds (default 1).
    """

    def __init__(self, domain, P, F, params: UnitCell, settings: StencilSearch,
                 t_vertex=None, pin: bool = False, rim=None, pin_scale3d: float = 1.0):
        self.domain, self.F, self.params, self.settings = domain, F, params, settings
        cells = unit_cells(F, face_adjacency(F))
        self.n_cells = len(cells.faces)
        self.fa, self.fb = cells.faces[:, 0], cells.faces[:, 1]
        o = opposite_vertices(F, cells)
        self.o1, self.o2 = o[:, 0], o[:, 1]
        varies = t_vertex is not None and np.ptp(np.asarray(t_vertex, float)) > TOL.time
        self.w_t = settings.opt_timing_weight if varies else 0.0
        if self.w_t > 0:
            self.log_ts = np.log(np.maximum(cell_target_times(
                t_vertex, cells.verts[:, 0], cells.verts[:, 1]), settings.opt_tiny))
            # cells with a base on the rim (temporal programming's ``boundary`` flag instead
            # asks for an end of the shared edge on the rim; they differ on about 1 % of cells)
            on_rim = np.any(face_adjacency(F) < 0, axis=1)
            self.bnd = (on_rim[self.fa] | on_rim[self.fb]).astype(float)
        self.log_cap = np.log(params.max_cell_length - settings.margin)
        # the half fold's tangent floored smoothly (``opt_fold_floor_deg``): at a flat cell
        # its square root has a kink, whose rounding noise L-BFGS amplified
        self.fold_floor = np.tan(np.radians(settings.opt_fold_floor_deg) / 2.0) ** 2
        self.pin = settings.opt_pin_weight if pin else 0.0
        self.pin_log = float(np.log(pin_scale3d))
        self.edges = igl.edges(F)
        self.fixed = np.zeros(len(P), dtype=bool)
        self.fixed[igl.boundary_loop(F)] = True
        self.free = np.flatnonzero(~self.fixed)
        self.rim, self.slides = None, np.zeros(0, dtype=np.int64)
        if rim is not None:
            self.rim = RimCurve(rim)
            rows = np.flatnonzero(self.fixed)
            _, d = self.rim.project(P[rows])
            self.slides = rows[d <= TOL.merge]
            if not len(self.slides):
                self.rim = None
        # Q = concat(free rows, fixed rows)[perm]: indexing keeps autograd's tape simple
        order = np.r_[self.free, np.flatnonzero(self.fixed)]
        self.perm = np.empty(len(P), dtype=np.int64)
        self.perm[order] = np.arange(len(P))
        self.A0 = _signed_areas(P, F)
        # flat corners within [floor, cap] (or no worse than at the start): each base's printed
        # disc and bracket roots must stay inside its triangle's neighbourhood, which the
        # membrane meshes of the simulator and of the per-cell correction assume
        start = _angles_np(P, F)
        self.floor = np.minimum(np.radians(settings.opt_min_angle_deg), start)
        self.cap = np.maximum(np.radians(settings.opt_max_angle_deg), start)
        # and every base centre (flat centroid) at least opt_centroid_edge_mm from its
        # triangle's edges once scaled (or no nearer than at the start)
        log_s2 = float(self._logs(self._geometry(P, domain.lift(P)), None)[1])
        self.log_clear = np.minimum(np.log(settings.opt_centroid_edge_mm),
                                    log_s2 + np.log(_np(centroid_edge_distances(P, F))))

    def _geometry(self, Q, X):
        return _cell_geometry(Q, X, self.F, self.fa, self.fb, self.o1, self.o2,
                              self.fold_floor)

    def _logs(self, geometry, sharpness):
        return _scaling_logs(geometry, self.params, sharpness)

    def main_terms(self, log_s3, log_s2, log_d, log_pinned):
        """Pinned: the longest flat cell per unit of 3D scaling, with the 3D scaling (log,
        ``log_pinned``: the exact one, or within a round the smoothed one less its excess at
        the round's start, as the timing cap's; either less the log of ``pin_scale3d``) held
        at 1 (or ``pin_scale3d``) (the shell keeps its target's
        size, so the count search can trade vertices for flat length); else the longest flat
        cell (+ the optional 3D scaling weight)."""
        if self.pin > 0:
            return log_s2 + log_d - log_s3 + self.pin * log_pinned ** 2
        return log_s2 + log_d + self.settings.opt_s3_weight * log_s3

    def timing(self, geometry, log_s3, log_s2, log_longest):
        """The timing misfit at the smoothed scalings (they over-estimate s2 by 6-7 %, so
        every flat length, which the margin absorbs; at the exact, non-smooth ones L-BFGS
        stalls and the count search lost its footing, measured on cover and dome), and a
        penalty that keeps the longest flat cell (log, ``log_longest``) under the limit less
        the search's margin: the exact one, or within a round the smoothed one less its
        excess at the round's start (exact there; the exact maximum has a kink wherever two
        cells tie, at which the cover's first rounds stopped, or not, with the last bits)."""
        if self.w_t <= 0:
            return 0.0
        over = anp.maximum(log_longest - self.log_cap, 0.0)
        return (self.w_t * _misfit(geometry, self.bnd, self.log_ts, log_s3, log_s2,
                                   self.params, self.settings)
                + self.settings.opt_cap_weight * over**2)

    def shortfall(self, Q, log_s2_exact) -> float:
        """Worst log shortfall of a base centre's clearance (0 when every one is clear)."""
        short = np.max(self.log_clear - log_s2_exact
                       - np.log(np.maximum(_np(centroid_edge_distances(Q, self.F)),
                                           self.settings.opt_tiny)))
        return max(float(short), 0.0)

    def exact(self, Q):
        """The objective without its penalties and barrier, on the exact lift of ``Q``, and
        the clearance shortfall (:meth:`shortfall`)."""
        g = self._geometry(Q, self.domain.lift(Q))
        a, b, c = self._logs(g, self.settings.opt_sharpness)
        ex = self._logs(g, None)
        return (float(self.main_terms(a, b, c, ex[0] - self.pin_log)
                      + self.timing(g, a, b, ex[1] + ex[2])),
                self.shortfall(Q, float(ex[1])))

    def linearised(self, P0, clearance_weight: float, autodiff: bool = False):
        """``fun(x) -> (f, g)`` over :meth:`start`'s variables ``x`` (the free vertices'
        coordinates, then with a rim one arc-length step per fixed vertex), with the
        lift linearised at ``P0`` (the Jacobian of the dense piecewise linear map), and the
        penalties and the orientation barrier.

        The gradient is the hand-written reverse pass of :mod:`.objective`;
        ``autodiff`` differentiates this module's functions by autograd instead (about five
        times slower: the check of the hand pass in ``tests/test_stencil.py``)."""
        st, F = self.settings, self.F
        X0, J = self.domain.lift(P0), self.domain.lift_jacobian(P0)
        Pfix, k2 = P0[self.fixed], 2 * len(self.free)
        T = np.zeros_like(Pfix)  # rim tangents of the sliding rows (0: fixed)
        if self.rim is not None:
            T[np.searchsorted(np.flatnonzero(self.fixed), self.slides)] = self.rim.tangent(
                self.rim.project(P0[self.slides])[0])
        pin_excess = cap_excess = 0.0  # (see :meth:`main_terms`, :meth:`timing`)
        if self.w_t > 0 or self.pin > 0:
            geo0 = self._geometry(P0, X0)
            sm0, ex0 = self._logs(geo0, st.opt_sharpness), self._logs(geo0, None)
            pin_excess = float(sm0[0] - ex0[0]) + self.pin_log  # (and the scaling held)
            cap_excess = float(sm0[1] + sm0[2] - ex0[1] - ex0[2])
        if not autodiff:
            return self._by_hand(P0, X0, J, Pfix, T, k2, clearance_weight,
                                 (pin_excess, cap_excess))

        def objective(x):
            if self.rim is not None:
                Qfix = Pfix + T * anp.reshape(x[k2:], (-1, 1))
                Q = anp.concatenate([anp.reshape(x[:k2], (-1, 2)), Qfix])[self.perm]
            else:
                Q = anp.concatenate([anp.reshape(x, (-1, 2)), Pfix])[self.perm]
            geo = self._geometry(Q, X0 + anp.einsum("nij,nj->ni", J, Q - P0))
            A, L2, cos = _flat_triangles(Q, F)
            log_s3, log_s2, log_d = self._logs(geo, st.opt_sharpness)
            ang = _corner_angles(cos)
            bad = anp.maximum(self.floor - ang, 0.0) + anp.maximum(ang - self.cap, 0.0)
            # the clearance takes the exact flat scaling (the smoothed one over-estimates it)
            ex = self._logs(geo, None)
            near = anp.maximum(self.log_clear - ex[1] - anp.log(anp.maximum(
                _clearances(A, L2), st.opt_tiny)), 0.0)
            return (self.main_terms(log_s3, log_s2, log_d, log_s3 - pin_excess)
                    + self.timing(geo, log_s3, log_s2, log_s2 + log_d - cap_excess)
                    + st.opt_angle_weight * anp.sum(bad**2)
                    + clearance_weight * anp.sum(near**2)
                    - st.opt_barrier * anp.sum(anp.log(anp.maximum(A / self.A0,
                                                                   st.opt_tiny))))

        fg = value_and_grad(objective)

        def fun(x):
            f, g = fg(x)
            return float(f), np.asarray(g, dtype=float)
        return fun

    def _by_hand(self, P0, X0, J, Pfix, T, k2: int, clearance_weight: float, excess):
        """:meth:`linearised`'s ``fun`` with the passes of :mod:`.objective`
        (``excess``: the smoothed log 3D scaling's and log longest flat cell's over the exact
        ones at ``P0``, :meth:`main_terms`, :meth:`timing`)."""
        pin_excess, cap_excess = excess
        st, F, params = self.settings, self.F, self.params
        fixed_rows = np.flatnonzero(self.fixed)

        def fun(x):
            Q = np.empty_like(P0)
            Q[self.free] = np.reshape(x[:k2], (-1, 2))
            Q[fixed_rows] = Pfix + (T * np.reshape(x[k2:], (-1, 1)) if self.rim is not None
                                    else 0.0)
            X = X0 + np.einsum("nij,nj->ni", J, Q - P0)
            geo = og.CellGeometry(Q, X, F, self.fa, self.fb, self.o1, self.o2, self.fold_floor)
            sm = og.Scalings(geo, params, st.opt_sharpness)
            ex = og.Scalings(geo, params, None, like=sm)
            flat = og.FlatTriangles(Q, F)
            # the objective, term by term, with each term's gradient in the logs
            g_sm = [0.0, 1.0, 1.0]  # (log s3, log s2, log d), smoothed
            g_ex = [0.0, 0.0, 0.0]  # exact
            if self.pin > 0:
                pinned = sm.log_s3 - pin_excess
                f = sm.log_s2 + sm.log_d - sm.log_s3 + self.pin * pinned**2
                g_sm[0] = -1.0 + 2.0 * self.pin * pinned
            else:
                f = sm.log_s2 + sm.log_d + st.opt_s3_weight * sm.log_s3
                g_sm[0] = st.opt_s3_weight
            back_t = None
            if self.w_t > 0:
                mis, back_t = og.timing(geo, sm, self.bnd, self.log_ts, params, st)
                over = max(sm.log_s2 + sm.log_d - cap_excess - self.log_cap, 0.0)
                f += self.w_t * mis + st.opt_cap_weight * over**2
                g_sm[1] += 2.0 * st.opt_cap_weight * over
                g_sm[2] += 2.0 * st.opt_cap_weight * over
            ang = flat.angles
            low, high = self.floor - ang, ang - self.cap
            bad = np.maximum(low, 0.0) + np.maximum(high, 0.0)
            f += st.opt_angle_weight * np.sum(bad**2)
            flat.g_angles += 2.0 * st.opt_angle_weight * bad * ((high > 0) * 1.0 - (low > 0))
            clear = np.maximum(flat.clearance, st.opt_tiny)
            near = np.maximum(self.log_clear - ex.log_s2 - np.log(clear), 0.0)
            f += clearance_weight * np.sum(near**2)
            g_near = 2.0 * clearance_weight * near
            g_ex[1] -= float(np.sum(g_near))
            flat.g_clearance -= np.where(flat.clearance > st.opt_tiny, g_near / clear, 0.0)
            Ar = flat.A / self.A0
            f -= st.opt_barrier * np.sum(np.log(np.maximum(Ar, st.opt_tiny)))
            flat.g_A -= np.where(Ar > st.opt_tiny, st.opt_barrier / (Ar * self.A0), 0.0)
            # backward
            if back_t is not None:
                d3, d2 = back_t(self.w_t)
                g_sm[0] += d3
                g_sm[1] += d2
            sm.backward(*g_sm)
            ex.backward(*g_ex)
            gX = np.zeros_like(X)
            gQ = np.zeros_like(Q)
            geo.backward(gX, gQ)
            flat.backward(gQ)
            gQ += np.einsum("nij,ni->nj", J, gX)
            g = gQ[self.free].ravel()
            if self.rim is not None:
                g = np.r_[g, np.sum(gQ[fixed_rows] * T, axis=1)]
            return float(f), g
        return fun

    def start(self, P):
        """The variables of :meth:`linearised` at ``P``: the free vertices' coordinates, and
        (sliding) every fixed vertex's arc-length step along the rim, 0."""
        x = P[self.free].ravel()
        return x if self.rim is None else np.r_[x, np.zeros(int(self.fixed.sum()))]

    @property
    def proximal(self) -> bool:
        """Whether each round is a converged proximal step (``StencilSearch.opt_prox``):
        unpinned (pinned rounds keep a budget, with the pin holding the figures: the polish,
        once per design)."""
        return self.pin <= 0 and self.settings.opt_prox > 0

    def median_edge(self, P) -> float:
        """The median flat edge (mm) of the stencil at flat points ``P`` (n, 2)."""
        E = self.edges
        return float(np.median(np.linalg.norm(P[E[:, 0]] - P[E[:, 1]], axis=1)))

    def lbfgs(self, P, maxiter: int):
        """The round's L-BFGS-B setup at ``P``: ``(options, lam)``; a proximal round
        (:attr:`proximal`) runs to ``opt_gtol`` (``ftol`` 0: not stopped by a small
        decrease of the objective) with its proximal weight ``lam`` (1/mm^2, ``opt_prox``
        over the median flat edge squared; with the timing term ``opt_timing_gtol`` and
        ``opt_timing_prox``), else ``maxiter`` iterations and ``lam`` 0."""
        st = self.settings
        if not self.proximal:
            return {"maxiter": maxiter}, 0.0
        gtol, prox = ((st.opt_timing_gtol, st.opt_timing_prox) if self.w_t > 0
                      else (st.opt_gtol, st.opt_prox))
        return ({"maxiter": st.opt_prox_iterations, "gtol": gtol, "ftol": 0.0,
                 "maxcor": st.opt_memory}, prox / self.median_edge(P) ** 2)

    def bounds(self, P):
        """Box bounds of :meth:`start`'s variables at ``P``: the round's trust region,
        ``opt_trust`` times the median flat edge around ``P`` (the rim steps from 0).

        None when pinned: the pin holds the 3D scaling, a maximum over the cells, and
        L-BFGS-B stalled at the box with the scaling 3 % off (a hemisphere); the pinned
        figures are held by the pin itself, not by where the path ends.  None for a
        proximal round (:attr:`proximal`) without the timing term, which its proximal term
        holds; with it, a round left free ran past its linearisation (petal, 143 vertices:
        1/16 of its step kept, objective 56 instead of 16 in the box)."""
        if self.pin > 0 or (self.proximal and self.w_t <= 0):
            return None
        r = self.settings.opt_trust * self.median_edge(P)
        x = self.start(P)
        return np.c_[x - r, x + r]

    def embed(self, P0, x):
        """(n, 2) float: ``P0`` with its free vertices at ``x`` and its sliding rim
        vertices moved along the rim by the arc lengths ``x`` gives them."""
        P = P0.copy()
        k2 = 2 * len(self.free)
        P[self.free] = np.reshape(x[:k2], (-1, 2))
        if self.rim is not None:
            ds = np.asarray(x[k2:])[np.searchsorted(np.flatnonzero(self.fixed), self.slides)]
            P[self.slides] = self.rim.point(self.rim.project(P0[self.slides])[0] + ds)
        return P

    def along(self, P0, Pn, a: float):
        """(n, 2) float: the point ``a`` of the way from ``P0`` to ``Pn`` (straight for the
        free vertices, along the rim for the sliding ones)."""
        Q = P0 + a * (Pn - P0)
        if self.rim is not None:
            s0 = self.rim.project(P0[self.slides])[0]
            sn = self.rim.project(Pn[self.slides])[0]
            Q[self.slides] = self.rim.point(s0 + a * self.rim.shortest(s0, sn))
        return Q

    def iterations(self) -> int:
        st = self.settings
        return st.opt_timing_iterations if self.w_t > 0 else st.opt_iterations


def accept_step(problem: StencilObjective, P0, Pn, current: float, short_now: float):
    """The farthest point from ``P0`` toward ``Pn`` that keeps the hard limits and lowers
    the exact objective: ``problem.along(P0, Pn, a)`` for ``a = 1, 1/2, 1/4, ...``
    (``StencilSearch.opt_backtracks`` halvings).

    The hard limits: every flat triangle positively oriented, and no base centre's clearance
    short by more than ``max(short_now, opt_clearance_slack)`` (log).  The clearance is a
    soft penalty in the objective, so L-BFGS may end a little beyond the limit; the segment
    back to the start (which keeps the limits) gives the improving point that does not,
    instead of losing the whole round.

    Returns
    -------
    step : dict
        ``kept`` (bool), ``step`` (the fraction ``a`` taken, or None), ``objective`` and
        ``clearance_shortfall`` at the point kept (or at ``Pn`` when none is), ``why``.
    P : (n, 2) float or None
        The point kept.
    """
    st = problem.settings
    limit = max(short_now, st.opt_clearance_slack)
    first = None
    for k in range(st.opt_backtracks + 1):
        a = 0.5**k
        Q = problem.along(P0, Pn, a)
        if not np.all(_signed_areas(Q, problem.F) > 0):
            first = first or {"why": "a flat triangle turns over"}
            continue
        new, short = problem.exact(Q)
        if new < current and short <= limit:
            return {"kept": True, "step": a, "objective": new, "clearance_shortfall": short,
                    "why": "kept" if k == 0 else f"kept at {a:g} of the step"}, Q
        first = first or {
            "objective": new, "clearance_shortfall": short,
            "why": (f"a base centre's clearance short by {short:.3f} (limit {limit:.3f})"
                    if short > limit else "the objective does not fall on the exact lift")}
    return {"kept": False, "step": None, **first}, None


def optimize_stencil(domain, P, F, params: UnitCell = UNIT_CELL,
                     settings: StencilSearch = STENCIL, t_vertex=None, pin: bool = False,
                     converge: bool = False, rim=None, pin_scale3d: float = 1.0):
    """Move the stencil vertices (the rim ones along the rim) to shorten the longest flat cell.

    The objective is ``log lmax + opt_s3_weight * log s3``, plus quadratic penalties on flat
    corner angles outside ``opt_min_angle_deg``-``opt_max_angle_deg`` and on base centres
    nearer than ``opt_centroid_edge_mm`` to their triangle's edges, and a log barrier on flat
    orientation; with a time landscape, ``opt_timing_weight`` times the cells' timing misfit
    (:func:`timing_misfit`).  Shortening the longest flat cells lowers the 3D scaling at a
    given vertex count (the count search restores it with more vertices); a negative
    ``opt_s3_weight`` credits that back (:class:`pysolver.params.StencilSearch`).  With
    ``pin`` the objective is the longest flat cell per unit of 3D scaling, ``log lmax - log
    s3``, and ``opt_pin_weight (log s3)^2`` (s3 exact at each round's start, smooth within
    it: :meth:`StencilObjective.main_terms`) holds the shell at its target's size: the count
    search's last pass.

    Each outer round runs L-BFGS on the linearised lift and checks it on the exact lift
    (:func:`accept_step`, :func:`_round`): an improving round is never thrown away for a soft
    penalty's overshoot.  An unpinned round runs L-BFGS to convergence with a proximal
    term (``opt_prox``: where it ends does not hang on last bits), inside the trust region
    (``opt_trust``) when the timing term is on; a pinned round, for an iteration budget.

    Parameters
    ----------
    domain : pysolver.design.stencil.remesh.FlatDomain
        Dense target and its conformal plane (``lift``, ``lift_jacobian``).
    P : (n, 2) float, mm
        Stencil vertices in the conformal plane; rim vertices stay (or slide, ``rim``).
    F : (m, 3) int
        Stencil triangles (positively oriented in the plane); the connectivity is kept.
    params : UnitCell
    settings : StencilSearch
    t_vertex : (n,) float, s, optional
        The time landscape at the stencil vertices (fixed while they move).  A constant one
        leaves the term out: programming then picks the constant most cells can reach, and
        evening the cells' speeds for it costs more than it saves (stand and cover).
    pin : bool
        Hold the 3D scaling at ``pin_scale3d``; minimise the longest flat cell per scaling.
    rim : (r, 2) float, mm, optional
        The curve the rim vertices lie on: they slide along it (:class:`RimCurve`).
    converge : bool
        Run up to ``opt_converge_rounds`` rounds (of ``opt_converge_iterations`` L-BFGS
        iterations each, or proximal ones), until a round gains less than
        ``opt_round_tol`` (the pick of the count search: where L-BFGS's path happened to
        stop does not move it); otherwise ``opt_rounds`` rounds (each candidate).

    Returns
    -------
    P : (n, 2) float, mm
        Optimised flat positions (every triangle still positively oriented).
    info : dict
        ``rounds``: outer rounds kept; ``converged``: the last round kept gained less than
        ``opt_round_tol``; ``history``: one record per round tried
        (``round``, ``start``, ``lbfgs``, ``iterations``, ``lbfgs_converged``,
        ``stiffened``, and
        :func:`accept_step`'s ``kept``, ``step``, ``objective``, ``clearance_shortfall``,
        ``why``).
    """
    P = np.array(P, dtype=float)
    F = np.asarray(F, dtype=np.int64)
    problem = StencilObjective(domain, P, F, params, settings, t_vertex, pin, rim, pin_scale3d)
    if problem.n_cells == 0:
        return P, {"rounds": 0, "history": [], "converged": True}
    st = settings
    n_rounds, maxiter = ((st.opt_converge_rounds, st.opt_converge_iterations) if converge
                         else (st.opt_rounds, problem.iterations()))
    current, short_now = problem.exact(P)
    history, converged = [], False
    for r in range(n_rounds):
        rec, step, Q = _round(problem, P, current, short_now, maxiter)
        history.append({"round": r + 1, **rec})
        if Q is None:
            break
        converged = current - step["objective"] < st.opt_round_tol
        P, current, short_now = Q, step["objective"], step["clearance_shortfall"]
        if converge and converged:
            break
    return P, {"rounds": sum(h["kept"] for h in history), "history": history,
               "converged": converged}


def _round(problem: StencilObjective, P, current: float, short_now: float, maxiter: int):
    """One outer round: L-BFGS on the lift linearised at ``P``, converged with the proximal
    term (:attr:`StencilObjective.proximal`) or for an iteration budget, within the round's
    trust region (:meth:`StencilObjective.bounds`) if it has one, the step checked on the exact
    lift (:func:`accept_step`), once more with the clearance penalty ``opt_stiffen`` times
    stiffer when no point of it is kept.  Returns the round's record, the step and the point
    kept (None when none is)."""
    st = problem.settings
    rec = {"start": round(current, 6)}
    x0 = problem.start(P)
    options, lam = problem.lbfgs(P, maxiter)
    box = problem.bounds(P)
    for stiffened, w in enumerate((st.opt_clearance_weight,
                                   st.opt_clearance_weight * st.opt_stiffen)):
        fun = problem.linearised(P, w)
        if lam > 0:
            fun = _proximal(fun, x0, lam)
        res = minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=box, options=options)
        step, Q = accept_step(problem, P, problem.embed(P, res.x), current, short_now)
        rec.update(lbfgs=round(float(res.fun), 6), iterations=int(res.nit),
                   lbfgs_converged=bool(res.status == 0), stiffened=bool(stiffened),
                   **_rounded(step))
        if Q is not None:
            break
    return rec, step, Q


def _proximal(fun, x0, lam: float):
    """``fun`` (value and gradient) plus ``lam |x - x0|^2 / 2``."""
    def prox(x):
        f, g = fun(x)
        d = x - x0
        return f + 0.5 * lam * float(d @ d), g + lam * d
    return prox


def _rounded(step: dict) -> dict:
    return {k: round(v, 6) if isinstance(v, float) else v for k, v in step.items()}


__all__ = ["opposite_vertices", "log_time_terms", "log_time_range", "layout_timing_terms",
           "estimated_clamping", "flat_corner_angles", "centroid_edge_distances", "layout_logs",
           "timing_misfit", "StencilObjective", "accept_step", "optimize_stencil"]
