"""Did the edit work?  Two builds of one target, cell by cell: the painted region's requested
and simulated times, their RMS, how many are out of reach, and the per-cell completion
difference A - B (the studio's *Compare*).

The two builds are compared on their unit cells, which a variant shares with its original
(the same design stage).  The *painted region* is, unless the user gives one, the cells
whose requested time t* differs between the two builds: exactly the cells the edit moved.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..temporal.program import timing_errors

REGION_TOL_S = 1e-6
"""Two requested times closer than this (s) are the same: ``time_landscape.csv`` keeps 9
significant digits, so an unedited cell's t* is equal to well within it."""


def _outcome(cells: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t_star = np.asarray([np.nan if v is None else v for v in cells["t_star"]], float)
    t_done = np.asarray([np.nan if v is None else v for v in cells["t_done"]], float)
    return t_star, t_done, np.asarray(cells["clamped"], bool)


def region_cells(a: dict, b: dict) -> np.ndarray:
    """The cells whose requested time differs between builds ``a`` and ``b``.

    Parameters
    ----------
    a, b : dict
        Per-cell ``t_star`` (s), ``t_done`` (s, None = never), ``clamped`` (bool) lists
        (the viewer's ``cells``), of the same length.

    Returns
    -------
    (k,) int -- cell ids, sorted
    """
    ta, tb = _outcome(a)[0], _outcome(b)[0]
    return np.flatnonzero(~(np.abs(ta - tb) <= REGION_TOL_S)).astype(int)


def _figures(t_star, t_done, clamped, cells) -> dict:
    """The region's figures of one build (the report's rule: RMS over the programmable cells
    that complete)."""
    ts, td, cl = t_star[cells], t_done[cells], clamped[cells]
    done = np.isfinite(td)
    rms = timing_errors(ts, td, exclude=cl)["rms_s"]

    def mean(x):
        return float(np.mean(x)) if x.size else None

    return {"requested_mean_s": mean(ts), "simulated_mean_s": mean(td[done]),
            "timing_rms_s": None if np.isnan(rms) else rms,
            "n_never_complete": int((~done).sum()), "n_out_of_reach": int(cl.sum())}


def _region(cells, n_cells: int) -> np.ndarray:
    """The cell ids ``cells`` (untrusted: a request's list) as a (k,) int array, each checked
    to be a whole number in ``0 .. n_cells - 1`` before any conversion (a huge id would
    overflow a fixed-size integer).

    Raises
    ------
    InputError
        Naming the first id that is not a whole number or not one of the cells.
    """
    if not isinstance(cells, (list, tuple)):
        raise InputError("the region must be a list of cell ids",
                         fix="give cell ids of these builds")
    for c in cells:
        if isinstance(c, bool) or not isinstance(c, (int, np.integer)):
            raise InputError(f"region cell {str(c)[:40]!r} is not a whole number",
                             fix="give cell ids of these builds")
        c = int(c)
        if not 0 <= c < n_cells:
            shown = str(c) if c.bit_length() <= 128 else f"(a {c.bit_length()}-bit number)"
            raise InputError(f"region cell {shown} is not one of 0-{n_cells - 1}",
                             fix="give cell ids of these builds")
    return np.asarray(cells, dtype=np.int64).reshape(-1)


def compare_cells(a: dict, b: dict, cells=None) -> dict:
    """Builds ``a`` and ``b`` cell by cell.

    Parameters
    ----------
    a, b : dict
        As :func:`region_cells`.
    cells : list of int, optional
        The region (cell ids); default the cells whose requested time differs.

    Returns
    -------
    dict
        ``region`` (list of int), ``a`` and ``b``: the region's ``requested_mean_s``,
        ``simulated_mean_s``, ``timing_rms_s`` (programmable cells that complete),
        ``n_never_complete``, ``n_out_of_reach`` (clamped); ``diff_done_s``: per cell
        ``t_done(a) - t_done(b)`` (s; None where either never completes).

    Raises
    ------
    InputError
        The builds have different numbers of cells (not variants of one design), or a
        region cell id that is not a whole number or outside them (:func:`_region`).
    """
    ta, da, ca = _outcome(a)
    tb, db, cb = _outcome(b)
    if len(ta) != len(tb):
        raise InputError(f"the builds have {len(ta)} and {len(tb)} unit cells: only builds of "
                         "one design (a build and its variants) compare cell by cell",
                         fix="compare a build with a variant made from it (Run into a new "
                             "build)")
    if cells is None:
        region = region_cells(a, b)
    else:
        region = _region(cells, len(ta))
    diff = da - db
    return {"region": region.tolist(),
            "a": _figures(ta, da, ca, region), "b": _figures(tb, db, cb, region),
            "diff_done_s": [None if not np.isfinite(x) else round(float(x), 4) for x in diff]}


__all__ = ["compare_cells", "region_cells", "REGION_TOL_S"]
