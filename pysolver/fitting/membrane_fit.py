"""Offline fit of the linearised membrane model ``F_mem(b, d)`` (SI Note 4), apart from the
runtime model (:mod:`pysolver.temporal.membrane_model`).

``make membrane-model`` (``morphshell fit-membrane``) samples regular patches with the FEM
membrane of :mod:`pysolver.temporal.membrane_model` (:func:`sample_patch`), fits the model by
least squares and writes ``pysolver/data/membrane_model.json`` with its picture.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import math
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from ..core.writes import atomic_file, atomic_write_text, make_dirs
from ..mechanics import MembraneMesh
from ..params import MEMBRANE_MODEL_FILE, MODEL_FITS, SIM, UNIT_CELL
from ..params import tol as TOL
from ..temporal.membrane_model import (
    FORM,
    MODEL_TERMS,
    SI_TERMS,
    PlaneMembrane,
    _design_matrix,
    cell_tractions,
    form_string,
    layout_membrane,
    relax_contracted,
)

DEFAULT_REPORT_DIR = Path("build") / "membrane"

# Sampling grid of the committed fit.  l0 = flat central length of the cells (mm):
# the material model covers l = 4..9 mm and the layout allows up to max_cell_length.
# d = bracket shortening (mm): collision lengths in the built-in shapes need up to
# about 2.3 mm; cells are sampled while the bracket stays longer than MIN_BRACKET.
SAMPLE_L0 = tuple(np.round(np.arange(4.0, UNIT_CELL.max_cell_length + 0.01, 0.5), 6))
SAMPLE_D = tuple(np.round(np.arange(0.0, 3.01, 0.25), 6))
MIN_BRACKET = 0.8            # mm, shortest sampled bracket ...
MIN_BRACKET_FRACTION = 0.35  # ... and at most 65 % shortening (the gap membrane stays stretched)
PATCH_RINGS = 3


def regular_patch(l0: float, rings: int = PATCH_RINGS):
    """Hexagonal patch of an equilateral stencil with central length ``l0``.

    Parameters
    ----------
    l0 : float, mm
        Distance between neighbouring face centroids (the cell's central length).
    rings : int
        Hexagon radius in stencil edges.

    Returns
    -------
    V : (nv, 2) float, mm
        Stencil vertices (flat).
    F : (nf, 3) int
        Faces, counter-clockwise.
    vdist : (nv,) int
        Hexagonal distance of each vertex from the central vertex.
    """
    a = math.sqrt(3.0) * l0
    e1 = np.array([a, 0.0])
    e2 = np.array([a / 2, a * math.sqrt(3.0) / 2])
    idx = {}
    V, dist = [], []
    for j in range(-rings, rings + 1):
        for i in range(-rings, rings + 1):
            h = (abs(i) + abs(j) + abs(i + j)) // 2       # hex distance, 60 deg basis
            if h <= rings:
                idx[(i, j)] = len(V)
                V.append(i * e1 + j * e2)
                dist.append(h)
    F = []
    for j in range(-rings - 1, rings + 1):
        for i in range(-rings - 1, rings + 1):
            _add_faces(i, j, idx, F)
    return np.array(V), np.array(F, dtype=int), np.array(dist, dtype=int)


def _add_faces(i, j, idx, F):
    """The up and down triangles of lattice rhombus (i, j) whose corners are all in ``idx``."""
    up = [(i, j), (i + 1, j), (i, j + 1)]
    down = [(i + 1, j), (i + 1, j + 1), (i, j + 1)]
    for tri in (up, down):
        if all(t in idx for t in tri):
            F.append([idx[t] for t in tri])


@dataclass
class PatchMesh:
    """A regular sampling patch: its stencil, its membrane mesh and its cells' bookkeeping.

    Attributes
    ----------
    l0 : float, mm -- flat central length of every cell
    mesh : MembraneMesh -- the patch's membrane (:func:`pysolver.mechanics.membrane_mesh`)
    centers : (nf, 2) float, mm -- flat base centres
    cell_bases : (nc, 2) int -- bases (a, b) of each cell (design-folder order)
    cell_boundary : (nc,) bool -- an end of the cell's stencil edge is a boundary vertex
    cell_boundary_faces : (nc,) int -- fewest faces around a boundary end (0 = interior)
    cell_depth : (nc,) int -- graph distance (edges) of the edge's ends from the boundary
    """

    l0: float
    mesh: MembraneMesh
    centers: np.ndarray
    cell_bases: np.ndarray
    cell_boundary: np.ndarray
    cell_boundary_faces: np.ndarray
    cell_depth: np.ndarray


def _vertex_depth(F, bnd):
    """Graph distance (edges) of every stencil vertex from the boundary, (nv,) int."""
    nv = len(bnd)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    A = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(nv, nv)).tocsr()
    return csgraph.dijkstra(A, directed=False, unweighted=True,
                            indices=np.flatnonzero(bnd)).min(axis=0).astype(int)


def patch_mesh(l0: float, rings: int = PATCH_RINGS,
               max_area: float = MODEL_FITS.membrane_fit_max_area) -> PatchMesh:
    """Membrane mesh of :func:`regular_patch`: the one membrane mesh of a flat layout
    (:func:`pysolver.temporal.membrane_model.layout_membrane`), and the cells' depth."""
    V, F, _ = regular_patch(l0, rings)
    mesh, g, C = layout_membrane(V, F, max_area)
    verts, bnd = g["cell_verts"], g["boundary_vertex"]
    nfaces = np.bincount(F.ravel(), minlength=len(V))
    at_bnd = np.where(bnd[verts], nfaces[verts], np.iinfo(np.int64).max).min(axis=1)
    return PatchMesh(l0=l0, mesh=mesh, centers=C, cell_bases=g["cell_bases"],
                     cell_boundary=g["cell_boundary"],
                     cell_boundary_faces=np.where(g["cell_boundary"], at_bnd, 0),
                     cell_depth=_vertex_depth(F, bnd)[verts].min(axis=1))


def sample_patch(l0: float, d_values, rings: int = PATCH_RINGS,
                 max_area: float = MODEL_FITS.membrane_fit_max_area, return_energy: bool = False,
                 mesh=None):
    """FEM tractions of every cell of a regular patch contracted by each ``d``.

    Parameters
    ----------
    l0 : float, mm
        Flat central length of the cells.
    d_values : (k,) float, mm
        Bracket shortenings to sample, ascending from 0.
    rings : int
        Patch size (stencil rings).
    max_area : float, mm^2
        Membrane mesh size (flat).
    return_energy : bool
        Also return the relaxed membrane energy.
    mesh : PatchMesh, optional
        A mesh of the patch made before (default :func:`patch_mesh`).

    Returns
    -------
    out : dict
        ``T`` (k, nc) N per cell, ``mesh`` (:class:`PatchMesh`), ``d`` (k,) mm,
        and with ``return_energy`` the relaxed energy ``E`` (k,) N mm.
    """
    pm = patch_mesh(l0, rings, max_area) if mesh is None else mesh
    mem = PlaneMembrane(pm.mesh.xy, pm.mesh.tris)
    x = pm.mesh.xy.copy()
    T, E = [], []
    for d in d_values:
        s = (l0 - d) / l0         # uniform contraction: every cell shortens by d * l / l0
        x = relax_contracted(pm.mesh, pm.centers, mem, s, x)
        T.append(cell_tractions(pm.mesh, pm.centers, pm.cell_bases, mem, x))
        E.append(mem.energy(x))
    out = {"T": np.array(T), "mesh": pm, "d": np.asarray(d_values, dtype=float)}
    if return_energy:
        out["E"] = np.array(E)
    return out


def _lstsq(b, d, T, terms):
    A = _design_matrix(b, d, terms)
    coef, *_ = np.linalg.lstsq(A, T, rcond=None)
    r = T - A @ coef
    return coef, {"terms": list(terms), "form": form_string(terms),
                  "coefficients": [float(c) for c in coef],
                  "residual_rms_N": float(np.sqrt(np.mean(r ** 2))),
                  "residual_max_N": float(np.max(np.abs(r))),
                  "relative_rms": float(np.sqrt(np.mean((r / T) ** 2))),
                  "relative_max": float(np.max(np.abs(r / T)))}


def _code_version() -> dict:
    src = Path(__file__).read_bytes()
    v = {"module_sha256": hashlib.sha256(src).hexdigest()[:16]}
    try:
        v["morphshell"] = importlib.metadata.version("morphshell")
    except Exception:  # noqa: BLE001 - provenance only
        v["morphshell"] = "unknown"
    try:
        r = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                           text=True, cwd=Path(__file__).resolve().parent, timeout=10)
        v["git_head"] = r.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        v["git_head"] = "unknown"
    return v


