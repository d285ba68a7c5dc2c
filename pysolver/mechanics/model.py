"""Simulation model of a shell: rigid bases, bracket springs, cross pairs and the membrane.

Facts restated from ``shared/design/simulator.md`` §3-§6 (no reference code):

* every stencil face is a rigid **base** with 6 DOF (centre + rotation vector); its 12
  bracket nodes (slot j, arm k, layer s) are read from the design's ``model.npz``;
* every unit cell has 4 **bracket springs** (index ``4c + 2s + q``: base a's arm q to base b's
  arm 1 - q in layer s) whose bumper (collision) length is the target-pose distance of the
  node pair, and 4 **cross pairs** (an in-plane X per layer, a through-thickness X per end);
* the **membrane** is a Triangle mesh (switches ``pzq20a5Q``) of the flat mid-plane between
  the base outlines (§6.6); vertices on a base outline are rigidly attached to that base, the
  others are free 3-DOF nodes.

Conventions.  A base's pose maps its flat position ``p`` to ``c + R (p - (x, y, 0))``:
``c`` is the current position of the base centre (flat face centroid) and ``R`` the
accumulated rotation (identity in the flat layout).  Each *point* of the model (bracket
node or membrane vertex) is either attached to a base (``point_body >= 0``, local offset
``point_local`` from the base centre in the flat frame) or free (its own 3 DOF).

Reduced DOF vector: ``[c_0, theta_0, c_1, theta_1, ..., f_0, f_1, ...]`` -- 6 per base
(centre mm, rotation vector rad, applied on the left of the accumulated rotation) and 3 per
free membrane vertex (mm).
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import Delaunay

from pysolver.errors import InputError
from pysolver.geometry import Cells, base_rotations, face_centroids, rotvec_to_matrix
from pysolver.params import (
    PHYSICS_DEFAULT,
    PHYSICS_OFF,
    SIM,
    UNIT_CELL,
    PhysicsOptions,
    SimConstants,
    UnitCell,
)
from pysolver.params import tol as TOL
from pysolver.tables import check_thickness, read_design, read_model

from .rim import margin_rest, rim_margin

CROSS_REST_MODES = ("flat", "zero")


@dataclass
class ShellModel:
    """Everything the energies need, precomputed once (mm, N, s).

    Attributes
    ----------
    V : (n, 3) float, mm -- target stencil vertices
    UV : (n, 2) float, mm -- flat stencil vertices
    F : (m, 3) int -- stencil faces = bases
    base_flat : (m, 3) float, mm -- flat base centres (x, y, 0)
    base_target : (m, 3) float, mm -- target base centres
    base_target_rotation : (m, 3, 3) float -- flat pose -> target pose rotation
    cell_bases, cell_slots : (c, 2) int
    cell_boundary : (c,) bool -- boundary cell (FFb)
    cell_bracket_length : (c,) float, mm -- flat bracket length b (material model axis)
    cell_thickness : (c, 2) float, mm -- bracket thickness (top, bottom)
    point_body : (p,) int -- base of each point, -1 = free
    point_free : (p,) int -- free index of each point, -1 = attached
    point_local : (p, 3) float, mm -- offset from the base centre (attached) or flat position
    spring_points : (4c, 2) int -- bracket springs (point on base a, point on base b)
    spring_rest0 : (4c,) float, mm -- flat length (initial rest length)
    spring_collision : (4c,) float, mm -- bumper contact length L_c
    cross_points : (4c, 4) int -- (a0, a1, b0, b1): segments a0-a1 and b0-b1
    cross_weight : (4c,) float, N/mm -- kappa_s * (flat La + flat Lb)
    cross_rest : (4c,) float, mm -- R0
    mem_point : (v,) int -- point id of each membrane vertex
    mem_flat : (v, 3) float, mm -- flat membrane vertices (z = 0)
    mem_body : (v,) int -- base a membrane vertex is attached to, -1 = free
    mem_triangles : (t, 3) int -- membrane triangles (membrane vertex ids, CCW in flat)
    tri_points : (t, 3) int -- same triangles as point ids
    tri_dm_inv : (t, 2, 2) float, 1/mm -- inverse rest edge matrix (flat / tau)
    tri_rest_area : (t,) float, mm^2 -- rest area (flat area / tau^2)
    node_point : (m, 3, 2, 2) int -- point id of bracket node [base, slot, k, layer], -1 unused
    consts : SimConstants
    unit : UnitCell
    physics : PhysicsOptions -- the options the model was built with (``rim`` and
        ``clearance`` shape it; the simulator checks that its own options agree)
    """

    V: np.ndarray
    UV: np.ndarray
    F: np.ndarray
    base_flat: np.ndarray
    base_target: np.ndarray
    base_target_rotation: np.ndarray
    cell_bases: np.ndarray
    cell_slots: np.ndarray
    cell_boundary: np.ndarray
    cell_bracket_length: np.ndarray
    cell_thickness: np.ndarray
    point_body: np.ndarray
    point_free: np.ndarray
    point_local: np.ndarray
    spring_points: np.ndarray
    spring_rest0: np.ndarray
    spring_collision: np.ndarray
    cross_points: np.ndarray
    cross_weight: np.ndarray
    cross_rest: np.ndarray
    mem_point: np.ndarray
    mem_flat: np.ndarray
    mem_body: np.ndarray
    mem_triangles: np.ndarray
    tri_points: np.ndarray
    tri_dm_inv: np.ndarray
    tri_rest_area: np.ndarray
    node_point: np.ndarray
    consts: SimConstants = SIM
    unit: UnitCell = UNIT_CELL
    source: str = ""
    info: dict = field(default_factory=dict)
    physics: PhysicsOptions = PHYSICS_OFF

    # -- sizes ------------------------------------------------------------------------------------
    @property
    def n_bases(self) -> int:
        return len(self.F)

    @property
    def n_cells(self) -> int:
        return len(self.cell_bases)

    @property
    def n_points(self) -> int:
        return len(self.point_body)

    @property
    def n_free(self) -> int:
        return int((self.point_body < 0).sum())

    @property
    def n_dof(self) -> int:
        return 6 * self.n_bases + 3 * self.n_free

    @property
    def free_points(self) -> np.ndarray:
        """(n_free,) int: point id of each free vertex, in free-index order."""
        idx = np.flatnonzero(self.point_body < 0)
        return idx[np.argsort(self.point_free[idx])]

    @property
    def spring_cell(self) -> np.ndarray:
        return np.repeat(np.arange(self.n_cells), 4)

    @property
    def spring_layer(self) -> np.ndarray:
        """(4c,) int: layer of each spring (0 top, 1 bottom)."""
        return np.tile([0, 0, 1, 1], self.n_cells)

    @property
    def spring_thickness(self) -> np.ndarray:
        return self.cell_thickness[self.spring_cell, self.spring_layer]

    @property
    def spring_bracket_length(self) -> np.ndarray:
        return self.cell_bracket_length[self.spring_cell]

    def dof_slices(self):
        """Index arrays ``(translation dofs, rotation dofs)`` of the reduced vector."""
        m = self.n_bases
        body = (6 * np.arange(m))[:, None]
        trans = np.r_[(body + np.arange(3)).ravel(), 6 * m + np.arange(3 * self.n_free)]
        rot = (body + 3 + np.arange(3)).ravel()
        return np.sort(trans), rot

    def point_dofs(self) -> np.ndarray:
        """(p, 6) int: reduced DOFs a point depends on; free points use -1 for columns 3..5."""
        out = -np.ones((self.n_points, 6), dtype=np.int64)
        att = self.point_body >= 0
        out[att] = 6 * self.point_body[att, None] + np.arange(6)
        fr = ~att
        out[fr, :3] = 6 * self.n_bases + 3 * self.point_free[fr, None] + np.arange(3)
        return out

    def fingerprint(self) -> str:
        """SHA-256 of every array that defines the model (for checkpoints)."""
        h = hashlib.sha256()
        for name in ("F", "point_body", "point_local", "spring_points", "spring_rest0",
                     "spring_collision", "cross_points", "cross_weight", "cross_rest",
                     "tri_points", "tri_dm_inv", "tri_rest_area", "cell_thickness",
                     "cell_bracket_length", "base_flat"):
            a = np.ascontiguousarray(getattr(self, name))
            h.update(name.encode())
            h.update(str(a.dtype).encode() + str(a.shape).encode())
            h.update(a.tobytes())
        h.update(repr(self.consts).encode())
        return h.hexdigest()

    def summary(self) -> dict:
        return {"bases": self.n_bases, "cells": self.n_cells, "membrane_vertices":
                len(self.mem_point), "membrane_free_vertices": self.n_free,
                "membrane_triangles": len(self.mem_triangles), "dofs": self.n_dof,
                "springs": len(self.spring_points), "cross_pairs": len(self.cross_points)}


# ------------------------------------------------------------------------------------------------
# membrane mesh (simulator.md §6.6): the one mesh of the simulator and temporal programming


@dataclass(frozen=True)
class MembraneMesh:
    """The flat membrane of a layout: the simulator's mesh, and temporal programming's.

    Attributes
    ----------
    xy : (v, 2) float, mm -- flat vertices
    tris : (t, 3) int -- triangles, counter-clockwise in the flat layout
    body : (v,) int -- base a vertex is attached to (it lies on the base outline), -1 free
    edge_segments : (e, 2) int -- vertex pairs along the cells' cuts (mesh edges): the
        stencil edge between its interior vertices; an end at a boundary vertex is moved to
        the facing base corner next to it (base a at ``cell_verts[:, 0]``, b at ``[:, 1]``;
        the other way round, or the stencil edge's crossing with the free edge, where that
        cut would cross a base)
    edge_cell : (e,) int -- unit cell of each edge segment
    """

    xy: np.ndarray
    tris: np.ndarray
    body: np.ndarray
    edge_segments: np.ndarray
    edge_cell: np.ndarray


def _cross2(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _crossing_cells(P, S, seg_face, E, cell_of):
    """Cells whose cut crosses an outline segment of one of its two bases, (c,) bool.

    ``P`` (k, 2) mm PSLG vertices, ``S`` (s, 2) outline segments of base ``seg_face`` (s,),
    ``E`` (c, 2) the cells' cuts, ``cell_of`` (m, 3) the cell of each base slot (-1 none).
    """
    sf = np.repeat(np.arange(len(S)), 3)
    cc = cell_of[seg_face].ravel()
    sf, cc = sf[cc >= 0], cc[cc >= 0]
    p, q = P[S[sf, 0]], P[S[sf, 1]]
    r, s = P[E[cc, 0]], P[E[cc, 1]]
    o1, o2 = _cross2(q - p, r - p), _cross2(q - p, s - p)
    o3, o4 = _cross2(s - r, p - r), _cross2(s - r, q - r)
    bad = (o1 * o2 < 0) & (o3 * o4 < 0)
    return np.bincount(cc[bad], minlength=len(E)) > 0


def _bases_reach_across(UV, F, cells, ci):
    """The error for a cell whose bases reach across its stencil edge."""
    fa, fb = (int(x) for x in cells.faces[ci])
    C = UV[F].mean(axis=1)
    d = []
    for f in (fa, fb):
        A, B = UV[F[f]], UV[F[f, [1, 2, 0]]]
        d.append(float(np.min(np.abs(_cross2(B - A, C[f] - A)) / np.linalg.norm(B - A, axis=1))))
    return InputError(f"the stencil's bases reach across its edges at cell {ci} (bases {fa}, "
                      f"{fb}: their centres are {d[0]:.2f} and {d[1]:.2f} mm from their "
                      "triangles' edges): a flat triangle is too thin or too obtuse for a "
                      f"{2 * UNIT_CELL.base_r:g} mm base at its centroid",
                      fix="let morphshell remesh the surface (its stencils keep every base "
                          "centre >= 2.3 mm from its triangle's edges), or improve that region "
                          "of your stencil")


def membrane_mesh(UV, F, geometry: dict, *, max_area=SIM.membrane_max_area,
                  min_angle=SIM.membrane_min_angle) -> MembraneMesh:
    """Triangulate the flat membrane between the base outlines of a layout.

    The one membrane mesh of the project: the simulator (:func:`build_model`), the ``F_mem``
    sampler and fit and the per-cell ``F_mem`` correction
    (:mod:`pysolver.temporal.membrane_model`) all mesh a layout with this function, so the
    per-cell tractions of temporal programming are read on the simulator's own membrane.

    The PSLG is built from the flat corner nodes (top-layer bracket nodes, ``nodes_flat``) of
    every interior side: per cell and per side (f, j) the base side segment (f,j,0)-(f,j,1);
    then at the corner by vertex ``F[f,(j+2)%3]`` either the base's corner edge
    (f,j,1)-(f,(j+1)%3,0) (interior vertex) or, at a boundary vertex, an open segment across
    the cell to the partner's facing node (free membrane edge).  Holes at the base centres
    remove the bases.  The stencil edge of every cell is a segment too (a constraint inside
    the membrane, it changes nothing of the physics): it runs between its interior stencil
    vertices; at a boundary vertex it ends at the facing corner of base a (first vertex)
    or b (second vertex), so no vertex is added on the free edge (on skewed faces whose
    bases would be crossed: the other corners, else the crossing with the free edge).  The
    force the membrane carries across each cell is then a sum over mesh edges
    (:func:`pysolver.temporal.membrane_model.cell_tractions`).  Triangle (``pzq<min_angle>
    a<max_area>Q``) adds points on segments where quality or size need them: on a base
    outline they are attached to that base, elsewhere free.

    Parameters
    ----------
    UV : (n, 2) float, mm
        Flat stencil vertices.
    F : (m, 3) int
        Stencil faces.
    geometry : dict
        The design's ``model.npz`` arrays (``pysolver.design.cellnodes.model_arrays``):
        ``face_adjacency``, ``cell_bases``, ``cell_slots``, ``cell_verts``, ``cell_of``,
        ``boundary_vertex`` and ``nodes_flat`` (m, 3, 2, 2, 3) mm.
    max_area : float, mm^2
        Largest triangle (flat).  The simulator uses ``SIM.membrane_max_area``; the ``F_mem``
        fit and correction finer meshes of the same construction.
    min_angle : float, deg

    Returns
    -------
    MembraneMesh

    Raises
    ------
    InputError
        A base outline crosses a stencil edge (too thin or obtuse a flat triangle), or the
        meshing produced no or a degenerate triangle.
    """
    import triangle  # heavy: Triangle only where a mesh is made

    UV = np.asarray(UV, float)[:, :2]
    F = np.asarray(F, dtype=np.int64)
    g = {k: np.asarray(geometry[k]) for k in ("cell_bases", "cell_slots", "cell_verts",
                                                "cell_of", "cell_boundary")}
    cells = Cells(faces=g["cell_bases"], slots=g["cell_slots"], verts=g["cell_verts"],
                  cell_of=g["cell_of"], boundary=g["cell_boundary"])
    vertex_boundary = np.asarray(geometry["boundary_vertex"], bool)
    corner_xy = np.asarray(geometry["nodes_flat"], float)[:, :, :, 0, :2]
    o = _base_outlines(F, cells, vertex_boundary, corner_xy)
    P, ends, split = _stencil_edge_ends(UV, F, cells, vertex_boundary, o)
    free_seg = []
    for i0, i1 in o.renum[o.corner[o.open_]]:
        x = split.get(frozenset((int(i0), int(i1))))
        free_seg += [(i0, i1)] if x is None else [(i0, x), (x, i1)]
    free_seg = np.array(free_seg, dtype=np.int64).reshape(-1, 2)
    c = len(cells.faces)
    seg = np.r_[o.renum[o.outline], free_seg, ends]
    mark = np.r_[o.outline_face + 2, np.ones(len(free_seg), np.int64), -(np.arange(c) + 1)]
    vmark = np.r_[o.used // 6 + 2, np.zeros(len(P) - len(o.used), np.int64)]
    pslg = {"vertices": P, "segments": seg, "segment_markers": mark[:, None].astype(np.int32),
            "vertex_markers": vmark[:, None].astype(np.int32)}
    holes = _base_holes(P, o.xy_all.reshape(len(F), 6, 2).mean(axis=1))
    if len(holes):  # (Triangle's wrapper refuses an empty array of holes)
        pslg["holes"] = holes
    return _membrane_from_triangle(triangle.triangulate(pslg, f"pzq{min_angle:g}a{max_area:g}Q"))


def _base_holes(P, centres):
    """The base centres (k, 2) that lie inside the convex hull of the PSLG's points ``P``.

    Triangle crashes the process (a segmentation fault) on a hole point outside the
    triangulation.  A base with two boundary edges has an open outline (one cell), so the
    mean of its six corners can lie beyond the points its outline uses (measured: 0.05 mm,
    on a spiral design); its region joins the outside and is removed with the concavities
    without a hole.
    """
    inside = Delaunay(P).find_simplex(centres) >= 0
    return centres[inside]


def _corner_id(f, j, k):
    """Index of the flat corner node ``(base f, slot j, arm k)`` among ``6 m``."""
    return 6 * f + 2 * j + k


@dataclass
class _Outlines:
    """The base outlines of a layout as PSLG segments (between flat corner nodes, numbered
    ``6 f + 2 j + k``): ``outline`` (k, 2) segments and their bases ``outline_face``;
    ``corner`` (2 c, 2) the corner segment of every cell side, across the cell where its
    vertex is on the boundary (``open_``: a free membrane edge); the corner nodes ``used``,
    their coordinates ``xy_all`` (6 m, 2) mm and their PSLG numbers ``renum`` (6 m,)."""

    outline: np.ndarray
    outline_face: np.ndarray
    corner: np.ndarray
    open_: np.ndarray
    used: np.ndarray
    xy_all: np.ndarray
    renum: np.ndarray


def _base_outlines(F, cells: Cells, vertex_boundary, corner_xy) -> _Outlines:
    """Per cell and side (f, j): the base side segment (f,j,0)-(f,j,1), and at the corner by
    vertex ``F[f,(j+2)%3]`` the base's corner edge (f,j,1)-(f,(j+1)%3,0) (interior vertex) or
    an open segment across the cell to the partner's facing node (boundary vertex)."""
    m = len(F)
    a, b = cells.faces[:, 0], cells.faces[:, 1]
    ja, jb = cells.slots[:, 0], cells.slots[:, 1]
    f = np.r_[a, b]
    j = np.r_[ja, jb]
    fo = np.r_[b, a]
    jo = np.r_[jb, ja]
    side = np.c_[_corner_id(f, j, 0), _corner_id(f, j, 1)]
    corner_vertex = F[f, (j + 2) % 3]
    open_ = vertex_boundary[corner_vertex]
    corner = np.c_[_corner_id(f, j, 1),
                   np.where(open_, _corner_id(fo, jo, 0), _corner_id(f, (j + 1) % 3, 0))]
    outline = np.r_[side, corner[~open_]]
    outline_face = np.r_[f, f[~open_]]
    used = np.unique(np.r_[outline.ravel(), corner[open_].ravel()])
    renum = -np.ones(6 * m, dtype=np.int64)
    renum[used] = np.arange(len(used))
    return _Outlines(outline, outline_face, corner, open_, used, corner_xy.reshape(-1, 2), renum)


