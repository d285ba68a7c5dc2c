"""Time-landscape editing for the studio: keyframes and brushes -> a smooth landscape,
and its feasibility from the temporal stage's own computation.

A *keyframe* fixes the time at one stencil vertex; a *brush* fixes it at every vertex
within a radius (mm, straight-line distance in the target shape) of a centre vertex.
Between the fixed vertices the landscape is harmonic on the target stencil (Laplace's
equation with the cotangent Laplacian, ``igl.harmonic``): smooth, no overshoot (the
maximum principle keeps it within the fixed times).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .. import tables, temporal
from ..design.time_landscape import cell_target_times
from ..errors import InputError
from ..params import tol as TOL
from ..temporal import program_cells
from ..temporal.membrane_model import load_membrane_model

MAX_TIME_S = 1000.0
"""Largest keyframe time accepted (s); the material models cover about 120 s."""
MAX_CONSTRAINTS = 10000
"""Most keyframes + brushes in one request."""


def parse_constraints(payload, n_vertices: int) -> tuple[list, list]:
    """Validate the editor's keyframes and brushes (untrusted JSON).

    Parameters
    ----------
    payload : dict
        ``{"keyframes": [{"vertex": int, "time": float}], "brushes": [{"vertex": int,
        "radius": float (mm), "time": float (s)}]}``.
    n_vertices : int

    Returns
    -------
    keyframes : list of (int, float)
    brushes : list of (int, float, float)

    Raises
    ------
    InputError
        Not a mapping, unknown keys, a vertex outside ``0..n_vertices-1``, a time outside
        ``[0, MAX_TIME_S]`` s or a radius outside ``(0, 1000]`` mm.
    """
    if not isinstance(payload, dict):
        raise InputError("the landscape request must be a JSON object",
                         fix='send {"keyframes": [...], "brushes": [...]}')
    bad = sorted(set(payload) - {"keyframes", "brushes"})
    if bad:
        raise InputError(f"unknown key(s) {bad} in the landscape request",
                         fix="use only 'keyframes' and 'brushes'")
    kfs, brs = payload.get("keyframes") or [], payload.get("brushes") or []
    if not isinstance(kfs, list) or not isinstance(brs, list):
        raise InputError("'keyframes' and 'brushes' must be lists")
    if len(kfs) + len(brs) > MAX_CONSTRAINTS:
        raise InputError(f"{len(kfs) + len(brs)} keyframes and brushes",
                         fix=f"use at most {MAX_CONSTRAINTS}")

    def number(item, key, lo, hi, what, integer=False):
        v = item.get(key) if isinstance(item, dict) else None
        ok = isinstance(v, int) if integer else isinstance(v, (int, float))
        if isinstance(v, bool) or not ok or not math.isfinite(v) or not lo <= v <= hi:
            raise InputError(f"{what}: {key} = {v!r} is not a number in [{lo}, {hi}]",
                             fix=f"give {key} as a number between {lo} and {hi}")
        return int(v) if integer else float(v)

    out_k = [(number(k, "vertex", 0, n_vertices - 1, f"keyframe {i}", True),
              number(k, "time", 0.0, MAX_TIME_S, f"keyframe {i}")) for i, k in enumerate(kfs)]
    out_b = [(number(b, "vertex", 0, n_vertices - 1, f"brush {i}", True),
              number(b, "radius", TOL.merge, 1000.0, f"brush {i}"),
              number(b, "time", 0.0, MAX_TIME_S, f"brush {i}")) for i, b in enumerate(brs)]
    return out_k, out_b


def constraint_values(V, keyframes, brushes) -> tuple[np.ndarray, np.ndarray]:
    """Fixed vertices and their times; later keyframes/brushes win on shared vertices.

    Parameters
    ----------
    V : (n, 3) float, mm -- target stencil vertices
    keyframes : list of (vertex, time_s)
    brushes : list of (vertex, radius_mm, time_s)

    Returns
    -------
    b : (k,) int -- fixed vertex ids (sorted)
    bc : (k,) float, s
    """
    V = np.asarray(V, float)
    fixed: dict[int, float] = {}
    for v, r, t in brushes:  # brushes first: a keyframe inside a brush keeps its own time
        for i in np.flatnonzero(np.linalg.norm(V - V[v], axis=1) <= r):
            fixed[int(i)] = t
    for v, t in keyframes:
        fixed[int(v)] = t
    b = np.array(sorted(fixed), dtype=np.int64)
    return b, np.array([fixed[int(i)] for i in b], float)


def harmonic_landscape(V, F, b, bc) -> np.ndarray:
    """Harmonic interpolation of fixed times over the target stencil.

    Parameters
    ----------
    V : (n, 3) float, mm ; F : (m, 3) int
    b : (k,) int -- fixed vertices (k >= 1) ; bc : (k,) float, s

    Returns
    -------
    t : (n,) float, s -- ``t[b] = bc``; harmonic (cotangent Laplacian) elsewhere.
    """
    import igl  # heavy: libigl only where it is used

    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    b = np.asarray(b, np.int64)
    bc = np.asarray(bc, np.float64)
    if b.size == 0:
        raise InputError("no keyframe: the landscape needs at least one fixed time",
                         fix="place a keyframe (a vertex and a time) or a brush")
    if b.size == 1 or np.ptp(bc) == 0:
        return np.full(len(V), float(bc[0]))
    t = igl.harmonic(V, F, b, bc.reshape(-1, 1), 1)
    t = np.asarray(t, float).reshape(-1)
    # the maximum principle bounds the exact solution; clip round-off only
    return np.clip(t, bc.min(), bc.max())


class Feasibility:
    """Which unit cells can finish at their time, by the temporal stage's own rule.

    Wraps :func:`pysolver.temporal.program_cells` with the design folder's cells and the
    models the program stage used (``temporal.json``: material file and per-cell
    membrane factors), so a landscape is judged exactly as ``morphshell program`` will.
    """

    def __init__(self, design_dir):

        self.folder = Path(design_dir)
        self.cells = tables.read_table(self.folder, "cells")
        rec = {}
        p = self.folder / temporal.STAGE_FILE
        if p.is_file():
            rec = json.loads(p.read_text())
        summ = rec.get("summary", {})
        mat_path = summ.get("material_model")
        self.material = temporal.load_material(mat_path if mat_path and Path(mat_path).is_file()
                                           else None)
        self.membrane = load_membrane_model(None)
        self.closing = temporal.closing_lengths(self.folder, self.cells)  # as program closes
        fac = rec.get("membrane_factor")
        if fac is not None and len(fac) == len(self.cells["cell_id"]):
            self.factor = np.asarray(fac, float)
        else:
            corr = (summ.get("membrane_correction") or {}).get("correction",
                                                                 temporal.DEFAULT_CORRECTION)
            self.factor, _ = temporal.membrane_factors(self.folder, self.cells, self.membrane,
                                                       corr)

    def evaluate(self, landscape) -> dict:
        """Per-cell t*, achievable range and clamping for a landscape per stencil vertex.

        Returns
        -------
        dict: ``t_star``, ``t_min``, ``t_max`` (n_cells,) s (inf/NaN as None in JSON),
        ``clamped`` (n_cells,) bool, ``side`` (-1 too early, +1 too late, 0 ok).
        """
        c = self.cells
        t_star = cell_target_times(np.asarray(landscape, float), c["vertex_a"], c["vertex_b"])
        res = program_cells(c["bracket_length_mm"], self.closing[:, 0], self.closing[:, 1],
                            c["boundary"], t_star,
                            material=self.material, membrane=self.membrane, factor=self.factor)
        return {"t_star": t_star, "t_min": res["t_min"], "t_max": res["t_max"],
                "clamped": np.asarray(res["clamped"], bool), "side": np.asarray(res["side"])}


__all__ = ["parse_constraints", "constraint_values", "harmonic_landscape", "Feasibility",
           "MAX_TIME_S"]
