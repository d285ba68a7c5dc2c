"""The time model of one unit cell: when a layer's brackets let its bumpers collide, the
thickness that makes that happen at a given time, and how the thickness scatter spreads it.

The functions here answer for one cell (or arrays of cells) what :mod:`pysolver.temporal.program`
asks for the whole design: the bracket model (:mod:`pysolver.material`) against the membrane's
pull, per layer (SI eq. 15), and the sensitivity of the closing time to the printed thickness
that the predicted timing spread and the robust programming read.
"""

from __future__ import annotations

import math

import numpy as np

from ..material import load_bracket_model
from ..params import PROGRAMMING, SIM, UNIT_CELL
from ..params import tol as TOL

# ----------------------------------------------------------------------------------------------
# models
# ----------------------------------------------------------------------------------------------


def load_material(material):
    """A bracket model object (has ``force``), loaded from a path or the committed default."""
    if material is not None and hasattr(material, "force"):
        return material
    return load_bracket_model(material)


def time_limit(material) -> float:
    """Latest time (s) the bracket model covers (its grid end; else the simulated 120 s)."""
    gm = getattr(material, "grid_max", None)
    if gm is not None:
        try:
            return float(np.asarray(gm, float)[2])
        except (IndexError, TypeError, ValueError):
            pass
    return float(SIM.t_end)


# ----------------------------------------------------------------------------------------------
# per-cell quantities
# ----------------------------------------------------------------------------------------------


def target_compressions(b0, b1_top, b1_bottom):
    """Per-layer target compression ``x_s = b0 - b1_s`` and membrane shortening ``d1`` (mm).

    Returns
    -------
    x : (n, 2) float, mm
        Columns (top, bottom).
    d1 : (n,) float, mm
        ``b0 - (b1_top + b1_bottom) / 2``.
    """
    b0 = np.asarray(b0, float)
    b1 = np.column_stack([np.asarray(b1_top, float), np.asarray(b1_bottom, float)])
    return b0[:, None] - b1, b0 - b1.mean(axis=1)


def bracket_target_force(membrane, b0, d1, boundary, boundary_factor=None, factor=None):
    """Target force of each single bracket (N): ``F_mem(b0, d1) * k / 4``.

    ``k`` = ``factor`` per cell when given (:data:`CORRECTIONS`), else
    ``boundary_factor`` (default the model's, 0.6) on boundary cells and 1 elsewhere.

    Returns
    -------
    f_cell : (n,) float, N
        Membrane traction on the whole cell (4 brackets), after the correction.
    f_bracket : (n,) float, N
        ``f_cell / 4``.
    """
    f = np.asarray(membrane.force(b0, d1), float)
    if factor is not None:
        f = f * np.asarray(factor, float)
    else:
        fac = membrane.boundary_factor if boundary_factor is None else float(boundary_factor)
        f = np.where(np.asarray(boundary, bool), fac * f, f)
    return f, f / 4.0


def solve_thickness(material, b0, x, t, f_bracket, steps: int = PROGRAMMING.bisection_steps):
    """Bracket thickness whose force at (t, x) equals the target (bisection on h).

    The bracket force grows with thickness (thicker = stiffer), so a bisection on
    ``[thickness_min, thickness_max]`` finds the root when it is bracketed.

    Parameters
    ----------
    material : bracket model with ``force(h_mm, b_mm, t_s, x_mm)`` (single bracket, N)
    b0, x, t, f_bracket : (n,) float -- mm, mm, s, N (broadcast)

    Returns
    -------
    h : (n,) float, mm
    side : (n,) int
        0 = solved; -1 = even the thinnest bracket is too stiff at ``t`` (clamped to
        0.30 mm, the cell finishes later); +1 = even the thickest is too soft
        (clamped to 0.65 mm, the cell finishes earlier).
    """
    b0, x, t, f = np.broadcast_arrays(*(np.asarray(v, float) for v in (b0, x, t, f_bracket)))
    shape = b0.shape
    b0, x, t, f = (v.ravel() for v in (b0, x, t, f))
    lo = np.full(b0.shape, UNIT_CELL.thickness_min)
    hi = np.full(b0.shape, UNIT_CELL.thickness_max)
    f_lo = np.asarray(material.force(lo, b0, t, x), float)
    f_hi = np.asarray(material.force(hi, b0, t, x), float)
    side = np.where(f_lo > f, -1, np.where(f_hi < f, 1, 0))
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        weak = np.asarray(material.force(mid, b0, t, x), float) < f
        lo = np.where(weak, mid, lo)
        hi = np.where(weak, hi, mid)
    h = np.where(side < 0, UNIT_CELL.thickness_min,
                 np.where(side > 0, UNIT_CELL.thickness_max, 0.5 * (lo + hi)))
    return h.reshape(shape), side.reshape(shape)


