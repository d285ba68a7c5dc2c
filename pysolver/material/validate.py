"""Validate the model files a build reads, before any stage runs.

Two JSON files steer the design: the bracket (material) model (``--material FILE``, default
``pysolver/data/bracket_model.json``, written by ``morphshell fit-material``) and the membrane
model (``pysolver/data/membrane_model.json``, written by ``morphshell fit-membrane``).  They are
user input: a hand edit, a truncated copy or a file from another tool must be refused with a
message naming the file, the key (with its index) and the rule, never an internal error or a
silently wrong design.

Rules (thresholds in :data:`pysolver.params.MODEL_FILES`):

* the path is an existing regular file (a folder is "a folder, not a file"), at most
  ``max_bytes``, UTF-8 JSON whose top level is an object;
* bracket model: ``format`` is ``morphshell.bracket_model`` (``format_version`` <= 1); ``grid``
  has ``min``, ``step``, ``num`` with 3 entries each, finite, steps > 0 (the nodes increase along
  every axis), at least 2 nodes per axis, time nodes >= 0 s; ``force_coefficients.data`` is a
  nested list of numbers of shape ``num + (4,)``, every entry finite; the stiffness at zero
  compression ``F'(0) = c1`` is positive and ``F'`` is not negative on ``[0, b]`` at every node;
  forces fall with time in water (no rise above ``force_rise_tol`` of ``F(t=0)`` at any node and
  compression; median ``F(t_last) / F(0)`` at most ``softening_median_max``); the optional
  ``plastic_fraction``, ``specimen_brackets`` and ``creep_model`` are well formed;
* membrane model: ``terms`` are known monomials, ``coefficients`` one finite number per term,
  ``fit.residual_rms_N`` and ``fit.residual_max_N`` finite and >= 0, ``boundary_factor`` in
  (0, 1], optional ``samples`` finite and of equal lengths; the membrane force is positive and
  does not grow as a cell shortens over the design range.
"""

from __future__ import annotations

import json
import math
import os
import stat
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..params import MODEL_FILES
from .polyfit import poly_force, poly_stiffness

BRACKET_KIND = "material model file"
MEMBRANE_KIND = "membrane model file"
BRACKET_FIX = ("fit a model with 'make material DATA=dir' (morphshell fit-material --data DIR "
               "--out FILE) and pass that file, or omit --material (MATERIAL=) to use the "
               "committed model.")
MEMBRANE_FIX = ("re-fit it with 'make membrane-model' (morphshell fit-membrane), or restore the "
                "committed file with 'git checkout pysolver/data/membrane_model.json'.")
_AXES = ("thickness", "bracket length", "time")
_AXIS_UNITS = ("mm", "mm", "s")


class _File:
    """The file under validation: names it in every error."""

    def __init__(self, path, kind: str, fix: str):
        self.path = Path(path)
        self.label = f"{kind} {str(path)!r}"
        self.fix = fix

    def fail(self, key: str, rule: str, fix: str | None = None):
        where = f"{self.label}: {key} " if key else f"{self.label} "
        raise InputError(where + rule, fix=fix or self.fix)


def _describe(v) -> str:
    """A short description of a JSON value for error messages."""
    if v is None:
        return "null"
    if isinstance(v, bool):
        return f"the boolean {str(v).lower()}"
    if isinstance(v, str):
        return f"the text {v[:30]!r}"
    if isinstance(v, list):
        return f"a list of {len(v)}"
    if isinstance(v, dict):
        return "an object"
    return repr(v)


