"""Stencil generation: isotropic remeshing of the target surface into N vertices, optimised.

Method ``"cvt"`` (default), in the conformal plane of the dense target (CETM, boundary
log-scale 0, or the one that lowers the measured bound with ``StencilSearch.rim_scale``
free, :func:`pysolver.design.flatten.cetm`):

0. **Frame**: the conformal layout is unique up to a rigid motion, which the solver fixes by
   labels; :func:`flat_frame` sets it from the layout's shape (centroid, most pronounced
   area moment), so that everything seeded in the plane is a function of the geometry.
1. **Boundary**: points along the target's boundary, or along a curve inset from it by a
   fraction of a cell spacing (``StencilSearch.rim_insets``), equally spaced in 3D arc length
   from where the frame's x axis crosses it.
2. **CVT**: weighted Lloyd iterations of the interior points, from points drawn by position
   with the CVT's density (:func:`_seed_points`), each quadrature point shared softly among
   its nearest generators (:func:`_soft_owners`, ``StencilSearch.lloyd_softness``) so that
   the iterations are continuous in the input.  A 2D CVT of density ``rho``
   spaces its points as ``rho^(-1/4)``; the density ``exp(-4 (1 - g) u)`` (u = conformal
   log-scale, flat = exp(u) 3D) spaces them as ``exp(u)^(1 - g)`` in the plane, i.e.
   ``exp(u)^(-g)`` on the target.  ``g = StencilSearch.grading``: 0 = uniform on the target,
   1 = uniform in the plane; the default 0.5 is the reference's ``exp(-2u)``
   (``pipeline.md`` §2.2), half-way.  Measured on the paper's cover
   (``bench/bench_design_cover.py`` and programming with a constant 60 s): 0.5 clamps fewer
   cells than 1 (figures in :class:`StencilSearch`); 0 needs more bases (about 700 against
   640 at 1 for the 0.1 mm bumper) and clamped 21 % at the reference's vertex count, 0.5
   15.5 %.  Either way the triangles are isotropic on the target, because the map is
   conformal.  Given a landscape whose seconds are the user's, the spacing also follows
   ``(t / t_mean)^(-timing_grading)`` (:func:`time_spacing_log`): smaller, slower cells
   where the landscape asks for late times.
3. **Relaxation**: Persson and Strang's spring relaxation (DistMesh): repulsive springs of
   rest length 1.2 x the RMS length, scaled by the desired spacing, Delaunay
   re-triangulation (Shewchuk's Triangle) every few steps.  It removes most of the valence
   defects a Lloyd iteration from random seeds leaves behind.
4. **Ears and flaps**: triangles with two boundary edges are removed; a rim vertex in only
   two triangles (a *flap*: two rim bases joined by one cell, a four-bar chain along the rim
   that turns in plane in water and locks with its cells closed at one end) is dropped and
   its two triangles merged, where the merged triangle neither folds nor has an angle under
   ``StencilSearch.flap_min_angle_deg`` (:func:`remove_flaps`).
5. **Optimisation** (:mod:`pysolver.design.stencil.optimise`): the interior vertices move in
   the plane, and the rim vertices slide along the curve of step 1
   (:class:`~pysolver.design.stencil.optimise.RimCurve`), to minimise the longest flat cell after
   both scaling rules and, given the time landscape, to suit each cell's speed to its
   requested time.
6. **Lift**: every flat point is mapped to 3D through its dense flat triangle.

Method ``"pymeshlab"`` (pymeshlab's isotropic explicit
remeshing in 3D) is kept for comparison; at the stencil's coarse resolution its triangles are
much less regular.

The vertex-count search that chooses among these stencils is
:mod:`pysolver.design.stencil.count_search`.
"""

from __future__ import annotations

import igl
import numpy as np
import triangle as tr
from matplotlib.path import Path as PolygonPath
from scipy.spatial import cKDTree
from shapely.geometry import LinearRing, Polygon

from ...errors import InputError
from ...geometry import face_adjacency, face_normals, signed_areas_2d
from ...params import STENCIL, StencilSearch
from ...params import tol as TOL
from ..flatten import cetm

PAPER_CELL_LENGTH = 7.0  # mm, l_avg of the vertex-count estimate (Supplementary Note 1)


def surface_area(V, F) -> float:
    """Total area (mm^2)."""
    return float(0.5 * igl.doublearea(np.asarray(V, float), np.asarray(F, dtype=np.int64)).sum())


def estimate_vertices(area: float) -> int:
    """Paper's estimate N ~ 0.38 A / l_avg^2 with l_avg = 7 mm."""
    return max(int(round(0.38 * area / PAPER_CELL_LENGTH**2)), 4)


