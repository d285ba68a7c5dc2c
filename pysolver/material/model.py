"""The fitted bracket model: per-bracket force/energy polynomials on an (h, b, t) grid.

A bracket of thickness ``h`` (mm) and flat length ``b`` (mm), after ``t`` seconds in hot water,
pushes back with force ``F(x) = c1 x + c2 x^2 + c3 x^3 + c4 x^4`` (N, compression positive) when
compressed by ``x`` (mm); its elastic energy is ``W(x) = c1 x^2/2 + .. + c4 x^5/5`` (N mm).  The
coefficients ``c`` are tabulated at the grid nodes (h 0.30..0.65 step 0.05, b 0.8055 + 0.25 j for
j < 21, t 0..120 s step 6 s) and interpolated trilinearly in between (SI Note 3).

Within each cell the fit imposes ``F' >= 0`` and ``F'' <= 0`` at x = 0, 0.01, .. mm and at b
(between two points ``F''`` can exceed 0 by at most ``3 |c4| (0.01 mm)^2``, <= 0.003 N/mm^2 in
the committed model).  Trilinear interpolation uses non-negative weights inside the grid and the
corner cells share those points up to the lower b node, so interpolated polynomials keep both
properties on ``[0, b_lo]``.

Outside the grid (``outside="clamp"``, the default) each coordinate is **clamped** to the grid
range.  The reference consumer instead extrapolates linearly up to one step past the last node
and holds beyond (available as ``outside="reference"``).  Clamping is chosen because
extrapolated weights are negative and can break the monotone/concave guarantee, and because no
measurement supports the extrapolated region (t > 120 s was never resampled; h > 0.65 is not
printable); its cost is that brackets longer than b = 5.805 mm (l > 9 mm) are modelled as stiff as
b = 5.805 mm.  ``BracketModel.in_grid`` tells callers when they are outside.

Plasticity (SI eq. 6, 7): with plastic fraction ``eta`` the elastic part of a compression ``x``
measured from the plastically shifted rest length is ``x / (1 - eta)`` of the envelope, so
``F_eta(x) = F(x / (1 - eta))``, ``W_eta(x) = (1 - eta) W(x / (1 - eta))``; the rest length
follows :func:`plastic_rest_length`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..params import BRACKET_MODEL_FILE, PAPER_BRACKET_HEIGHT_MM, SIM, UNIT_CELL, UnitCell
from ..params import tol as TOL
from .creep import CreepModel
from .polyfit import poly_energy, poly_force, poly_stiffness
from .validate import validate_bracket_model_file

OUTSIDE_MODES = ("clamp", "reference")
_POW = np.arange(1, 5)


def plastic_rest_length(rest, rest0, length, eta: float = SIM.eta):
    """Rest-length update of the elasto-plastic bracket spring.

    ``rest_new = min(rest, rest0 - eta * (rest0 - length))``: the plastic set is ``eta`` times
    the largest compression reached; the rest length never grows back.

    Parameters
    ----------
    rest : (n,) float, mm
        Current rest length.
    rest0 : (n,) float, mm
        Initial (flat) rest length b.
    length : (n,) float, mm
        Current length (previous equilibrium).
    eta : float
        Plastic fraction (0.2).

    Returns
    -------
    (n,) float, mm
    """
    rest, rest0, length = np.broadcast_arrays(np.asarray(rest, float), np.asarray(rest0, float),
                                              np.asarray(length, float))
    return np.minimum(rest, rest0 - eta * (rest0 - length))


class BracketModel:
    """Per-bracket force, energy and stiffness of the fitted model (vectorised).

    Every method broadcasts its array arguments together; the result has the broadcast shape.
    Time is in **seconds** in hot water; lengths in mm; forces in N per single bracket
    (a test specimen has 4).

    Parameters
    ----------
    grid_min, grid_step : (3,) float
        Grid origin and spacing along (h mm, b mm, t s).
    coef : (nh, nb, nt, 4) float
        Force coefficients of x^1..x^4 per node (N mm^-k).
    outside : {"clamp", "reference"}
        Behaviour outside the grid (module docstring).
    meta : dict, optional
        The rest of the model file (provenance, residuals, creep model).
    """

    def __init__(self, grid_min, grid_step, coef, outside: str = "clamp", meta=None):
        if outside not in OUTSIDE_MODES:
            raise InputError(f"outside must be one of {OUTSIDE_MODES}, got {outside!r}.")
        self.grid_min = np.asarray(grid_min, float)
        self.grid_step = np.asarray(grid_step, float)
        self.coef = np.ascontiguousarray(coef, dtype=float)
        self.grid_num = np.array(self.coef.shape[:3])
        self.outside = outside
        self.meta = {} if meta is None else meta
        self.path = None

    # -- grid -------------------------------------------------------------------------------------
    @property
    def grid_max(self) -> np.ndarray:
        """Last grid node along (h, b, t)."""
        return self.grid_min + self.grid_step * (self.grid_num - 1)

    def axes(self):
        """Grid nodes ``(h (nh,) mm, b (nb,) mm, t (nt,) s)``."""
        return tuple(self.grid_min[k] + self.grid_step[k] * np.arange(self.grid_num[k])
                     for k in range(3))

    def in_grid(self, h_mm, b_mm, t_s):
        """True where (h, b, t) lies inside the tabulated grid (no clamping/extrapolation)."""
        h, b, t = np.broadcast_arrays(*(np.asarray(v, float) for v in (h_mm, b_mm, t_s)))
        eps = TOL.rel
        lo, hi = self.grid_min - eps, self.grid_max + eps
        return ((h >= lo[0]) & (h <= hi[0]) & (b >= lo[1]) & (b <= hi[1]) & (t >= lo[2])
                & (t <= hi[2]))

    def _locate(self, p, axis):
        """Cell index (lower node) and fraction along one axis, with the outside rule."""
        n = int(self.grid_num[axis])
        u = (p - self.grid_min[axis]) / self.grid_step[axis]
        u = np.clip(u, 0.0, (n - 1) if self.outside == "clamp" else n)
        i = np.minimum(np.floor(u).astype(np.int64), n - 2)
        return i, u - i

    # -- coefficients -----------------------------------------------------------------------------
    def coefficients(self, h_mm, b_mm, t_s, eta: float = 0.0):
        """Force-polynomial coefficients of single brackets.

        Parameters
        ----------
        h_mm, b_mm : array_like, mm
            Thickness and flat bracket length (broadcast together with ``t_s``).
        t_s : array_like, s
            Time in hot water.
        eta : float
            Plastic fraction; the coefficients of ``F(x / (1 - eta))`` are returned
            (``c_k / (1 - eta)^k``).

        Returns
        -------
        c : (..., 4) float, N mm^-k
            Coefficients of x^1..x^4; ``F(x) = poly_force(c, x)``. For 1-d inputs of length n
            this is (n, 4).
        """
        h, b, t = np.broadcast_arrays(*(np.asarray(v, float) for v in (h_mm, b_mm, t_s)))
        shape = h.shape
        h, b, t = h.ravel(), b.ravel(), t.ravel()
        (ih, ah), (ib, ab), (it, at) = self._locate(h, 0), self._locate(b, 1), self._locate(t, 2)
        out = np.zeros((len(h), 4))
        for dh in (0, 1):
            wh = ah if dh else 1.0 - ah
            for db in (0, 1):
                wb = ab if db else 1.0 - ab
                for dt in (0, 1):
                    wt = at if dt else 1.0 - at
                    out += (wh * wb * wt)[:, None] * self.coef[ih + dh, ib + db, it + dt]
        if eta:
            out = out / (1.0 - eta) ** _POW
        return out.reshape(shape + (4,))

    def energy_coefficients(self, h_mm, b_mm, t_s, eta: float = 0.0):
        """Energy coefficients of x^2..x^5 (N mm^(1-k)), shape (..., 4).

        With ``eta`` they are those of ``(1 - eta) W(x / (1 - eta))``.
        """
        c = self.coefficients(h_mm, b_mm, t_s, eta)
        return c / (_POW + 1)

    # -- evaluation -------------------------------------------------------------------------------
    def force(self, h_mm, b_mm, t_s, x_mm, eta: float = 0.0):
        """Bracket force (N, compression positive) at compression ``x_mm`` (mm).

        Parameters
        ----------
        h_mm, b_mm : array_like, mm
        t_s : array_like, s
        x_mm : array_like, mm
            Compression (rest length minus current length); negative = tension (the polynomial
            is evaluated as is).
        eta : float
            Plastic fraction: returns ``F(x / (1 - eta))``.

        Returns
        -------
        array, N
        """
        c = self.coefficients(h_mm, b_mm, t_s)
        return poly_force(c, np.asarray(x_mm, float) / (1.0 - eta))

    def energy(self, h_mm, b_mm, t_s, x_mm, eta: float = 0.0):
        """Elastic energy (N mm) at compression x: ``(1 - eta) W(x / (1 - eta))``."""
        c = self.coefficients(h_mm, b_mm, t_s)
        return (1.0 - eta) * poly_energy(c, np.asarray(x_mm, float) / (1.0 - eta))

    def stiffness(self, h_mm, b_mm, t_s, x_mm, eta: float = 0.0):
        """``dF/dx`` (N/mm) at compression x, i.e. ``F'(x / (1 - eta)) / (1 - eta)``."""
        c = self.coefficients(h_mm, b_mm, t_s)
        return poly_stiffness(c, np.asarray(x_mm, float) / (1.0 - eta)) / (1.0 - eta)

    def thickness_for_force(self, b_mm, x_mm, t_s, force_N, eta: float = 0.0):
        """Thickness whose bracket force at compression x and time t equals ``force_N``.

        Force is piecewise linear in h between the h nodes (trilinear interpolation), so the
        solution is exact: the first node interval (from thin to thick) whose end forces bracket
        the target is solved linearly.  Targets below the force at h = 0.30 mm or above the
        force at h = 0.65 mm are clamped to that end.

        Parameters
        ----------
        b_mm : array_like, mm
        x_mm : array_like, mm
            Required compression (flat length minus target length).
        t_s : array_like, s
        force_N : array_like, N
            Target force per bracket.

        Returns
        -------
        h : array, mm
            In [thickness_min, thickness_max] = [0.30, 0.65].
        clamped : array of bool
            True where the target lies outside the printable range's forces.
        """
        b, x, t, f = np.broadcast_arrays(*(np.asarray(v, float) for v in
                                           (b_mm, x_mm, t_s, force_N)))
        shape = b.shape
        b, x, t, f = b.ravel(), x.ravel(), t.ravel(), f.ravel()
        hmin, hmax = UNIT_CELL.thickness_min, UNIT_CELL.thickness_max
        hn = self.axes()[0]
        hn = hn[(hn >= hmin - TOL.rel) & (hn <= hmax + TOL.rel)]
        Fn = np.stack([self.force(hk, b, t, x, eta) for hk in hn], axis=1)  # (n, nh)
        h = np.full(len(b), np.nan)
        lo, hi = f < Fn[:, 0], f > Fn[:, -1]
        h[lo], h[hi] = hmin, hmax
        todo = ~(lo | hi)
        for k in range(len(hn) - 1):
            f0, f1 = Fn[:, k], Fn[:, k + 1]
            hit = todo & (np.minimum(f0, f1) <= f) & (f <= np.maximum(f0, f1))
            den = np.where(f1 != f0, f1 - f0, 1.0)
            a = np.where(f1 != f0, (f - f0) / den, 0.0)
            h[hit] = hn[k] + a[hit] * (hn[k + 1] - hn[k])
            todo &= ~hit
        # non-monotone ends (f between the end forces but never bracketed): nearest end
        h[todo] = np.where(np.abs(f[todo] - Fn[todo, 0]) <= np.abs(f[todo] - Fn[todo, -1]),
                           hmin, hmax)
        return h.reshape(shape), (lo | hi).reshape(shape)

    def compression_for_force(self, h_mm, b_mm, t_s, force_N, iters: int = 60):
        """Invert the force polynomial on [0, b]: compression x (mm) with F(x) = force_N.

        Uses bisection (the polynomial is monotone on [0, b] at grid nodes); targets above
        F(b) return b.
        """
        h, b, t, f = np.broadcast_arrays(*(np.asarray(v, float) for v in
                                           (h_mm, b_mm, t_s, force_N)))
        c = self.coefficients(h, b, t)
        lo, hi = np.zeros(h.shape), b.copy()
        for _ in range(iters):
            mid = 0.5 * (lo + hi)
            below = poly_force(c, mid) < f
            lo = np.where(below, mid, lo)
            hi = np.where(below, hi, mid)
        return 0.5 * (lo + hi)

    # -- creep model (specimen level) ------------------------------------------------------------
    def creep_model(self):
        """The fitted displacement model of SI eq. 9 (:class:`CreepModel`), if stored."""
        if "creep_model" not in self.meta:
            raise InputError("this model file has no creep model (p_dry/p_wet).")
        return CreepModel.from_dict(self.meta["creep_model"])

    def __repr__(self) -> str:
        return (f"BracketModel(grid {tuple(int(v) for v in self.grid_num)}, outside="
                f"{self.outside!r}, file={str(self.path) if self.path else None!r})")

    # -- io ---------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return model_dict(self.grid_min, self.grid_step, self.coef, self.meta)