def _stencil_edge_ends(UV, F, cells: Cells, vertex_boundary, o: _Outlines):
    """The ends of every cell's stencil-edge segment, and the PSLG's points.

    An interior vertex is a (free) mesh vertex; at a boundary vertex the cut ends at a base
    corner next to it, of base a at the edge's first vertex and of base b at its second (no
    new vertex on the free edge: any cut from one end to the free boundary between the two
    bases separates the same two membrane pieces).  Where that cut would cross a base outline
    (skewed faces) the other bases' corners are tried, then the points where the stencil
    edge line meets the free edge (free vertices splitting it).

    Returns
    -------
    P : (p, 2) float, mm -- the PSLG's points: used corner nodes, interior stencil vertices,
        free-edge splits
    ends : (c, 2) int -- the PSLG points of every cell's stencil-edge segment
    split : dict -- frozenset of a free segment's ends -> the point that splits it
    """
    c = len(cells.faces)
    a, b = cells.faces[:, 0], cells.faces[:, 1]
    ja, jb = cells.slots[:, 0], cells.slots[:, 1]
    inner_v = np.unique(cells.verts[~vertex_boundary[cells.verts]])
    vnode = -np.ones(len(UV), dtype=np.int64)
    vnode[inner_v] = len(o.used) + np.arange(len(inner_v))
    bnd_end = vnode[cells.verts] < 0
    corner_at = np.empty((c, 2, 2), dtype=np.int64)    # [cell, end, base a/b] PSLG vertex
    for e in (0, 1):
        w = cells.verts[:, e]
        for q, (ff_, jj) in enumerate(((a, ja), (b, jb))):
            corner_at[:, e, q] = o.renum[_corner_id(ff_, jj,
                                                    np.where(F[ff_, (jj + 1) % 3] == w, 0, 1))]
    ends = np.where(bnd_end, corner_at[:, [0, 1], [0, 1]], vnode[cells.verts])
    P = np.r_[o.xy_all[o.used], UV[inner_v]]
    S_out = o.renum[o.outline]
    split = {}
    # hand-written: a loop over the few cells of skewed faces, none in a regular stencil
    for ci in np.flatnonzero(_crossing_cells(P, S_out, o.outline_face, ends, cells.cell_of)):
        be = np.flatnonzero(bnd_end[ci])
        ends[ci, be] = corner_at[ci, be, 1 - be]                  # the other bases' corners
        if not _crossing_cells(P, S_out, o.outline_face, ends, cells.cell_of)[ci]:
            continue
        A, B = UV[cells.verts[ci, 0]], UV[cells.verts[ci, 1]]
        for e in be:                                              # the free-edge crossings
            p0, p1 = P[corner_at[ci, e, 0]], P[corner_at[ci, e, 1]]
            den = _cross2(B - A, p0 - p1)
            u = _cross2(B - A, p0 - A) / den if abs(den) > TOL.degenerate else 0.5
            P = np.r_[P, [p0 + min(max(u, 0.1), 0.9) * (p1 - p0)]]
            ends[ci, e] = len(P) - 1
            split[frozenset((int(corner_at[ci, e, 0]), int(corner_at[ci, e, 1])))] = len(P) - 1
    bad = _crossing_cells(P, S_out, o.outline_face, ends, cells.cell_of)
    if bad.any():
        raise _bases_reach_across(UV, F, cells, int(np.argmax(bad)))
    return P, ends, split


