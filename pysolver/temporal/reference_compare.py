"""Compare a design's bracket thicknesses with a reference design of the same stencil.

The reference implementation's per-cell table (``cover_reference_cells.csv`` in
``../shared/reference-shapes``) has one row per unit cell in its face-major order with the
columns ``cell, face_a, face_b, thickness_pos_normal_mm, thickness_neg_normal_mm,
t_star_s``.  Its ``+normal`` layer (``o``) is morphshell's ``top`` and its ``-normal``
layer (``u``) is ``bottom`` (``docs/design-folder.md``, frames).  Cells are matched by
their (unordered) face pair, so the two tables may list them in any order.

Used by ``bench/bench_reference.py``; the mechanism is tested in
``tests/test_reference_compare.py``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..params import UNIT_CELL
from ..params import tol as TOL

REFERENCE_COLUMNS = ("cell", "face_a", "face_b", "thickness_pos_normal_mm",
                     "thickness_neg_normal_mm", "t_star_s")


def read_reference_cells(path) -> dict:
    """Read a reference per-cell table (CSV with the header :data:`REFERENCE_COLUMNS`).

    Returns
    -------
    dict of (c,) arrays
        ``face_a``, ``face_b`` int; ``top_mm`` (+normal), ``bottom_mm`` (-normal),
        ``t_star_s`` float.

    Raises
    ------
    InputError
        Missing file or column, a value that is not a number.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file", fix="give the reference cells CSV")
    lines = [ln.strip() for ln in path.read_text().splitlines() if ln.strip()]
    if not lines:
        raise InputError(f"{path}: empty file")
    head = [h.strip() for h in lines[0].split(",")]
    missing = [c for c in REFERENCE_COLUMNS[1:] if c not in head]
    if missing:
        raise InputError(f"{path}: missing column(s) {missing}; header is {head}",
                         fix=f"expected the columns {', '.join(REFERENCE_COLUMNS)}")
    rows = []
    for k, ln in enumerate(lines[1:], start=2):
        parts = ln.split(",")
        if len(parts) != len(head):
            raise InputError(f"{path}:{k}: {len(parts)} fields for {len(head)} columns")
        try:
            rows.append([float(p) for p in parts])
        except ValueError:
            raise InputError(f"{path}:{k}: a value is not a number ({ln[:60]!r})") from None
    a = np.array(rows, float).reshape(-1, len(head))
    col = {h: a[:, i] for i, h in enumerate(head)}
    return {"face_a": col["face_a"].astype(np.int64), "face_b": col["face_b"].astype(np.int64),
            "top_mm": col["thickness_pos_normal_mm"], "bottom_mm": col["thickness_neg_normal_mm"],
            "t_star_s": col["t_star_s"]}


def match_cells(base_a, base_b, ref_face_a, ref_face_b) -> np.ndarray:
    """Row of the reference table for each design cell, matched by the unordered face pair.

    Parameters
    ----------
    base_a, base_b : (c,) int -- the design's cells (``cells.csv``)
    ref_face_a, ref_face_b : (r,) int -- the reference's cells

    Returns
    -------
    idx : (c,) int

    Raises
    ------
    InputError
        A design cell missing from the reference, or a face pair listed twice there.
    """
    key = {}
    for i, (a, b) in enumerate(zip(ref_face_a, ref_face_b, strict=True)):
        k = (min(int(a), int(b)), max(int(a), int(b)))
        if k in key:
            raise InputError(f"reference cells: faces {k} listed twice (rows {key[k]}, {i})")
        key[k] = i
    idx = []
    for a, b in zip(base_a, base_b, strict=True):
        k = (min(int(a), int(b)), max(int(a), int(b)))
        if k not in key:
            raise InputError(f"reference cells: no row for the cell of faces {k}",
                             fix="compare designs of the same stencil (same faces)")
        idx.append(key[k])
    return np.asarray(idx, dtype=np.int64)


def _pearson(x, y) -> float:
    x, y = np.asarray(x, float), np.asarray(y, float)
    if len(x) < 2 or np.std(x) == 0 or np.std(y) == 0:
        return float("nan")
    return float(np.corrcoef(x, y)[0, 1])


def thickness_correlation(cells: dict, ref: dict) -> dict:
    """Pearson correlation of the bracket thicknesses (both layers pooled, and per layer).

    Parameters
    ----------
    cells : dict -- ``cells.csv`` columns (``base_a``, ``base_b``, ``thickness_top_mm``,
        ``thickness_bottom_mm``, ``t_star_s``, ``boundary``)
    ref : dict -- :func:`read_reference_cells`

    Returns
    -------
    dict
        ``pearson`` (top and bottom pooled: 2c pairs), ``pearson_top``, ``pearson_bottom``,
        ``pearson_interior``/``pearson_boundary`` (cells whose edge touches the rim),
        ``t_star_max_abs_diff_s``, mean differences (ours - reference, mm), the fraction of
        brackets at each bound, ``same_order`` (the reference lists the cells in our order).
    """
    idx = match_cells(cells["base_a"], cells["base_b"], ref["face_a"], ref["face_b"])
    top, bot = (np.asarray(cells[k], float) for k in ("thickness_top_mm",
                                                      "thickness_bottom_mm"))
    rt, rb = ref["top_mm"][idx], ref["bottom_mm"][idx]
    bnd = np.asarray(cells.get("boundary", np.zeros(len(top))), bool)
    ours, theirs = np.r_[top, bot], np.r_[rt, rb]

    def at_bounds(h):
        lo, hi = UNIT_CELL.thickness_min, UNIT_CELL.thickness_max
        return {f"at_{lo:.2f}": float(np.mean(h <= lo + TOL.thickness)),
                f"at_{hi:.2f}": float(np.mean(h >= hi - TOL.thickness))}

    return {
        "cells": int(len(top)), "same_order": bool(np.all(idx == np.arange(len(idx)))),
        "pearson": _pearson(ours, theirs),
        "pearson_top": _pearson(top, rt), "pearson_bottom": _pearson(bot, rb),
        "pearson_interior": _pearson(np.r_[top[~bnd], bot[~bnd]], np.r_[rt[~bnd], rb[~bnd]]),
        "pearson_boundary": _pearson(np.r_[top[bnd], bot[bnd]], np.r_[rt[bnd], rb[bnd]]),
        "mean_diff_top_mm": float(np.mean(top - rt)),
        "mean_diff_bottom_mm": float(np.mean(bot - rb)),
        "rms_diff_mm": float(np.sqrt(np.mean((ours - theirs) ** 2))),
        "t_star_max_abs_diff_s": float(np.max(np.abs(np.asarray(cells["t_star_s"], float)
                                                     - ref["t_star_s"][idx]))),
        "bounds_ours": at_bounds(ours), "bounds_reference": at_bounds(theirs),
    }


__all__ = ["REFERENCE_COLUMNS", "read_reference_cells", "match_cells", "thickness_correlation"]