def remove_ears(V, F):
    """Drop faces with two (or three) boundary edges, repeatedly; drop unused vertices.

    Returns
    -------
    V : (k, 3) float
    F : (f, 3) int
    """
    F = np.asarray(F, dtype=np.int64)
    for _ in range(10):
        ff = face_adjacency(F)
        ear = np.sum(ff < 0, axis=1) >= 2
        if not ear.any() or ear.all():
            break
        F = F[~ear]
    used = np.unique(F)
    remap = -np.ones(len(V), dtype=np.int64)
    remap[used] = np.arange(len(used))
    return np.asarray(V)[used], remap[F]


def remove_flaps(P, F, min_angle_deg: float = STENCIL.flap_min_angle_deg):
    """Merge the two triangles of every rim vertex that has only two (a *flap*), in the plane.

    Such a vertex ``v`` with rim neighbours ``a``, ``b`` and inner neighbour ``w`` gives two
    rim bases joined by a rim-to-rim unit cell, hanging from the rest of the shell by one cell
    each: a four-bar chain along the rim.  In water the chain turns in plane (the bases rotate
    in opposite senses), its cells close at one end only and lock.  The two triangles
    ``(v, a, w)``, ``(v, w, b)`` become ``(a, w, b)`` and ``v`` is dropped: the rim runs
    straight from ``a`` to ``b`` (inside the old rim where it is convex at ``v``, outside
    where it is concave; no point moves, and the stencil's flat layout is computed from its
    3D points anyway).  A flap stays where the merged triangle would fold or have an angle
    under ``min_angle_deg`` (``w`` near the chord: a base would reach across its edge).
    Measured on the spiral, whose inner rim is concave: keeping the concave flaps leaves 6
    cells that never close, merging them none.  Used on the flat stencil of the CVT method;
    the ``"pymeshlab"`` comparison method keeps its flaps.

    Parameters
    ----------
    P : (k, 2) float, mm -- flat points
    F : (f, 3) int -- a triangulated disk (one rim loop), consistently oriented
    min_angle_deg : float, deg

    Returns
    -------
    P : (k', 2) float, mm -- ``P`` without the dropped vertices (no point moves)
    F : (f', 3) int -- one face fewer per dropped vertex
    """
    P = np.asarray(P, float)
    F = np.asarray(F, dtype=np.int64).copy()
    sense = np.sign(signed_areas_2d(P, F).sum())
    skip = set()
    while len(F) >= 2:
        count = np.bincount(F.ravel(), minlength=len(P))
        flaps = [int(v) for v in igl.boundary_loop(F) if count[v] == 2 and int(v) not in skip]
        if not flaps:
            break
        v = flaps[0]
        pair = np.flatnonzero((F == v).any(axis=1))
        u = np.setdiff1d(F[pair[1]], F[pair[0]])
        if len(u) != 1:
            raise InputError(f"remove_flaps: the two triangles of rim vertex {v} share "
                             f"{3 - len(u)} vertices", fix="give a manifold triangle mesh "
                             "without repeated faces.")
        merged = np.where(F[pair[0]] == v, u[0], F[pair[0]])
        if (signed_areas_2d(P, merged[None])[0] * sense <= 0
                or np.degrees(igl.internal_angles(P, merged[None]).min()) < min_angle_deg):
            skip.add(v)
            continue
        F = np.vstack([np.delete(F, pair, axis=0), merged])
        skip -= set(merged.tolist())  # their triangles changed: look at them again
    used = np.unique(F)
    remap = -np.ones(len(P), dtype=np.int64)
    remap[used] = np.arange(len(used))
    return P[used], remap[F]


# --------------------------------------------------------------------------------------
# pymeshlab (3D) remeshing


def isotropic_remesh(V, F, edge_length: float, iterations: int = 12):
    """pymeshlab isotropic explicit remeshing to a target edge length (mm).

    The ``"pymeshlab"`` stencil method (kept for comparison).  Orientation of the input is
    kept.
    """
    import pymeshlab  # heavy: MeshLab only for remeshing

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.asarray(V, float),
                               face_matrix=np.asarray(F, dtype=np.int32)))
    ms.meshing_isotropic_explicit_remeshing(
        iterations=iterations, targetlen=pymeshlab.PureValue(float(edge_length)),
        featuredeg=60.0, checksurfdist=True,
        maxsurfdist=pymeshlab.PureValue(STENCIL.remesh_surface_dist * edge_length),
        reprojectflag=True)
    m = ms.current_mesh()
    V2 = np.asarray(m.vertex_matrix(), float)
    F2 = np.asarray(m.face_matrix(), dtype=np.int64)
    return _keep_orientation(V2, F2, V, F)