def _membrane_from_triangle(out: dict) -> MembraneMesh:
    """The membrane mesh from Triangle's output: the vertices triangles use, each attached to
    its base (vertex marker - 2) or free (-1), triangles turned counter-clockwise, the
    stencil-edge segments (negative markers) sorted by cell."""
    xy = np.asarray(out["vertices"], float)
    tris = np.asarray(out["triangles"], dtype=np.int64)
    vm = np.asarray(out["vertex_markers"]).ravel()
    body = np.where(vm >= 2, vm - 2, -1).astype(np.int64)
    osm = np.asarray(out["segment_markers"]).ravel()
    eseg = np.asarray(out["segments"], dtype=np.int64)[osm < 0]
    ecell = -osm[osm < 0] - 1
    if len(tris) == 0:
        raise InputError("membrane meshing produced no triangle", fix="check the flat layout")
    # keep only vertices used by triangles (Triangle keeps eaten input vertices)
    used_v = np.unique(tris)
    if len(used_v) != len(xy):
        keep = -np.ones(len(xy), dtype=np.int64)
        keep[used_v] = np.arange(len(used_v))
        xy, body, tris, eseg = xy[used_v], body[used_v], keep[tris], keep[eseg]
    e1 = xy[tris[:, 1]] - xy[tris[:, 0]]
    e2 = xy[tris[:, 2]] - xy[tris[:, 0]]
    area = 0.5 * _cross2(e1, e2)
    flip = area < 0
    tris[flip] = tris[flip][:, [0, 2, 1]]
    if np.any(np.abs(area) < TOL.degenerate):
        raise InputError("membrane meshing produced a degenerate triangle",
                         fix="check the flat layout for overlapping bases")
    order = np.lexsort((eseg.min(axis=1), ecell))
    return MembraneMesh(xy=xy, tris=tris, body=body, edge_segments=eseg[order],
                        edge_cell=ecell[order])


