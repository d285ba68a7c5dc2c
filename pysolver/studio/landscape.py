"""Time-landscape editing for the studio: the requests' validation, keyframes -> a smooth
landscape, and a landscape's feasibility from the temporal stage's own computation.

The studio edits the landscape in the browser (brush strokes change the current landscape
where they pass; ``studio.js``) and sends it whole, one time per stencil vertex, to be
previewed or built.  A *keyframe* fixes the time at one stencil vertex; the keyframe tool
replaces the landscape by the harmonic interpolation of its keyframes on the target stencil
(Laplace's equation with the cotangent Laplacian, ``igl.harmonic``): smooth, no overshoot
(the maximum principle keeps it within the keyframe times).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from pathlib import Path

import numpy as np

from .. import tables, temporal
from ..build import check_landscape
from ..design.time_landscape import cell_target_times
from ..errors import InputError
from ..params import LIMITS
from ..temporal import program_cells
from ..temporal.membrane_model import load_membrane_model

EDIT_TOOLS = {"brush": ("set", "add", "subtract", "smooth"), "keyframes": ("harmonic",),
              "reset": ("build",), "import": ("csv",)}
"""The edit log's tools and their modes (``studio_landscape.json``)."""
_EDIT_NUMBERS = {"value": (-LIMITS.max_landscape_s, LIMITS.max_landscape_s),
                 "radius": (1e-3, LIMITS.studio_max_radius_mm),
                 "falloff": (0.0, 1.0), "vertices": (0, 10 ** 7),
                 "keyframes": (0, LIMITS.studio_max_edits)}


def _object(item, what: str, allowed) -> dict:
    """``item`` as a JSON object with only ``allowed`` keys."""
    if not isinstance(item, dict):
        raise InputError(f"{what} must be a JSON object, got {type(item).__name__}",
                         fix=f"send {{{', '.join(repr(k) for k in allowed)}}}")
    bad = sorted(set(item) - set(allowed))
    if bad:
        raise InputError(f"{what}: unknown key(s) {bad}",
                         fix=f"use only {', '.join(repr(k) for k in allowed)}")
    return item


def _number(item: dict, key: str, lo: float, hi: float, what: str, unit: str = "",
            integer: bool = False):
    """``item[key]`` as a finite number in ``[lo, hi]``; the message says which rule broke."""
    v = item.get(key)
    kind = "a whole number" if integer else "a number"
    ok = isinstance(v, int) if integer else isinstance(v, (int, float))
    if v is None or isinstance(v, bool) or not ok or not math.isfinite(v):
        raise InputError(f"{what}: {key} {v!r} is not {kind}" if key in item
                         else f"{what}: no {key}",
                         fix=f"give {key} as {kind} from {lo:g} to {hi:g}{unit}")
    if not lo <= v <= hi:
        raise InputError(f"{what}: {key} {v:g}{unit} is outside {lo:g}-{hi:g}{unit}",
                         fix=f"give {key} from {lo:g} to {hi:g}{unit}")
    return int(v) if integer else float(v)


def _list(payload: dict, key: str, most: int) -> list:
    v = payload.get(key, [])
    if not isinstance(v, list):
        raise InputError(f"'{key}' must be a list, got {type(v).__name__}")
    if len(v) > most:
        raise InputError(f"{len(v)} {key}", fix=f"send at most {most}")
    return v


def parse_keyframes(payload, n_vertices: int) -> list[tuple[int, float]]:
    """Validate the keyframe tool's request (untrusted JSON).

    Parameters
    ----------
    payload : dict
        ``{"keyframes": [{"vertex": int, "time": float (s)}, ...]}``.
    n_vertices : int

    Returns
    -------
    list of (int, float) -- vertex id, time (s)

    Raises
    ------
    InputError
        Not an object, unknown keys (also inside a keyframe), a vertex outside
        ``0..n_vertices-1``, a time that is not a number or outside
        ``[0, Limits.max_landscape_s]`` s.
    """
    payload = _object(payload, "the keyframe request", ("keyframes",))
    out = []
    for i, k in enumerate(_list(payload, "keyframes", LIMITS.studio_max_edits)):
        k = _object(k, f"keyframe {i}", ("vertex", "time"))
        out.append((_number(k, "vertex", 0, n_vertices - 1, f"keyframe {i}", integer=True),
                    _number(k, "time", 0.0, LIMITS.max_landscape_s, f"keyframe {i}", " s")))
    return out