def _keep_orientation(V2, F2, V, F):
    _, fi, _ = igl.point_mesh_squared_distance(V2[F2].mean(1), np.asarray(V, float),
                                               np.asarray(F, dtype=np.int64))
    n_src = face_normals(V, F)[fi]
    if np.sum(np.sum(face_normals(V2, F2) * n_src, axis=1)) < 0:
        F2 = F2[:, ::-1].copy()
    return V2, F2


def needs_dense(V, F, settings: StencilSearch = STENCIL) -> bool:
    """Whether a target is resampled before flattening (:func:`resample_dense`): its
    smallest triangle angle under ``dense_min_angle_deg`` or fewer than ``dense_min_faces``
    faces.  The subdivision keeps a sliver's angles: for a mesh with slivers and faces
    enough it drops the ears only (the cover: 5648 faces, no pass).  The decision is a
    threshold on the input, which a jitter of the input crosses only within its last bits
    of 15 deg or at a face count of exactly the limit."""
    minang = np.degrees(igl.internal_angles(np.asarray(V, float),
                                            np.asarray(F, dtype=np.int64)).min())
    return bool(minang < settings.dense_min_angle_deg or len(F) < settings.dense_min_faces)


def resample_dense(V, F, faces: int = STENCIL.dense_faces):
    """Resample a user mesh to about ``faces`` triangles by midpoint subdivision.

    Each pass splits every triangle into four at its edges' midpoints (``igl.upsample``), as
    many passes as bring the face count nearest ``faces`` on a log scale (none for a mesh
    already that fine), after the input's ears are dropped (:func:`remove_ears`; none arise
    in the passes: a corner in one triangle only is an ear of the input).  The surface is the
    input's, point for point, and the new points are fixed linear combinations of the input's,
    so the dense mesh is a continuous function of the input: a change of the input's last bits
    moves it by as little.  A remeshing that splits, collapses and flips edges by thresholds
    (pymeshlab's isotropic remeshing, used here before) gives another mesh, and another
    stencil, under a jitter of 1e-7 of the size (``docs/results.md``).  Subdivision keeps the
    input's triangle shapes: slivers stay slivers, which the conformal flattening (CETM, a
    convex energy on edge lengths) and the quadrature of the CVT take as they are.

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    faces : int -- the face count aimed at

    Returns
    -------
    V : (k, 3) float, mm
    F : (f, 3) int -- ``4^p`` faces for each face left (``p`` passes)

    Examples
    --------
    >>> import numpy as np
    >>> a = np.pi / 3 * np.arange(6)  # a hexagon of unit radius in six triangles
    >>> V = np.r_[[[0, 0, 0]], np.c_[np.cos(a), np.sin(a), 0 * a], [[1, 1, 0]]]
    >>> F = np.r_[[[0, i, i % 6 + 1] for i in range(1, 7)], [[1, 7, 2]]]  # and an ear
    >>> V2, F2 = resample_dense(V, F, faces=96)  # the ear (1, 7, 2) is dropped first
    >>> len(F2), bool(np.isclose(surface_area(V2, F2), 3 * np.sqrt(3) / 2))
    (96, True)
    """
    F = np.asarray(F, dtype=np.int64)
    if F.ndim != 2 or F.shape[1] != 3 or not len(F) or int(faces) < 1:
        raise InputError(f"resample_dense: faces of shape {F.shape} toward {faces} faces; "
                         "needs (m, 3) triangles, m >= 1",
                         fix="give a triangle mesh with at least one face, and faces >= 1")
    V, F = remove_ears(np.asarray(V, float), F)
    # passes nearest on a log scale, in integers (a float log can land on the half either
    # side of it with another libm): one more pass while n 4^p is further from ``faces``
    passes, n = 0, len(F)
    while n * 4**passes * n * 4 ** (passes + 1) < int(faces) ** 2:
        passes += 1
    if passes:
        V, F = igl.upsample(V, F, passes)
    return V, np.asarray(F, dtype=np.int64)


# --------------------------------------------------------------------------------------
# the conformal plane of the dense target


class RimInsetError(InputError):
    """A rim inset does not leave one connected region (a neck narrower than twice the inset);
    the search then tries the next inset."""


def _polyline_by_length(C, X, k: int) -> np.ndarray:
    """``k`` points of the closed flat polyline ``C`` (r, 2) equally spaced in the arc length
    of its 3D image ``X`` (r, 3); the last point of C repeats the first."""
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(X, axis=0), axis=1))]
    q = np.linspace(0.0, s[-1], k, endpoint=False)
    return np.c_[np.interp(q, s, C[:, 0]), np.interp(q, s, C[:, 1])]


