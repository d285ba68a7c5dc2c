"""Stencil generation: isotropic remeshing of the target surface into N vertices, optimised.

Method ``"cvt"`` (default), in the conformal plane of the dense target (CETM, boundary
log-scale 0, :func:`pysolver.design.flatten.cetm`):

1. **Boundary**: points along the target's boundary, or along a curve inset from it by a
   fraction of a cell spacing (``StencilSearch.rim_insets``), equally spaced in 3D arc length.
2. **CVT**: weighted Lloyd iterations of the interior points.  A 2D CVT of density ``rho``
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
5. **Optimisation** (:mod:`pysolver.design.stencil_opt`): the interior vertices move in the plane
   to minimise the longest flat cell after both scaling rules and, given the time landscape,
   to suit each cell's speed to its requested time.
6. **Lift**: every flat point is mapped to 3D through its dense flat triangle.

Method ``"pymeshlab"`` (pymeshlab's isotropic explicit
remeshing in 3D) is kept for comparison; at the stencil's coarse resolution its triangles are
much less regular.

Vertex count: ``vertices=N`` or searched: secant steps on the 3D scaling (about
``sqrt(N)``) toward 1, so that the shell keeps the size of its target, then another seed when
the first leaves no margin, then the next rim inset when nothing is printable; among the
candidates whose longest flat cell is within the limit the one with the scaling closest to 1
wins (:func:`remesh_surface`).  When the chosen inset stencil covers too little of the target
(``StencilSearch.min_area_covered``, a narrow strip), the stencil without an inset is searched
as well and replaces it if it prints at least as well (:func:`_rim_fallback`); the choice and
its reason are recorded (``info["rim"]``).  The winner is optimised once more with its 3D
scaling held at 1 (``StencilSearch.opt_pin_weight``), and kept when that is nearer the target's
size at no longer cell (or still printable and no longer per unit of scaling).  Nothing is
tuned per shape.
"""

from __future__ import annotations

from dataclasses import replace

import igl
import numpy as np
import triangle as tr
from matplotlib.path import Path as PolygonPath
from scipy.spatial import cKDTree
from shapely.geometry import LinearRing, Polygon

from ..errors import InputError
from ..geometry import face_adjacency, face_normals, signed_areas_2d
from ..params import STENCIL, UNIT_CELL, StencilSearch, UnitCell
from ..params import tol as TOL
from .flatten import cetm
from .layout import build_layout
from .stencil_opt import estimated_clamping, optimize_stencil
from .time_landscape import cell_target_times, interpolate_to_stencil

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

    Used to resample user meshes finely (decent triangles for CETM) and as the
    ``"pymeshlab"`` stencil method.  Orientation of the input is kept.
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


