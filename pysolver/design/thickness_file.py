"""Bracket thicknesses given with the design (``morphshell design --thickness-file``).

A stencil made elsewhere (the paper's own shells, a design from another tool) comes with its
bracket thicknesses.  :func:`read_thickness_file` reads them and :func:`cell_thicknesses`
assigns them to the design's cells, so that the design folder is simulated with the
thicknesses that were printed instead of programming new ones.

The file is a CSV with a header row and one row per unit cell:

* the cell's two bases (stencil faces, 0-based): columns ``base_a, base_b`` (a morphshell
  ``cells.csv``) or ``face_a, face_b``;
* its thickness per layer, mm: ``thickness_top_mm, thickness_bottom_mm`` (morphshell's
  names; top = the +face-normal side) or ``thickness_plus_normal_mm,
  thickness_minus_normal_mm``;
* any other column is ignored (``cell``, ``t_star_s``, ...).

Values are parsed as numbers, never evaluated.  Every cell of the design must appear once.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..params import UNIT_CELL
from ..tables import check_thickness
from .time_landscape import read_option_text

BASE_COLUMNS = (("base_a", "base_b"), ("face_a", "face_b"))
THICKNESS_COLUMNS = (("thickness_top_mm", "thickness_bottom_mm"),
                     ("thickness_plus_normal_mm", "thickness_minus_normal_mm"))
FIX = ("write a CSV with a header row and one row per unit cell: its two bases (base_a, base_b "
       "or face_a, face_b: 0-based stencil faces) and its thickness per layer in mm "
       "(thickness_top_mm, thickness_bottom_mm or thickness_plus_normal_mm, "
       "thickness_minus_normal_mm)")


def _pick(header: list, options, path, what: str) -> tuple:
    for cols in options:
        if all(c in header for c in cols):
            return tuple(header.index(c) for c in cols)
    names = " or ".join(", ".join(c) for c in options)
    raise InputError(f"--thickness-file {path}: no {what} columns ({names}) in the header "
                     f"{header}", fix=FIX)


def read_thickness_file(path) -> dict:
    """Read a thickness file.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    dict
        ``bases`` (k, 2) int, ``thickness`` (k, 2) float mm (top, bottom), ``sha256`` (of the
        file's bytes), ``path`` (str).

    Raises
    ------
    InputError
        Missing, unreadable, too large or non-text file; missing columns; a value that is not
        a number, a base id that is not a non-negative integer, a thickness that is not
        positive and finite (named by line); the same cell twice.
    """
    path = Path(path)
    text, data = read_option_text(path, "--thickness-file", FIX)
    lines = [(n, ln.strip()) for n, ln in enumerate(text.splitlines(), start=1) if ln.strip()]
    if not lines:
        raise InputError(f"--thickness-file {path}: empty", fix=FIX)
    header = [c.strip() for c in lines[0][1].split(",")]
    ib = _pick(header, BASE_COLUMNS, path, "base")
    it = _pick(header, THICKNESS_COLUMNS, path, "thickness")
    bases, thick = [], []
    for lineno, line in lines[1:]:
        f = [c.strip() for c in line.split(",")]
        if len(f) != len(header):
            raise InputError(f"--thickness-file {path}:{lineno}: {len(f)} fields, the header "
                             f"has {len(header)}", fix=FIX)
        try:
            b = [float(f[i]) for i in ib]
            t = [float(f[i]) for i in it]
        except ValueError:
            raise InputError(f"--thickness-file {path}:{lineno}: not a number in "
                             f"{line[:60]!r}", fix=FIX) from None
        if not all(math.isfinite(v) and v >= 0 and v == int(v) for v in b):
            raise InputError(f"--thickness-file {path}:{lineno}: bases {b} are not "
                             "non-negative integers", fix=FIX)
        if not all(math.isfinite(v) and v > 0 for v in t):
            raise InputError(f"--thickness-file {path}:{lineno}: thickness {t} mm is not "
                             "positive", fix=FIX)
        bases.append([int(v) for v in b])
        thick.append(t)
    if not bases:
        raise InputError(f"--thickness-file {path}: no rows after the header", fix=FIX)
    bases = np.array(bases, dtype=np.int64)
    key = np.sort(bases, axis=1)
    _, first, count = np.unique(key, axis=0, return_index=True, return_counts=True)
    if np.any(count > 1):
        k = int(np.flatnonzero(count > 1)[0])
        raise InputError(f"--thickness-file {path}: cell of bases {key[first[k]].tolist()} "
                         f"appears {int(count[k])} times", fix=FIX)
    return {"bases": bases, "thickness": np.array(thick, float),
            "sha256": hashlib.sha256(data).hexdigest(), "path": str(path)}


def cell_thicknesses(given: dict, cell_bases, unit=UNIT_CELL) -> np.ndarray:
    """The given thicknesses in the design's cell order.

    Parameters
    ----------
    given : dict -- :func:`read_thickness_file`
    cell_bases : (c, 2) int -- the design's cells (``cells.csv`` ``base_a, base_b``)
    unit : UnitCell -- the printable thickness range

    Returns
    -------
    (c, 2) float, mm -- top, bottom

    Raises
    ------
    InputError
        A cell of the design missing from the file, a row that is no cell of the design, a
        thickness outside the printable range.
    """
    cb = np.sort(np.asarray(cell_bases, np.int64), axis=1)
    gb = np.sort(given["bases"], axis=1)
    n = int(max(cb.max(initial=0), gb.max(initial=0))) + 1
    code_c = cb[:, 0] * n + cb[:, 1]
    code_g = gb[:, 0] * n + gb[:, 1]
    order = np.argsort(code_g)
    pos = np.searchsorted(code_g[order], code_c)
    pos = np.minimum(pos, len(order) - 1)
    found = code_g[order][pos] == code_c
    path = given["path"]
    if not found.all():
        k = int(np.flatnonzero(~found)[0])
        raise InputError(f"--thickness-file {path}: no row for cell {k} (bases "
                         f"{cb[k].tolist()}); {int((~found).sum())} of the design's "
                         f"{len(cb)} cells are missing",
                         fix="give one row per interior edge of the stencil (two adjacent "
                             "faces), with the stencil the thicknesses were made for")
    extra = np.setdiff1d(code_g, code_c)
    if len(extra):
        j = int(np.flatnonzero(code_g == extra[0])[0])
        raise InputError(f"--thickness-file {path}: row {j + 2} (bases "
                         f"{given['bases'][j].tolist()}) is not a unit cell of the design "
                         f"({len(extra)} such row(s))",
                         fix="use the stencil the thicknesses were made for, with --stencil")
    th = given["thickness"][order[pos]]
    check_thickness(th, f"--thickness-file {path}", rows=False, programmed=True, unit=unit)
    return th


__all__ = ["read_thickness_file", "cell_thicknesses", "BASE_COLUMNS", "THICKNESS_COLUMNS"]