def triangulate_flat(P, n_boundary: int) -> np.ndarray:
    """Constrained Delaunay triangulation of flat points whose first ``n_boundary`` rows are a
    closed boundary polygon (no Steiner points, Shewchuk's Triangle), positively oriented.

    Returns
    -------
    F : (m, 3) int
    """
    P = np.asarray(P, float)
    nb = int(n_boundary)
    seg = np.c_[np.arange(nb), (np.arange(nb) + 1) % nb]
    t = tr.triangulate({"vertices": P, "segments": seg}, "pYQ")
    if len(t["vertices"]) != len(P) or "triangles" not in t:
        raise InputError("remeshing: the flat domain boundary self-intersects",
                         fix="check the input surface (it folds onto itself when flattened)")
    F = t["triangles"].astype(np.int64)
    A = ((P[F[:, 1], 0] - P[F[:, 0], 0]) * (P[F[:, 2], 1] - P[F[:, 0], 1])
         - (P[F[:, 1], 1] - P[F[:, 0], 1]) * (P[F[:, 2], 0] - P[F[:, 0], 0]))
    F[A < 0] = F[A < 0][:, ::-1]
    return F


class FlatDomain:
    """Dense target mesh with its conformal flattening (CETM), where stencils are made.

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    settings : StencilSearch
    time : (n,) float, s, optional -- the landscape the spacing follows
    rim_log_scale : (n,) float, optional
        The flattening's boundary log-scale (:func:`pysolver.design.stencil.feasibility.
        rim_log_scale`, harmonic; its rim values are the Dirichlet data); default 0, the
        rim's lengths kept.
    posed : bool
        ``V`` is in the target's own frame (:func:`pysolver.geometry.canonical_pose`
        decided it): :func:`flat_frame` breaks a mirror tie by it.  Not in a frame given by
        the user's file, whose axes a rigid motion turns.
    """

    def __init__(self, V, F, settings: StencilSearch = STENCIL, time=None, rim_log_scale=None,
                 posed: bool = False):
        self.V = np.asarray(V, float)
        self.F = np.asarray(F, dtype=np.int64)
        self.settings = settings
        self.rim_u = None if rim_log_scale is None else np.asarray(rim_log_scale, float)
        UV, self.u, _ = cetm(self.V, self.F, u_boundary=self.rim_u)
        self.UV = flat_frame(UV, self.F, V=self.V if posed else None)
        # log of the relative 3D spacing the time landscape asks for (0 without one)
        self.w = (np.zeros(len(self.V)) if time is None
                  else time_spacing_log(time, settings.timing_grading))
        self.face_w = self.w[self.F].mean(axis=1)
        self.UV3 = np.c_[self.UV, np.zeros(len(self.UV))]
        self.area3 = 0.5 * igl.doublearea(self.V, self.F)
        self.area2 = 0.5 * igl.doublearea(self.UV, self.F)
        self.face_u = self.u[self.F].mean(axis=1)
        loop = igl.boundary_loop(self.F)
        self.loop = np.asarray(loop, dtype=np.int64)
        self.perimeter = float(np.linalg.norm(self.V[np.roll(loop, -1)] - self.V[loop],
                                              axis=1).sum())
        self.quad = quadrature_points(self.UV, self.F)
        self.quad_face = np.tile(np.arange(len(self.F)), 4)

    # -- maps ------------------------------------------------------------------------
    def _barycentric(self, P):
        P = np.asarray(P, float)
        _, fi, C = igl.point_mesh_squared_distance(np.c_[P, np.zeros(len(P))], self.UV3, self.F)
        T = self.UV[self.F[fi]]
        e1, e2, w = T[:, 1] - T[:, 0], T[:, 2] - T[:, 0], C[:, :2] - T[:, 0]
        det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        b1 = (w[:, 0] * e2[:, 1] - w[:, 1] * e2[:, 0]) / det
        b2 = (e1[:, 0] * w[:, 1] - e1[:, 1] * w[:, 0]) / det
        return fi, np.c_[1 - b1 - b2, b1, b2]

    def lift(self, P) -> np.ndarray:
        """(k, 3) float, mm: target points of flat points ``P`` (k, 2) (barycentric in the
        dense flat triangle; points outside are first moved to the nearest one)."""
        fi, B = self._barycentric(P)
        return np.einsum("ij,ijk->ik", B, self.V[self.F[fi]])

    def lift_jacobian(self, P) -> np.ndarray:
        """(k, 3, 2) float: derivative of :meth:`lift` at ``P`` (piecewise constant)."""
        fi, _ = self._barycentric(P)
        T, X = self.UV[self.F[fi]], self.V[self.F[fi]]
        Mu = np.stack([T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]], axis=2)
        Mx = np.stack([X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]], axis=2)
        return Mx @ np.linalg.inv(Mu)

    def interpolate(self, values, P) -> np.ndarray:
        """(k,) float: per-dense-vertex ``values`` (n,) at flat points ``P`` (k, 2)."""
        fi, B = self._barycentric(P)
        return np.einsum("ij,ij->i", B, np.asarray(values, float)[self.F[fi]])

    def rim_scale_at(self, X):
        """(k,) float or None: the flattening's harmonic rim log-scale at target points
        ``X`` (k, 3) mm (on the target: a stencil's vertices), the boundary data of a
        stencil's own flattening; None when the rim's lengths are kept."""
        if self.rim_u is None:
            return None
        _, fi, C = igl.point_mesh_squared_distance(np.asarray(X, float), self.V, self.F)
        T = self.V[self.F[fi]]
        B = igl.barycentric_coordinates(C, T[:, 0].copy(), T[:, 1].copy(), T[:, 2].copy())
        return np.einsum("ij,ij->i", B, self.rim_u[self.F[fi]])

    def log_scale(self, P) -> np.ndarray:
        """(k,) float: conformal log-scale u at flat points (flat length = exp(u) 3D)."""
        fi, B = self._barycentric(P)
        return np.einsum("ij,ij->i", B, self.u[self.F[fi]])

    def log_spacing_at_vertices(self) -> np.ndarray:
        """(n,) float: :meth:`log_spacing` at the dense vertices (its extremes: it is linear
        in each dense triangle)."""
        return (1 - self.settings.grading) * self.u + self.w

    def log_spacing(self, P) -> np.ndarray:
        """(k,) float: log of the desired flat spacing at flat points, up to a constant:
        ``(1 - grading) u + w`` (``w``: :func:`time_spacing_log`, 0 without a landscape)."""
        fi, B = self._barycentric(P)
        out = (1 - self.settings.grading) * np.einsum("ij,ij->i", B, self.u[self.F[fi]])
        if np.any(self.w):
            out = out + np.einsum("ij,ij->i", B, self.w[self.F[fi]])
        return out

    # -- stencil -----------------------------------------------------------------------
    def spacing(self, n: int, inside=None, rim_length=None) -> float:
        """3D edge length h (mm) at the rim (u = 0, or of mean 0 with the rim's scale free,
        where the rim cells then differ from their neighbours by ``exp(-grading h)``) of a
        mesh of ``n`` vertices graded as
        ``exp(u)^(-grading)`` (Euler's formula on the graded area) on this target, or on the
        part of it whose quadrature points are ``inside`` (mask) with rim length (mm)."""
        g = self.settings.grading
        wq = np.tile(self.area3 * np.exp(2 * g * self.face_u - 2 * self.face_w), 4) / 4
        area = float(wq.sum() if inside is None else wq[inside].sum())
        return edge_for_count(area, self.perimeter if rim_length is None else rim_length, n)

    def boundary_polygon(self, inset_mm: float = 0.0) -> np.ndarray:
        """(r, 2) float: the flat boundary, or the curve ``inset_mm`` inside it (the boundary
        log-scale is 0, or of mean 0 with a free rim scale, so flat and 3D distances agree
        there, on average), closed (last = first)."""
        C = _start_on_axis(self.UV[self.loop])
        if inset_mm <= 0:
            return C
        poly = Polygon(C).buffer(-float(inset_mm), join_style="round", quad_segs=8)
        if poly.is_empty or poly.geom_type != "Polygon":
            raise RimInsetError(f"an inset of {inset_mm:.2f} mm from the rim splits or empties "
                                "the target", fix="use a smaller inset (0 keeps the rim)")
        R = np.asarray(poly.exterior.coords)
        if LinearRing(R).is_ccw != LinearRing(C).is_ccw:
            R = R[::-1]
        R = _start_on_axis(R[:-1])
        # densify so that the arc length of the lift is accurate
        seg = np.linalg.norm(np.diff(R, axis=0), axis=1)
        s = np.r_[0.0, np.cumsum(seg)]
        t = np.linspace(0.0, s[-1], max(4 * len(self.loop), 200))
        return np.c_[np.interp(t, s, R[:, 0]), np.interp(t, s, R[:, 1])]

    def region_covered(self, inset_mm: float) -> float:
        """Fraction of the target's 3D area inside the curve ``inset_mm`` (mm) from its rim
        (:meth:`boundary_polygon`): the share the stencils of that inset can cover, a
        function of the target alone (each quadrature point carries a quarter of its
        triangle's 3D area), where one stencil's own area also depends on where its rim
        points fell (the petal's inset stencils: 74.9 % to 75.1 %, its region 78 %)."""
        a3 = 0.5 * igl.doublearea(self.V, self.F)
        w = np.tile(a3 / 4, 4)
        inside = PolygonPath(self.boundary_polygon(inset_mm)).contains_points(self.quad)
        return round(float(w[inside].sum() / w.sum()), 4)

    def cvt(self, n: int, seed: int = 0, inset: float = 0.0):
        """Flat points of a weighted CVT with ``n`` points, boundary first, the boundary
        ``inset`` mm inside the target's rim.

        Returns
        -------
        P : (n', 2) float, mm
        n_boundary : int
        """
        st = self.settings
        C = self.boundary_polygon(inset)
        X = self.lift(C)
        length = float(np.sum(np.linalg.norm(np.diff(X, axis=0), axis=1)))
        inside = PolygonPath(C).contains_points(self.quad)
        h = self.spacing(n, inside, length)  # of the region the points go to
        nb = max(int(round(length / h)), st.min_boundary_points)
        B = _polyline_by_length(C, X, nb)
        inside = PolygonPath(B).contains_points(self.quad)
        quad = self.quad[inside]
        # CVT density exp(-4 (1 - grading) u - 4 w) per flat area (module docstring)
        w = (self.area2 * np.exp(-4 * (1 - st.grading) * self.face_u
                                 - 4 * self.face_w))[self.quad_face[inside]]
        ni = max(n - nb, 1)
        if len(quad) < ni:
            raise InputError(f"the target is too small for {n} stencil vertices",
                             fix="use fewer vertices (--vertices) or a larger target")
        Y = _seed_points(B, self, ni, seed)
        for _ in range(st.lloyd_iterations):
            owner, share = _soft_owners(np.vstack([B, Y]), quad, st.lloyd_softness)
            owner = owner - nb
            ok = owner >= 0
            wk = (share * w[:, None])[ok]
            W = np.bincount(owner[ok], weights=wk, minlength=ni)
            Sx = np.bincount(owner[ok], weights=wk * np.broadcast_to(quad[:, :1], owner.shape)[ok],
                             minlength=ni)
            Sy = np.bincount(owner[ok], weights=wk * np.broadcast_to(quad[:, 1:], owner.shape)[ok],
                             minlength=ni)
            has = W > 0
            Y[has] = np.c_[Sx[has] / W[has], Sy[has] / W[has]]
        return np.vstack([B, Y]), nb

    def relax(self, P, n_boundary: int) -> np.ndarray:
        """Spring relaxation of the interior points (Persson and Strang, 2004): repulsive
        springs along the Delaunay edges with rest length ``fscale`` x the RMS length, scaled
        by the desired spacing ``exp(u)^(1 - grading)`` (times the time landscape's, if
        any: :meth:`log_spacing`); boundary points fixed.

        Written here because DistMesh itself is a MATLAB script and no maintained Python
        package relaxes points in a given domain with a given size function.
        """
        st = self.settings
        P = np.array(P, float)
        nb = int(n_boundary)
        domain = PolygonPath(P[:nb])
        E = None
        for it in range(st.relax_iterations):
            if it % st.relax_retriangulate == 0:
                E = igl.edges(triangulate_flat(P, nb))
            d = P[E[:, 0]] - P[E[:, 1]]
            length = np.linalg.norm(d, axis=1)
            want = np.exp(self.log_spacing(0.5 * (P[E[:, 0]] + P[E[:, 1]])))
            rest = want * st.relax_fscale * np.sqrt(np.sum(length**2) / np.sum(want**2))
            f = np.maximum(rest - length, 0.0) / length
            force = np.zeros_like(P)
            np.add.at(force, E[:, 0], f[:, None] * d)
            np.add.at(force, E[:, 1], -f[:, None] * d)
            step = st.relax_step * force[nb:]
            moved = P[nb:] + step
            ok = domain.contains_points(moved)
            P[nb:][ok] = moved[ok]
        return P

    def stencil(self, n: int, seed: int = 0, inset: float = 0.0):
        """Flat stencil before optimisation: CVT, relaxation, triangulation, ear removal,
        flap merging (``inset``: mm from the rim).

        Returns
        -------
        P : (k, 2) float, mm -- flat points (the conformal plane)
        F : (f, 3) int
        """
        P, nb = self.cvt(n, seed=seed, inset=inset)
        P = self.relax(P, nb)
        F = triangulate_flat(P, nb)
        P, F = remove_ears(P, F)
        if self.settings.remove_flaps:
            P, F = remove_flaps(P, F, self.settings.flap_min_angle_deg)
        return P, F