def completion_time(material, h, b0, x, f_bracket, t_max=None,
                    steps: int = PROGRAMMING.bisection_steps):
    """Earliest time (s) at which a bracket's force at compression ``x`` drops to the target.

    Bisection in time on the (softening) bracket model.

    Returns
    -------
    t : (n,) float, s
        0 if the dry bracket already yields; ``inf`` if it never does within ``t_max``
        (default: the model's time range).
    """
    t_max = time_limit(material) if t_max is None else float(t_max)
    h, b0, x, f = np.broadcast_arrays(*(np.asarray(v, float) for v in (h, b0, x, f_bracket)))
    shape = h.shape
    h, b0, x, f = (v.ravel() for v in (h, b0, x, f))
    lo = np.zeros(h.shape)
    hi = np.full(h.shape, t_max)
    f = f * (1.0 + TOL.force_rtol)          # a thickness solved for t yields at t, not just after
    at0 = np.asarray(material.force(h, b0, lo, x), float) <= f
    never = np.asarray(material.force(h, b0, hi, x), float) > f
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        done = np.asarray(material.force(h, b0, mid, x), float) <= f
        hi = np.where(done, mid, hi)
        lo = np.where(done, lo, mid)
    t = np.where(at0, 0.0, np.where(never, np.inf, hi))
    return t.reshape(shape)


def time_ranges(material, b0, x, f_bracket, t_max=None):
    """Achievable completion times per cell and layer (thinnest -> earliest).

    A cell completes when the later of its two layers closes (all four bracket springs at
    their bumpers, :func:`sim.model.collisions.completion_times`), so its completion time
    is ``max(t_top, t_bottom)`` with each layer's time ``t_s`` in its own range
    ``[t_s(thinnest), t_s(thickest)]``.  The reachable completion times are therefore
    ``[max_s t_s(thinnest), max_s t_s(thickest)]``: no cell completes before its slower
    layer can close, and a time past the range of one layer is reached by the other one
    timing the cell while the first, at its thickest, closes earlier and waits at its
    bumpers.  (The paper asks both layers to close at ``t*``, the intersection of the two
    ranges; at the petal's rim, folded cells compress one layer up to 5.5 times more than
    the other, and the little-compressed layer closes within 13-68 s even at its thickest:
    17 of its 21 clamped cells at a755258 were clamped by that layer alone.)

    Parameters
    ----------
    b0 : (n,) float, mm
    x : (n, 2) float, mm -- target compression per layer
    f_bracket : (n,) float, N

    Returns
    -------
    t_min, t_max : (n,) float, s
        ``max`` over the two layers of ``t(thinnest)`` and of ``t(thickest)``; ``t_max``
        is capped at the model's time range.  ``t_min = inf`` if even the thinnest bracket
        of a layer never yields.
    layer_min, layer_max : (n, 2) float, s
    """
    t_end = time_limit(material) if t_max is None else float(t_max)
    b0 = np.asarray(b0, float)
    x = np.asarray(x, float)
    bb, ff = np.repeat(b0[:, None], 2, 1), np.repeat(np.asarray(f_bracket, float)[:, None], 2, 1)
    lmin = completion_time(material, UNIT_CELL.thickness_min, bb, x, ff, t_end)
    lmax = np.minimum(completion_time(material, UNIT_CELL.thickness_max, bb, x, ff, t_end), t_end)
    return lmin.max(axis=1), lmax.max(axis=1), lmin, lmax