def fit_membrane_model(out_path=None, report_dir=None, *, l0_values=SAMPLE_L0,
                       d_values=SAMPLE_D, rings: int = PATCH_RINGS,
                       max_area: float = MODEL_FITS.membrane_fit_max_area,
                       progress: bool = True) -> dict:
    """Re-fit the linearised membrane model from FEM samples of regular patches.

    Parameters
    ----------
    out_path : path-like, optional
        Model file to write (default: the committed ``pysolver/data/membrane_model.json``).
    report_dir : path-like, optional
        Folder for the fit picture ``membrane_fit.png`` (default ``build/membrane``).
    l0_values, d_values : sequence of float, mm
        Sampling grid: flat central lengths and bracket shortenings.
    rings, max_area
        Patch size (stencil rings) and membrane mesh size (flat mm^2).

    Returns
    -------
    model : dict
        The content written to ``out_path``: ``form``, ``coefficients``, ``fit``
        (residuals), ``boundary`` (measured weakening of boundary cells),
        ``samples``, ``sampling`` and ``provenance``.
    """
    t0 = time.perf_counter()
    out_path = Path(out_path) if out_path is not None else MEMBRANE_MODEL_FILE
    report_dir = Path(report_dir) if report_dir is not None else DEFAULT_REPORT_DIR
    b_all, d_all, T_all, ratio, per_l0 = _fit_samples(l0_values, d_values, rings, max_area,
                                                      progress, t0)
    coef, fit = _lstsq(b_all, d_all, T_all, MODEL_TERMS)
    alternatives = [_lstsq(b_all, d_all, T_all, t)[1] for t in (SI_TERMS, ("1", "b", "d"))]
    by_faces = {str(int(k)): {"mean": float(ratio[ratio[:, 2] == k, 3].mean()),
                              "min": float(ratio[ratio[:, 2] == k, 3].min()),
                              "max": float(ratio[ratio[:, 2] == k, 3].max())}
                for k in np.unique(ratio[:, 2])}
    model = {
        "form": FORM,
        "description": "Membrane traction pulling a unit cell's two bases together (N, total "
                       "over the cell's 4 brackets); b = flat bracket length b0 (mm), d = "
                       "shortening b0 - b (mm). Per-bracket target = F_mem / 4.",
        "terms": list(MODEL_TERMS),
        "coefficients": [float(c) for c in coef],
        "units": "N for F; b, d in mm",
        "boundary_factor": float(SIM.boundary_weakening),
        "fit": dict(fit, n_samples=int(len(T_all)), alternatives=alternatives),
        "boundary": {
            "ratio_by_faces_at_boundary_vertex": by_faces,
            "note": "FEM traction of boundary cells / interior traction at the same (b0, d) in "
                    "the uniformly contracted patch, grouped by the number of stencil faces "
                    "around the cell's boundary end (3 = straight boundary, 2 = convex corner). "
                    "The design uses boundary_factor (the paper's 0.6) for every boundary cell.",
            "rows_b0_d_faces_ratio": np.round(ratio, 6).tolist(),
        },
        "samples": {"b0_mm": b_all.tolist(), "d_mm": d_all.tolist(),
                    "force_N": [float(t) for t in T_all]},
        "sampling": _sampling_record(l0_values, d_values, rings, max_area, per_l0),
        "provenance": dict(_code_version(), command="morphshell fit-membrane",
                           fit_seconds=round(time.perf_counter() - t0, 2)),
    }

    atomic_write_text(out_path, json.dumps(model, indent=1) + "\n")
    png = plot_membrane_fit(model, report_dir / "membrane_fit.png")
    model["picture"] = str(png)
    if progress:
        f = model["fit"]
        print(f"[membrane] F_mem = {FORM}, c = {np.round(coef, 4).tolist()}  "
              f"(rms {f['residual_rms_N']:.4f} N, max "
              f"{f['residual_max_N']:.4f} N) -> {out_path}, {png}", file=sys.stderr, flush=True)
    return model