def parse_landscape(payload, n_vertices: int, *, edits: bool = False):
    """Validate a landscape request (untrusted JSON): preview or run.

    Parameters
    ----------
    payload : dict
        ``{"landscape": [s per stencil vertex]}``, and with ``edits`` also ``"edits"``: the
        edit log, a list of ``{"tool", "mode", "value", "radius", "falloff", "vertices",
        "keyframes"}`` (tools and modes :data:`EDIT_TOOLS`; the numbers optional).
    n_vertices : int
    edits : bool
        Accept (and return) the edit log.

    Returns
    -------
    landscape : (n_vertices,) float, s
    edits : list of dict (only with ``edits=True``)

    Raises
    ------
    InputError
        Unknown keys, a landscape of the wrong length or with a time outside
        ``[0, LIMITS.max_landscape_s]`` s, or a malformed edit.
    """
    payload = _object(payload, "the landscape request",
                      ("landscape", "edits") if edits else ("landscape",))
    if "landscape" not in payload:
        raise InputError("the request has no 'landscape'",
                         fix="send one time in seconds per stencil vertex")
    land = payload["landscape"]
    if not isinstance(land, list) or any(isinstance(v, bool) or not isinstance(v, (int, float))
                                         for v in land):
        raise InputError("'landscape' must be a list of numbers (s)",
                         fix="send one time in seconds per stencil vertex")
    land = check_landscape(land, n_vertices)
    if not edits:
        return land
    log = []
    for i, e in enumerate(_list(payload, "edits", LIMITS.studio_max_edits)):
        e = _object(e, f"edit {i}", ("tool", "mode", *_EDIT_NUMBERS))
        tool, mode = e.get("tool"), e.get("mode")
        if tool not in EDIT_TOOLS or mode not in EDIT_TOOLS[tool]:
            raise InputError(f"edit {i}: tool {tool!r} mode {mode!r} is not a studio edit",
                             fix="tools and modes: " + "; ".join(
                                 f"{t}: {', '.join(m)}" for t, m in EDIT_TOOLS.items()))
        rec = {"tool": tool, "mode": mode}
        for key, (lo, hi) in _EDIT_NUMBERS.items():
            if key in e:
                rec[key] = _number(e, key, lo, hi, f"edit {i}",
                                   integer=key in ("vertices", "keyframes"))
        log.append(rec)
    return land, log


VARIANT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}")
"""Names a variant build may have (a folder beside the original: no path, no dot)."""
SHA256 = re.compile(r"[0-9a-f]{64}")


def landscape_sha256(landscape) -> str:
    """The hash that names a landscape in the studio's requests: SHA-256 of its times as
    little-endian float64 (``time_landscape.csv``'s values, as the build keeps them).

    Parameters
    ----------
    landscape : (n_vertices,) float, s
    """
    return hashlib.sha256(np.asarray(landscape, float).astype("<f8").tobytes()).hexdigest()


def run_base_sha256(folder, landscape) -> str:
    """The hash that names the landscape of one build in a *Run* request (``base_sha256``):
    SHA-256 of the build folder's resolved path and :func:`landscape_sha256`, so that an
    edit made on one build is refused by another, even one of the same name and landscape.

    Parameters
    ----------
    folder : path-like
        The build folder (as the studio opened it; resolved here).
    landscape : (n_vertices,) float, s
    """
    path = os.fsencode(Path(folder).resolve())
    return hashlib.sha256(path + b"\0" + landscape_sha256(landscape).encode()).hexdigest()