# ------------------------------------------------------------------------------------------------
# assembly


def build_model(V, UV, F, thickness, geometry: dict, *, rotvec=None, bracket_length=None,
                collision=None, consts: SimConstants = SIM, unit: UnitCell = UNIT_CELL,
                cross_rest: str = "flat", source: str = "",
                physics: PhysicsOptions = PHYSICS_OFF, clearance=None) -> ShellModel:
    """Assemble a :class:`ShellModel` from a scaled stencil and the design's geometry.

    Parameters
    ----------
    V : (n, 3) float, mm
        Target stencil vertices (scaled, as in ``stencil.obj``).
    UV : (n, 2) float, mm
        Flat stencil vertices (scaled), faces CCW.
    F : (m, 3) int
    thickness : (c, 2) float, mm
        Bracket thickness per cell (face-major order) and layer (top, bottom).
    geometry : dict
        The design's ``model.npz`` arrays (:data:`pysolver.tables.MODEL_ARRAYS`: unit-cell
        topology and bracket nodes), as :func:`pysolver.tables.read_model` returns them;
        the design stage computes them (``pysolver.design.cellnodes.model_arrays``).
    rotvec : (m, 3) float, rad, optional
        Base rotations flat -> target (``bases.csv``); recomputed if omitted.
    bracket_length : (c,) float, mm, optional
        Flat bracket length b per cell for the material model (``cells.csv``); default
        flat central length minus ``unit.bracket_offset``.
    collision : (c, 2) float, mm, optional
        Per-layer collision lengths (``cells.csv``).  The per-spring lengths are the target
        distances of each node pair, shifted per cell and layer so that their mean equals
        this value (a no-op for an unedited design).
    consts : SimConstants
    unit : UnitCell
    cross_rest : {"flat", "zero"}
        Cross-pair rest difference R0: ``"flat"`` (SI Note 2: the difference in the initial
        configuration, zero force at rest) or ``"zero"`` (the reference code).
    source : str -- description for messages
    physics : PhysicsOptions
        ``rim``: the membrane gets the latex margin of :func:`rim_margin` (rest state
        :func:`margin_rest`); ``clearance``: the contact lengths less ``clearance``.
    clearance : (c, 2) float, mm, optional
        The printed bumpers' clearance per cell and layer (:func:`bumper_clearance`);
        required with ``physics.clearance``.

    Returns
    -------
    ShellModel
    """
    V, UV, F = np.asarray(V, float), np.asarray(UV, float), np.asarray(F, dtype=np.int64)
    if cross_rest not in CROSS_REST_MODES:
        raise InputError(f"cross_rest must be one of {CROSS_REST_MODES}, got {cross_rest!r}")
    ff = geometry["face_adjacency"]
    cells, thickness = _checked_cells(geometry, thickness, source, unit)
    c = len(cells.faces)
    C2 = face_centroids(UV, F)
    base_flat = np.c_[C2, np.zeros(len(F))]
    Rt = (base_rotations(V, UV, F, ff)[0] if rotvec is None
          else rotvec_to_matrix(np.asarray(rotvec, float).reshape(-1, 3)))
    nodes = _BracketNodes.of(ff, geometry["nodes_flat"], geometry["nodes_target"], base_flat)
    spring_points, cross_points = nodes.pairs(cells)
    rest0, Lc, cross_weight, cross_rest_v = _spring_lengths(
        nodes, spring_points, cross_points, collision, (physics.clearance, clearance), consts,
        cross_rest, source)
    if bracket_length is None:
        bracket_length = (np.linalg.norm(C2[cells.faces[:, 1]] - C2[cells.faces[:, 0]], axis=1)
                          - unit.bracket_offset)
    bracket_length = np.asarray(bracket_length, float)
    if bracket_length.shape != (c,) or np.any(bracket_length <= 0):
        raise InputError(f"{source}: bracket lengths must be ({c},) positive values",
                         fix="check cells.csv bracket_length_mm")
    mem = _membrane(UV, F, geometry, C2, base_flat, nodes, consts, unit, physics)
    return ShellModel(
        V=V, UV=UV, F=F, base_flat=base_flat, base_target=face_centroids(V, F),
        base_target_rotation=Rt, cell_bases=cells.faces.copy(), cell_slots=cells.slots.copy(),
        cell_boundary=cells.boundary.copy(), cell_bracket_length=bracket_length,
        cell_thickness=thickness, point_body=mem["point_body"], point_free=mem["point_free"],
        point_local=mem["point_local"], spring_points=spring_points, spring_rest0=rest0,
        spring_collision=Lc, cross_points=cross_points, cross_weight=cross_weight,
        cross_rest=cross_rest_v, mem_point=mem["mem_point"], mem_flat=mem["mem_flat"],
        mem_body=mem["mem_body"], mem_triangles=mem["tris"],
        tri_points=mem["mem_point"][mem["tris"]], tri_dm_inv=mem["dm_inv"],
        tri_rest_area=mem["rest_area"], node_point=nodes.point, consts=consts, unit=unit,
        source=source, physics=physics)