def quadrature_points(UV, F) -> np.ndarray:
    """(4 m, 2) float, mm: four points per triangle of ``UV`` (n, 2), ``F`` (m, 3), the
    centroids of its midpoint subdivision (corner triangles 0, 1, 2, then the middle one),
    each standing for a quarter of its triangle's area."""
    T = np.asarray(UV, float)[np.asarray(F, dtype=np.int64)]
    m = (T + np.roll(T, -1, axis=1)) / 2
    q = [(T[:, k] + m[:, k] + m[:, (k + 2) % 3]) / 3 for k in range(3)]
    return np.concatenate(q + [m.mean(axis=1)])


def flat_frame(UV, F, orders=range(2, 7), V=None, tie: float = TOL.frame_tie) -> np.ndarray:
    """A flat layout moved into a frame given by its shape alone.

    A conformal flattening is unique up to a rigid motion of the plane, which the solver
    fixes by whichever triangle it lays out first: a matter of labelling.  The stencil is
    seeded in the plane, so the plane's frame is set here from the layout's area: its
    centroid at the origin, and its x axis along the angle ``arg(m_k) / k`` of the complex
    area moment ``m_k = integral z^k dA`` of the order k in ``orders`` that is the most
    pronounced (``|m_k| / integral |z|^k dA``, 2 for an elongated shape, 3 for a trefoil),
    of the k directions so given the one toward which the area reaches furthest (the
    largest third moment of x).  A shape with no such moment (a disk) keeps the solver's
    angle, which is then a symmetry.  A mirror-symmetric layout (the stand) has two such
    directions, mirror images, whose third moments tie to the last bits (both zero when the
    two are opposite), and the stencil seeded in one frame is not the mirror image of the
    one seeded in the other.  With the target ``V`` in its own frame
    (:func:`pysolver.geometry.canonical_pose`: right-handed, so its axis along the mirror's
    normal has a sign), of the directions within ``tie`` of the largest (relative to
    ``integral |x|^3 dA``), the one whose area lies furthest toward the + side of that axis
    (of ``sum A (x . d) X``, the 3D component in which the tied directions differ most) is
    taken: the mirror turns that sign.

    Parameters
    ----------
    UV : (n, 2) float, mm
    F : (m, 3) int
    orders : iterable of int
    V : (n, 3) float, mm, optional
        The target, in its own frame; without it a tie goes to the largest third moment.
    tie : float
        :attr:`pysolver.params.Tolerances.frame_tie`.

    Returns
    -------
    UV : (n, 2) float, mm -- rotated and translated (lengths and angles kept)

    Examples
    --------
    >>> import numpy as np
    >>> UV = np.array([[0., 0], [4, 0], [4, 1], [0, 1]]) @ [[0, 1], [-1, 0]] + 5
    >>> P = flat_frame(UV, np.array([[0, 1, 2], [0, 2, 3]]))
    >>> bool(np.ptp(P[:, 0]) > 3.9 > 1.2 > np.ptp(P[:, 1]))  # its long side along x
    True
    >>> bool(np.abs(P.mean(axis=0)).max() < 1e-12)  # its centroid at the origin
    True
    """
    UV = np.asarray(UV, float)
    F = np.asarray(F, dtype=np.int64)
    Q = quadrature_points(UV, F)
    A = np.tile(np.abs(signed_areas_2d(UV, F)), 4)
    c = A @ Q / A.sum()
    z = (Q - c) @ np.array([1.0, 1.0j])
    best, angle, ks = 0.0, 0.0, []
    for k in orders:
        mk = A @ z**k
        rel = abs(mk) / max(float(A @ np.abs(z) ** k), 1e-300)
        if rel > best:
            best, angle = rel, float(np.angle(mk)) / k
            ks = [angle + 2 * np.pi * j / k for j in range(k)]
    if ks:
        reach = [float(A @ np.real(z * np.exp(-1j * a)) ** 3) for a in ks]
        angle = ks[int(np.argmax(reach))]
        top, scale = max(reach), float(A @ np.abs(z) ** 3)
        tied = [a for a, r in zip(ks, reach, strict=True) if r >= top - tie * scale]
        if V is not None and len(tied) > 1:
            X = np.tile(np.asarray(V, float)[F].mean(axis=1), (4, 1))
            C = np.array([A @ (np.real(z * np.exp(-1j * a))[:, None] * X) for a in tied])
            axis = int(np.argmax(np.ptp(C, axis=0)))  # (the mirror's normal)
            angle = tied[int(np.argmax(C[:, axis]))]
    R = np.array([[np.cos(angle), np.sin(angle)], [-np.sin(angle), np.cos(angle)]])
    return (UV - c) @ R.T