class CompliantBracketModel:
    """A bracket model ``s`` times as compliant as ``base``: ``F_s(x) = F(x / s)``.

    Parameters
    ----------
    base : BracketModel
        Anything with ``coefficients(h_mm, b_mm, t_s, eta) -> (n, 4)``.
    scale : float or (n,) float
        Compliance factor ``s > 0`` (1 = the base model).
    """

    def __init__(self, base, scale):
        s = np.asarray(scale, float)
        if not np.all(np.isfinite(s) & (s > 0)):
            raise InputError(f"compliance factor {scale!r}", fix="use a positive number")
        self.base = base
        self.scale = s
        self.path = getattr(base, "path", None)

    def coefficients(self, h_mm, b_mm, t_s, eta: float = 0.0):
        """Force coefficients of ``x^1..x^4`` (N mm^-k), shape ``(n, 4)``."""
        c = np.asarray(self.base.coefficients(h_mm, b_mm, t_s, eta=eta), float)
        s = self.scale if self.scale.ndim == 0 else self.scale[:, None]
        return c / s ** _POW

    @property
    def grid_max(self) -> np.ndarray:
        """Last grid node of the base model along (h mm, b mm, t s)."""
        return self.base.grid_max

    def force(self, h_mm, b_mm, t_s, x_mm):
        """Bracket force (N) at compression ``x_mm`` (mm): ``F(x / s)`` of the base model."""
        c = self.coefficients(h_mm, b_mm, t_s)
        return poly_force(c, np.asarray(x_mm, float))


