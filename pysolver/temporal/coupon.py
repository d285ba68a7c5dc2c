"""The timing coupon: a strip of unit cells timed in the bath, and the fit of its times.

A printed shell closes late or early mostly because of factors that move every cell of a
print together: the bracket material of this spool and printer (its compliance) and the
latex sheet (its modulus) (``docs/tolerance.md``).  The coupon measures them before the
shell is printed.  It is the paper's flat test patch (:func:`pysolver.design.surfaces.regular`)
cut to a strip of :class:`pysolver.params.Coupon` ``rows x cols`` triangles of 9 mm cells,
rendered by the render stage from the shells' own SCAD modules.  Each cell that the shipped
model closes within its time range is *timed*: it gets a label and a bracket thickness, the
labels spread over the printable thicknesses (``docs/coupon.md``).

The time model is the programming's own (:mod:`pysolver.temporal.program`): a layer of a cell
closes when its bracket force at the target compression ``x`` falls to the membrane's pull
``F_mem(b0, d1) k / 4`` (``k``: the per-cell FEM factor of the coupon's own stencil).  A print
is described by two factors:

* ``s``, the bracket compliance: brackets ``s`` times as compliant,
  ``F_s(x) = F(x / s)`` (:class:`pysolver.material.model.CompliantBracketModel`, the same
  factor as the tolerance analysis draws);
* ``m``, the membrane modulus factor: the membrane pulls ``m`` times as hard.

:func:`fit_coupon` fits ``ln s`` (and ``ln m`` where the data separate them) to the measured
closing times by least squares, with confidence intervals from the Jacobian.
:func:`calibrated_model` writes them into a bracket model file that the build accepts
(``--material``): coefficients ``c_k / (m s^k)``.  Dividing the bracket force by ``m`` is what
a membrane ``m`` times as strong does to every force balance of the programming (the bracket
and the membrane pull against each other), so the build programs with the fitted print without
a second model file.

The pre-stretch is not a coupon factor: near ``tau = 3`` the membrane stress hardly depends on
it (``1 - tau^-6``; 0.1 % of the timing variance in the tolerance analysis).
"""

from __future__ import annotations

import csv
import hashlib
import io
import math

import numpy as np
from scipy import optimize, stats

from ..core.records import json_text
from ..core.writes import atomic_write_text
from ..design.time_landscape import read_option_text
from ..errors import InputError
from ..material.model import CompliantBracketModel, model_dict
from ..params import COUPON, TOLERANCE_RUN, UNCERTAINTY, UNIT_CELL, Coupon
from ..tables import read_table
from .membrane_model import load_membrane_model
from .program import (
    bracket_target_force,
    completion_time,
    later_layer_moments,
    load_material,
    membrane_factors,
    solve_thickness,
    target_compressions,
    time_limit,
)

CSV_NAME = "coupon.csv"
"""The coupon's table, written beside its STLs; the maker fills in ``closing_time_s``."""
COLUMNS = ("label", "cell_id", "thickness_top_mm", "thickness_bottom_mm",
           "bracket_length_mm", "compression_top_mm", "compression_bottom_mm",
           "target_force_N", "predicted_s", "closing_time_s")
"""Columns of :data:`CSV_NAME`, in order (``docs/coupon.md``)."""
MEASURED = "closing_time_s"
NEVER = "never"
"""``closing_time_s`` of a cell that had not closed when the coupon left the bath (a
right-censored time: the fit only asks the model not to close it earlier)."""
CSV_FIX = ("fill in closing_time_s (seconds from the moment the coupon enters the bath until "
           "the cell's bumpers touch) for every row of the coupon.csv that 'morphshell coupon' "
           "wrote, and keep its other columns as written (docs/coupon.md)")
CALIBRATION_FORMAT = "morphshell.coupon_calibration"


def coupon_source(coupon: Coupon = COUPON) -> str:
    """The coupon's shape, as the design stage reads it (a strip of the built-in ``regular``)."""
    return (f"regular:rows={coupon.rows},cols={coupon.cols},"
            f"central_length={coupon.central_length_mm:g}")


# ----------------------------------------------------------------------------------------------
# the time model