def _start_on_axis(C) -> np.ndarray:
    """The closed polygon of the points ``C`` (r, 2), not closed, started where it crosses
    the frame's positive x axis furthest out (:func:`flat_frame`), not at its first label
    (at its point furthest along x when it does not cross); closed (last = first).  A
    crossing moves with the polygon; a vertex chosen among vertices of equal x would not."""
    C = np.asarray(C, float)
    D = np.roll(C, -1, axis=0)
    cross = (C[:, 1] <= 0) != (D[:, 1] <= 0)
    if not cross.any():
        C = np.roll(C, -int(np.argmax(C[:, 0])), axis=0)
        return np.vstack([C, C[:1]])
    t = C[:, 1] / np.where(cross, C[:, 1] - D[:, 1], 1.0)
    x = np.where(cross, C[:, 0] + t * (D[:, 0] - C[:, 0]), -np.inf)
    i = int(np.argmax(x))
    start = np.array([x[i], 0.0])
    C = np.vstack([start, np.roll(C, -(i + 1), axis=0)])
    return np.vstack([C, C[:1]])


def _soft_owners(G, Q, softness: float, k: int = 4):
    """Each point of ``Q`` (q, 2) shared among its ``k`` nearest generators ``G`` (g, 2):
    shares ``exp(-(d^2 - d_1^2) / (softness d_k^2))``, normalised (d_1 the nearest distance,
    d_k the k-th).  A Lloyd step on hard Voronoi owners of quadrature points jumps when a
    point changes owner, and forty steps of such jumps sent a surface moved by 1e-7 of its
    size to another stencil; with soft shares the step is continuous in the generators (a
    point entering the k nearest comes in with a share of ``exp(-1 / softness)`` at most
    its nearest's).

    Returns
    -------
    owner : (q, k) int -- generator indices
    share : (q, k) float -- rows sum to 1
    """
    d, owner = cKDTree(G).query(Q, k=k)
    d2 = d**2
    share = np.exp(-(d2 - d2[:, :1]) / (softness * d2[:, -1:] + 1e-300))
    return owner, share / share.sum(axis=1, keepdims=True)