def _checked_cells(geometry: dict, thickness, source: str, unit: UnitCell):
    """The unit cells of ``model.npz`` and the thicknesses (c, 2) mm, checked: at least one
    cell, one thickness per cell and layer, printable values."""
    cells = Cells(faces=geometry["cell_bases"], slots=geometry["cell_slots"],
                  verts=geometry["cell_verts"], cell_of=geometry["cell_of"],
                  boundary=geometry["cell_boundary"])
    c = len(cells.faces)
    if c == 0:
        raise InputError(f"{source or 'stencil'}: no unit cell (interior edge)",
                         fix="use a stencil with at least two adjacent triangles")
    thickness = np.asarray(thickness, float)
    if thickness.shape != (c, 2):
        raise InputError(f"{source or 'model'}: thickness has shape {thickness.shape}, "
                         f"expected ({c}, 2) (cells x layers)")
    check_thickness(thickness, source or "model", rows=False, programmed=True, in_range=False,
                    unit=unit)
    return cells, thickness


@dataclass
class _BracketNodes:
    """The bracket nodes of the interior slots as model points (``simulator.md`` §4):
    ``point`` (m, 3, 2, 2) int, the point of node ``[base, slot, arm, layer]`` (-1 on the
    boundary); ``n`` points; each one's ``body`` and ``local`` position (mm, flat, relative
    to its base centre); their ``flat`` and ``target`` positions (mm)."""

    point: np.ndarray
    n: int
    body: np.ndarray
    local: np.ndarray
    flat: np.ndarray
    target: np.ndarray

    @classmethod
    def of(cls, ff, nodes_f, nodes_t, base_flat) -> _BracketNodes:
        m = len(ff)
        interior = ff >= 0  # (m, 3)
        point = -np.ones((m, 3, 2, 2), dtype=np.int64)
        mask = np.broadcast_to(interior[:, :, None, None], point.shape)
        n = int(mask.sum())
        point[mask] = np.arange(n)
        body = np.broadcast_to(np.arange(m)[:, None, None, None], point.shape)[mask]
        local = (nodes_f - base_flat[:, None, None, None, :])[mask]
        return cls(point, n, body, local, nodes_f[mask], nodes_t[mask])

    def pairs(self, cells: Cells):
        """The bracket springs (4 per cell, index ``4 c + 2 s + q``) and the cross pairs
        (4 per cell) of ``simulator.md`` §5, as point indices: (4c, 2) and (4c, 4)."""
        fa, fb = cells.faces[:, 0], cells.faces[:, 1]
        ja, jb = cells.slots[:, 0], cells.slots[:, 1]
        node = self.point
        sp, xp = [], []
        for s in (0, 1):
            for q in (0, 1):
                sp.append(np.c_[node[fa, ja, q, s], node[fb, jb, 1 - q, s]])
            xp.append(np.c_[node[fa, ja, 0, s], node[fb, jb, 0, s],
                            node[fa, ja, 1, s], node[fb, jb, 1, s]])
            xp.append(np.c_[node[fa, ja, s, 0], node[fb, jb, 1 - s, 1],
                            node[fa, ja, s, 1], node[fb, jb, 1 - s, 0]])
        spring_points = np.stack(sp, axis=1).reshape(-1, 2)  # cell-major, index 4c + 2s + q
        cross_points = np.stack(xp, axis=1).reshape(-1, 4)
        assert np.all(spring_points >= 0) and np.all(cross_points >= 0)
        return spring_points, cross_points