def cell_geometry(design_dir, membrane=None) -> dict:
    """What the time model needs of each cell of a design folder.

    Returns
    -------
    dict
        ``cell_id`` (n,) int, ``b0`` (n,) mm (flat bracket length), ``x`` (n, 2) mm (target
        compression, top and bottom), ``f_bracket`` (n,) N (the membrane's pull per bracket,
        FEM-corrected), ``boundary`` (n,) bool.
    """
    cells = read_table(design_dir, "cells")
    membrane = load_membrane_model() if membrane is None else membrane
    factor, _ = membrane_factors(design_dir, cells, membrane)
    b0 = np.asarray(cells["bracket_length_mm"], float)
    x, d1 = target_compressions(b0, cells["collision_length_top_mm"],
                                cells["collision_length_bottom_mm"])
    _, f_br = bracket_target_force(membrane, b0, d1, cells["boundary"], factor=factor)
    return {"cell_id": np.asarray(cells["cell_id"], int), "b0": b0, "x": x, "f_bracket": f_br,
            "boundary": np.asarray(cells["boundary"], bool)}


def closing_times(material, b0, x, f_bracket, thickness, compliance=1.0, modulus=1.0):
    """Closing time of each cell (the later of its two layers) for a print.

    Parameters
    ----------
    material : bracket model (``force(h, b, t, x)``, ``grid_max``)
    b0 : (n,) float, mm
    x : (n, 2) float, mm -- target compression per layer
    f_bracket : (n,) float, N -- the nominal membrane pull per bracket
    thickness : (n, 2) float, mm
    compliance : float or (n,) float -- bracket compliance factor ``s``
    modulus : float or (n,) float -- membrane modulus factor ``m``

    Returns
    -------
    t : (n,) float, s
        ``inf`` where a layer never closes within the model's time range.
    """
    mat = material if np.all(np.asarray(compliance) == 1.0) else CompliantBracketModel(
        material, compliance)
    b0 = np.asarray(b0, float)
    f = np.asarray(f_bracket, float) * np.asarray(modulus, float)
    th = np.asarray(thickness, float)
    t = completion_time(mat, th, np.repeat(b0[:, None], 2, 1), np.asarray(x, float),
                        np.repeat(np.broadcast_to(f, b0.shape)[:, None], 2, 1))
    return t.max(axis=1)


def expected_closing_times(material, b0, x, f_bracket, thickness, compliance=1.0, modulus=1.0,
                           thickness_sd: float = UNCERTAINTY.thickness_sd):
    """Expected closing time of each cell of a print whose brackets scatter by
    ``thickness_sd`` each: the later of two independently printed layers closes late on
    average.

    Each layer's mean and sd under ``h + N(0, thickness_sd)`` by three-point Gauss-Hermite
    quadrature (nodes ``h``, ``h +- sqrt(3) thickness_sd``: the mean exact for a closing time
    cubic in the thickness, the sd for one quadratic, so the curvature of ``t(h)`` counts, not
    only its slope), then the later
    layer's mean by Clark's moments (:func:`pysolver.temporal.cell_time.later_layer_moments`).

    Parameters are :func:`closing_times`' (``compliance`` and ``modulus`` scalars), and
    ``thickness_sd`` (float, mm).

    Returns
    -------
    t : (n,) float, s -- the nominal time (:func:`closing_times`) where a layer does not close
        within the model's range at one of the nodes (``inf`` where it never closes).
    """
    t = closing_times(material, b0, x, f_bracket, thickness, compliance, modulus)
    if thickness_sd <= 0:
        return t
    mat = material if compliance == 1.0 else CompliantBracketModel(material, compliance)
    b0 = np.asarray(b0, float)
    bb = np.repeat(b0[:, None], 2, 1)
    ff = np.repeat((np.asarray(f_bracket, float) * float(modulus))[:, None], 2, 1)
    h = np.asarray(thickness, float)
    k = math.sqrt(3.0) * thickness_sd
    lo, mid, hi = (completion_time(mat, np.maximum(h + dh, TOLERANCE_RUN.thickness_floor_mm), bb,
                                   np.asarray(x, float), ff) for dh in (-k, 0.0, k))
    ok = np.all(np.isfinite(lo) & np.isfinite(mid) & np.isfinite(hi), axis=1)
    with np.errstate(invalid="ignore"):
        mean = (lo + 4.0 * mid + hi) / 6.0
        sd = np.sqrt(np.maximum((lo ** 2 + 4.0 * mid ** 2 + hi ** 2) / 6.0 - mean ** 2, 0.0))
    origin = np.where(ok, mid.max(axis=1), 0.0)
    m, _ = later_layer_moments(np.where(ok[:, None], mean - origin[:, None], 0.0),
                               np.where(ok[:, None], sd, 0.0))
    return np.where(ok, origin + m, t)


