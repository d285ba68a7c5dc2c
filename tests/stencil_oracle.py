"""The stencil objective stated again with autograd: the tests' oracle for the hand passes.

The optimiser (:mod:`pysolver.design.stencil.optimise`) evaluates its objective and gradient
with the numpy forward and reverse passes of :mod:`pysolver.design.stencil.objective`.  Here
the same rules are written plainly, in autograd's numpy, and differentiated by autograd
(about five times slower, which is why the optimiser does not use them):
``tests/test_stencil.py`` checks the hand passes' value and gradient against these, and
these rules against :func:`pysolver.design.layout.build_layout`.
"""

from __future__ import annotations

import autograd.numpy as anp
import numpy as np
from autograd import value_and_grad
from autograd.scipy.special import logsumexp

from pysolver.params import STENCIL, UnitCell
from pysolver.params import tol as TOL


def flat_triangles(Q, F):
    """Signed areas (m,), squared edge lengths (m, 3) and corner cosines (m, 3) of the flat
    triangles; edge k runs from corner k to k + 1, corner k lies between edges k and k - 1."""
    T = Q[F]
    E = T[:, [1, 2, 0]] - T
    L2 = anp.sum(E * E, axis=2)
    A = 0.5 * (E[:, 2, 0] * E[:, 0, 1] - E[:, 0, 0] * E[:, 2, 1])
    cos = -anp.sum(E * E[:, [2, 0, 1]], axis=2) / anp.sqrt(L2 * L2[:, [2, 0, 1]])
    return A, L2, cos


def corner_angles(cos):
    return anp.arccos(anp.clip(cos, -1.0 + TOL.exact, 1.0 - TOL.exact))


def clearances(A, L2):
    """(m, 3): distance from each flat centroid to its edges, ``2 A / (3 |e|)``."""
    return 2.0 * A[:, None] / (3.0 * anp.sqrt(L2))


def cell_geometry(Q, X, F, fa, fb, o1, o2, tiny: float = STENCIL.opt_tiny):
    """Per cell: the half fold's cosine and tangent on the target, the target (mm) and flat
    centroid distances."""
    N = anp.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
    N = N / anp.sqrt(anp.sum(N * N, axis=1, keepdims=True))
    cphi = anp.clip(anp.sum(N[fa] * N[fb], axis=1), -0.99, 1.0)
    cos_t = anp.sqrt((1.0 + cphi) / 2.0)
    tan_t = anp.sqrt(anp.maximum(1.0 - cphi, 0.0) / (1.0 + cphi) + tiny)
    D = anp.sqrt(anp.sum((X[o1] - X[o2]) ** 2, axis=1)) / 3.0
    d = anp.sqrt(anp.sum((Q[o1] - Q[o2]) ** 2, axis=1)) / 3.0
    return cos_t, tan_t, D, d


def scaling_logs(geometry, params: UnitCell, sharpness):
    """``log s3``, ``log s2``, ``log max d`` of the layout rules (smoothed by log-sum-exp at
    ``sharpness``; None: exact maxima)."""
    cos_t, tan_t, D, d = geometry

    def smax(v):
        return anp.max(anp.log(v)) if sharpness is None else \
            logsumexp(sharpness * anp.log(v)) / sharpness

    r3 = (params.base_r + params.layer_h * tan_t + params.min_bumper) * 2.0 * cos_t / D
    log_s3 = smax(r3)
    r2 = (anp.exp(log_s3) * D / (2.0 * cos_t) + params.layer_h * tan_t
          + params.min_gap / 2.0) / (d / 2.0)
    return log_s3, smax(r2), smax(d)


def layout_logs(Q, X, F, fa, fb, o1, o2, params: UnitCell, sharpness):
    return scaling_logs(cell_geometry(Q, X, F, fa, fb, o1, o2), params, sharpness)


