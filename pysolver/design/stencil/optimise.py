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
:func:`~.objective.timing`) toward its requested time: the paper's cover carrying the
reference's landscape clamps 8.7 % of its cells (``bench/bench_design_cover.py``).  The
target positions are the exact lift of the flat points, linearised per vertex (the Jacobian
of the dense piecewise linear map) inside each of a few outer rounds and lifted again after
each.

The objective and its gradient are written once, in :mod:`.objective` (numpy forward and
reverse passes, 0.7 ms per evaluation on petal's 132-vertex stencil); this module holds the
optimiser around them: the free and sliding variables, the rounds, the step acceptance.
``tests/stencil_oracle.py`` states the rules again with autograd, as the tests' oracle, and
the rules themselves are checked against :func:`pysolver.design.layout.build_layout` by
``tests/test_stencil.py``.
"""

from __future__ import annotations

import igl
import numpy as np
from scipy.optimize import minimize
from scipy.special import logsumexp

from ...geometry import face_adjacency, unit_cells
from ...params import STENCIL, UNIT_CELL, StencilSearch, UnitCell
from ...params import tol as TOL
from ..time_landscape import cell_target_times
from . import objective as og
from .objective import log_time_range


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


def layout_timing_terms(lay):
    """What :func:`~.objective.log_time_range` reads of a laid-out stencil, as the optimiser
    states it (:func:`~.objective.timing`).

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
    """Fraction of cells whose time ``t_star`` (s) lies outside
    :func:`~.objective.log_time_range`.

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
        flat = og.FlatTriangles(P, F)
        self.A0 = flat.A
        # flat corners within [floor, cap] (or no worse than at the start): each base's printed
        # disc and bracket roots must stay inside its triangle's neighbourhood, which the
        # membrane meshes of the simulator and of the per-cell correction assume
        start = flat.angles
        self.floor = np.minimum(np.radians(settings.opt_min_angle_deg), start)
        self.cap = np.maximum(np.radians(settings.opt_max_angle_deg), start)
        # and every base centre (flat centroid) at least opt_centroid_edge_mm from its
        # triangle's edges once scaled (or no nearer than at the start)
        log_s2 = og.Scalings(self.geometry(P, domain.lift(P)), params, None).log_s2
        self.log_clear = np.minimum(np.log(settings.opt_centroid_edge_mm),
                                    log_s2 + np.log(flat.clearance))

    def geometry(self, Q, X) -> og.CellGeometry:
        """The cells' geometry at flat points ``Q`` (n, 2) and target points ``X`` (n, 3) mm."""
        return og.CellGeometry(Q, X, self.F, self.fa, self.fb, self.o1, self.o2,
                               self.fold_floor)

    def scalings(self, geo: og.CellGeometry, checked: bool = False):
        """The smoothed (``opt_sharpness``) and the exact :class:`~.objective.Scalings`;
        ``checked``: the smoothed values as the exact checks take them (scipy's log-sum-exp,
        :func:`~.objective.smax`), for :meth:`exact` and each round's start."""
        sm = og.Scalings(geo, self.params, self.settings.opt_sharpness,
                         lse=logsumexp if checked else None)
        return sm, og.Scalings(geo, self.params, None, like=sm)

    def main_terms(self, sm: og.Scalings, log_pinned: float):
        """Pinned: the longest flat cell per unit of 3D scaling, with the 3D scaling (log,
        ``log_pinned``: the exact one, or within a round the smoothed one less its excess at
        the round's start, as the timing cap's; either less the log of ``pin_scale3d``) held
        at 1 (or ``pin_scale3d``) (the shell keeps its target's size, so the count search can
        trade vertices for flat length); else the longest flat cell (+ the optional 3D
        scaling weight); at the smoothed scalings ``sm``.

        Returns
        -------
        value : float
        g_s3, g_pinned : float -- its derivatives in ``sm.log_s3`` and in ``log_pinned``
            (its derivatives in ``sm.log_s2`` and ``sm.log_d`` are 1)
        """
        if self.pin > 0:
            return (sm.log_s2 + sm.log_d - sm.log_s3 + self.pin * log_pinned ** 2, -1.0,
                    2.0 * self.pin * log_pinned)
        w = self.settings.opt_s3_weight
        return sm.log_s2 + sm.log_d + w * sm.log_s3, w, 0.0

    def timing(self, geo: og.CellGeometry, sm: og.Scalings, log_longest: float):
        """The timing misfit at the smoothed scalings (they over-estimate s2 by 6-7 %, so
        every flat length, which the margin absorbs; at the exact, non-smooth ones L-BFGS
        stalls and the count search lost its footing, measured on cover and dome), and a
        penalty that keeps the longest flat cell (log, ``log_longest``) under the limit less
        the search's margin: the exact one, or within a round the smoothed one less its
        excess at the round's start (exact there; the exact maximum has a kink wherever two
        cells tie, at which the cover's first rounds stopped, or not, with the last bits).

        Returns
        -------
        value : float
        backward : callable or None -- the misfit's (:func:`~.objective.timing`)
        g_longest : float -- the derivative in ``log_longest``
        """
        if self.w_t <= 0:
            return 0.0, None, 0.0
        mis, back = og.timing(geo, sm, self.bnd, self.log_ts, self.params, self.settings)
        over = max(log_longest - self.log_cap, 0.0)
        cap = self.settings.opt_cap_weight
        return self.w_t * mis + cap * over**2, back, 2.0 * cap * over

    def shortfall(self, Q, log_s2_exact) -> float:
        """Worst log shortfall of a base centre's clearance (0 when every one is clear)."""
        short = np.max(self.log_clear - log_s2_exact
                       - np.log(np.maximum(og.FlatTriangles(Q, self.F).clearance,
                                           self.settings.opt_tiny)))
        return max(float(short), 0.0)

    def exact(self, Q):
        """The objective without its penalties and barrier, on the exact lift of ``Q``, and
        the clearance shortfall (:meth:`shortfall`)."""
        geo = self.geometry(Q, self.domain.lift(Q))
        sm, ex = self.scalings(geo, checked=True)
        main = self.main_terms(sm, ex.log_s3 - self.pin_log)[0]
        return (float(main + self.timing(geo, sm, ex.log_s2 + ex.log_d)[0]),
                self.shortfall(Q, ex.log_s2))

    def linearised(self, P0, clearance_weight: float):
        """``fun(x) -> (f, g)`` over :meth:`start`'s variables ``x`` (the free vertices'
        coordinates, then with a rim one arc-length step per fixed vertex), with the
        lift linearised at ``P0`` (the Jacobian of the dense piecewise linear map), and the
        penalties and the orientation barrier.

        The gradient is the hand-written reverse pass of :mod:`.objective` (checked against
        autograd's differentiation of ``tests/stencil_oracle.py``)."""
        X0, J = self.domain.lift(P0), self.domain.lift_jacobian(P0)
        Pfix, k2 = P0[self.fixed], 2 * len(self.free)
        T = np.zeros_like(Pfix)  # rim tangents of the sliding rows (0: fixed)
        if self.rim is not None:
            T[np.searchsorted(np.flatnonzero(self.fixed), self.slides)] = self.rim.tangent(
                self.rim.project(P0[self.slides])[0])
        pin_excess = cap_excess = 0.0  # (see :meth:`main_terms`, :meth:`timing`)
        if self.w_t > 0 or self.pin > 0:
            sm0, ex0 = self.scalings(self.geometry(P0, X0), checked=True)
            pin_excess = float(sm0.log_s3 - ex0.log_s3) + self.pin_log  # (and the scaling held)
            cap_excess = float(sm0.log_s2 + sm0.log_d - ex0.log_s2 - ex0.log_d)
        return self._by_hand(P0, X0, J, Pfix, T, k2, clearance_weight, (pin_excess, cap_excess))

    def _by_hand(self, P0, X0, J, Pfix, T, k2: int, clearance_weight: float, excess):
        """:meth:`linearised`'s ``fun`` with the passes of :mod:`.objective`
        (``excess``: the smoothed log 3D scaling's and log longest flat cell's over the exact
        ones at ``P0``, :meth:`main_terms`, :meth:`timing`)."""
        pin_excess, cap_excess = excess
        st, F = self.settings, self.F
        fixed_rows = np.flatnonzero(self.fixed)

        def fun(x):
            Q = np.empty_like(P0)
            Q[self.free] = np.reshape(x[:k2], (-1, 2))
            Q[fixed_rows] = Pfix + (T * np.reshape(x[k2:], (-1, 1)) if self.rim is not None
                                    else 0.0)
            X = X0 + np.einsum("nij,nj->ni", J, Q - P0)
            geo = self.geometry(Q, X)
            sm, ex = self.scalings(geo)
            flat = og.FlatTriangles(Q, F)
            # the objective, term by term, with each term's gradient in the logs
            f, g3, g_pinned = self.main_terms(sm, sm.log_s3 - pin_excess)
            g_sm = [g3 + g_pinned, 1.0, 1.0]  # (log s3, log s2, log d), smoothed
            g_ex = [0.0, 0.0, 0.0]  # exact
            t, back_t, g_longest = self.timing(geo, sm, sm.log_s2 + sm.log_d - cap_excess)
            f += t
            g_sm[1] += g_longest
            g_sm[2] += g_longest
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
        """Whether each round is a converged proximal step (``StencilSearch.opt_prox``),
        pinned or not.  (The polish's pinned rounds kept an iteration budget: where it stopped
        L-BFGS moved with the last bits, the cover's polished stencil by up to 1.2 mm between
        CPU code paths; converged, by 1e-5 mm.)"""
        return self.settings.opt_prox > 0

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
        if not np.all(og.signed_areas(Q, problem.F) > 0):
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
    (:func:`~.objective.timing`).  Shortening the longest flat cells lowers the 3D scaling at a
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


__all__ = ["opposite_vertices", "layout_timing_terms", "estimated_clamping", "RimCurve",
           "StencilObjective", "accept_step", "optimize_stencil"]