# ----------------------------------------------------------------------------------------------
# the coupon's thicknesses and table


def spread_order(n: int) -> np.ndarray:
    """Fractions in [0, 1] for ``n`` items, evenly spaced, ordered so that neighbours in the
    list are far apart (the golden-ratio sequence's ranks): (n,) float."""
    if n <= 1:
        return np.zeros(n)
    key = (np.arange(n) * (math.sqrt(5.0) - 1.0) / 2.0) % 1.0
    return np.argsort(np.argsort(key)) / (n - 1)


def coupon_thicknesses(material, geom: dict, coupon: Coupon = COUPON):
    """Bracket thicknesses of the coupon's cells, spread over what each cell can time.

    A cell is timed when its thinnest bracket closes at least ``time_margin_s`` before the end
    of the model's time range.  Its thickest timed bracket is the one that closes then
    (at most ``thickness_max``).  The timed cells of each kind (interior, boundary) take
    evenly spaced fractions of their own thickness range (:func:`spread_order`, so that
    neighbouring cells differ): the interior cells span the whole printable range.

    Returns
    -------
    thickness : (n, 2) float, mm
    timed : (n,) bool
    """
    b0, x, f = geom["b0"], geom["x"], geom["f_bracket"]
    n = len(b0)
    t_last = time_limit(material) - coupon.time_margin_s
    h_min = np.full((n, 2), UNIT_CELL.thickness_min)
    timed = closing_times(material, b0, x, f, h_min) <= t_last
    bb, ff = np.repeat(b0[:, None], 2, 1), np.repeat(f[:, None], 2, 1)
    h_max, _ = solve_thickness(material, bb, x, np.full((n, 2), t_last), ff)
    u = np.zeros(n)
    for kind in (True, False):
        sel = np.flatnonzero(timed & (geom["boundary"] == kind))
        u[sel] = spread_order(len(sel))
    th = h_min + u[:, None] * (h_max - h_min)
    return np.where(timed[:, None], th, h_min), timed


def coupon_rows(geom: dict, thickness, timed, material) -> list[dict]:
    """The rows of :data:`CSV_NAME`: one per timed cell, labelled 1, 2, ... in cell order,
    with the shipped model's predicted closing time; ``closing_time_s`` left empty."""
    t = closing_times(material, geom["b0"], geom["x"], geom["f_bracket"], thickness)
    rows = []
    for k, j in enumerate(np.flatnonzero(timed)):
        rows.append({"label": str(k + 1), "cell_id": int(geom["cell_id"][j]),
                     "thickness_top_mm": float(thickness[j, 0]),
                     "thickness_bottom_mm": float(thickness[j, 1]),
                     "bracket_length_mm": float(geom["b0"][j]),
                     "compression_top_mm": float(geom["x"][j, 0]),
                     "compression_bottom_mm": float(geom["x"][j, 1]),
                     "target_force_N": float(geom["f_bracket"][j]),
                     "predicted_s": float(t[j]), "closing_time_s": ""})
    return rows


def coupon_csv_text(rows: list[dict]) -> str:
    """The text of :data:`CSV_NAME` (header, then one line per row; ``%.9g`` numbers)."""
    out = [",".join(COLUMNS)]
    for r in rows:
        out.append(",".join(v if isinstance(v, str) else str(v) if isinstance(v, int)
                            else f"{v:.9g}" for v in (r[c] for c in COLUMNS)))
    return "\n".join(out) + "\n"


# ----------------------------------------------------------------------------------------------
# reading the measured coupon


def _number(text: str, where: str, column: str) -> float:
    """A finite number from a CSV field (parsed, never evaluated)."""
    s = text.strip()
    try:
        v = float(s)
    except ValueError:
        raise InputError(f"{where}: {column} = {s[:40]!r} is not a number",
                         fix=CSV_FIX) from None
    if not math.isfinite(v):
        raise InputError(f"{where}: {column} = {s[:40]!r} is not a finite number", fix=CSV_FIX)
    return v


