"""The one membrane mesh (pysolver.mechanics.membrane_mesh) of the simulator and of temporal
programming (F_mem sampler, fit and per-cell correction).

Tolerances: identity of the meshes is exact (same arrays); geometric properties to 1e-9 mm
(collinearity, lengths) or 1e-9 relative (areas); triangle areas within max_area.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from synthetic import regular_stencil

from pysolver.design.cellnodes import model_arrays
from pysolver.design.surfaces import regular_grid
from pysolver.fitting.membrane_fit import patch_mesh
from pysolver.mechanics import build_model, membrane_mesh
from pysolver.params import PROGRAMMING, SIM, UNIT_CELL
from pysolver.temporal.membrane_model import (
    cell_membrane_factors,
    layout_membrane,
    load_membrane_model,
)


def _cap_layout():
    """A curved design's layout: flat corners are the target nodes rotated flat."""
    lay = regular_stencil(6, 5, central_length=6.5, radius=30.0)
    g = model_arrays(lay.V, lay.UV, lay.F, rotvec=lay.rotvec)
    return lay.V, lay.UV, lay.F, g


def _jittered_layout():
    """A flat, irregular layout (vertices moved up to 0.6 mm, deterministic)."""
    UV, F = regular_grid(6, 6, 7.0 * np.sqrt(3))
    rng = np.random.default_rng(3)
    UV = UV + rng.uniform(-0.6, 0.6, UV.shape)
    V = np.c_[UV, np.zeros(len(UV))]
    return V, UV, F, model_arrays(V, UV, F)


def _area(P):
    """Signed area of triangles P (t, 3, 2), mm^2."""
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def test_simulator_and_temporal_programming_mesh_the_same_membrane():
    V, UV, F, g = _cap_layout()
    nc = len(g["cell_bases"])
    for area in (SIM.membrane_max_area, PROGRAMMING.membrane_factor_max_area):
        consts = dataclasses.replace(SIM, membrane_max_area=area)
        model = build_model(V, UV, F, np.full((nc, 2), 0.45), g, consts=consts)
        mesh, _, centers = layout_membrane(UV, F, area, g)
        assert np.array_equal(model.mem_flat[:, :2], mesh.xy)
        assert np.array_equal(model.mem_triangles, mesh.tris)
        assert np.array_equal(model.mem_body, mesh.body)
        assert np.allclose(model.base_flat[:, :2], centers, atol=1e-12)
    # the per-cell correction runs on that mesh (same triangle count at its mesh size)
    cells = {"base_a": g["cell_bases"][:, 0], "base_b": g["cell_bases"][:, 1],
             "vertex_a": g["cell_verts"][:, 0], "vertex_b": g["cell_verts"][:, 1],
             "central_length_mm": np.linalg.norm(
                 centers[g["cell_bases"][:, 0]] - centers[g["cell_bases"][:, 1]], axis=1)}
    b0 = cells["central_length_mm"] - UNIT_CELL.bracket_offset
    r = cell_membrane_factors(UV, F, cells, b0, 0.15 * b0, load_membrane_model(), geometry=g)
    assert r["n_triangles"] == len(mesh.tris)
    # and the F_mem sampler's patch mesh is the same function's output for its layout
    pm = patch_mesh(6.0, rings=2, max_area=2.0)
    assert pm.mesh.tris.shape[1] == 3 and np.all(_area(pm.mesh.xy[pm.mesh.tris]) > 0)