def later_layer_moments(mu, sd):
    """Mean and second moment of the later of two independent normal closing times (Clark,
    1961): a cell completes when its later layer closes.

    Parameters
    ----------
    mu, sd : (..., 2) float, s -- each layer's mean closing time (relative to any origin) and
        its sd

    Returns
    -------
    mean, second : (...,) float, s and s^2 -- ``E[max]`` and ``E[max^2]`` about the same
        origin
    """
    from scipy.special import ndtr  # heavy: this scipy submodule loads only where it is used

    mu, sd = np.asarray(mu, float), np.asarray(sd, float)
    m1, m2, s1, s2 = mu[..., 0], mu[..., 1], sd[..., 0], sd[..., 1]
    theta = np.sqrt(s1 ** 2 + s2 ** 2)
    tie = theta <= TOL.time
    th = np.where(tie, 1.0, theta)
    a = (m1 - m2) / th
    p1, pdf = ndtr(a), np.exp(-0.5 * a * a) / math.sqrt(2.0 * math.pi)
    mean = m1 * p1 + m2 * (1.0 - p1) + th * pdf
    second = (m1 ** 2 + s1 ** 2) * p1 + (m2 ** 2 + s2 ** 2) * (1.0 - p1) + (m1 + m2) * th * pdf
    hard = np.maximum(m1, m2)
    return np.where(tie, hard, mean), np.where(tie, hard ** 2, second)


def layer_sensitivity(material, h, b0, x, f_bracket, dh: float = 0.005):
    """Each layer's completion time and its sensitivity to the bracket thickness.

    ``dt/dh`` is the central difference of :func:`completion_time` over ``+-dh`` mm (one-sided
    at the thinnest printable bracket).

    Parameters
    ----------
    h, x : (n, 2) float, mm
    b0, f_bracket : (n,) float, mm, N

    Returns
    -------
    t : (n, 2) float, s -- nominal completion time of each layer (``inf``: never)
    dtdh : (n, 2) float, s/mm -- NaN where a layer does not close within the model's range at
        ``h +- dh``
    """
    h = np.asarray(h, float)
    bb = np.repeat(np.asarray(b0, float)[:, None], 2, 1)
    ff = np.repeat(np.asarray(f_bracket, float)[:, None], 2, 1)
    t = completion_time(material, h, bb, x, ff)
    t_hi = completion_time(material, h + dh, bb, x, ff)
    t_lo = completion_time(material, np.maximum(h - dh, UNIT_CELL.thickness_min), bb, x, ff)
    step = h + dh - np.maximum(h - dh, UNIT_CELL.thickness_min)
    with np.errstate(invalid="ignore"):
        dtdh = np.where(np.isfinite(t_hi) & np.isfinite(t_lo), (t_hi - t_lo) / step, np.nan)
    return t, dtdh