def read_coupon_csv(path) -> dict:
    """Read a measured coupon table (:data:`COLUMNS`), refusing anything malformed.

    Returns
    -------
    dict
        ``label`` (n,) str, ``cell_id`` (n,) int, ``thickness`` (n, 2) mm, ``b0`` (n,) mm,
        ``x`` (n, 2) mm, ``f_bracket`` (n,) N, ``predicted`` (n,) s, ``t`` (n,) s (measured;
        NaN where blank, refused by :func:`check_fit_data`), ``sha256`` of the file.

    Raises
    ------
    InputError
        Not a small UTF-8 file, a missing column, a field that is not a finite number, a
        repeated cell, or geometry no coupon has (naming the file, line and column).
    """
    text, data = read_option_text(path, "coupon CSV", CSV_FIX)
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        raise InputError(f"coupon CSV {path}: the file is empty", fix=CSV_FIX)
    header = [h.strip() for h in rows[0]]
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise InputError(f"coupon CSV {path}: no column {', '.join(missing)} in the header "
                         f"{header[:12]}", fix=CSV_FIX)
    idx = {c: header.index(c) for c in COLUMNS}
    body = [(i + 2, r) for i, r in enumerate(rows[1:]) if any(f.strip() for f in r)]
    vals = {c: [] for c in COLUMNS if c != "label"}
    labels = []
    for line, r in body:
        where = f"coupon CSV {path}:{line}"
        if len(r) < len(header):
            raise InputError(f"{where}: {len(r)} fields, the header has {len(header)}",
                             fix=CSV_FIX)
        labels.append(r[idx["label"]].strip()[:20])
        for c in vals:  # blank: not timed yet (refused by the fit); NEVER: did not close
            word = r[idx[c]].strip().lower() if c == MEASURED else None
            vals[c].append(math.nan if word == "" else math.inf if word == NEVER
                           else _number(r[idx[c]], where, c))
    out = _coupon_arrays(labels, vals)
    _check_geometry(out, path)
    out["sha256"] = hashlib.sha256(data).hexdigest()
    return out


def _coupon_arrays(labels, vals: dict) -> dict:
    a = {c: np.asarray(v, float) for c, v in vals.items()}
    return {"label": np.asarray(labels, dtype=object), "cell_id": a["cell_id"],
            "thickness": np.c_[a["thickness_top_mm"], a["thickness_bottom_mm"]].reshape(-1, 2),
            "b0": a["bracket_length_mm"],
            "x": np.c_[a["compression_top_mm"], a["compression_bottom_mm"]].reshape(-1, 2),
            "f_bracket": a["target_force_N"], "predicted": a["predicted_s"], "t": a[MEASURED]}


def _check_geometry(d: dict, path) -> None:
    """Refuse rows whose geometry no coupon has (a hand edit of the written columns)."""
    cid = d["cell_id"]
    for i in range(len(cid)):
        where = f"coupon CSV {path}:{i + 2}"
        if cid[i] != round(cid[i]) or cid[i] < 0:
            raise InputError(f"{where}: cell_id = {cid[i]:g} is not a cell number", fix=CSV_FIX)
        if np.sum(cid == cid[i]) > 1:
            raise InputError(f"{where}: cell {int(cid[i])} appears twice", fix=CSV_FIX)
        h, b, x, f = d["thickness"][i], d["b0"][i], d["x"][i], d["f_bracket"][i]
        if not np.all((h > 0) & (h < UNIT_CELL.bracket_w)):
            raise InputError(f"{where}: thickness {h.tolist()} mm is outside (0, "
                             f"{UNIT_CELL.bracket_w:g}) mm", fix=CSV_FIX)
        if not (b > 0 and np.all((x > 0) & (x < b)) and f > 0):
            raise InputError(f"{where}: bracket length {b:g} mm, compressions {x.tolist()} mm "
                             f"and force {f:g} N are not a unit cell's", fix=CSV_FIX)


# ----------------------------------------------------------------------------------------------
# the fit