def _fit_samples(l0_values, d_values, rings: int, max_area: float, progress: bool, t0: float):
    """The FEM samples of the fit: per flat central length, the interior cells' mean
    traction at each shortening, and the boundary cells' ratio to it.

    Returns
    -------
    b, d, T : (k,) float -- bracket length (mm), shortening (mm), traction (N)
    ratio : (r, 4) float -- rows ``[b0, d, faces at the boundary vertex, ratio]``
    per_l0 : list of dict -- mesh sizes and the interior spread per length
    """
    b_all, d_all, T_all, ratio_rows = [], [], [], []
    per_l0 = []
    for k, l0 in enumerate(l0_values):
        b0 = UNIT_CELL.bracket_length(l0)
        ds = [d for d in d_values
              if b0 - d >= max(MIN_BRACKET, MIN_BRACKET_FRACTION * b0) - TOL.exact]
        res = sample_patch(l0, ds, rings, max_area)
        mesh = res["mesh"]
        inner = (mesh.cell_depth >= 2) & ~mesh.cell_boundary
        Tin = res["T"][:, inner].mean(axis=1)
        spread = np.ptp(res["T"][:, inner], axis=1).max() if inner.sum() > 1 else 0.0
        b_all += [b0] * len(ds)
        d_all += list(ds)
        T_all += list(Tin)
        for i, d in enumerate(ds):
            for nf in np.unique(mesh.cell_boundary_faces[mesh.cell_boundary]):
                sel = mesh.cell_boundary_faces == nf
                ratio_rows.append((b0, d, nf, res["T"][i, sel].mean() / Tin[i]))
        per_l0.append({"l0_mm": float(l0), "b0_mm": float(b0),
                       "n_nodes": int(len(mesh.mesh.xy)), "n_triangles": int(len(mesh.mesh.tris)),
                       "n_interior_cells": int(inner.sum()),
                       "n_boundary_cells": int(mesh.cell_boundary.sum()),
                       "interior_spread_N": float(spread)})
        if progress:
            el = time.perf_counter() - t0
            eta = el / (k + 1) * (len(l0_values) - k - 1)
            print(f"[membrane] l0 = {l0:.2f} mm: {len(ds)} samples, "
                  f"{len(mesh.mesh.tris)} triangles, "
                  f"T(d=0) = {Tin[0]:.3f} N  ({el:.0f} s, ETA {eta:.0f} s)",
                  file=sys.stderr, flush=True)
    b_all, d_all, T_all = map(np.asarray, (b_all, d_all, T_all))
    return b_all, d_all, T_all, np.array(ratio_rows), per_l0