def timing_sd(material, h, b0, x, f_bracket, thickness_sd: float, dh: float = 0.005):
    """Predicted sd (s) of each cell's completion time under the per-bracket thickness scatter.

    A layer's closing time scatters by ``|dt/dh| thickness_sd`` (first order,
    :func:`layer_sensitivity`); the cell completes with the later of its two independently
    printed layers, whose sd (and mean lateness over the later nominal layer) are Clark's
    (:func:`later_layer_moments`).  Two layers programmed for the same time with the same sd
    ``s`` give ``0.83 s`` and close ``0.56 s`` late on average.

    Parameters
    ----------
    h, x : (n, 2) float, mm
    b0, f_bracket : (n,) float, mm, N
    thickness_sd : float, mm

    Returns
    -------
    sd : (n,) float, s -- NaN where a layer does not close within the model's range at
        ``h +- dh``
    dtdh : (n, 2) float, s/mm
    late : (n,) float, s -- expected completion minus the later layer's nominal time
    """
    t, dtdh = layer_sensitivity(material, h, b0, x, f_bracket, dh)
    ok = np.all(np.isfinite(t) & np.isfinite(dtdh), axis=1)
    origin = np.where(ok, np.max(np.where(np.isfinite(t), t, 0.0), axis=1), 0.0)
    mu = np.where(ok[:, None], t - origin[:, None], 0.0)
    mean, second = later_layer_moments(mu, np.where(ok[:, None], np.abs(dtdh), 0.0)
                                       * thickness_sd)
    sd = np.sqrt(np.maximum(second - mean ** 2, 0.0))
    return np.where(ok, sd, np.nan), dtdh, np.where(ok, mean, np.nan)


def robust_layers(material, h, b0, x, f_bracket, t_program, layer_min,
                  thickness_sd: float, grid: int = PROGRAMMING.robust_grid,
                  max_lead: float = PROGRAMMING.robust_max_lead_s):
    """Thicknesses that lower each cell's expected squared timing error under the
    per-bracket thickness scatter, its nominal completion time kept.

    A cell completes with the later of its layers; programmed for the same time, each layer
    can be the late one.  The layer whose time is less sensitive to its thickness (smaller
    ``|dt/dh|``, :func:`layer_sensitivity`) stays at ``t_program`` and times the cell; the
    other is programmed ``delta`` s earlier (a thinner bracket), ``delta`` chosen on a grid
    of ``grid`` steps from 0 to ``min(room, 4 sqrt(s_1^2 + s_2^2), max_lead)`` to minimise
    ``E[(max(t_1, t_2) - t_program)^2]`` (:func:`later_layer_moments`, first order in the
    scatter; ``room``: down to the layer's earliest achievable time).  ``delta = 0`` is on
    the grid, so no cell is made worse by this model.

    Parameters
    ----------
    h, x : (n, 2) float, mm -- thicknesses solved for ``t_program``, target compressions
    b0, f_bracket, t_program : (n,) float, mm, N, s
    layer_min : (n, 2) float, s -- earliest completion time of each layer
    thickness_sd : float, mm
    max_lead : float, s -- ``Programming.robust_max_lead_s``: the simulator's layers are not
        independent, and a long lead costs more than the model gains

    Returns
    -------
    h : (n, 2) float, mm
    lead : (n,) float, s -- ``delta`` of each cell (0: unchanged)
    """
    h = np.asarray(h, float)
    t, dtdh = layer_sensitivity(material, h, b0, x, f_bracket)
    sd = np.abs(dtdh) * thickness_sd
    ok = np.all(np.isfinite(t) & np.isfinite(sd), axis=1) & (np.abs(t - t_program[:, None])
                                                            .max(axis=1) <= 1.0)
    timer = np.argmin(np.where(np.isfinite(sd), sd, np.inf), axis=1)
    rows = np.arange(len(h))
    other = 1 - timer
    room = np.where(ok, np.maximum(t_program - layer_min[rows, other], 0.0), 0.0)
    sd = np.where(ok[:, None], sd, 0.0)
    span = np.minimum(np.minimum(room, 4.0 * np.hypot(sd[:, 0], sd[:, 1])), max_lead)
    deltas = span[:, None] * np.linspace(0.0, 1.0, grid + 1)[None, :]       # (n, k)
    mu = np.zeros(deltas.shape + (2,))
    mu[rows, :, other] = -deltas
    sdk = np.broadcast_to(sd[:, None, :], mu.shape)
    _, second = later_layer_moments(mu, sdk)
    best = deltas[rows, np.argmin(second, axis=1)]
    h2, _ = solve_thickness(material, b0, x[rows, other], t_program - best, f_bracket)
    out = h.copy()
    move = best > 0
    out[rows[move], other[move]] = h2[move]
    return out, np.where(move, best, 0.0)