def _spring_lengths(nodes: _BracketNodes, spring_points, cross_points, collision, clearance,
                    consts: SimConstants, cross_rest: str, source: str):
    """Rest lengths (flat) and collision lengths (target, shifted per cell and layer to the
    design's ``collision``, less the printed bumpers' clearance when ``clearance`` = (on,
    (c, 2) mm) is on) of the bracket springs; weights and rest differences of the cross
    pairs.

    Returns
    -------
    rest0, Lc : (4c,) float, mm
    cross_weight : (4c,) float, N/mm
    cross_rest : (4c,) float, mm
    """
    c = len(spring_points) // 4
    seg_len = lambda P, i, k: np.linalg.norm(P[i[:, k]] - P[i[:, k - 1]], axis=1)  # noqa: E731
    rest0 = seg_len(nodes.flat, spring_points, 1)
    Lc = seg_len(nodes.target, spring_points, 1)
    if collision is not None:
        collision = np.asarray(collision, float)
        if collision.shape != (c, 2):
            raise InputError(f"{source}: collision lengths have shape {collision.shape}, "
                             f"expected ({c}, 2)")
        mean = Lc.reshape(c, 2, 2).mean(axis=2)
        Lc = (Lc.reshape(c, 2, 2) + (collision - mean)[:, :, None]).ravel()
    on, clear = clearance
    if on and (clear is None or np.shape(clear) != (c, 2)):
        raise InputError(f"{source}: the printing clearance needs the bumpers of every "
                         f"cell and layer, ({c}, 2) values",
                         fix="build the model with load_model (it reads bumpers.csv)")
    if on:
        Lc = (Lc.reshape(c, 2, 2) - np.asarray(clear, float)[:, :, None]).ravel()
    if np.any(Lc <= 0):
        k = int(np.flatnonzero(Lc <= 0)[0]) // 4
        raise InputError(f"{source}: cell {k} has a non-positive collision length",
                         fix="check cells.csv collision_length_* columns")
    flat = nodes.flat
    La = seg_len(flat, cross_points, 1)
    Lb = np.linalg.norm(flat[cross_points[:, 3]] - flat[cross_points[:, 2]], axis=1)
    cross_weight = consts.kappa_s * (La + Lb)
    cross_rest_v = (La - Lb) if cross_rest == "flat" else np.zeros_like(La)
    return rest0, Lc, cross_weight, cross_rest_v