def model_dict(grid_min, grid_step, coef, meta) -> dict:
    """The JSON object of a model file (see ``docs`` in the file itself)."""
    d = {"format": "morphshell.bracket_model", "format_version": 1,
         "description": "Per-bracket force polynomials F(x) = sum_k c_k x^k, k = 1..4 (N, x in "
                        "mm, compression positive) on a regular (thickness, bracket length, "
                        "time in water) grid, interpolated trilinearly; energy W = "
                        "sum_k c_k x^(k+1)/(k+1) (N mm). Fitted from unit-cell tests (4 brackets "
                        "per specimen) by pysolver.fitting.material_fit (SI Note 3).",
         "units": {"thickness": "mm", "bracket_length": "mm", "time": "s", "x": "mm",
                   "force": "N", "energy": "N mm"},
         "grid": {"axes": ["thickness_mm", "bracket_length_mm", "time_s"],
                  "min": [float(v) for v in grid_min], "step": [float(v) for v in grid_step],
                  "num": [int(v) for v in np.shape(coef)[:3]]},
         "force_coefficients": {"powers": [1, 2, 3, 4], "per": "bracket",
                                "layout": "nested [i_thickness][i_length][i_time][k]",
                                "data": np.asarray(coef).tolist()}}
    d.update(meta)
    return d


