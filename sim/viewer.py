"""Data and assets of the interactive 3D morph viewer (report and studio share them).

The viewer itself is one JavaScript file, ``sim/static/morph_viewer.js``, drawn with
three.js (MIT, vendored as ``sim/static/three.min.js``, licence beside it).  Both are
classic scripts, so the report can inline them and open from ``file://`` with no server
and no network; the studio serves the same two files.

:func:`viewer_data` turns a loaded design folder (:class:`sim.report.SimData`) into the
JSON the viewer reads: frames in the *target frame* (each frame moved by the rigid
motion that aligns its base centres to the target, as the report's renders), base
poses as quaternions, the membrane, the target stencil, and per-cell rows (t*, t_done,
thickness, clamped).  Large arrays are base64 of little-endian float32 (positions
quantised to uint16 over their bounding box when ``quantise``).
"""

from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np

from pysolver.geometry import rigid_fit
from pysolver.params import UNIT_CELL
from pysolver.params import tol as TOL

STATIC_DIR = Path(__file__).resolve().parent / "static"
"""Folder of the viewer's static files (``three.min.js``, ``morph_viewer.js``, ``viewer.css``)."""

ASSETS = ("three.min.js", "morph_viewer.js", "viewer.css")


def asset_text(name: str) -> str:
    """Text of one of the viewer's static files (``name`` must be in :data:`ASSETS`)."""
    if name not in ASSETS:
        raise ValueError(f"unknown viewer asset {name!r}")
    return (STATIC_DIR / name).read_text(encoding="utf-8")


def _b64(a, dtype) -> str:
    return base64.b64encode(np.ascontiguousarray(a, dtype=np.dtype(dtype).newbyteorder("<"))
                            .tobytes()).decode("ascii")


def _positions(X, quantise: bool) -> dict:
    """Encode positions ``X`` ((..., 3) float, mm): float32, or uint16 over their box."""
    X = np.asarray(X, float)
    if not quantise or X.size == 0:
        return {"enc": "f32", "data": _b64(X, np.float32)}
    lo = X.reshape(-1, 3).min(axis=0)
    hi = X.reshape(-1, 3).max(axis=0)
    span = np.maximum(hi - lo, TOL.rel)
    q = np.rint((X - lo) / span * 65535.0)
    return {"enc": "u16", "lo": lo.tolist(), "span": span.tolist(), "data": _b64(q, np.uint16)}