def _is_number(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def read_model_json(path, kind: str = BRACKET_KIND, fix: str = BRACKET_FIX) -> dict:
    """Read a model file as a JSON object, refusing anything else with a named error.

    Parameters
    ----------
    path : path-like
        The model file.
    kind : str
        What the file is, for messages (``"material model file"``).
    fix : str
        The fix given with every refusal.

    Returns
    -------
    dict
        The top-level JSON object.

    Raises
    ------
    InputError
        Missing path, folder, special file, too large, unreadable, not UTF-8, not JSON, or a
        JSON value other than an object.
    """
    f = _File(path, kind, fix)
    p = f.path
    try:
        st = os.stat(p)
    except (FileNotFoundError, NotADirectoryError):
        f.fail("", "does not exist.")
    except (OSError, ValueError) as e:  # no permission on a folder, name too long, NUL byte
        f.fail("", f"cannot be opened ({getattr(e, 'strerror', None) or e}).",
               fix="check the path and its permissions.")
    if stat.S_ISDIR(st.st_mode):
        f.fail("", "is a folder, not a file.",
               fix="give the path of the model JSON file itself (e.g. build/material/x.json).")
    if not stat.S_ISREG(st.st_mode):
        f.fail("", "is not a regular file (a device, pipe or socket).")
    size = st.st_size
    if size > MODEL_FILES.max_bytes:
        f.fail("", f"is {size / 2**20:.0f} MB; a model file is at most "
                   f"{MODEL_FILES.max_bytes / 2**20:.0f} MB (the committed one is < 1 MB).")
    try:
        text = p.read_bytes().decode("utf-8")
    except PermissionError:
        f.fail("", "cannot be read (permission denied).",
               fix="make it readable (chmod u+r) or give another file.")
    except UnicodeDecodeError as e:
        f.fail("", f"is not UTF-8 text (byte {e.start}); a model file is JSON.")
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        f.fail("", f"is not valid JSON ({e.msg} at line {e.lineno}, column {e.colno}).")
    except RecursionError:
        f.fail("", "is not a model file: its JSON is nested too deeply.")
    if not isinstance(d, dict):
        kind_of = "a JSON list" if isinstance(d, list) else f"the JSON value {_describe(d)}"
        f.fail("", f"is {kind_of}, not a JSON object; a model file is one object with named "
                   "keys.")
    return d


def _get(f: _File, d: dict, key: str, path: str):
    if not isinstance(d, dict):
        f.fail(path.rsplit(".", 1)[0], f"is {_describe(d)}, expected an object.")
    if key not in d:
        f.fail(path, "is missing (a required key).")
    return d[key]


def nested_numbers(f: _File, value, key: str, ndim: int) -> np.ndarray:
    """A nested JSON list of numbers as a float array, naming the first bad entry by index.

    Parameters
    ----------
    f : _File
    value : nested list
    key : str
        Key for messages (``force_coefficients.data``).
    ndim : int
        Expected nesting depth.

    Returns
    -------
    ndarray of float, ``ndim`` dimensions (non-finite values kept; see :func:`_finite`).
    """
    flat: list = []

    def walk(v, idx):
        name = key + "".join(f"[{i}]" for i in idx)
        if len(idx) == ndim:
            if not _is_number(v):
                f.fail(name, f"is {_describe(v)}, not a number.")
            flat.append(float(v))
            return ()
        if not isinstance(v, list):
            f.fail(name, f"is {_describe(v)}; expected a list nested {ndim} deep "
                         f"(depth {len(idx)} of {ndim}).")
        shapes = [walk(x, idx + (i,)) for i, x in enumerate(v)]
        for i, s in enumerate(shapes[1:], start=1):
            if s != shapes[0]:
                f.fail(name + f"[{i}]", f"has shape {s}, its sibling {name}[0] has "
                                        f"{shapes[0]}: the nested lists must be rectangular.")
        inner = shapes[0] if shapes else (0,) * (ndim - len(idx) - 1)
        return (len(v),) + inner

    shape = walk(value, ())
    return np.asarray(flat, dtype=float).reshape(shape)


def _finite(f: _File, a: np.ndarray, key: str, meaning=None) -> None:
    """Refuse NaN / infinite entries, naming the first one by index (and its meaning)."""
    bad = np.argwhere(~np.isfinite(a))
    if len(bad):
        i = tuple(int(k) for k in bad[0])
        name = key + "".join(f"[{k}]" for k in i)
        what = f" ({meaning(i)})" if meaning else ""
        more = f"; {len(bad)} of {a.size} entries are not finite" if len(bad) > 1 else ""
        v = float(a[i])
        text = "NaN" if math.isnan(v) else ("+inf" if v > 0 else "-inf")
        f.fail(name, f"is {text}{what}{more}; every value must be a finite number.")


def _vector(f: _File, value, key: str, n: int | None = None) -> np.ndarray:
    a = nested_numbers(f, value, key, 1)
    if n is not None and a.shape != (n,):
        f.fail(key, f"has {a.size} entries, expected {n}.")
    _finite(f, a, key)
    return a


# ----------------------------------------------------------------------------------------------
# bracket (material) model
# ----------------------------------------------------------------------------------------------


def check_bracket_model(d: dict, path=None) -> dict:
    """Check the content of a bracket model file (see the module docstring for the rules).

    Parameters
    ----------
    d : dict
        The file's JSON object.
    path : path-like, optional
        The file, for messages.

    Returns
    -------
    dict
        ``grid_min`` (3,) float (mm, mm, s), ``grid_step`` (3,) float, ``coef``
        (nh, nb, nt, 4) float (N mm^-k).

    Raises
    ------
    InputError
        Naming the file, the key (with index) and the rule.
    """
    f = _File(path if path is not None else "<model>", BRACKET_KIND, BRACKET_FIX)
    fmt = d.get("format")
    if fmt != "morphshell.bracket_model":
        f.fail("format", f"is {fmt!r}, not 'morphshell.bracket_model': this is not a morphshell "
                         "bracket model (the authors' bracket_model.json, with energy "
                         "coefficients and minutes, is a different format).")
    ver = d.get("format_version", 1)
    if not (isinstance(ver, int) and not isinstance(ver, bool)) or not \
            1 <= ver <= MODEL_FILES.format_version:
        f.fail("format_version", f"is {_describe(ver)}; this morphshell reads format_version "
                                 f"1..{MODEL_FILES.format_version}.",
               fix="update morphshell, or re-fit the model with this version.")
    grid = _get(f, d, "grid", "grid")
    if not isinstance(grid, dict):
        f.fail("grid", f"is {_describe(grid)}, expected an object with min, step and num.")
    gmin = _vector(f, _get(f, grid, "min", "grid.min"), "grid.min", 3)
    gstep = _vector(f, _get(f, grid, "step", "grid.step"), "grid.step", 3)
    num = _get(f, grid, "num", "grid.num")
    if not (isinstance(num, list) and len(num) == 3
            and all(isinstance(v, int) and not isinstance(v, bool) for v in num)):
        f.fail("grid.num", f"is {_describe(num)}; expected 3 whole numbers (nodes along "
                           "thickness, bracket length, time).")
    for k in range(3):
        unit = _AXIS_UNITS[k]
        if gstep[k] <= 0:
            f.fail(f"grid.step[{k}]", f"= {gstep[k]:g} {unit}; the {_AXES[k]} grid step must be "
                                      "> 0 (grid nodes increase along every axis).")
        if num[k] < MODEL_FILES.grid_min_nodes:
            f.fail(f"grid.num[{k}]", f"= {num[k]}; the {_AXES[k]} axis needs at least "
                                     f"{MODEL_FILES.grid_min_nodes} nodes to interpolate.")
    if gmin[0] <= 0 or gmin[1] <= 0:
        k = 0 if gmin[0] <= 0 else 1
        f.fail(f"grid.min[{k}]", f"= {gmin[k]:g} mm; the {_AXES[k]} grid must start above "
                                 "0 mm.")
    if gmin[2] < 0:
        f.fail("grid.min[2]", f"= {gmin[2]:g} s; time in water starts at 0 s.")
    fc = _get(f, d, "force_coefficients", "force_coefficients")
    data = _get(f, fc, "data", "force_coefficients.data")
    coef = nested_numbers(f, data, "force_coefficients.data", 4)
    want = tuple(num) + (4,)
    if coef.shape != want:
        f.fail("force_coefficients.data",
               f"has shape {coef.shape}; grid.num = {list(num)} needs {want} "
               "([i_thickness][i_length][i_time][coefficient of x^1..x^4]).")
    axes = [gmin[k] + gstep[k] * np.arange(num[k]) for k in range(3)]

    def node(i):
        return (f"h = {axes[0][i[0]]:.3g} mm, b = {axes[1][i[1]]:.4g} mm, t = "
                f"{axes[2][i[2]]:.4g} s" + (f", coefficient of x^{i[3] + 1}" if len(i) > 3 else ""))

    _finite(f, coef, "force_coefficients.data", node)
    _check_stiffness(f, coef, axes, node)
    _check_time_fall(f, coef, axes, node)
    _check_meta(f, d)
    return {"grid_min": gmin, "grid_step": gstep, "coef": coef}


def _compressions(b: np.ndarray) -> np.ndarray:
    """(nx, nb) compressions b/n .. b per bracket length (mm)."""
    n = MODEL_FILES.compressions
    return np.arange(1, n + 1)[:, None] / n * b[None, :]


def _check_stiffness(f: _File, coef, axes, node) -> None:
    c1 = coef[..., 0]
    if np.any(c1 <= MODEL_FILES.stiffness_min):
        i = np.unravel_index(np.argmin(c1), c1.shape)
        name = "force_coefficients.data" + "".join(f"[{k}]" for k in i) + "[0]"
        f.fail(name, f"= {c1[i]:.4g} N/mm ({node(i)}): the stiffness at zero compression "
                     f"F'(0) = c1 must be > {MODEL_FILES.stiffness_min:g} N/mm at every node "
                     f"({int(np.sum(c1 <= MODEL_FILES.stiffness_min))} nodes are not); a "
                     "bracket pushes back when compressed.")
    x = _compressions(axes[1])                                  # (nx, nb)
    S = poly_stiffness(coef[None], x[:, None, :, None])         # (nx, nh, nb, nt)
    if S.min() < -MODEL_FILES.stiffness_tol:
        k, *i = np.unravel_index(np.argmin(S), S.shape)
        name = "force_coefficients.data" + "".join(f"[{j}]" for j in i)
        f.fail(name, f"({node(tuple(i))}): the stiffness dF/dx = {S.min():.4g} N/mm at "
                     f"compression x = {x[k, i[1]]:.3g} mm; it must not be negative on "
                     f"[0, b] (tolerance {MODEL_FILES.stiffness_tol:g} N/mm).")


def _check_time_fall(f: _File, coef, axes, node) -> None:
    x = _compressions(axes[1])
    F = poly_force(coef[None], x[:, None, :, None])             # (nx, nh, nb, nt) N
    F0 = F[..., :1]
    rise = (F - np.minimum.accumulate(F, axis=-1)) / np.abs(F0)
    if rise.max() > MODEL_FILES.force_rise_tol:
        k, ih, ib, it = np.unravel_index(np.argmax(rise), rise.shape)
        prev = int(np.argmin(F[k, ih, ib, :it]))
        f.fail(f"force_coefficients.data[{ih}][{ib}][{it}]",
               f"({node((ih, ib, it))}): the force at compression x = {x[k, ib]:.3g} mm is "
               f"{F[k, ih, ib, it]:.4g} N, up from {F[k, ih, ib, prev]:.4g} N at t = "
               f"{axes[2][prev]:.4g} s; forces must fall with time in water (a rise of at most "
               f"{100 * MODEL_FILES.force_rise_tol:.0f} % of F(t=0) = {F[k, ih, ib, 0]:.4g} N "
               "is tolerated).")
    ratio = float(np.median(F[..., -1] / F0[..., 0]))
    if not ratio <= MODEL_FILES.softening_median_max:
        f.fail("force_coefficients.data",
               f"hardly changes with time: the median of F(t = {axes[2][-1]:.4g} s) / F(t = "
               f"{axes[2][0]:.4g} s) over the grid is {ratio:.3g}, above "
               f"{MODEL_FILES.softening_median_max:g}; forces must fall with time in water (the "
               "brackets soften), otherwise no time can be programmed.")


def _check_meta(f: _File, d: dict) -> None:
    if "plastic_fraction" in d:
        eta = d["plastic_fraction"]
        if not (_is_number(eta) and 0 <= eta < MODEL_FILES.plastic_fraction_max):
            f.fail("plastic_fraction", f"is {_describe(eta)}; it must be a number in [0, "
                                       f"{MODEL_FILES.plastic_fraction_max:g}).")
    if "specimen_brackets" in d:
        n = d["specimen_brackets"]
        if not (isinstance(n, int) and not isinstance(n, bool) and n >= 1):
            f.fail("specimen_brackets", f"is {_describe(n)}; it must be a whole number >= 1.")
    if "bracket" in d:
        b = d["bracket"]
        h = b.get("height_mm") if isinstance(b, dict) else None
        wr = b.get("width_mm") if isinstance(b, dict) else None
        if not (_is_number(h) and h > 0):
            f.fail("bracket.height_mm", f"is {_describe(h)}; it must be a positive number (mm).")
        if not (isinstance(wr, list) and len(wr) == 2 and all(_is_number(x) for x in wr)
                and 0 < wr[0] <= wr[1]):
            f.fail("bracket.width_mm", f"is {_describe(wr)}; it must be [min, max] mm, "
                                       "0 < min <= max.")
    if "creep_model" in d:
        cm = d["creep_model"]
        if not isinstance(cm, dict):
            f.fail("creep_model", f"is {_describe(cm)}, expected an object with dry and wet.")
        for part in ("dry", "wet"):
            p = _get(f, cm, part, f"creep_model.{part}")
            key = f"creep_model.{part}"
            e = nested_numbers(f, _get(f, p, "exponents", key + ".exponents"),
                               key + ".exponents", 2)
            c = _vector(f, _get(f, p, "coefficients", key + ".coefficients"),
                        key + ".coefficients")
            if len(e) != len(c):
                f.fail(key, f"has {len(e)} exponent rows and {len(c)} coefficients; they must "
                            "pair up.")
            if e.size and (np.any(e < 0) or np.any(e != np.round(e))):
                f.fail(key + ".exponents", "must be whole numbers >= 0.")


def validate_bracket_model_file(path) -> dict:
    """Read and check a bracket model file.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    dict
        ``data`` (the JSON object), ``grid_min`` (3,), ``grid_step`` (3,), ``coef``
        (nh, nb, nt, 4) (see :func:`check_bracket_model`).

    Raises
    ------
    InputError
        The first rule the file breaks, naming the file, key and rule.
    """
    return validate_model_file(path, BRACKET_KIND, BRACKET_FIX, check_bracket_model)


def validate_model_file(path, kind: str, fix: str, check) -> dict:
    """Read a model file (:func:`read_model_json`) and ``check(d, path)`` it; returns the
    check's dict plus ``data`` (the JSON object)."""
    d = read_model_json(path, kind, fix)
    return dict(check(d, path), data=d)




__all__ = ["read_model_json", "validate_model_file", "check_bracket_model",
           "validate_bracket_model_file",
           "nested_numbers", "BRACKET_KIND", "MEMBRANE_KIND"]