def _membrane(UV, F, geometry, C2, base_flat, nodes: _BracketNodes, consts: SimConstants,
              unit: UnitCell, physics: PhysicsOptions) -> dict:
    """The membrane of the model (:func:`membrane_mesh`, with the rim margin when
    ``physics.rim``): its points after the bracket nodes (on a base, or free), triangles and
    their inverse rest shapes (pre-stretched by ``tau``).

    Returns
    -------
    dict
        ``point_body``, ``point_free``, ``point_local`` (every model point), ``mem_point``,
        ``mem_flat``, ``mem_body``, ``tris``, ``dm_inv`` (t, 2, 2) 1/mm, ``rest_area`` mm^2.
    """
    mesh = membrane_mesh(UV, F, geometry, max_area=consts.membrane_max_area,
                         min_angle=consts.membrane_min_angle)
    xy, tris, mbody = mesh.xy, mesh.tris, mesh.body
    tau = np.full(len(tris), consts.tau)
    area_factor = None
    if physics.rim:
        xy, tris, mbody, margin = rim_margin(xy, tris, mbody, C2, unit.base_r,
                                             physics.rim_margin_mm)
        tau, area_factor = margin_rest(margin, consts.tau, physics.rim_stretch)
    nm = len(xy)
    mem_flat = np.c_[xy, np.zeros(nm)]
    mem_point = nodes.n + np.arange(nm)
    point_body = np.r_[nodes.body, mbody]
    point_local = np.r_[nodes.local, np.where((mbody >= 0)[:, None],
                                              mem_flat - base_flat[np.maximum(mbody, 0)],
                                              mem_flat)]
    point_free = -np.ones(len(point_body), dtype=np.int64)
    fr = point_body < 0
    point_free[fr] = np.arange(int(fr.sum()))
    P = xy[tris]
    if not physics.rim:
        tau = consts.tau  # (the scalar: bit-identical to the reference model)
    else:
        tau = tau[:, None, None]
    Dm = np.stack([P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]], axis=2) / tau  # columns = edges
    det = Dm[:, 0, 0] * Dm[:, 1, 1] - Dm[:, 0, 1] * Dm[:, 1, 0]
    dm_inv = np.stack([np.stack([Dm[:, 1, 1], -Dm[:, 0, 1]], 1),
                       np.stack([-Dm[:, 1, 0], Dm[:, 0, 0]], 1)], 1) / det[:, None, None]
    rest_area = 0.5 * np.abs(det)
    if area_factor is not None:
        rest_area = rest_area * area_factor
    return {"point_body": point_body, "point_free": point_free, "point_local": point_local,
            "mem_point": mem_point, "mem_flat": mem_flat, "mem_body": mbody, "tris": tris,
            "dm_inv": dm_inv, "rest_area": rest_area}