def _sampling_record(l0_values, d_values, rings: int, max_area: float, per_l0) -> dict:
    """``sampling`` of the model file: how the samples were made, and a mesh check at one
    length (the fit's mesh, a finer one and the simulator's coarser one)."""
    check_d = [0.0, 1.0, 2.0]
    mesh_check = {"l0_mm": 7.0, "d_mm": check_d}
    for key, area in (("fit_mesh", max_area), ("fine_mesh", max_area / 2.5),
                      ("simulator_mesh", SIM.membrane_max_area)):
        r = sample_patch(7.0, check_d, rings, area)
        ms = r["mesh"]
        inner = (ms.cell_depth >= 2) & ~ms.cell_boundary
        mesh_check[key] = {"max_area_mm2": area, "n_triangles": int(len(ms.mesh.tris)),
                           "force_N": [float(v) for v in r["T"][:, inner].mean(axis=1)]}
    return {
        "method": "hexagonal patch of an equilateral stencil, uniform contraction of the "
                  "base centres (bases rigid, not rotating), free membrane relaxed "
                  "(incompressible neo-Hookean CST, rest = flat / tau); force across the "
                  "stencil edge of interior cells (>= 2 rings from the boundary), averaged",
        "l0_mm": [float(v) for v in l0_values],
        "d_mm": [float(v) for v in d_values],
        "min_bracket_mm": MIN_BRACKET,
        "min_bracket_fraction": MIN_BRACKET_FRACTION, "patch_rings": rings,
        "mesh_max_area_mm2": max_area, "mesh_min_angle_deg": SIM.membrane_min_angle,
        "tau": SIM.tau, "mu_MPa": SIM.mu, "membrane_h_mm": SIM.membrane_h,
        "base_r_mm": UNIT_CELL.base_r, "alpha_deg": UNIT_CELL.alpha_deg,
        "per_l0": per_l0,
        "mesh_check": mesh_check,
    }