def check_fit_data(d: dict, material, coupon: Coupon = COUPON) -> None:
    """Refuse measured times that cannot support a fit (exit code 2), saying why.

    Raises
    ------
    InputError
        Fewer than ``min_cells`` cells, a thickness range under ``min_thickness_spread_mm``,
        or a time that is not in (0, end of the model's time range] s.
    """
    n = int(np.sum(np.isfinite(d["t"])))
    if n < coupon.min_cells:
        raise InputError(f"{n} cell(s) with a closing time; a fit needs at least "
                         f"{coupon.min_cells}", fix="time every labelled cell of the coupon "
                         "(docs/coupon.md)")
    spread = float(np.ptp(d["thickness"]))
    if spread < coupon.min_thickness_spread_mm:
        raise InputError(f"the cells' bracket thicknesses span only {spread:.3f} mm; the fit "
                         f"needs at least {coupon.min_thickness_spread_mm:g} mm to tell the "
                         "factors from the thickness", fix="time the cells of the whole "
                         "coupon, thin and thick (docs/coupon.md)")
    empty = np.flatnonzero(np.isnan(d["t"]))
    if len(empty):
        i = int(empty[0])
        raise InputError(f"cell {d['label'][i]} (line {i + 2}) has no closing time", fix=CSV_FIX)
    t_end = time_limit(material)
    bad = np.flatnonzero(~(((d["t"] > 0) & (d["t"] <= t_end)) | np.isposinf(d["t"])))
    if len(bad):
        i = int(bad[0])
        raise InputError(f"cell {d['label'][i]} (line {i + 2}): closing time {d['t'][i]:g} s is "
                         f"outside (0, {t_end:g}] s, the time range of the material model",
                         fix="give seconds from the moment the coupon enters the bath; a cell "
                             "that has not closed after that long is a failed bath (check the "
                             "water temperature) or a mistyped time")


def _residuals(p, d: dict, material, t_cap: float, late):
    s = math.exp(p[0])
    m = math.exp(p[1]) if len(p) > 1 else 1.0
    t = closing_times(material, d["b0"], d["x"], d["f_bracket"], d["thickness"], s, m) + late
    t = np.where(np.isfinite(t), t, t_cap)
    never = np.isposinf(d["t"])  # censored: only a model closing it in the bath is an error
    return np.where(never, np.minimum(t - time_limit(material), 0.0),
                    t - np.where(never, 0.0, d["t"]))


def _lateness(d: dict, material, p, thickness_sd: float) -> np.ndarray:
    """Each cell's mean lateness (n,) s under the per-bracket scatter ``thickness_sd`` (mm)
    at the factors ``p`` (``(ln s[, ln m])``): :func:`expected_closing_times` minus
    :func:`closing_times`; 0 where either is not finite."""
    s = math.exp(p[0])
    m = math.exp(p[1]) if len(p) > 1 else 1.0
    args = (material, d["b0"], d["x"], d["f_bracket"], d["thickness"], s, m)
    with np.errstate(invalid="ignore"):  # inf - inf: a cell that never closes
        late = expected_closing_times(*args, thickness_sd) - closing_times(*args)
    return np.where(np.isfinite(late), late, 0.0)


def _fit(d: dict, material, n_par: int, coupon: Coupon, late=0.0) -> dict:
    """Least squares in ``(ln s[, ln m])``, each cell's model time plus its mean lateness
    ``late`` (s, (n,) or 0); covariance from the Jacobian and the residual sd (floored at the
    reading error)."""
    lo = [math.log(coupon.compliance_bounds[0]), math.log(coupon.modulus_bounds[0])][:n_par]
    hi = [math.log(coupon.compliance_bounds[1]), math.log(coupon.modulus_bounds[1])][:n_par]
    t_cap = 2.0 * time_limit(material)
    r = optimize.least_squares(_residuals, np.zeros(n_par), bounds=(lo, hi), method="trf",
                               diff_step=1e-3, x_scale=0.1, args=(d, material, t_cap, late))
    n = int(np.sum(np.isfinite(d["t"])))
    dof = max(n - n_par, 1)
    sd = max(math.sqrt(float(r.fun @ r.fun) / dof), coupon.reading_sd_s)
    jtj = r.jac.T @ r.jac
    try:
        cov = np.linalg.inv(jtj) * sd ** 2
    except np.linalg.LinAlgError:
        cov = np.full((n_par, n_par), np.inf)
    at_bound = bool(np.any(np.isclose(r.x, lo, atol=1e-6) | np.isclose(r.x, hi, atol=1e-6)))
    return {"p": r.x, "cov": cov, "sd_s": sd, "dof": dof, "at_bound": at_bound,
            "rms_s": math.sqrt(float(r.fun @ r.fun) / n), "residuals": r.fun}