def misfit(geometry, boundary, log_t_star, log_s3, log_s2, params: UnitCell, settings):
    """The timing misfit: mean squared distance (log time) from each cell's requested time
    to its estimated achievable range narrowed by ``timing_margin``."""
    cos_t, _, D, d = geometry
    L = anp.exp(log_s2) * d
    contact = anp.exp(log_s3) * D / cos_t
    log_b0 = anp.log(anp.maximum(L - params.bracket_offset, settings.opt_tiny))
    xm = settings.timing_compression_floor
    log_x = anp.log(xm * anp.logaddexp(0.0, (L - contact) / xm))

    def estimate(m):
        return m[0] + m[1] * log_b0 + m[2] * log_x + m[3] * boundary

    lo, hi = estimate(settings.timing_fastest), estimate(settings.timing_slowest)
    m = settings.timing_margin
    early = anp.maximum(lo - log_t_star + m, 0.0)
    late = anp.maximum(log_t_star - hi + m, 0.0)
    return anp.mean(early**2 + late**2)


def timing_misfit(Q, X, F, fa, fb, o1, o2, boundary, log_t_star, log_s3, log_s2,
                  params: UnitCell, settings):
    return misfit(cell_geometry(Q, X, F, fa, fb, o1, o2), boundary, log_t_star, log_s3,
                  log_s2, params, settings)


def linearised(prob, P0, clearance_weight: float):
    """``fun(x) -> (f, g)`` of :meth:`pysolver.design.stencil.optimise.StencilObjective.
    linearised` for the objective ``prob``, written with autograd's numpy and differentiated
    by autograd."""
    st, F, params = prob.settings, prob.F, prob.params
    X0, J = prob.domain.lift(P0), prob.domain.lift_jacobian(P0)
    Pfix, k2 = P0[prob.fixed], 2 * len(prob.free)
    T = np.zeros_like(Pfix)
    if prob.rim is not None:
        T[np.searchsorted(np.flatnonzero(prob.fixed), prob.slides)] = prob.rim.tangent(
            prob.rim.project(P0[prob.slides])[0])
    args = (F, prob.fa, prob.fb, prob.o1, prob.o2)
    geo0 = cell_geometry(P0, X0, *args, prob.fold_floor)
    sm0, ex0 = scaling_logs(geo0, params, st.opt_sharpness), scaling_logs(geo0, params, None)
    pin_excess = float(sm0[0] - ex0[0]) + prob.pin_log
    cap_excess = float(sm0[1] + sm0[2] - ex0[1] - ex0[2])
    order = np.r_[prob.free, np.flatnonzero(prob.fixed)]
    perm = np.empty(len(P0), dtype=np.int64)
    perm[order] = np.arange(len(P0))

    def objective(x):
        Qfix = Pfix + T * anp.reshape(x[k2:], (-1, 1)) if prob.rim is not None else Pfix
        Q = anp.concatenate([anp.reshape(x[:k2], (-1, 2)), Qfix])[perm]
        geo = cell_geometry(Q, X0 + anp.einsum("nij,nj->ni", J, Q - P0), *args,
                            prob.fold_floor)
        A, L2, cos = flat_triangles(Q, F)
        log_s3, log_s2, log_d = scaling_logs(geo, params, st.opt_sharpness)
        ex = scaling_logs(geo, params, None)
        if prob.pin > 0:
            f = log_s2 + log_d - log_s3 + prob.pin * (log_s3 - pin_excess) ** 2
        else:
            f = log_s2 + log_d + st.opt_s3_weight * log_s3
        if prob.w_t > 0:
            over = anp.maximum(log_s2 + log_d - cap_excess - prob.log_cap, 0.0)
            f = f + prob.w_t * misfit(geo, prob.bnd, prob.log_ts, log_s3, log_s2, params, st) \
                + st.opt_cap_weight * over**2
        ang = corner_angles(cos)
        bad = anp.maximum(prob.floor - ang, 0.0) + anp.maximum(ang - prob.cap, 0.0)
        near = anp.maximum(prob.log_clear - ex[1] - anp.log(anp.maximum(
            clearances(A, L2), st.opt_tiny)), 0.0)
        return (f + st.opt_angle_weight * anp.sum(bad**2)
                + clearance_weight * anp.sum(near**2)
                - st.opt_barrier * anp.sum(anp.log(anp.maximum(A / prob.A0, st.opt_tiny))))

    fg = value_and_grad(objective)

    def fun(x):
        f, g = fg(x)
        return float(f), np.asarray(g, dtype=float)
    return fun