def bracket_record(model: BracketModel, unit: UnitCell = UNIT_CELL) -> dict:
    """The bracket geometry a model is fitted for, as its file records it (``"bracket"``):
    ``height_mm`` (out of plane, :attr:`UnitCell.bracket_w`) and ``width_mm`` (the in-plane
    thickness range of the fit grid)."""
    return {"height_mm": float(unit.bracket_w),
            "width_mm": [float(model.grid_min[0]), float(model.grid_max[0])]}


def check_bracket_geometry(model, unit: UnitCell = UNIT_CELL, source: str = "") -> None:
    """Refuse a material model fitted for other brackets than the unit cell's.

    The model's ``"bracket"`` record (height and width range it was fitted for) must match
    :attr:`UnitCell.bracket_w` and cover ``thickness_min``-``thickness_max``.  A file
    without the record predates it and was fitted on the paper's 1 mm brackets
    (:data:`pysolver.params.PAPER_BRACKET_HEIGHT_MM`).  Model objects without ``meta``
    (test stand-ins) are not checked.

    Raises
    ------
    InputError
        Naming both geometries, with the fix (``make material``).
    """
    meta = getattr(model, "meta", None)
    if meta is None:
        return
    rec = meta.get("bracket") or {}
    height = float(rec.get("height_mm", PAPER_BRACKET_HEIGHT_MM))
    width = rec.get("width_mm")
    where = source or getattr(model, "path", None) or "the material model"
    fix = ("fit a material model for these brackets from their tensile tests: make material "
           "(morphshell fit-material), then build with --material FILE; or restore the "
           "bracket dimensions the model was fitted for in pysolver/params (UnitCell)")
    if abs(height - unit.bracket_w) > TOL.merge:
        raise InputError(f"{where} was fitted for brackets {height:g} mm high; the unit cell "
                         f"has {unit.bracket_w:g} mm brackets (UnitCell.bracket_w)", fix=fix)
    if width is not None and (unit.thickness_min < width[0] - TOL.merge
                              or unit.thickness_max > width[1] + TOL.merge):
        raise InputError(f"{where} was fitted for bracket widths {width[0]:g}-{width[1]:g} mm; "
                         f"the unit cell prints {unit.thickness_min:g}-"
                         f"{unit.thickness_max:g} mm", fix=fix)


def load_bracket_model(path=None, outside: str = "clamp") -> BracketModel:
    """Load a fitted bracket model file.

    Parameters
    ----------
    path : path-like, optional
        Model JSON (default: the committed ``pysolver/data/bracket_model.json``).
    outside : {"clamp", "reference"}
        Behaviour outside the grid (see module docstring).

    Returns
    -------
    BracketModel

    Raises
    ------
    InputError
        Missing or malformed file, or a model that breaks a rule of
        :mod:`pysolver.material.validate` (the message names the key and the rule).
    """
    path = Path(BRACKET_MODEL_FILE if path is None else path)
    v = validate_bracket_model_file(path)
    meta = {k: val for k, val in v["data"].items()
            if k not in ("format", "format_version", "description", "units", "grid",
                         "force_coefficients")}
    m = BracketModel(v["grid_min"], v["grid_step"], v["coef"], outside=outside, meta=meta)
    m.path = path
    return m