def _fit_later_layer(d: dict, material, coupon: Coupon,
                     thickness_sd: float) -> tuple[dict, np.ndarray]:
    """The compliance fitted to the cells' expected closing times (:attr:`Coupon.later_layer`):
    the lateness is evaluated at the current fit and the fit repeated
    (:attr:`Coupon.later_layer_rounds` times).  Returns (fit, lateness (n,) s)."""
    late = np.zeros(len(d["t"]))
    fit = _fit(d, material, 1, coupon, late)
    for _ in range(coupon.later_layer_rounds if coupon.later_layer else 0):
        if fit["at_bound"]:
            break
        late = _lateness(d, material, fit["p"], thickness_sd)
        fit = _fit(d, material, 1, coupon, late)
    return fit, late


def _interval(p: float, var: float, dof: int, level: float) -> tuple[float, float, float]:
    """(value, low, high) of ``exp(p)`` with a Student-t interval on ``p``."""
    q = float(stats.t.ppf(0.5 + level / 2.0, dof))
    se = math.sqrt(var) if var >= 0 and math.isfinite(var) else math.inf
    return math.exp(p), math.exp(p - q * se) if math.isfinite(se) else 0.0, \
        math.exp(p + q * se) if math.isfinite(se) else math.inf


def _separable(fit2: dict, coupon: Coupon) -> bool:
    cov = fit2["cov"]
    if fit2["at_bound"] or not np.all(np.isfinite(cov)) or np.any(np.diag(cov) <= 0):
        return False
    rho = cov[0, 1] / math.sqrt(cov[0, 0] * cov[1, 1])
    return abs(rho) <= coupon.max_correlation


def fit_coupon(d: dict, material=None, coupon: Coupon = COUPON,
               thickness_sd: float = UNCERTAINTY.thickness_sd) -> dict:
    """Fit the print's factors to a measured coupon (:func:`read_coupon_csv`).

    The compliance ``s`` alone first; then ``s`` and the membrane modulus ``m`` together,
    kept only when the data separate them (:attr:`Coupon.max_correlation`).

    Parameters
    ----------
    d : dict -- the measured coupon
    material : path-like or bracket model, optional (default: the committed model)
    coupon : Coupon
    thickness_sd : float, mm
        The printer's per-bracket thickness scatter, which makes each cell close late on
        average (:attr:`Coupon.later_layer`); default the tolerance model's.

    Returns
    -------
    dict
        ``compliance``, ``modulus``: each ``{"value", "ci": [low, high], "z_from_model"}``
        (``z_from_model``: ``|ln value|`` in standard errors, the distance from the shipped
        model); ``modulus_fitted`` (bool), ``why``, ``correlation``, ``residual_rms_s``,
        ``residual_sd_s``, ``cells``, ``confidence``, ``residuals_s`` (n,).

    Raises
    ------
    InputError
        Data that cannot support a fit (:func:`check_fit_data`), or a fit that ends at a bound
        of :attr:`Coupon.compliance_bounds` (the times are not the coupon's).
    """
    material = load_material(material)
    if not thickness_sd >= 0:
        raise InputError(f"a thickness sd of {thickness_sd!r} mm",
                         fix="give the printer's per-bracket thickness sd, 0 mm or more")
    check_fit_data(d, material, coupon)
    fit1, late = _fit_later_layer(d, material, coupon, thickness_sd)
    if fit1["at_bound"]:
        raise InputError(f"no bracket compliance in {list(coupon.compliance_bounds)} explains "
                         f"these times (the fit stops at s = {math.exp(fit1['p'][0]):.3g}, "
                         f"residual {fit1['rms_s']:.1f} s rms)",
                         fix="check the CSV belongs to this coupon and the times are seconds in "
                             "the bath (docs/coupon.md)")
    n = int(np.sum(np.isfinite(d["t"])))
    fit2 = _fit(d, material, 2, coupon, late) if n > coupon.min_cells else None
    if fit2 is not None and coupon.later_layer and not fit2["at_bound"]:
        fit2 = _fit(d, material, 2, coupon, _lateness(d, material, fit2["p"], thickness_sd))
    use2 = fit2 is not None and _separable(fit2, coupon)
    f = fit2 if use2 else fit1
    rho = None
    if fit2 is not None and np.all(np.isfinite(fit2["cov"])) and np.all(np.diag(fit2["cov"]) > 0):
        c = fit2["cov"]
        rho = float(c[0, 1] / math.sqrt(c[0, 0] * c[1, 1]))
    return _fit_summary(f, use2, rho, n, coupon)


