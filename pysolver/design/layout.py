"""Layout of bases, bumpers and brackets from a stencil (V target, UV flat, F).

Restates ``shared/design/pipeline.md`` §2.4-2.8 and §1.4 (facts, not code):

* connectivity: ``ff[i, j]`` = face across the edge opposite vertex ``F[i, j]``;
  unit cells enumerated face-major, pairs with neighbour > i;
* 3D scaling rule (min-bumper) and 2D scaling rule (min-gap), closed form;
  then the 2D scale is raised, if needed, until the *printed* flat footprints
  (bumpers rotated with the base, so off their flat axes by the local conformal
  angle error, and trimmed by the printing clearance) keep ``min_gap`` -- the
  reference ignores the angle error;
* base rotations ``R_i`` (flat -> target), reference neighbour = first interior slot;
* bumpers per layer with their ideal contact plane and cut type;
* boundary cells, alignment bases, support-frame outline.

Cut type (documented choice).  For every base, layer and interior slot we
intersect the bisector plane of the two *layer* centres with the bumper axis at
the layer's far face (|z| = 2.3 mm) and at its membrane-side face (|z| = 0.3 mm).
If the bumper would be longer at the membrane side than at the far face, a
bisector cut is an overhang when printed far face down: this layer is on the
concave side of that fold and gets a ``straight`` (vertical) cut at the far-face
length.  Otherwise (convex side, or an exactly flat fold where both cuts coincide)
it gets the ``bisector`` cut.  This is the reference's rule (elevation sign test)
expressed through the quantity that matters for printing.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import igl
import numpy as np
from scipy.spatial import cKDTree

from ..errors import InputError
from ..geometry import (
    Cells,
    base_rotations,
    face_adjacency,
    face_centroids,
    face_normals,
    fold_angles_deg,
    matrix_to_rotvec,
    signed_areas_2d,
    unit_cells,
)
from ..params import UNIT_CELL, UnitCell
from ..params import tol as TOL
from ..tables import round_sig9

# --------------------------------------------------------------------------------------
# per-cell geometry (connectivity and per-face geometry: pysolver.geometry)


def _cell_geometry(V, F, cells: Cells):
    """Centroid distance and half fold angle per cell (target)."""
    Fc = face_centroids(V, F)
    N = face_normals(V, F)
    a, b = cells.faces[:, 0], cells.faces[:, 1]
    D = np.linalg.norm(Fc[b] - Fc[a], axis=1)
    cosphi = np.clip(np.sum(N[a] * N[b], axis=1), -1.0, 1.0)
    half = 0.5 * np.arccos(cosphi)
    return D, half


def scale_3d(V, F, cells: Cells, params: UnitCell = UNIT_CELL):
    """3D (min-bumper) scaling rule.

    For every cell with half fold angle theta:
    ``required = base_r + layer_h tan(theta) + min_bumper`` and
    ``available = |Fc_a - Fc_b| / (2 cos theta)``; the factor is the max of
    required / available (the critical cell meets the rule with equality).

    Returns
    -------
    factor : float
        Multiply V by this.
    ratio : (c,) float
        required / available per cell (before scaling).
    """
    D, th = _cell_geometry(V, F, cells)
    if np.any(th >= np.radians(89.0)):
        k = int(np.argmax(th))
        raise InputError(f"cell {k} folds by {np.degrees(2 * th[k]):.1f} deg: too sharp to build",
                         fix="smooth the target surface or use more vertices")
    required = params.base_r + params.layer_h * np.tan(th) + params.min_bumper
    available = D / (2 * np.cos(th))
    ratio = required / available
    return float(ratio.max()), ratio


def scale_2d(V, UV, F, cells: Cells, params: UnitCell = UNIT_CELL):
    """2D (min-gap) scaling rule, closed form (V already scaled).

    ``required_half = |dFc|/(2 cos theta) + layer_h tan(theta) + min_gap/2``,
    ``available_half = |dFc2d| / 2``; factor = max ratio.

    Returns
    -------
    factor : float
        Multiply UV by this.
    ratio : (c,) float
    """
    D, th = _cell_geometry(V, F, cells)
    C2 = face_centroids(UV, F)
    a, b = cells.faces[:, 0], cells.faces[:, 1]
    d2 = np.linalg.norm(C2[b] - C2[a], axis=1)
    req = D / (2 * np.cos(th)) + params.layer_h * np.tan(th) + params.min_gap / 2
    ratio = req / (d2 / 2)
    return float(ratio.max()), ratio


# --------------------------------------------------------------------------------------
# orientation of bases


# --------------------------------------------------------------------------------------
# bumpers


@dataclass
class Bumpers:
    """One row per (base, layer, interior slot); arrays of length k.

    Geometry is in the flat shell frame relative to the base centre (mm);
    target-frame copies (``*_t``) are kept for checks.
    """

    base: np.ndarray
    layer: np.ndarray  # 0 top, 1 bottom
    slot: np.ndarray
    cell: np.ndarray
    neighbour: np.ndarray
    dir_deg: np.ndarray
    plane_p: np.ndarray  # (k, 3) flat frame, relative to the base centre
    plane_n: np.ndarray  # (k, 3)
    cut: np.ndarray  # str: "bisector" | "straight"
    length: np.ndarray  # far-face length, mm
    length_mem: np.ndarray  # length at the membrane-side face of the bumper, mm
    axis_t: np.ndarray  # (k, 3) unit axis in the target
    tip_t: np.ndarray  # (k, 3) far-face axis point on the ideal plane, target frame
    bis_p_t: np.ndarray  # (k, 3) point of the bisector plane (target)
    bis_n_t: np.ndarray  # (k, 3) bisector normal (target), away from the base

    def __len__(self):
        return len(self.base)


def build_bumpers(V, F, ff, cells: Cells, R, params: UnitCell = UNIT_CELL) -> Bumpers:
    """Bumper axes, contact planes and cut types for every base, layer and interior slot.

    Parameters
    ----------
    V : (n, 3) float, mm
        Target vertices (scaled).
    F : (m, 3) int
    ff : (m, 3) int
    cells : Cells
    R : (m, 3, 3) float
        Base rotations (flat -> target).
    """
    F = np.asarray(F, dtype=np.int64)
    Fc = face_centroids(V, F)
    N = face_normals(V, F)
    hc = params.base_th / 2 + params.base_p  # layer centre height (1.3)
    h_far = params.layer_h  # 2.3
    h_mem = params.base_p  # 0.3
    rows = []
    for s, sg in ((0, 1.0), (1, -1.0)):
        ii, jj = np.nonzero(ff >= 0)
        nb = ff[ii, jj]
        ci = Fc[ii] + sg * hc * N[ii]
        cn = Fc[nb] + sg * hc * N[nb]
        vrf = cn - ci
        m_ = vrf / np.linalg.norm(vrf, axis=1, keepdims=True)
        d = vrf - np.sum(vrf * N[ii], axis=1, keepdims=True) * N[ii]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        M = 0.5 * (ci + cn)
        dm = np.sum(d * m_, axis=1)

        def length_at(h, ii=ii, sg=sg, M=M, m_=m_, dm=dm):
            P0 = Fc[ii] + sg * h * N[ii]
            return np.sum((M - P0) * m_, axis=1) / dm

        L_far = length_at(h_far)
        L_mem = length_at(h_mem)
        straight = L_far < L_mem - TOL.rel
        tip = Fc[ii] + sg * h_far * N[ii] + L_far[:, None] * d
        pn_t = np.where(straight[:, None], d, m_)
        Ri = R[ii]
        # to the flat frame relative to the base centre: R^T (p - Fc)
        p_flat = np.einsum("kji,kj->ki", Ri, tip - Fc[ii])
        n_flat = np.einsum("kji,kj->ki", Ri, pn_t)
        d_flat = np.einsum("kji,kj->ki", Ri, d)
        rows.append(dict(base=ii, layer=np.full(len(ii), s), slot=jj,
                         cell=cells.cell_of[ii, jj], neighbour=nb,
                         dir_deg=np.degrees(np.arctan2(d_flat[:, 1], d_flat[:, 0])),
                         plane_p=p_flat, plane_n=n_flat,
                         cut=np.where(straight, "straight", "bisector"),
                         length=L_far, length_mem=L_mem, axis_t=d, tip_t=tip,
                         bis_p_t=M, bis_n_t=m_))
    out = {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}
    # order: base, layer, slot
    order = np.lexsort((out["slot"], out["layer"], out["base"]))
    return Bumpers(**{k: v[order] for k, v in out.items()})


# --------------------------------------------------------------------------------------
# flat footprints (exact 2D geometry) and gaps


def footprint_rectangles(bumpers: Bumpers, C2: np.ndarray, params: UnitCell = UNIT_CELL,
                         printed: bool = False):
    """Flat footprint of every bumper as a rectangle (corners CCW), absolute flat coordinates.

    The bumper is a square prism of side ``base_th`` along its axis from the base
    centre; its end plane's in-plane trace is perpendicular to the axis, so the
    footprint is ``[0, max(L_far, L_mem)] x [-base_th/2, base_th/2]`` in the axis frame.

    Parameters
    ----------
    bumpers : Bumpers
    C2 : (m, 2) float, mm -- flat base centres
    params : UnitCell
    printed : bool
        The printed bumper: its end plane moved back by the printing clearance along its
        unit normal (``bumper_trim_plane`` in ``scad/bumper.scad``), which shortens the
        footprint by ``clearance / |n_xy|`` (``n_xy`` = the in-plane part of the plane's
        unit normal, parallel to the axis).  Default: the ideal contact planes.

    Returns
    -------
    Q : (k, 4, 2) float, mm
    """
    ang = np.radians(bumpers.dir_deg)
    u = np.stack([np.cos(ang), np.sin(ang)], 1)
    w = np.stack([-u[:, 1], u[:, 0]], 1)
    L = np.maximum(bumpers.length, bumpers.length_mem)
    if printed:
        n = bumpers.plane_n / np.linalg.norm(bumpers.plane_n, axis=1, keepdims=True)
        L = L - params.clearance / np.hypot(n[:, 0], n[:, 1])
    L = L[:, None]
    h = params.base_th / 2
    c = C2[bumpers.base]
    Q = np.stack([c - h * w, c + L * u - h * w, c + L * u + h * w, c + h * w], axis=1)
    return Q


def _point_segment_dist(P, A, B):
    """Distances from points P (..., 2) to segments AB (..., 2), broadcasting."""
    AB = B - A
    t = np.sum((P - A) * AB, -1) / np.maximum(np.sum(AB * AB, -1), TOL.tiny)
    t = np.clip(t, 0, 1)
    return np.linalg.norm(P - (A + t[..., None] * AB), axis=-1)


def convex_polygon_distance(P, Q):
    """Distance between convex polygons, vectorised; 0 when they intersect.

    Hand-written (shapely is not a dependency): separating-axis test for
    intersection, else min vertex-to-edge distance both ways.

    Parameters
    ----------
    P, Q : (k, 4, 2) float
        Convex quads, CCW.

    Returns
    -------
    d : (k,) float
    """
    P = np.asarray(P, float)
    Q = np.asarray(Q, float)
    Pn, Qn = np.roll(P, -1, axis=1), np.roll(Q, -1, axis=1)
    dP = _point_segment_dist(Q[:, None, :, :], P[:, :, None, :], Pn[:, :, None, :])
    dQ = _point_segment_dist(P[:, None, :, :], Q[:, :, None, :], Qn[:, :, None, :])
    d = np.minimum(dP.reshape(len(P), -1).min(1), dQ.reshape(len(P), -1).min(1))
    # separating axis test
    sep = np.zeros(len(P), dtype=bool)
    for A, An, B in ((P, Pn, Q), (Q, Qn, P)):
        e = An - A
        nrm = np.stack([e[..., 1], -e[..., 0]], -1)  # outward for CCW
        proj_B = np.einsum("kie,kje->kij", nrm, B)  # (k, edge, vertex)
        off = np.sum(nrm * A, -1)[:, :, None]
        sep |= np.any(np.all(proj_B > off, axis=2), axis=1)
    return np.where(sep, d, 0.0)


def point_polygon_distance(c, Q):
    """Distance from points ``c (k, 2)`` to convex quads ``Q (k, 4, 2)`` (0 inside)."""
    Qn = np.roll(Q, -1, axis=1)
    d = _point_segment_dist(c[:, None, :], Q, Qn).min(1)
    e = Qn - Q
    cross = e[..., 0] * (c[:, None, 1] - Q[..., 1]) - e[..., 1] * (c[:, None, 0] - Q[..., 0])
    inside = np.all(cross >= 0, axis=1)
    return np.where(inside, 0.0, d)


@dataclass
class Gaps:
    """Flat gaps between footprints of different bases of one layer (mm)."""

    pairs: np.ndarray  # (p, 2) base pairs
    layer: np.ndarray  # (p,)
    gap: np.ndarray  # (p,) min distance between the two bases' footprints (0 = overlap)


def footprint_gaps(bumpers: Bumpers, C2, params: UnitCell = UNIT_CELL, reach=None) -> Gaps:
    """Minimum flat distance between the printed footprints (disc + bumpers) of nearby bases.

    What is printed is measured: each bumper rotated with its base (off its flat axis by
    the local conformal angle error) and trimmed by its plane moved back by the printing
    clearance (:func:`footprint_rectangles` with ``printed=True``).  ``min_gap`` is the
    smallest gap allowed between printed parts of different bases.  The closed-form 2D
    rule (:func:`scale_2d`, the reference's) keeps ``min_gap`` between the ideal,
    axis-aligned tips, i.e. ``min_gap + 2 clearance`` once printed; this measure raises
    the scale only where the real footprints come closer than ``min_gap``.

    Parameters
    ----------
    bumpers : Bumpers
    C2 : (m, 2) float, mm
        Flat base centres.
    """
    C2 = np.asarray(C2, float)
    r = params.base_r
    Lmax = np.maximum(bumpers.length, bumpers.length_mem)
    if reach is None:
        reach = max(r, float(np.hypot(Lmax.max(initial=r), params.base_th / 2)))
    pairs = np.array(sorted(cKDTree(C2).query_pairs(2 * reach + 1.0)), dtype=np.int64)
    if len(pairs) == 0:
        return Gaps(np.zeros((0, 2), int), np.zeros(0, int), np.zeros(0))
    Q = footprint_rectangles(bumpers, C2, params, printed=True)
    out_p, out_l, out_g = [], [], []
    for s in (0, 1):
        sel = np.flatnonzero(bumpers.layer == s)
        rect_base = bumpers.base[sel]
        Qs = Q[sel]
        order = np.argsort(rect_base, kind="stable")
        rect_base, Qs = rect_base[order], Qs[order]
        first = np.searchsorted(rect_base, np.arange(len(C2)))
        last = np.searchsorted(rect_base, np.arange(len(C2)), side="right")
        g = np.linalg.norm(C2[pairs[:, 0]] - C2[pairs[:, 1]], axis=1) - 2 * r
        # disc-rect and rect-rect, by expanding pairs over rectangles
        for A, B in ((0, 1), (1, 0)):
            a, b = pairs[:, A], pairs[:, B]
            cnt = last[b] - first[b]
            pi = np.repeat(np.arange(len(pairs)), cnt)
            ri = (np.concatenate([np.arange(f, e) for f, e in
                                  zip(first[b], last[b], strict=True)])
                  if len(pi) else np.zeros(0, int))
            dd = point_polygon_distance(C2[a[pi]], Qs[ri]) - r
            np.minimum.at(g, pi, np.maximum(dd, 0.0))
        a, b = pairs[:, 0], pairs[:, 1]
        ca, cb = last[a] - first[a], last[b] - first[b]
        pi = np.repeat(np.arange(len(pairs)), ca * cb)
        if len(pi):
            ra = np.concatenate([np.repeat(np.arange(f, e), nb_) for f, e, nb_ in
                                 zip(first[a], last[a], cb, strict=True)])
            rb = np.concatenate([np.tile(np.arange(f, e), na_) for f, e, na_ in
                                 zip(first[b], last[b], ca, strict=True)])
            dd = convex_polygon_distance(Qs[ra], Qs[rb])
            np.minimum.at(g, pi, dd)
        out_p.append(pairs)
        out_l.append(np.full(len(pairs), s))
        out_g.append(np.maximum(g, 0.0))
    return Gaps(np.concatenate(out_p), np.concatenate(out_l), np.concatenate(out_g))


# --------------------------------------------------------------------------------------
# boundary, alignment, support frame


def alignment_bases(C2, boundary_faces, min_dist: float = 10.0) -> np.ndarray:
    """Alignment bases (§2.8): farthest boundary pair, drop those within ``min_dist`` of
    either, farthest pair among the rest.  Returns sorted face ids (<= 4)."""
    cand = np.asarray(boundary_faces, dtype=np.int64)
    chosen = []
    for _ in range(2):
        if len(cand) < 2:
            break
        P = C2[cand]
        D = np.linalg.norm(P[:, None] - P[None], axis=2)
        i, j = np.unravel_index(np.argmax(D), D.shape)
        pick = [int(cand[i]), int(cand[j])]
        chosen += pick
        dmin = np.min(np.linalg.norm(C2[cand][:, None] - C2[pick][None], axis=2), axis=1)
        cand = cand[dmin > min_dist]
    return np.array(sorted(set(chosen)), dtype=np.int64)


def flat_boundary_loop(UV, F) -> np.ndarray:
    """(b, 2) float: the flat boundary loop (stencil vertices), CCW."""
    loop = igl.boundary_loop(np.asarray(F, dtype=np.int64))
    if len(loop) == 0:
        raise InputError("the stencil has no boundary", fix="cut the surface open")
    P = np.asarray(UV, float)[loop]
    area = 0.5 * np.sum(P[:, 0] * np.roll(P[:, 1], -1) - np.roll(P[:, 0], -1) * P[:, 1])
    if area < 0:
        P = P[::-1]
    return P


# --------------------------------------------------------------------------------------
# the whole layout


@dataclass
class Layout:
    """Everything the tables need, for one scaled stencil (mm)."""

    V: np.ndarray
    UV: np.ndarray
    F: np.ndarray
    ff: np.ndarray
    cells: Cells
    Fc: np.ndarray
    N: np.ndarray
    C2: np.ndarray
    R: np.ndarray
    rotvec: np.ndarray
    ref_slot: np.ndarray
    bumpers: Bumpers
    boundary_face: np.ndarray
    alignment: np.ndarray
    support: np.ndarray
    central_length: np.ndarray
    target_length: np.ndarray
    fold_angle_deg: np.ndarray
    scale3d: float
    scale2d: float
    scale2d_rule: float
    scale3d_ratio: np.ndarray
    gaps: Gaps | None = None
    info: dict = field(default_factory=dict)


def orient_flat(UV, F):
    """Make every flat triangle CCW: mirror y if they are all CW; raise on mixed orientation.

    Returns
    -------
    UV : (n, 2) float
    flipped : int
        Number of flipped (inverted) triangles found (0 when consistent).
    """
    A = signed_areas_2d(UV, F)
    UV = np.array(UV, dtype=float)
    if np.sum(A < 0) > np.sum(A > 0):
        UV[:, 1] *= -1
        A = -A
    return UV, int(np.sum(A <= 0))


def _flat_scale(C2u, cells, bumpers: Bumpers, s2_rule: float, central_length,
                enforce_gap: bool, params: UnitCell) -> float:
    """The 2D scale of the flat layout (face centroids ``C2u`` before scaling): the min-gap
    rule's ``s2_rule``, or the one that makes the shortest cell ``central_length`` long, then
    raised until the printed footprints keep ``min_gap`` (``enforce_gap``)."""
    s2 = s2_rule
    if central_length is not None:
        a, b = cells.faces[:, 0], cells.faces[:, 1]
        lmin = np.linalg.norm(C2u[b] - C2u[a], axis=1).min()
        s_req = float(central_length) / lmin
        if s_req < s2_rule * (1 - TOL.rel):
            raise InputError(
                f"central_length={central_length} mm is shorter than the min-gap rule allows "
                f"({s2_rule * lmin:.3f} mm)", fix="use a larger central_length or omit it")
        s2 = s_req
    if enforce_gap:
        for _ in range(30):
            gaps = footprint_gaps(bumpers, C2u * s2, params)
            worst = gaps.gap.min(initial=np.inf)
            if worst >= params.min_gap - TOL.rel:
                break
            k = int(np.argmin(gaps.gap))
            i, j = gaps.pairs[k]
            lk = np.linalg.norm(C2u[i] - C2u[j]) * s2
            s2 *= 1 + (params.min_gap - worst + TOL.gap) / lk
    return s2


def build_layout(V, UV, F, params: UnitCell = UNIT_CELL, *, central_length=None,
                 enforce_gap: bool = True) -> Layout:
    """Scale a stencil and lay out bases, bumpers and cells.

    Parameters
    ----------
    V : (n, 3) float
        Target vertices (any scale; centred here at the vertex mean).
    UV : (n, 2) float
        Flat layout row-aligned with V (any scale; centred at the vertex mean).
    F : (m, 3) int
    params : UnitCell
    central_length : float, mm, optional
        If given, the flat layout is scaled so the *shortest* flat central length is
        this value (test patches); it must not violate the min-gap rule.
    enforce_gap : bool
        Raise the 2D scale until the printed flat footprints keep ``min_gap``
        (:func:`footprint_gaps`).

    Returns
    -------
    Layout
    """
    V = np.asarray(V, dtype=float)
    F = np.asarray(F, dtype=np.int64)
    UV, flipped = orient_flat(UV, F)
    if flipped:
        raise InputError(f"{flipped} flat triangle(s) are inverted (flipped) in the layout",
                         fix="use a flattening without flips (flattening='cetm') or remesh")
    V = V - V.mean(axis=0)
    UV = UV - UV.mean(axis=0)
    ff = face_adjacency(F)
    cells = unit_cells(F, ff)
    if len(cells.faces) == 0:
        raise InputError("the stencil has no interior edge (no unit cell)",
                         fix="use a surface with at least two triangles")
    s3, ratio3 = scale_3d(V, F, cells, params)
    V = V * s3
    s2_rule, _ = scale_2d(V, UV, F, cells, params)
    R, ref = base_rotations(V, UV, F, ff)
    bumpers = build_bumpers(V, F, ff, cells, R, params)
    s2 = _flat_scale(face_centroids(UV, F), cells, bumpers, s2_rule, central_length,
                     enforce_gap, params)
    # round to what the files store, then derive everything from the rounded stencil
    V = round_sig9(V)
    UV = round_sig9(UV * s2)
    R, ref = base_rotations(V, UV, F, ff)
    bumpers = build_bumpers(V, F, ff, cells, R, params)
    C2 = face_centroids(UV, F)
    gaps = footprint_gaps(bumpers, C2, params) if enforce_gap else None
    Fc = face_centroids(V, F)
    N = face_normals(V, F)
    a, b = cells.faces[:, 0], cells.faces[:, 1]
    boundary_face = np.any(ff < 0, axis=1)
    lay = Layout(
        V=V, UV=UV, F=F, ff=ff, cells=cells, Fc=Fc, N=N, C2=C2, R=R,
        rotvec=matrix_to_rotvec(R), ref_slot=ref, bumpers=bumpers,
        boundary_face=boundary_face,
        alignment=alignment_bases(C2, np.flatnonzero(boundary_face)),
        support=flat_boundary_loop(UV, F),
        central_length=np.linalg.norm(C2[b] - C2[a], axis=1),
        target_length=np.linalg.norm(Fc[b] - Fc[a], axis=1),
        fold_angle_deg=fold_angles_deg(Fc, N, cells),
        scale3d=s3, scale2d=s2, scale2d_rule=s2_rule, scale3d_ratio=ratio3 / ratio3.min(),
        gaps=gaps)
    return lay


__all__ = ["scale_3d", "scale_2d", "Bumpers", "build_bumpers", "footprint_rectangles",
           "convex_polygon_distance", "point_polygon_distance", "Gaps", "footprint_gaps",
           "alignment_bases", "flat_boundary_loop", "Layout", "orient_flat", "build_layout"]