def bumper_clearance(bumpers: dict, cells: dict, unit: UnitCell = UNIT_CELL) -> np.ndarray:
    """How much shorter than the target the printed bumpers of every cell close, per layer.

    Each printed bumper's end plane is moved back by ``unit.clearance`` along its unit
    normal (``scad/bumper.scad``), which shortens it along its axis by
    ``clearance / |n_xy|`` (:func:`pysolver.design.layout.footprint_rectangles` with
    ``printed=True``); a cell's two facing bumpers of a layer close by the sum.

    Parameters
    ----------
    bumpers : dict of arrays -- ``bumpers.csv`` (:func:`pysolver.tables.read_table`)
    cells : dict of arrays -- ``cells.csv``
    unit : UnitCell

    Returns
    -------
    (c, 2) float, mm -- per cell and layer (top, bottom)
    """
    c = len(cells["cell_id"])
    n = np.c_[bumpers["plane_nx"], bumpers["plane_ny"], bumpers["plane_nz"]]
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    short = unit.clearance / np.maximum(np.hypot(n[:, 0], n[:, 1]), TOL.tiny)
    layer = (np.asarray(bumpers["layer"]) == "bottom").astype(np.int64)
    cid = np.asarray(bumpers["cell_id"], np.int64)
    ok = cid >= 0
    out = np.zeros((c, 2))
    np.add.at(out, (cid[ok], layer[ok]), short[ok])
    count = np.zeros((c, 2), np.int64)
    np.add.at(count, (cid[ok], layer[ok]), 1)
    if np.any(count != 2):
        k = int(np.argwhere(count != 2)[0][0])
        raise InputError(f"bumpers.csv: cell {k} has {count[k].tolist()} bumpers per layer, "
                         "expected 2 (one on each base)", fix="re-run the design stage")
    return out


def load_model(design_dir, *, consts: SimConstants = SIM, cross_rest: str = "flat",
               physics: PhysicsOptions = PHYSICS_DEFAULT) -> ShellModel:
    """Assemble the model of a design folder (``stencil.obj``, ``bases.csv``, ``cells.csv``,
    ``model.npz``, and the unit cell of ``design.json``).

    Parameters
    ----------
    design_dir : path-like
        Design folder (``docs/design-folder.md``).
    physics : PhysicsOptions
        ``rim`` (the latex margin) and ``clearance`` (the printed bumpers' contact
        lengths, :func:`bumper_clearance`) change the model (see :func:`build_model`).
        Default: the simulator's default physics, :data:`~pysolver.params.PHYSICS_DEFAULT`.

    Returns
    -------
    ShellModel

    Raises
    ------
    InputError
        Missing files, inconsistent tables or missing thicknesses, naming the file and row.
    """
    folder = Path(design_dir)
    d = read_design(folder)
    unit = d.params  # the design's own unit cell (design.json)
    c = d.cells
    th = np.c_[c["thickness_top_mm"], c["thickness_bottom_mm"]]
    check_thickness(th, str(folder / "cells.csv"), programmed=True, in_range=False, unit=unit)
    rot = np.c_[d.bases["rot_x_rad"], d.bases["rot_y_rad"], d.bases["rot_z_rad"]]
    coll = np.c_[c["collision_length_top_mm"], c["collision_length_bottom_mm"]]
    geometry = read_model(folder, n_vertices=len(d.V), n_faces=d.n_bases, n_cells=d.n_cells,
                          params=unit)
    clear = bumper_clearance(d.bumpers, c, unit) if physics.clearance else None
    return build_model(d.V, d.UV, d.F, th, geometry, rotvec=rot,
                       bracket_length=c["bracket_length_mm"], collision=coll, consts=consts,
                       unit=unit, cross_rest=cross_rest,
                       source=str(folder), physics=physics, clearance=clear)


def vary_model(model: ShellModel, *, thickness=None, consts: SimConstants | None = None
               ) -> ShellModel:
    """A copy of ``model`` with other bracket thicknesses and/or simulator constants.

    For the Monte Carlo tolerance analysis (:mod:`pysolver.tolerance`): the stencil, the membrane
    mesh and every table stay the nominal design's; only the printed/material values change.
    The membrane rest shape is the flat mesh divided by the pre-stretch ``tau``
    (:func:`build_model`), so a new ``tau`` rescales the inverse rest edge matrices by
    ``tau' / tau`` and the rest areas by ``(tau / tau')^2`` (the same numbers as building
    the model with the new constants, to round-off; tested).  ``mu`` and the other
    constants are read by the energies from ``consts`` directly.

    Parameters
    ----------
    model : ShellModel
    thickness : (c, 2) float, mm, optional
        Bracket thickness per cell and layer (top, bottom); default the model's.
    consts : SimConstants, optional
        Default the model's.

    Returns
    -------
    ShellModel
        A new model; the arrays of ``model`` are not modified.
    """
    changes = {}
    if thickness is not None:
        th = np.asarray(thickness, float)
        if th.shape != model.cell_thickness.shape:
            raise InputError(f"thickness has shape {th.shape}, expected "
                             f"{model.cell_thickness.shape} positive mm",
                             fix="pass one thickness per cell and layer")
        check_thickness(th, "vary_model", rows=False, programmed=True, in_range=False,
                        unit=model.unit)
        changes["cell_thickness"] = th
    if consts is not None:
        if not (np.isfinite(consts.tau) and consts.tau > 1.0 and np.isfinite(consts.mu)
                and consts.mu > 0):
            raise InputError(f"pre-stretch tau = {consts.tau} and modulus mu = {consts.mu} MPa",
                             fix="tau must exceed 1 and mu must be positive")
        r = consts.tau / model.consts.tau
        changes.update(consts=consts, tri_dm_inv=model.tri_dm_inv * r,
                       tri_rest_area=model.tri_rest_area / (r * r))
    return dataclasses.replace(model, **changes)


__all__ = ["ShellModel", "MembraneMesh", "build_model", "load_model", "vary_model", "membrane_mesh",
           "rim_margin", "margin_rest", "bumper_clearance", "CROSS_REST_MODES"]
