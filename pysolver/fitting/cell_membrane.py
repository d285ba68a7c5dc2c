"""Membrane traction on a unit cell at prescribed bracket lengths (for temporal programming).

Supplementary Note 4 models the membrane of a cell as a linear spring ``F_mem(b, d)`` fitted to
FEM simulations.  :func:`membrane_traction` provides such samples from *this* simulator's
mechanics (:mod:`pysolver.mechanics`, the model, energy and solver the simulator steps):

1. a flat regular patch (equilateral stencil, ``nx`` x ``ny`` vertices) whose cells all have
   the flat bracket length ``b0`` (central length ``b0 + 2 r cos 37``);
2. every bracket spring is replaced by a stiff linear spring (``k = 1e4 N/mm``) with rest
   length ``b0 - d`` -- the brackets are "prescribed" to length ``b0 - d``; the cross pairs and
   the membrane (pre-stretch, neo-Hookean, same mesh as a design) are unchanged;
3. the static equilibrium is solved (:func:`pysolver.mechanics.solver.newton`): bases and
   free membrane vertices relax;
4. the traction of the most interior cell is the compression force of its four springs,
   ``sum k (rest - L)`` (N): the force with which the membrane pulls the two bases together,
   which the brackets must carry.  Per bracket it is a quarter of that.

The stiff springs hold the lengths to ~1e-4 mm; with symmetric layers the patch stays flat.
At ``d = 0`` the pre-stress is uniform and the traction has the closed form
``mu h (1 - tau^-6) sqrt(3) l0`` (first Piola stress times the stencil edge; tested).
Interior cells of a patch with 2+ rings of cells around them are representative of cells
far from a free boundary (boundary cells carry less; Note 4 uses a factor 0.6).
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import numpy as np

from pysolver.design.cellnodes import model_arrays
from pysolver.design.surfaces import regular_grid
from pysolver.errors import InputError
from pysolver.mechanics import build_model
from pysolver.mechanics.energies import ShellEnergy, State
from pysolver.mechanics.solver import StaticProblem, newton
from pysolver.params import MODEL_FITS, SIM, UNIT_CELL

K_PRESCRIBE = 1e4  # N/mm, stiffness of the length-prescribing springs


@lru_cache(maxsize=16)
def _patch(b0: float, nx: int, ny: int, max_area: float):
    l0 = b0 + UNIT_CELL.bracket_offset
    UV, F = regular_grid(nx, ny, l0 * np.sqrt(3))  # centroid distance = edge / sqrt 3
    UV = UV - UV.mean(axis=0)
    V = np.c_[UV, np.zeros(len(UV))]
    geometry = model_arrays(V, UV, F)
    nc = len(geometry["cell_bases"])
    consts = dataclasses.replace(SIM, membrane_max_area=max_area)
    model = build_model(V, UV, F, np.full((nc, 2), 0.45), geometry, consts=consts,
                        source="membrane_traction patch")
    # most interior cell: farthest (flat) from the free boundary vertices
    vb = geometry["boundary_vertex"]
    mid = 0.5 * (model.base_flat[model.cell_bases[:, 0]] + model.base_flat[model.cell_bases[:, 1]])
    dist = np.linalg.norm(mid[:, None, :2] - UV[vb][None], axis=2).min(axis=1)
    return model, ShellEnergy(model), int(np.argmax(dist))


def membrane_traction(l0_mm, d_mm, *, nx: int = 7, ny: int = 6,
                      max_area: float = SIM.membrane_max_area, return_details: bool = False):
    """Membrane pull on an interior unit cell whose brackets are held at ``l0 - d``.

    Parameters
    ----------
    l0_mm : float or array_like, mm
        Initial (flat) bracket length b0 of the cells (0.8-6.3 mm; central length
        ``b0 + 3.1945``).
    d_mm : float or array_like, mm
        Shortening of the brackets, ``b0 - b`` (0 <= d < b0).
    nx, ny : int
        Patch size in stencil vertices (default 7 x 6: 60 bases, the central cell has two
        rings of cells around it).
    max_area : float, mm^2
        Membrane mesh size.  The default is the simulator's (5 mm^2, as the reference), so the
        traction is the one the simulation will see; finer meshes converge to the continuum
        value, which is up to ~10 % higher for short cells at large d.
    return_details : bool
        Also return a dict (per sample: residual N, maximum out-of-plane mm, cell id).

    Returns
    -------
    T : float or ndarray, N
        Total force of the cell's four brackets (positive = the membrane compresses them).
    details : list of dict, optional
    """
    l0, d = np.broadcast_arrays(np.asarray(l0_mm, float), np.asarray(d_mm, float))
    out = np.empty(l0.shape)
    details = []
    for idx in np.ndindex(l0.shape):
        b0, dd = float(l0[idx]), float(d[idx])
        b_lo, b_hi = MODEL_FITS.membrane_b0_mm
        d_frac = MODEL_FITS.membrane_d_max_fraction
        if not (b_lo <= b0 <= b_hi) or not (0.0 <= dd < d_frac * b0):
            raise InputError(f"membrane_traction: b0 = {b0} mm, d = {dd} mm out of range",
                             fix=f"use {b_lo:g} <= b0 <= {b_hi:g} mm and 0 <= d < {d_frac:g} b0")
        model, energy, cell = _patch(round(b0, 9), nx, ny, float(max_area))
        rest = np.full(len(model.spring_rest0), b0 - dd)
        energy.spring_rest = rest
        energy.spring_coef = np.tile([K_PRESCRIBE, 0.0, 0.0, 0.0], (len(rest), 1))
        s = State.flat(model)
        scale = (b0 - dd + UNIT_CELL.bracket_offset) / (b0 + UNIT_CELL.bracket_offset)
        c0 = s.c.mean(axis=0)
        s.c = c0 + scale * (s.c - c0)  # start from the uniformly contracted layout
        s.f = c0 + scale * (s.f - c0)
        problem = StaticProblem(energy, s)
        res = newton(problem, max_iter=100)
        X, _ = energy.positions(problem.state)
        sp_ = model.spring_points[4 * cell: 4 * cell + 4]
        L = np.linalg.norm(X[sp_[:, 1]] - X[sp_[:, 0]], axis=1)
        out[idx] = float(np.sum(K_PRESCRIBE * (rest[:4] - L)))
        details.append({"residual_N": res.residual, "converged": res.converged,
                        "max_out_of_plane_mm": float(np.abs(X[:, 2]).max()), "cell": cell})
    T = out if out.shape else float(out)
    return (T, details) if return_details else T


__all__ = ["membrane_traction", "K_PRESCRIBE"]