def plot_membrane_fit(model: dict, png) -> Path:
    """Linear model (dashed) against the FEM samples (solid) per initial length, like SI Fig. 8a."""
    import matplotlib  # optional heavy dependency: matplotlib loads only when a picture is drawn

    matplotlib.use("Agg")
    # optional heavy dependency: matplotlib loads only when a picture is drawn
    import matplotlib.pyplot as plt

    png = Path(png)
    make_dirs(png.parent)
    s = model["samples"]
    b, d, T = (np.asarray(s[k]) for k in ("b0_mm", "d_mm", "force_N"))
    coef = np.asarray(model["coefficients"])
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.5), gridspec_kw={"width_ratios": [3, 2]})
    bs = np.unique(b)
    cmap = plt.get_cmap("viridis")
    for i, bb in enumerate(bs):
        m = b == bb
        col = cmap(i / max(1, len(bs) - 1))
        ax.plot(d[m], T[m], "-", color=col, lw=1.6, label=f"b0 = {bb:.2f} mm")
        dd = np.linspace(0, d[m].max(), 20)
        ax.plot(dd, _design_matrix(np.full_like(dd, bb), dd, model["terms"]) @ coef, "--",
                color=col, lw=1.2)
    ax.set_xlabel("membrane spring shortening d = b0 - b (mm)")
    ax.set_ylabel("membrane traction on a unit cell F_mem (N, 4 brackets)")
    f = model["fit"]
    ax.set_title(f"FEM patch samples (solid) vs {model['form']} (dashed)\n"
                 f"rms {f['residual_rms_N']:.3f} N, max {f['residual_max_N']:.3f} N, "
                 f"{f['n_samples']} samples", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    rows = np.asarray(model["boundary"]["rows_b0_d_faces_ratio"])
    styles = {2: ":", 3: "-", 4: "-."}
    for nf in np.unique(rows[:, 2]):
        for i, bb in enumerate(bs):
            m = np.isclose(rows[:, 0], bb) & (rows[:, 2] == nf)
            ax2.plot(rows[m, 1], rows[m, 3], styles.get(int(nf), "--"),
                     color=cmap(i / max(1, len(bs) - 1)), lw=1.2,
                     label=f"{int(nf)} faces at the boundary end" if i == len(bs) - 1 else None)
    ax2.axhline(model["boundary_factor"], color="k", ls="--", lw=1,
                label=f"design factor {model['boundary_factor']:.2f}")
    ax2.set_xlabel("d (mm)")
    ax2.set_ylabel("boundary / interior traction")
    ax2.set_title("boundary cells of the patch (colour = b0)", fontsize=9)
    ax2.legend(fontsize=8)
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    with atomic_file(png) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)
    return png


__all__ = ["fit_membrane_model", "plot_membrane_fit", "regular_patch", "patch_mesh", "PatchMesh",
           "sample_patch", "SAMPLE_L0", "SAMPLE_D", "PATCH_RINGS"]