@pytest.mark.parametrize("layout", [_cap_layout, _jittered_layout])
def test_membrane_mesh_properties(layout):
    V, UV, F, g = layout()
    max_area = 1.0
    M = membrane_mesh(UV, F, g, max_area=max_area)
    A = _area(M.xy[M.tris])
    assert np.all(A > 0) and np.all(A <= max_area * (1 + 1e-9))  # CCW, within max_area
    C = UV[F].mean(axis=1)
    att = M.body >= 0
    # attached vertices lie on their base's outline (corners at base_r, inside the disc)
    r = np.linalg.norm(M.xy[att] - C[M.body[att]], axis=1)
    assert np.all(r <= UNIT_CELL.base_r + 1e-9) and np.all(r > 0.5 * UNIT_CELL.base_r)
    # the mesh conforms to the stencil edges of the interior faces (all three vertices
    # interior): a triangle whose centroid lies in such a face lies wholly in it
    P = M.xy[M.tris]
    T = UV[F]
    d1, d2 = T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]
    det = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]

    def bary_inside(X):                                                   # (..., 2) -> (..., m)
        w = X[..., None, :] - T[:, 0]
        l1 = (w[..., 0] * d2[:, 1] - w[..., 1] * d2[:, 0]) / det
        l2 = (d1[:, 0] * w[..., 1] - d1[:, 1] * w[..., 0]) / det
        return (l1 >= -1e-9) & (l2 >= -1e-9) & (l1 + l2 <= 1 + 1e-9)

    in_c = bary_inside(P.mean(axis=1))                                    # (t, m)
    assert np.all(in_c.any(axis=1))
    face = in_c.argmax(axis=1)
    interior = ~np.any(g["boundary_vertex"][F], axis=1)
    sel = interior[face]
    assert np.all(bary_inside(P[sel])[np.arange(sel.sum()), :, face[sel]].all(axis=1))
    # the triangles of an interior face tile it minus its base (hexagon of its corners)
    corners = g["nodes_flat"][:, :, :, 0, :2].reshape(len(F), 6, 2)
    hexa = 0.5 * np.abs(np.sum(corners[..., 0] * np.roll(corners[..., 1], -1, axis=1)
                               - np.roll(corners[..., 0], -1, axis=1) * corners[..., 1], axis=1))
    assert interior.sum() >= 4
    got = np.bincount(face, weights=A, minlength=len(F))
    assert got[interior] == pytest.approx(0.5 * np.abs(det[interior]) - hexa[interior],
                                          rel=1e-9)
    # every cell's cut is a straight chain of mesh edges: along its stencil edge from an
    # interior vertex, or ending at the facing base corner (a at the first vertex, b at the
    # second) at a boundary vertex; the vertices inside the chain are free
    e = np.sort(np.r_[M.tris[:, [0, 1]], M.tris[:, [1, 2]], M.tris[:, [2, 0]]], axis=1)
    edges = set(map(tuple, e))
    assert all(tuple(s) in edges for s in np.sort(M.edge_segments, axis=1))
    verts, cb = g["cell_verts"], g["cell_bases"]
    bnd = g["boundary_vertex"]
    assert np.array_equal(np.unique(M.edge_cell), np.arange(len(verts)))
    for c in range(len(verts)):
        S = M.edge_segments[M.edge_cell == c]
        ids, cnt = np.unique(S, return_counts=True)
        ends = ids[cnt == 1]
        assert len(ends) == 2 and np.all(cnt <= 2)                        # one open chain
        want = []
        for k in (0, 1):
            v = verts[c, k]
            if bnd[v]:
                i = ends[np.argmin(np.linalg.norm(M.xy[ends] - UV[v], axis=1))]
                assert M.body[i] in (cb[c, k], cb[c, 1 - k], -1)         # a corner (or the
                #                                             free edge, on skewed faces)
                want.append(M.xy[i])
            else:
                assert np.min(np.linalg.norm(M.xy[ends] - UV[v], axis=1)) < 1e-9
                want.append(UV[v])
        p, q = want
        t = (q - p) / np.linalg.norm(q - p)
        Q = M.xy[ids] - p
        assert np.abs(Q[:, 0] * t[1] - Q[:, 1] * t[0]).max() < 1e-9       # straight
        L = np.linalg.norm(M.xy[S[:, 1]] - M.xy[S[:, 0]], axis=1).sum()
        assert L == pytest.approx(np.linalg.norm(q - p), rel=1e-9)
        assert np.all(M.body[np.setdiff1d(ids, ends)] < 0)                # free inside


def test_base_holes_outside_the_points_are_left_to_the_concavities(monkeypatch):
    """A base with two boundary edges (one cell) has an open outline; the mean of its six
    corners can lie outside the PSLG's points (here the grid's two corner bases), and Triangle
    crashed the process on such a hole (a spiral design, 0.05 mm outside).  Every hole given
    to Triangle lies inside the points' convex hull, and dropping the others changes no
    triangle of the mesh: their regions join the outside."""
    import triangle
    from scipy.spatial import Delaunay

    import pysolver.mechanics.model as mechanics_model
    UV, F = regular_grid(4, 4, 7.0 * np.sqrt(3))
    V = np.c_[UV, np.zeros(len(UV))]
    g = model_arrays(V, UV, F)
    given = []
    real = triangle.triangulate

    def spy(pslg, opts):
        given.append(pslg)
        return real(pslg, opts)
    monkeypatch.setattr(triangle, "triangulate", spy)
    mesh = membrane_mesh(UV, F, g, max_area=1.0)
    P, H = given[-1]["vertices"], given[-1]["holes"]
    assert len(H) == len(F) - 2 and np.all(Delaunay(P).find_simplex(H) >= 0)
    monkeypatch.setattr(mechanics_model, "_base_holes", lambda P, centres: centres)
    every = membrane_mesh(UV, F, g, max_area=1.0)
    assert Delaunay(given[-1]["vertices"]).find_simplex(given[-1]["holes"]).min() < 0
    assert np.array_equal(mesh.xy, every.xy) and np.array_equal(mesh.tris, every.tris)