def _seed_points(B, dom, n: int, seed: int) -> np.ndarray:
    """``n`` starting points of the CVT inside the polygon ``B`` (r, 2), drawn by position,
    not by label: uniform draws in the bounding box of the domain ``dom``
    (:class:`FlatDomain`, in its :func:`flat_frame`), each kept with probability the CVT's
    density there, ``exp(-4 log_spacing)`` (:meth:`FlatDomain.log_spacing`, linear in each
    dense triangle, so continuous), over its largest value.  The same surface so gives the
    same points whatever the order of its triangles, and a surface moved by its last bits
    gives the same draws, kept or not as before but where a draw is within the last bits of
    its threshold.

    Returns
    -------
    Y : (n, 2) float, mm
    """
    rng = np.random.default_rng(seed)
    lo, hi = dom.UV.min(axis=0), dom.UV.max(axis=0)
    inside = PolygonPath(B)
    top = float(np.exp(-4 * dom.log_spacing_at_vertices().min()))
    out, got = [], 0
    while got < n:
        X = lo + (hi - lo) * rng.random((max(4 * n, 256), 2))
        u = rng.random(len(X))
        keep = inside.contains_points(X)
        X, u = X[keep], u[keep]
        X = X[u * top < np.exp(-4 * dom.log_spacing(X))]
        out.append(X[: n - got])
        got += len(out[-1])
    return np.vstack(out)


