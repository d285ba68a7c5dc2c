"""A simulated design folder, loaded and validated: the design (:func:`pysolver.tables.read_design`)
and its ``sim/frames.npz`` (the frames contract, ``docs/design-folder.md``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pysolver.errors import InputError
from pysolver.tables import Design, read_design

FRAME_KEYS = ("t", "base_center", "base_rotation", "bracket_length", "collided")
"""Arrays every ``frames.npz`` holds."""
OPTIONAL_KEYS = ("membrane_vertices", "membrane_triangles", "newton_iterations", "residual",
                 "wall_s", "converged", "marker_top", "marker_bottom")
"""Arrays a ``frames.npz`` may hold (checked when present)."""


def targets(design: Design) -> np.ndarray:
    """Target base centres, (m, 3) float, mm (``bases.csv``)."""
    b = design.bases
    return np.c_[b["target_x_mm"], b["target_y_mm"], b["target_z_mm"]]


def target_normals(design: Design) -> np.ndarray:
    """Target base normals, (m, 3) float (``bases.csv``)."""
    b = design.bases
    return np.c_[b["normal_x"], b["normal_y"], b["normal_z"]]


def cell_pairs(design: Design) -> np.ndarray:
    """The two bases of every unit cell, (c, 2) int (``cells.csv``)."""
    return np.c_[design.cells["base_a"], design.cells["base_b"]]


@dataclass
class SimData:
    """A design folder and its simulation, loaded and validated.

    The design is read by the one design-folder reader (:func:`pysolver.tables.read_design`,
    tables cross-checked against the stencil); the attributes below are views of it.

    Attributes
    ----------
    design : pysolver.tables.Design
    frames : dict of arrays — ``sim/frames.npz``
    folder : Path
    bases, cells : dict of (r,) arrays — ``bases.csv`` / ``cells.csv`` columns
    V, UV : (n, 3), (n, 2) float, mm — stencil (target, flat)
    F : (m, 3) int
    landscape : (n,) float, s — time landscape per stencil vertex
    """

    design: Design
    frames: dict

    folder = property(lambda self: self.design.folder)
    bases = property(lambda self: self.design.bases)
    cells = property(lambda self: self.design.cells)
    V = property(lambda self: self.design.V)
    UV = property(lambda self: self.design.UV)
    F = property(lambda self: self.design.F)
    landscape = property(lambda self: self.design.time)
    n_bases = property(lambda self: self.design.n_bases)
    n_cells = property(lambda self: self.design.n_cells)

    @property
    def t(self):
        return self.frames["t"]

    @property
    def target(self):
        return targets(self.design)

    @property
    def target_normals(self):
        return target_normals(self.design)

    @property
    def flat_xy(self):
        return np.c_[self.bases["flat_x_mm"], self.bases["flat_y_mm"]]

    @property
    def cell_pairs(self):
        return cell_pairs(self.design)


def load_frames(path, n_bases=None, n_cells=None) -> dict:
    """Read and validate ``sim/frames.npz``.

    Parameters
    ----------
    path : path-like
    n_bases, n_cells : int, optional
        Expected counts (from the tables).

    Returns
    -------
    dict of arrays (all contract keys present in the file).
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: file not found",
                         fix="run the simulation first (morphshell simulate <design_dir>)")
    try:
        with np.load(path, allow_pickle=False) as z:
            fr = {k: z[k] for k in z.files}
    except Exception as e:
        raise InputError(f"{path}: cannot read ({type(e).__name__}: {e})",
                         fix="re-run the simulation; the file is damaged") from None
    missing = [k for k in FRAME_KEYS if k not in fr]
    if missing:
        raise InputError(f"{path}: missing array(s) {missing}",
                         fix="re-run the simulation with the current sim.model.simulate")
    t = np.asarray(fr["t"], float)
    nf = len(t)
    if t.ndim != 1 or nf < 1:
        raise InputError(f"{path}: t has shape {t.shape}, expected (n_frames,) with n_frames >= 1")
    nb = fr["base_center"].shape[1] if fr["base_center"].ndim == 3 else -1
    nc = fr["collided"].shape[1] if fr["collided"].ndim == 3 else -1
    shapes = {"base_center": (nf, nb, 3), "base_rotation": (nf, nb, 3, 3),
              "bracket_length": (nf, nc, 4), "collided": (nf, nc, 4)}
    for k, s in shapes.items():
        if fr[k].shape != s:
            raise InputError(f"{path}: {k} has shape {fr[k].shape}, expected {s} "
                             "(n_frames, n_bases/n_cells, ...)",
                             fix="re-run the simulation; frames.npz does not follow the contract")
    if n_bases is not None and nb != n_bases:
        raise InputError(f"{path}: {nb} bases in the frames but {n_bases} rows in bases.csv",
                         fix="re-run the simulation after the last design change")
    if n_cells is not None and nc != n_cells:
        raise InputError(f"{path}: {nc} cells in the frames but {n_cells} rows in cells.csv",
                         fix="re-run the simulation after the last design change")
    if "membrane_vertices" in fr:
        mv = fr["membrane_vertices"]
        if mv.ndim != 3 or mv.shape[0] != nf or mv.shape[2] != 3:
            raise InputError(f"{path}: membrane_vertices has shape {mv.shape}, expected "
                             f"({nf}, n_mem, 3)")
        tri = fr.get("membrane_triangles")
        if tri is not None and tri.size and (tri.ndim != 2 or tri.shape[1] != 3 or tri.min() < 0
                                             or tri.max() >= mv.shape[1]):
            raise InputError(f"{path}: membrane_triangles must be (n_tri, 3) indices into "
                             f"0..{mv.shape[1] - 1}")
    for k in ("newton_iterations", "residual", "wall_s", "converged"):
        if k in fr and fr[k].shape != (nf,):
            raise InputError(f"{path}: {k} has shape {fr[k].shape}, expected ({nf},)")
    fr["t"] = t
    return fr


def load_sim(design_dir) -> SimData:
    """Load a design folder (:func:`pysolver.tables.read_design`) and its ``sim/frames.npz``."""
    folder = Path(design_dir)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a design folder",
                         fix="pass the folder written by the design stage (build/<shape>)")
    design = read_design(folder)
    frames = load_frames(folder / "sim" / "frames.npz", design.n_bases, design.n_cells)
    return SimData(design, frames)


def n_valid_frames(fr: dict) -> int:
    """Number of frames up to the first one with a non-finite position.

    Parameters
    ----------
    fr : dict
        ``frames.npz`` arrays: ``base_center`` (f, m, 3) mm, ``base_rotation`` (f, m, 3, 3),
        optionally ``membrane_vertices`` (f, k, 3) mm.
    """
    finite = (np.isfinite(fr["base_center"]).all(axis=(1, 2))
              & np.isfinite(fr["base_rotation"]).all(axis=(1, 2, 3)))
    M = fr.get("membrane_vertices")
    if M is not None and np.asarray(M).ndim == 3:
        finite &= np.isfinite(M).all(axis=(1, 2))
    return int(np.argmin(finite)) if not finite.all() else len(finite)


__all__ = ["FRAME_KEYS", "OPTIONAL_KEYS", "SimData", "load_frames", "load_sim",
           "n_valid_frames", "targets", "target_normals", "cell_pairs"]