def _quaternions(R) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) quaternions (x, y, z, w)."""
    # heavy: this scipy submodule loads only where it is used
    from scipy.spatial.transform import Rotation

    shp = R.shape[:-2]
    q = Rotation.from_matrix(np.asarray(R, float).reshape(-1, 3, 3)).as_quat()
    return q.reshape(*shp, 4)


def _per_base(values, cell_pairs, n_bases) -> np.ndarray:
    """Mean of a per-cell value over the unit cells of each base (NaN ignored; NaN if none)."""
    v = np.asarray(values, float)
    s = np.zeros(n_bases)
    c = np.zeros(n_bases)
    ok = np.isfinite(v)
    for k in (0, 1):
        np.add.at(s, cell_pairs[ok, k], v[ok])
        np.add.at(c, cell_pairs[ok, k], 1.0)
    with np.errstate(invalid="ignore"):
        return np.where(c > 0, s / np.maximum(c, 1), np.nan)


def _nan_list(a, nd=4) -> list:
    return [None if not np.isfinite(x) else round(float(x), nd) for x in np.asarray(a, float)]


def frame_alignments(C, target):
    """Rigid motion of every frame onto the target (Kabsch on the base centres, no scaling).

    Parameters
    ----------
    C : (n_frames, n_bases, 3) float, mm ; target : (n_bases, 3) float, mm

    Returns
    -------
    Q : (n_frames, 3, 3) float ; s : (n_frames, 3) float, mm -- ``x -> Q x + s``
    """
    fits = [rigid_fit(c, target) for c in np.asarray(C, float)]
    return np.stack([q for q, _ in fits]), np.stack([np.asarray(v, float) for _, v in fits])


def viewer_data(sd, t_done, *, max_frames: int = 80, quantise: bool = True,
                name: str | None = None) -> dict:
    """The viewer's JSON for a simulated design folder.

    Parameters
    ----------
    sd : sim.report.SimData
        Loaded design folder (tables, stencil, frames).
    t_done : (n_cells,) float, s
        Simulated completion time per cell (NaN = never), ``sim.model.collisions.completion_times``.
    max_frames : int
        Frames kept (evenly spaced, first and last always kept).
    quantise : bool
        uint16 positions (about 1/65535 of the box, < 0.003 mm on a 150 mm shell).
    name : str, optional
        Label of the build (default: the folder name).

    Returns
    -------
    dict (JSON-serialisable); see ``morph_viewer.js`` for the reader.
    """
    fr = sd.frames
    C = np.asarray(fr["base_center"], float)
    R = np.asarray(fr["base_rotation"], float)
    ok = np.isfinite(C).all(axis=(1, 2)) & np.isfinite(R).all(axis=(1, 2, 3))
    n_ok = len(ok) if ok.all() else int(np.argmin(ok))
    n_ok = max(n_ok, 1)
    sel = np.unique(np.linspace(0, n_ok - 1, min(max_frames, n_ok)).round().astype(int))
    t = np.asarray(fr["t"], float)[sel]
    # every frame in the target frame by its own rigid fit: the shell does not drift or
    # spin on screen while it morphs, and the distance to the target is the shape error
    Q, s = frame_alignments(C[sel], sd.target)
    Cd = np.einsum("fij,fbj->fbi", Q, C[sel]) + s[:, None]
    Rd = np.einsum("fij,fbjk->fbik", Q, R[sel])
    pairs = sd.cell_pairs.astype(int)
    cells = sd.cells
    nb = sd.n_bases
    dist = np.linalg.norm(Cd - sd.target[None], axis=2)          # (n_sel, n_bases) mm
    t_star = np.asarray(cells["t_star_s"], float)
    t_done = np.asarray(t_done, float)
    h_top = np.asarray(cells["thickness_top_mm"], float)
    h_bot = np.asarray(cells["thickness_bottom_mm"], float)
    clamped = np.asarray(cells.get("clamped", np.zeros(len(t_star))), int)
    out = {
        "version": 1, "name": name or sd.folder.resolve().name,
        "base_r": UNIT_CELL.base_r, "layer_h": UNIT_CELL.layer_h,
        "n_bases": int(nb), "n_cells": int(len(t_star)),
        "t": [round(float(x), 4) for x in t], "frames": sel.tolist(),
        "center": _positions(Cd, quantise),
        "quat": _b64(_quaternions(Rd), np.float32),
        "distance": _b64(dist, np.float32),
        "cells": {
            "base_a": pairs[:, 0].tolist(), "base_b": pairs[:, 1].tolist(),
            "t_star": _nan_list(t_star), "t_done": _nan_list(t_done),
            "h_top": _nan_list(h_top), "h_bottom": _nan_list(h_bot),
            "clamped": clamped.tolist(),
        },
        "base_fields": {
            "completion": _nan_list(_per_base(t_done, pairs, nb)),
            "timing_error": _nan_list(_per_base(t_done - t_star, pairs, nb)),
            "thickness": _nan_list(_per_base(0.5 * (h_top + h_bot), pairs, nb)),
        },
    }
    M = fr.get("membrane_vertices")
    tri = fr.get("membrane_triangles")
    if M is not None and tri is not None and np.asarray(tri).size:
        Md = np.einsum("fij,fvj->fvi", Q, np.asarray(M, float)[sel]) + s[:, None]
        out["membrane"] = {"tri": _b64(np.asarray(tri), np.uint32),
                           "n_vertices": int(Md.shape[1]), "pos": _positions(Md, quantise)}
    if sd.V is not None and sd.F is not None:
        out["target"] = {"V": _positions(sd.V, False), "F": _b64(sd.F, np.uint32),
                         "n_vertices": int(len(sd.V))}
    return out


def viewer_json(data: dict) -> str:
    """``data`` as JSON safe to embed in a ``<script type="application/json">`` element."""
    return json.dumps(data, separators=(",", ":")).replace("</", "<\\/")


__all__ = ["STATIC_DIR", "ASSETS", "asset_text", "frame_alignments", "viewer_data",
           "viewer_json"]