def time_spacing_log(time, grading: float) -> np.ndarray:
    """Log of the relative 3D stencil spacing a time landscape asks for, per vertex.

    Larger cells are faster (the fitted laws of ``StencilSearch.timing_fastest`` /
    ``timing_slowest`` give ``t ~ size^-2.1`` and ``size^-0.9`` under a uniform scaling), so
    cells asked to finish late are made smaller and those asked to finish early larger:
    spacing ``~ (t / t_mean)^(-grading)``, ``t_mean`` the geometric mean.

    Parameters
    ----------
    time : (n,) float, s
    grading : float

    Returns
    -------
    w : (n,) float
        ``-grading (log t - mean log t)``.
    """
    log_t = np.log(np.maximum(np.asarray(time, float), STENCIL.opt_tiny))
    return -float(grading) * (log_t - log_t.mean())


def edge_for_count(area: float, perimeter: float, n: int) -> float:
    """Edge length h of a regular triangle mesh with ``n`` vertices on a disk of the given
    area and perimeter: ``n = 2 A / (sqrt(3) h^2) + P / (2 h)`` (Euler's formula)."""
    a, b = 2 * area / np.sqrt(3), perimeter / 2
    x = (-b + np.sqrt(b * b + 4 * a * n)) / (2 * a)  # x = 1/h
    return float(1.0 / x)


__all__ = ["surface_area", "time_spacing_log", "estimate_vertices", "remove_ears",
           "remove_flaps", "isotropic_remesh", "needs_dense", "resample_dense",
           "triangulate_flat",
           "FlatDomain", "edge_for_count", "flat_frame"]