def parse_run(payload, n_vertices: int) -> dict:
    """Validate a *Run* request (untrusted JSON).

    Parameters
    ----------
    payload : dict
        ``{"build": name, "base_sha256": hex, "landscape": [...], "edits": [...],
        "variant": name or null}``: the build the edit was made on (its folder's name), the
        hash of that build and its landscape as the editor loaded them
        (:func:`run_base_sha256`),
        the landscape and edit log (:func:`parse_landscape`), and the name of a new build to
        run into (absent or null: the build itself).
    n_vertices : int

    Returns
    -------
    dict
        ``build`` (str), ``base_sha256`` (str), ``landscape`` ((n_vertices,) float, s),
        ``edits`` (list of dict), ``variant`` (str or None).

    Raises
    ------
    InputError
        No build name or hash, a hash that is not 64 hex digits, a variant name that is not
        a plain folder name, or a bad landscape or edit log.
    """
    keys = ("build", "base_sha256", "variant")
    payload = _object(payload, "the run request", ("landscape", "edits", *keys))
    name, base = payload.get("build"), payload.get("base_sha256")
    if not isinstance(name, str) or not name:
        raise InputError("the run request does not name its build",
                         fix="send 'build': the name of the build the edit was made on")
    if not isinstance(base, str) or not SHA256.fullmatch(base):
        raise InputError("the run request has no 'base_sha256' (64 hex digits)",
                         fix="send the hash of the landscape the editor loaded")
    variant = payload.get("variant")
    if variant is not None and (not isinstance(variant, str)
                                or not VARIANT_NAME.fullmatch(variant)):
        raise InputError(f"variant name {str(variant)[:80]!r} is not a plain folder name",
                         fix="use 1-64 letters, digits, '-' or '_' (e.g. petal-2), starting "
                             "with a letter or digit")
    land, edits = parse_landscape({k: v for k, v in payload.items() if k not in keys},
                                  n_vertices, edits=True)
    return {"build": name, "base_sha256": base, "landscape": land, "edits": edits,
            "variant": variant}


def parse_landscape_csv(text, n_vertices: int) -> np.ndarray:
    """A landscape from CSV text (untrusted: an upload), as the editor's *CSV* writes it.

    Parameters
    ----------
    text : str
        ``vertex_id,time_s`` then one row per stencil vertex, each id once (any order).
    n_vertices : int

    Returns
    -------
    (n_vertices,) float, s

    Raises
    ------
    InputError
        Not text, another header, a row that is not two numbers, an id outside
        ``0..n_vertices-1`` or given twice, a missing id, a time outside
        ``[0, LIMITS.max_landscape_s]`` s; the message names the line.
    """
    if not isinstance(text, str):
        raise InputError("the CSV must be sent as text", fix="send {'csv': '<file contents>'}")
    lines = [ln.strip() for ln in text.replace("\r\n", "\n").split("\n")]
    while lines and not lines[-1]:
        lines.pop()
    fix = "export a landscape with the CSV button and edit its time_s column"
    if not lines or lines[0].replace(" ", "") != "vertex_id,time_s":
        raise InputError(f"line 1 is {lines[0][:60] if lines else ''!r}, not the header "
                         "'vertex_id,time_s'", fix=fix)
    if len(lines) - 1 != n_vertices:
        raise InputError(f"{len(lines) - 1} rows for a target of {n_vertices} vertices",
                         fix=f"give one row per vertex, {n_vertices} in all")
    land = np.full(n_vertices, np.nan)
    for k, line in enumerate(lines[1:], start=2):
        cells = line.split(",")
        if len(cells) != 2 or not re.fullmatch(r"[0-9]{1,9}", cells[0].strip()):
            raise InputError(f"line {k} {line[:60]!r} is not 'vertex_id,time_s'", fix=fix)
        i = int(cells[0])
        if i >= n_vertices or not np.isnan(land[i]):
            raise InputError(f"line {k}: vertex {i} is "
                             + ("given twice" if i < n_vertices else
                                f"not one of 0-{n_vertices - 1}"), fix=fix)
        try:
            t = float(cells[1]) if _NUMBER.fullmatch(cells[1].strip()) else math.nan
        except ValueError:
            t = math.nan
        if not math.isfinite(t) or not 0 <= t <= LIMITS.max_landscape_s:
            raise InputError(f"line {k}: time {cells[1].strip()[:30]!r} is not a number from 0 "
                             f"to {LIMITS.max_landscape_s:g} s", fix=fix)
        land[i] = t
    return land


_NUMBER = re.compile(r"[-+]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][-+]?[0-9]+)?")


def keyframe_values(keyframes) -> tuple[np.ndarray, np.ndarray]:
    """Fixed vertices and their times; a later keyframe on the same vertex wins.

    Parameters
    ----------
    keyframes : list of (vertex, time_s)

    Returns
    -------
    b : (k,) int -- fixed vertex ids (sorted)
    bc : (k,) float, s
    """
    fixed = {int(v): float(t) for v, t in keyframes}
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
        raise InputError("no keyframe: the interpolation needs at least one fixed time",
                         fix="place a keyframe (click the target with the keyframe tool)")
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


__all__ = ["parse_keyframes", "parse_landscape", "parse_run", "parse_landscape_csv",
           "landscape_sha256", "run_base_sha256", "VARIANT_NAME", "keyframe_values",
           "harmonic_landscape", "Feasibility", "EDIT_TOOLS"]