def _fit_summary(f: dict, use2: bool, rho, n: int, coupon: Coupon) -> dict:
    def factor(k):
        if k >= len(f["p"]):
            return {"value": 1.0, "ci": [1.0, 1.0], "z_from_model": 0.0}
        v, lo, hi = _interval(float(f["p"][k]), float(f["cov"][k, k]), f["dof"],
                              coupon.confidence)
        se = math.sqrt(f["cov"][k, k]) if f["cov"][k, k] > 0 else math.inf
        return {"value": v, "ci": [lo, hi], "z_from_model": abs(float(f["p"][k])) / se}

    why = ("the data separate compliance and modulus" if use2 else
           "the data do not separate the membrane modulus from the bracket compliance "
           f"(|correlation| > {coupon.max_correlation:g}, or too few cells): the modulus is "
           "kept at 1 and the compliance carries both")
    return {"format": CALIBRATION_FORMAT, "compliance": factor(0), "modulus": factor(1),
            "modulus_fitted": bool(use2), "why": why, "correlation": rho,
            "residual_rms_s": f["rms_s"], "residual_sd_s": f["sd_s"], "cells": n,
            "confidence": coupon.confidence,
            "residuals_s": [float(v) for v in f["residuals"]]}


def calibrated_model(material, fit: dict, source: dict) -> dict:
    """A bracket model file's object with the fitted print: coefficients ``c_k / (m s^k)``.

    Parameters
    ----------
    material : BracketModel -- the model the coupon was fitted with
    fit : dict -- :func:`fit_coupon`'s result
    source : dict -- what was fitted (the coupon CSV's path and sha256), recorded

    Returns
    -------
    dict -- JSON-ready (``morphshell.bracket_model``, with ``calibration`` and ``provenance``)
    """
    s = float(fit["compliance"]["value"])
    m = float(fit["modulus"]["value"])
    coef = np.asarray(material.coef, float) / (m * s ** np.arange(1, 5))
    meta = {k: v for k, v in material.meta.items() if k != "provenance"}
    meta["calibration"] = {k: fit[k] for k in ("compliance", "modulus", "modulus_fitted", "why",
                                               "correlation", "residual_rms_s", "cells")}
    meta["calibration"]["base_model"] = str(material.path) if material.path else None
    meta["provenance"] = dict(source, tool="morphshell calibrate-time",
                              base_provenance=material.meta.get("provenance"))
    return model_dict(material.grid_min, material.grid_step, coef, meta)


def fit_text(fit: dict) -> str:
    """The fit as the command line prints it: each factor with its interval and its distance
    from the shipped model."""
    pct = int(round(100 * fit["confidence"]))
    lines = [f"coupon fit ({fit['cells']} cells, residual {fit['residual_rms_s']:.1f} s rms):"]
    for k, what in (("compliance", "bracket compliance s"), ("modulus", "membrane modulus m")):
        f = fit[k]
        if k == "modulus" and not fit["modulus_fitted"]:
            lines.append(f"  {what}: 1 (not fitted: {fit['why']})")
            continue
        lines.append(f"  {what}: {f['value']:.3f} ({pct} % CI {f['ci'][0]:.3f}-{f['ci'][1]:.3f}); "
                     f"{100 * (f['value'] - 1):+.1f} % from the shipped model, "
                     f"{f['z_from_model']:.1f} standard errors")
    return "\n".join(lines)


def calibrate(csv_path, out, material=None) -> str:
    """``morphshell calibrate-time``: read and fit a timed coupon, write the material file
    ``out`` (:func:`calibrated_model`) and return the fit's text (:func:`fit_text`)."""
    mat = load_material(material)
    d = read_coupon_csv(csv_path)
    fit = fit_coupon(d, mat)
    model = calibrated_model(mat, fit, {"coupon_csv": str(csv_path),
                                        "coupon_csv_sha256": d["sha256"]})
    atomic_write_text(out, json_text(model, indent=1, strict=True))
    return fit_text(fit)


__all__ = ["CSV_NAME", "COLUMNS", "coupon_source", "cell_geometry", "closing_times",
           "expected_closing_times", "spread_order", "coupon_thicknesses", "coupon_rows",
           "coupon_csv_text",
           "read_coupon_csv", "check_fit_data", "fit_coupon", "calibrated_model", "fit_text",
           "calibrate"]