def resample_dense(V, F, faces: int = STENCIL.dense_faces):
    """Resample a user mesh to about ``faces`` well-shaped triangles (pymeshlab)."""
    A = surface_area(V, F)
    L = float(np.sqrt(4 * A / (np.sqrt(3) * faces)))
    V2, F2 = isotropic_remesh(V, F, L, iterations=8)
    return remove_ears(V2, F2)


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
    """

    def __init__(self, V, F, settings: StencilSearch = STENCIL, time=None):
        self.V = np.asarray(V, float)
        self.F = np.asarray(F, dtype=np.int64)
        self.settings = settings
        self.UV, self.u, _ = cetm(self.V, self.F)
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
        # quadrature: 4 points per dense face (midpoint-subdivision centroids)
        T = self.UV[self.F]
        m = (T + np.roll(T, -1, axis=1)) / 2
        q = [(T[:, k] + m[:, k] + m[:, (k + 2) % 3]) / 3 for k in range(3)]
        self.quad = np.concatenate(q + [m.mean(axis=1)])
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

    def log_scale(self, P) -> np.ndarray:
        """(k,) float: conformal log-scale u at flat points (flat length = exp(u) 3D)."""
        fi, B = self._barycentric(P)
        return np.einsum("ij,ij->i", B, self.u[self.F[fi]])

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
        """3D edge length h (mm) at the rim (u = 0) of a mesh of ``n`` vertices graded as
        ``exp(u)^(-grading)`` (Euler's formula on the graded area) on this target, or on the
        part of it whose quadrature points are ``inside`` (mask) with rim length (mm)."""
        g = self.settings.grading
        wq = np.tile(self.area3 * np.exp(2 * g * self.face_u - 2 * self.face_w), 4) / 4
        area = float(wq.sum() if inside is None else wq[inside].sum())
        return edge_for_count(area, self.perimeter if rim_length is None else rim_length, n)

    def boundary_polygon(self, inset_mm: float = 0.0) -> np.ndarray:
        """(r, 2) float: the flat boundary, or the curve ``inset_mm`` inside it (the boundary
        log-scale is 0, so flat and 3D distances agree there), closed (last = first)."""
        C = self.UV[np.r_[self.loop, self.loop[:1]]]
        if inset_mm <= 0:
            return C
        poly = Polygon(C).buffer(-float(inset_mm), join_style="round", quad_segs=8)
        if poly.is_empty or poly.geom_type != "Polygon":
            raise RimInsetError(f"an inset of {inset_mm:.2f} mm from the rim splits or empties "
                                "the target", fix="use a smaller inset (0 keeps the rim)")
        R = np.asarray(poly.exterior.coords)
        if LinearRing(R).is_ccw != LinearRing(C).is_ccw:
            R = R[::-1]
        # densify so that the arc length of the lift is accurate
        seg = np.linalg.norm(np.diff(R, axis=0), axis=1)
        s = np.r_[0.0, np.cumsum(seg)]
        t = np.linspace(0.0, s[-1], max(4 * len(self.loop), 200))
        return np.c_[np.interp(t, s, R[:, 0]), np.interp(t, s, R[:, 1])]

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
        rng = np.random.default_rng(seed)
        Y = quad[rng.choice(len(quad), size=ni, replace=False, p=w / w.sum())].copy()
        for _ in range(st.lloyd_iterations):
            _, owner = cKDTree(np.vstack([B, Y])).query(quad)
            owner = owner - nb
            ok = owner >= 0
            W = np.bincount(owner[ok], weights=w[ok], minlength=ni)
            Sx = np.bincount(owner[ok], weights=w[ok] * quad[ok, 0], minlength=ni)
            Sy = np.bincount(owner[ok], weights=w[ok] * quad[ok, 1], minlength=ni)
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


# --------------------------------------------------------------------------------------
# measuring and choosing stencils


def stencil_figures(V, F, params: UnitCell = UNIT_CELL, time=None,
                    settings: StencilSearch = STENCIL) -> dict:
    """Layout margins and regularity of a stencil (its CETM layout after both scaling rules).

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    params : UnitCell
    time : (n,) float, s, optional
        The time landscape at the stencil's vertices: adds ``clamped_estimate``.
    settings : StencilSearch

    Returns
    -------
    dict
        ``scale3d``; ``max_cell_length_mm``; (both None, and ``error``, when the layout fails);
        ``bumper_mm`` [min, max] target bumper length beyond the rim; ``edge_spread``
        (95th / 5th percentile of the 3D edge length, after scaling), ``min_angle_deg``
        (smallest 3D triangle angle); with ``time``, ``clamped_estimate``: the fraction of
        cells whose time the estimate of :func:`~pysolver.design.stencil_opt.estimated_clamping`
        puts out of reach.
    """
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    E = igl.edges(F)
    edge = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    out = {"edge_spread": round(float(np.percentile(edge, 95) / np.percentile(edge, 5)), 4),
           "min_angle_deg": round(float(np.degrees(igl.internal_angles(V, F).min())), 2)}
    try:
        UV, _, _ = cetm(V, F)
        lay = build_layout(V, UV, F, params)
    except InputError as e:
        out.update(scale3d=None, max_cell_length_mm=None, bumper_mm=None,
                   error=str(e).splitlines()[0])
        return out
    bump = lay.bumpers.length - params.base_r
    out.update(scale3d=round(float(lay.scale3d), 6),
               max_cell_length_mm=round(float(lay.central_length.max()), 4),
               bumper_mm=[round(float(bump.min()), 4), round(float(bump.max()), 4)])
    if time is not None:
        c = lay.cells
        t_star = cell_target_times(np.asarray(time, float), c.verts[:, 0], c.verts[:, 1])
        out["clamped_estimate"] = round(estimated_clamping(
            lay.central_length, lay.target_length, c.boundary, t_star, params, settings), 4)
    return out


def _laid_out(c: dict) -> bool:
    return c.get("max_cell_length_mm") is not None


def _pick(tried: dict, params: UnitCell, margin: float):
    """Best candidate: 3D scaling closest to 1 among those whose longest flat cell keeps
    ``margin`` below the limit; else below the limit; else the shortest longest cell.
    Candidates whose layout failed are never picked (None if all failed)."""
    tried = {k: c for k, c in tried.items() if _laid_out(c)}
    if not tried:
        return None
    for lim in (params.max_cell_length - margin, params.max_cell_length):
        ok = [k for k, c in tried.items() if c["max_cell_length_mm"] <= lim]
        if ok:
            return min(ok, key=lambda k: (round(abs(np.log(tried[k]["scale3d"])), 3),
                                          tried[k]["max_cell_length_mm"], k))
    return min(tried, key=lambda k: (tried[k]["max_cell_length_mm"], k))


def _covered(V, F, area: float) -> float:
    """Fraction of the target's area ``area`` (mm^2) the stencil ``V, F`` covers (its own 3D
    area over the target's; the stencil's flat triangles are chords of the target)."""
    return round(surface_area(V, F) / area, 4)


def _tier(c: dict, params: UnitCell, margin: float) -> int:
    """0 when the longest flat cell keeps ``margin`` (mm) below the limit, 1 when it is within
    the limit, 2 otherwise (or when the layout failed)."""
    if not _laid_out(c):
        return 2
    L = c["max_cell_length_mm"]
    return 0 if L <= params.max_cell_length - margin else 1 if L <= params.max_cell_length else 2


def _rim_fallback(best, tried: dict, meshes: dict, area: float, params: UnitCell,
                  settings: StencilSearch, search_rim):
    """The stencil without a rim inset as a measured alternative to an inset stencil.

    When the chosen inset stencil ``best`` covers less than ``settings.min_area_covered`` of
    the target, ``search_rim()`` searches the counts without an inset; its best candidate
    replaces ``best`` only if it prints at least as well (:func:`_tier`, never worse than the
    inset stencil and never beyond the limit).

    Parameters
    ----------
    best : (int, int, float)
        Key (N, seed, inset mm) of the chosen inset stencil in ``tried`` and ``meshes``.
    tried, meshes : dict
        Figures (:func:`stencil_figures`) and meshes of every candidate, by key; filled by
        ``search_rim``.
    area : float, mm^2
        The target's area.
    params : UnitCell
    settings : StencilSearch
    search_rim : callable
        Searches the vertex count with inset 0 (adds its candidates to ``tried``).

    Returns
    -------
    best : (int, int, float)
        The key chosen.
    rim : dict
        ``inset_mm``, ``min_area_covered``, ``inset_area_covered`` (of the inset stencil),
        ``fallback`` (None when not searched, else ``requested``, ``seed``, ``scale3d``,
        ``max_cell_length_mm``, ``area_covered``, ``taken``) and ``why``.
    """
    cov = _covered(*meshes[best][:2], area)
    rim = {"inset_mm": float(best[2]), "min_area_covered": settings.min_area_covered,
           "inset_area_covered": cov, "fallback": None}
    if cov >= settings.min_area_covered:
        rim["why"] = (f"the inset stencil covers {100 * cov:.0f} % of the target (at least "
                      f"{100 * settings.min_area_covered:.0f} %)")
        return best, rim
    try:
        search_rim()
    except RimInsetError:  # (inset 0 never splits the target; kept for symmetry)
        pass
    alt = _pick({k: c for k, c in tried.items() if k[2] == 0.0}, params, settings.margin)
    if alt is None:
        rim["why"] = (f"the inset stencil covers {100 * cov:.0f} % of the target; no stencil "
                      "without the inset could be laid out")
        return best, rim
    c, c0 = tried[alt], tried[best]
    taken = _tier(c, params, settings.margin) <= min(_tier(c0, params, settings.margin), 1)
    rim["fallback"] = {"requested": int(alt[0]), "seed": int(alt[1]),
                       "scale3d": c["scale3d"], "max_cell_length_mm": c["max_cell_length_mm"],
                       "area_covered": _covered(*meshes[alt][:2], area), "taken": bool(taken)}
    if taken:
        rim["why"] = (f"the inset stencil covers {100 * cov:.0f} % of the target (under "
                      f"{100 * settings.min_area_covered:.0f} %); the stencil reaching the rim "
                      f"prints (longest flat cell {c['max_cell_length_mm']:.2f} mm, "
                      f"{c0['max_cell_length_mm']:.2f} mm with the inset)")
        rim["inset_mm"] = 0.0
        return alt, rim
    rim["why"] = (f"the inset stencil covers {100 * cov:.0f} % of the target (under "
                  f"{100 * settings.min_area_covered:.0f} %), but the stencil reaching the rim "
                  f"prints worse (longest flat cell {c['max_cell_length_mm']:.2f} mm, "
                  f"{c0['max_cell_length_mm']:.2f} mm with the inset; limit "
                  f"{params.max_cell_length:.2f} mm, margin {settings.margin:.2f} mm)")
    return best, rim


def _trade(best, V2, F2, chosen, trial, tried, meshes, params, settings, info, progress,
           seeds=None):
    """Fewer, larger (faster) cells for a landscape that asks for early times.

    Tries ``settings.trade_counts`` x the chosen count (each of ``seeds``, default the
    chosen one; same inset) and takes, among every stencil tried with fewer vertices, the
    one with the lowest estimated clamped fraction among those that are printable with
    the margin, keep a 3D scaling of at least ``trade_min_scale3d`` and clamp at least
    ``trade_gain`` fewer cells than the chosen stencil.  Records ``info["trade"]``.
    """
    n0, sd, inset = best
    limit = params.max_cell_length - settings.margin
    for f in settings.trade_counts:
        for s in (seeds or [sd]):
            trial(round(n0 * f), s, inset)
    est0 = chosen["clamped_estimate"]
    ok = [k for k, c in tried.items()
          if k[2] == inset and k[0] < n0 and _laid_out(c)
          and c["max_cell_length_mm"] <= limit and c["scale3d"] >= settings.trade_min_scale3d
          and c["clamped_estimate"] <= est0 - settings.trade_gain]
    record = {"vertices": int(n0), "scale3d": chosen["scale3d"], "clamped_estimate": est0,
              "tried": [[k[0], k[1], tried[k]["scale3d"], tried[k].get("clamped_estimate")]
                        for k in sorted(tried) if k[2] == inset and k[0] < n0],
              "taken": False}
    if ok:
        k = min(ok, key=lambda k: (tried[k]["clamped_estimate"], -k[0]))
        V2, F2, _ = meshes[k]
        record.update(taken=True, to_vertices=int(k[0]), to_scale3d=tried[k]["scale3d"],
                      to_clamped_estimate=tried[k]["clamped_estimate"])
        best, chosen = k, tried[k]
    info["trade"] = record
    if progress is not None:
        after = (f", N={best[0]} ~{100 * chosen['clamped_estimate']:.0f} % at "
                 f"{chosen['scale3d']:.3f}" if ok else "")
        progress(("fewer, larger cells for the landscape: " if ok else "kept the count: ")
                 + f"N={n0} clamps ~{100 * est0:.0f} % of cells at scale3d "
                 f"{record['scale3d']:.3f}" + after)
    return best, V2, F2, chosen


def remesh_surface(V, F, *, vertices=None, seed=None, target_bases=None,
                   params: UnitCell = UNIT_CELL, settings: StencilSearch = STENCIL,
                   method: str = "cvt", dense: bool | None = None, optimize: bool = True,
                   time=None, user_times: bool = False, progress=None):
    """Remesh a target surface into a stencil, searching the vertex count.

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    vertices : int, optional
        Vertex count N; otherwise searched (module docstring).
    seed : int, optional
        Seed of the CVT initialisation; otherwise ``settings.seeds`` seeds are tried.
    target_bases : int, optional
        Start of the search (about 2 N); default ``count_start`` x the paper's estimate.
    params : UnitCell
    settings : StencilSearch
    method : {"cvt", "pymeshlab"}
    dense : bool, optional
        Resample the input finely with pymeshlab first (default: when the input's
        triangles are poor, min angle < 15 deg, or it has fewer than 2000 faces).
    optimize : bool
        Run the stencil optimisation (:mod:`pysolver.design.stencil_opt`).
    time : (n,) float, s, optional
        The time landscape at the vertices of V; the optimisation then also evens the
        cells' speeds against it (``StencilSearch.opt_timing_weight``).
    user_times : bool
        The landscape's seconds are the user's (not mapped later onto what the cells can
        reach): the CVT spacing follows it (``StencilSearch.timing_grading``, redone
        without when that is not printable), and with the vertex count searched, fewer
        vertices are also tried (``StencilSearch.trade_counts``) and taken when they clamp
        markedly fewer cells by the estimate, at a 3D scaling of at least
        ``trade_min_scale3d``; recorded in ``info["timing_grading"]`` and ``info["trade"]``.
    progress : callable, optional
        Called with one line per tried candidate.

    Returns
    -------
    V2 : (k, 3) float, mm
    F2 : (f, 3) int
    info : dict
        ``vertices``, ``requested``, ``seed``, ``rim_inset_mm``, ``estimate_paper``,
        ``scale3d``, ``max_cell_length_mm``, ``before_optimisation`` / ``after_optimisation``
        (:func:`stencil_figures` of the chosen stencil), ``candidates``
        [[N, seed, inset, scale3d, longest flat cell], ...], ``polish`` (the last pass at
        scale 1: ``scale3d``, ``max_cell_length_mm``, ``kept``) and ``rim`` (the rim inset
        chosen and why: ``inset_mm``, ``area_covered`` of the returned stencil, ``fallback``
        and ``why``, see :func:`_rim_fallback`), ``timing_grading`` (``grading``, ``taken``:
        whether the spacing followed the landscape, ``StencilSearch.timing_grading``) and,
        with ``user_times``, ``trade`` (:func:`_trade`).
    """
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    call = dict(V=V, F=F, vertices=vertices, seed=seed, target_bases=target_bases,
                params=params, method=method, dense=dense, optimize=optimize, time=time,
                user_times=user_times, progress=progress)
    A = surface_area(V, F)
    info = {"remeshed": True, "method": method, "area_mm2": round(A, 2),
            "estimate_paper": estimate_vertices(A)}
    if method not in ("cvt", "pymeshlab"):
        raise InputError(f"remesh method {method!r}", fix="use 'cvt' or 'pymeshlab'")
    if dense is None:
        minang = np.degrees(igl.internal_angles(V, F).min())
        dense = minang < settings.dense_min_angle_deg or len(F) < settings.dense_min_faces
    if time is not None:
        time = np.asarray(time, float)
        if time.shape != (len(V),):
            raise InputError(f"time has shape {time.shape}, expected ({len(V)},): one value "
                             "per target vertex", fix="give the time landscape per vertex of V")
    if time is not None and np.ptp(time) <= TOL.time:
        time = None  # a constant landscape: programming picks the constant itself
    if dense:
        V2, F2 = resample_dense(V, F, settings.dense_faces)
        if time is not None:
            time = interpolate_to_stencil(time, V, F, V2)
        V, F = V2, F2
        info["dense_resampled_faces"] = int(len(F))
    graded = method == "cvt" and user_times and time is not None and settings.timing_grading > 0
    if method == "cvt":
        dom = FlatDomain(V, F, settings, time=time if graded else None)

        def make(n, sd, inset):
            P, F2 = dom.stencil(n, seed=sd, inset=inset)
            before = (dom.lift(P), F2)
            if optimize:
                t_P = None if time is None else dom.interpolate(time, P)
                P, _ = optimize_stencil(dom, P, F2, params, settings, t_vertex=t_P)
                flat[(n, sd, float(inset))] = (P, t_P)
            return dom.lift(P), F2, before

        def polish(key, F2):
            # the chosen stencil again, its 3D scaling held at 1: the longest flat cell per
            # unit of scaling, with the shell at its target's size
            P, t_P = flat[key]
            P, _ = optimize_stencil(dom, P, F2, params, settings, t_vertex=t_P, pin=True)
            return dom.lift(P)
        # insets in mm: a fraction of the edge of the smallest regular cell the min-bumper rule
        # allows (fixed, so that the 3D scaling stays monotone in the vertex count)
        edge = np.sqrt(3) * 2 * (params.base_r + params.min_bumper)
        insets = tuple(round(float(f) * edge, 4) for f in settings.rim_insets)
    else:
        def make(n, sd, inset):
            L = np.sqrt(2 * A / (np.sqrt(3) * n))
            V2, F2 = remove_ears(*isotropic_remesh(V, F, L))
            return V2, F2, (V2, F2)
        insets = (0.0,)
    def figures(V2, F2):
        t2 = None if time is None else interpolate_to_stencil(time, V, F, V2)
        return stencil_figures(V2, F2, params, time=t2, settings=settings)

    tried: dict = {}
    meshes: dict = {}
    flat: dict = {}  # (N, seed, inset) -> optimised flat points, time at them

    def trial(n, sd, inset):
        n = max(int(n), 8)
        key = (n, int(sd), float(inset))
        if key not in tried:
            V2, F2, before = make(n, int(sd), inset)
            tried[key] = figures(V2, F2)
            meshes[key] = (V2, F2, before)
            if progress is not None:
                c = tried[key]
                what = (f"scale3d {c['scale3d']:.3f}, longest flat cell "
                        f"{c['max_cell_length_mm']:.2f} mm" if _laid_out(c)
                        else f"no layout ({c['error']})")
                if c.get("clamped_estimate") is not None:
                    what += f", ~{100 * c['clamped_estimate']:.0f} % of cells clamped"
                progress(f"N={n} seed={sd} rim inset {inset:g} mm: {what}")
        return n

    if not len(insets):
        raise InputError("settings.rim_insets is empty", fix="give at least one inset (0 = none)")
    seed_list = ([int(seed)] if seed is not None
                 else [0] if method == "pymeshlab"  # (it has no seed)
                 else list(range(settings.seeds)))
    limit = params.max_cell_length
    sd0 = seed_list[0]
    start = [int(target_bases / 2) if target_bases
             else round(settings.count_start * estimate_vertices(A))]

    def search_counts(inset):
        if vertices is not None:
            for sd in seed_list:
                trial(int(vertices), sd, inset)
            return
        pts = []  # (log N, log scale3d) of this inset's secant
        n = trial(start[0], sd0, inset)
        for _ in range(settings.count_steps):
            s3 = tried[(n, sd0, float(inset))]["scale3d"]
            if s3 is None or abs(np.log(s3)) < settings.count_tolerance:
                break
            pts.append((np.log(n), np.log(s3)))
            # scale3d ~ N^k: k = 1/2 for a uniform mesh, else the slope of the last two
            k = 0.5
            if len(pts) >= 2 and abs(pts[-1][0] - pts[-2][0]) > settings.count_secant_min:
                k = float(np.clip((pts[-1][1] - pts[-2][1]) / (pts[-1][0] - pts[-2][0]),
                                  0.25, 1.0))
            n = trial(round(n * s3 ** (-1.0 / k)), sd0, inset)
        start[0] = n
        for f in settings.candidates:
            trial(round(n * f), sd0, inset)
        here = {k: c for k, c in tried.items() if k[2] == float(inset)}
        best = _pick(here, params, settings.margin)
        if best is None or here[best]["max_cell_length_mm"] > limit - settings.margin:
            for sd in seed_list[1:]:  # another seed only when the first leaves no margin
                trial(best[0] if best else n, sd, inset)

    for inset in insets:
        try:
            search_counts(inset)
        except RimInsetError:
            continue
        if any(_laid_out(c) and c["max_cell_length_mm"] <= limit - settings.margin
               for c in tried.values()):
            break
    best = _pick(tried, params, settings.margin)
    rim = None
    if best is not None and best[2] > 0:
        best, rim = _rim_fallback(
            best, tried, meshes, A, params, settings,
            lambda: None if any(k[2] == 0.0 for k in tried) else search_counts(0.0))
        if progress is not None:
            progress(f"rim: {rim['why']}")
    if best is None:
        why = "; ".join(sorted({c["error"] for c in tried.values() if "error" in c}))
        why = why or "every rim inset splits the target"
        raise InputError(f"no stencil of this target could be laid out ({why})",
                         fix="check the target (it may fold sharply or be too small for 4 mm "
                             "bases), or give --vertices")
    V2, F2, before = meshes[best]
    chosen = tried[best]
    if best in flat and settings.opt_pin_weight > 0:
        Vp = polish(best, F2)
        fig = figures(Vp, F2)
        L0 = chosen["max_cell_length_mm"]
        # kept when it is nearer the target's size and no longer (or still printable, with
        # no longer cell per unit of scaling)
        if _laid_out(fig) and abs(np.log(fig["scale3d"])) <= abs(np.log(chosen["scale3d"])) \
                and (fig["max_cell_length_mm"] <= max(L0, limit - settings.margin)
                     or (fig["max_cell_length_mm"] <= limit and fig["max_cell_length_mm"]
                         / fig["scale3d"] <= L0 / chosen["scale3d"])):
            V2, chosen = Vp, fig
        info["polish"] = {"scale3d": fig["scale3d"], "max_cell_length_mm":
                          fig["max_cell_length_mm"], "kept": chosen is fig}
        if progress is not None:
            progress(f"N={best[0]} seed={best[1]} held at scale 1: "
                     + (f"scale3d {fig['scale3d']:.3f}, longest flat cell "
                        f"{fig['max_cell_length_mm']:.2f} mm" if _laid_out(fig)
                        else "no layout") + (" (kept)" if chosen is fig else " (dropped)"))
    if user_times and time is not None and vertices is None and _laid_out(chosen):
        best, V2, F2, chosen = _trade(best, V2, F2, chosen, trial, tried, meshes, params,
                                      settings, info, progress, seeds=seed_list)
    if graded and not (chosen["max_cell_length_mm"] <= limit
                       and chosen["scale3d"] >= settings.trade_min_scale3d):
        # the graded spacing asked for cells the limit does not allow: the search again,
        # spaced by the target alone
        if progress is not None:
            progress(f"time-graded stencil: longest flat cell {chosen['max_cell_length_mm']:.2f}"
                     f" mm, scale3d {chosen['scale3d']:.3f}: searching again without")
        V2, F2, again = remesh_surface(**call, settings=replace(settings, timing_grading=0.0))
        again["timing_grading"] = {"grading": settings.timing_grading, "taken": False,
                                   "max_cell_length_mm": chosen["max_cell_length_mm"],
                                   "scale3d": chosen["scale3d"]}
        return V2, F2, again
    info["timing_grading"] = {"grading": settings.timing_grading if graded else 0.0,
                              "taken": bool(graded)}
    if rim is None:
        rim = {"inset_mm": float(best[2]), "area_covered": _covered(V2, F2, A),
               "fallback": None, "why": ("the stencil reaches the target's rim" if best[2] <= 0
                                         else "the inset stencil covers enough of the target")}
    else:
        rim["area_covered"] = _covered(V2, F2, A)  # of the final stencil (polished, traded)
    info.update(vertices=int(len(V2)), requested=int(best[0]), seed=int(best[1]),
                rim_inset_mm=float(best[2]), rim=rim, scale3d=chosen["scale3d"],
                max_cell_length_mm=chosen["max_cell_length_mm"],
                before_optimisation=stencil_figures(*before, params) if optimize else None,
                after_optimisation=chosen,
                candidates=[[k[0], k[1], k[2], v["scale3d"], v["max_cell_length_mm"]]
                            for k, v in sorted(tried.items())])
    return V2, F2, info


__all__ = ["surface_area", "time_spacing_log", "estimate_vertices", "remove_ears",
           "remove_flaps",
           "isotropic_remesh", "resample_dense", "triangulate_flat", "FlatDomain", "edge_for_count",
           "stencil_figures", "remesh_surface"]
