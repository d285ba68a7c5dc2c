"""Bracket node layout of the simulator (``shared/design/simulator.md`` §4), shared by design.

Per base ``i``, slot ``j`` (edge opposite ``F[i, j]``), arm ``k`` in {0, 1} and layer
``s`` in {0 top, 1 bottom}, the node sits on the base rim at +-alpha (37 deg) around
the in-plane direction to the neighbour, at the layer's far face:

    node = Fc_i + r (cos(alpha) d + (1 - 2k) sin(alpha) p) + (1 - 2s) layer_h n_i

with ``d_raw = Fc_nb - Fc_i`` (or, on a boundary slot, the edge midpoint minus Fc_i),
``p = normalize(d_raw x n_i)``, ``d = normalize(n_i x p)``.  ``k = 0`` lies next to
vertex ``F[i, (j+1)%3]``, ``k = 1`` next to ``F[i, (j+2)%3]``.  Across a cell, base a's
node ``k = q`` faces base b's node ``k = 1 - q`` (both by the same stencil vertex).

The flat pose is the same rigid base moved rigidly:
``x_flat = R_i^T (x_target - Fc_i) + (Fc2d_i, 0)``, with ``R_i`` from
:func:`pysolver.geometry.base_rotations` (the rotation stored in ``bases.csv``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import tables
from ..geometry import (
    Cells,
    base_rotations,
    boundary_vertex_mask,
    face_adjacency,
    face_centroids,
    face_normals,
    rotvec_to_matrix,
    unit_cells,
)
from ..params import UNIT_CELL, UnitCell


def bracket_nodes(V, UV, F, params: UnitCell = UNIT_CELL, *, ff=None, rotvec=None):
    """Bracket node positions in the target and in the flat pose.

    Parameters
    ----------
    V : (n, 3) float, mm
        Target stencil vertices (scaled, as in ``stencil.obj``).
    UV : (n, 2) float, mm
        Flat stencil vertices (scaled).
    F : (m, 3) int
    params : UnitCell
    ff : (m, 3) int, optional
        Face adjacency (computed if omitted).
    rotvec : (m, 3) float, rad, optional
        Base rotations (``bases.csv`` ``rot_*_rad``); recomputed if omitted.

    Returns
    -------
    nodes_target : (m, 3, 2, 2, 3) float, mm
        Indexed ``[base, slot j, arm k, layer s, xyz]``.
    nodes_flat : (m, 3, 2, 2, 3) float, mm
        Same nodes in the flat shell frame (top layer z = +2.3, bottom z = -2.3).
    """
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    if ff is None:
        ff = face_adjacency(F)
    if rotvec is None:
        R, _ = base_rotations(V, UV, F, ff)
    else:
        R = rotvec_to_matrix(np.asarray(rotvec, float).reshape(-1, 3))
    Fc = face_centroids(V, F)
    C2 = face_centroids(UV, F)
    N = face_normals(V, F)
    m = len(F)
    # d_raw per slot: to the neighbour centroid, or to the boundary edge midpoint
    mid = 0.5 * (V[F[:, [1, 2, 0]]] + V[F[:, [2, 0, 1]]])  # (m, 3 slots, 3)
    nbc = Fc[np.maximum(ff, 0)]
    d_raw = np.where((ff >= 0)[..., None], nbc, mid) - Fc[:, None, :]
    Nn = np.broadcast_to(N[:, None, :], d_raw.shape)
    p = np.cross(d_raw, Nn)
    p /= np.linalg.norm(p, axis=-1, keepdims=True)
    d = np.cross(Nn, p)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    a = params.alpha_rad
    r = params.base_r
    h = params.layer_h
    k_sign = np.array([1.0, -1.0])  # (1 - 2k)
    s_sign = np.array([1.0, -1.0])  # (1 - 2s)
    nodes_t = (Fc[:, None, None, None, :]
               + r * np.cos(a) * d[:, :, None, None, :]
               + r * np.sin(a) * k_sign[None, None, :, None, None] * p[:, :, None, None, :]
               + h * s_sign[None, None, None, :, None] * N[:, None, None, None, :])
    rel = nodes_t - Fc[:, None, None, None, :]
    flat = np.einsum("mji,mabcj->mabci", R, rel)  # R^T rel
    flat[..., :2] += C2[:, None, None, None, :]
    assert nodes_t.shape == (m, 3, 2, 2, 3)
    return nodes_t, flat


def collision_lengths(nodes_target, cells: Cells) -> np.ndarray:
    """Bracket length at bumper contact per cell and layer (mm), b1 of Note 4.

    Mean target distance of the layer's two facing node pairs: base a's ``k = q``
    node and base b's ``k = 1 - q`` node, q in {0, 1}.

    Parameters
    ----------
    nodes_target : (m, 3, 2, 2, 3) float
    cells : Cells

    Returns
    -------
    L : (c, 2) float, mm
        Columns: top, bottom.
    """
    a, b = cells.faces[:, 0], cells.faces[:, 1]
    ja, jb = cells.slots[:, 0], cells.slots[:, 1]
    out = np.zeros((len(a), 2))
    for s in (0, 1):
        acc = 0.0
        for q in (0, 1):
            acc = acc + np.linalg.norm(nodes_target[a, ja, q, s] - nodes_target[b, jb, 1 - q, s],
                                       axis=1)
        out[:, s] = acc / 2
    return out


def cell_collision_lengths(V, UV, F, params: UnitCell = UNIT_CELL) -> np.ndarray:
    """Convenience: ``collision_lengths(bracket_nodes(V, UV, F)[0], unit_cells(F))``."""
    nt, _ = bracket_nodes(V, UV, F, params)
    return collision_lengths(nt, unit_cells(F))


def model_arrays(V, UV, F, params: UnitCell = UNIT_CELL, *, rotvec=None) -> dict:
    """The simulator's geometry of a stencil: unit-cell topology and bracket nodes.

    The design stage writes these arrays to ``model.npz`` (:func:`write_model_file`); the
    simulator reads them (:func:`pysolver.tables.read_model`) instead of re-deriving the
    design's geometry.

    Parameters
    ----------
    V : (n, 3) float, mm
    UV : (n, 2) float, mm
    F : (m, 3) int
    params : UnitCell
    rotvec : (m, 3) float, rad, optional
        Base rotations (``bases.csv``); recomputed if omitted.

    Returns
    -------
    dict
        ``face_adjacency`` (m, 3) int, ``cell_bases``, ``cell_slots``, ``cell_verts`` (c, 2)
        int, ``cell_of`` (m, 3) int, ``cell_boundary`` (c,) bool, ``boundary_vertex`` (n,)
        bool, ``nodes_target`` and ``nodes_flat`` (m, 3, 2, 2, 3) float, mm
        (:func:`bracket_nodes`).
    """
    F = np.asarray(F, dtype=np.int64)
    ff = face_adjacency(F)
    cells = unit_cells(F, ff)
    nodes_t, nodes_f = bracket_nodes(V, UV, F, params, ff=ff, rotvec=rotvec)
    return {"face_adjacency": ff, "cell_bases": cells.faces, "cell_slots": cells.slots,
            "cell_verts": cells.verts, "cell_of": cells.cell_of,
            "cell_boundary": cells.boundary,
            "boundary_vertex": boundary_vertex_mask(F, ff, len(V)),
            "nodes_target": nodes_t, "nodes_flat": nodes_f}


def write_model_file(folder, params: UnitCell = UNIT_CELL) -> Path:
    """Write ``model.npz`` from the folder's ``stencil.obj`` and ``bases.csv`` as stored.

    The arrays are computed from the tables read back (rounded as written), so the
    simulator sees exactly the geometry the tables describe.
    """
    folder = Path(folder)
    V, UV, F = tables.read_stencil(folder / "stencil.obj")
    b = tables.read_table(folder, "bases")
    rot = np.c_[b["rot_x_rad"], b["rot_y_rad"], b["rot_z_rad"]]
    arrays = model_arrays(V, UV, F, params, rotvec=rot)
    return tables.write_model(folder, arrays, tables.model_inputs_hash(folder, params))


__all__ = ["bracket_nodes", "collision_lengths", "cell_collision_lengths", "model_arrays",
           "write_model_file"]
