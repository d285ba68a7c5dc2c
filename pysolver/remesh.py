"""Isotropic remeshing of the target surface into the stencil (N vertices).

Default method ``"cvt"`` (as the reference, restated): flatten the dense target
conformally (CETM), place N points in the flat domain by a weighted Lloyd iteration
(centroidal Voronoi tessellation) whose density ``exp(-2u)`` makes the spacing uniform
*in 3D*, triangulate them (constrained Delaunay, Shewchuk's Triangle) and lift every
point to 3D with the barycentric coordinates of its dense flat triangle.  Because the
map is conformal, near-equilateral flat triangles stay near-equilateral in 3D.
Boundary points are spaced uniformly in 3D arc length and kept fixed.

Method ``"pymeshlab"``: pymeshlab's isotropic explicit remeshing in 3D (kept for
comparison; at the coarse stencil resolution its triangles are much less regular).

Vertex count: ``vertices=N`` or searched.  The paper's estimate ``N ~ 0.38 A / 7^2``
is recorded; the search starts from the count of a regular mesh whose centroid spacing
meets the min-bumper rule, then tries a few candidates and keeps the one whose 3D
scaling factor (:func:`pysolver.layout.scale_3d`) is closest to 1, so the shell keeps
the input's size.  Finally "ear" triangles (two boundary edges) are removed.
"""

from __future__ import annotations

import igl
import numpy as np
import triangle as tr
from scipy.spatial import cKDTree

from .errors import InputError
from .params import UNIT_CELL, UnitCell

PAPER_CELL_LENGTH = 7.0  # mm, l_avg of the vertex-count estimate (Supplementary Note 1)
LLOYD_ITERATIONS = 40
BOUNDARY_DENSITY = 1.0  # boundary points per (regular-mesh edge length) of perimeter
DENSE_FACES = 6000  # user meshes are resampled to about this many faces before flattening


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
    from .layout import face_adjacency

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


# --------------------------------------------------------------------------------------
# pymeshlab (3D) remeshing


def isotropic_remesh(V, F, edge_length: float, iterations: int = 12):
    """pymeshlab isotropic explicit remeshing to a target edge length (mm).

    Used to resample user meshes finely (decent triangles for CETM) and as the
    ``"pymeshlab"`` stencil method.  Orientation of the input is kept.
    """
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.asarray(V, float),
                               face_matrix=np.asarray(F, dtype=np.int32)))
    ms.meshing_isotropic_explicit_remeshing(
        iterations=iterations, targetlen=pymeshlab.PureValue(float(edge_length)),
        featuredeg=60.0, checksurfdist=True,
        maxsurfdist=pymeshlab.PureValue(0.05 * edge_length), reprojectflag=True)
    m = ms.current_mesh()
    V2 = np.asarray(m.vertex_matrix(), float)
    F2 = np.asarray(m.face_matrix(), dtype=np.int64)
    return _keep_orientation(V2, F2, V, F)


def _keep_orientation(V2, F2, V, F):
    from .layout import face_normals

    _, fi, _ = igl.point_mesh_squared_distance(V2[F2].mean(1), np.asarray(V, float),
                                               np.asarray(F, dtype=np.int64))
    n_src = face_normals(V, F)[fi]
    if np.sum(np.sum(face_normals(V2, F2) * n_src, axis=1)) < 0:
        F2 = F2[:, ::-1].copy()
    return V2, F2


def resample_dense(V, F, faces: int = DENSE_FACES):
    """Resample a user mesh to about ``faces`` well-shaped triangles (pymeshlab)."""
    A = surface_area(V, F)
    L = float(np.sqrt(4 * A / (np.sqrt(3) * faces)))
    V2, F2 = isotropic_remesh(V, F, L, iterations=8)
    return remove_ears(V2, F2)


# --------------------------------------------------------------------------------------
# CVT remeshing in the conformal flat domain


def required_spacing(V, F, params: UnitCell = UNIT_CELL, smooth: int = 3) -> np.ndarray:
    """Relative cell spacing the min-bumper rule needs at each vertex (1 where flat).

    A cell of centroid distance D on a surface of normal curvature k folds by about
    ``theta ~ sqrt(3) D k / 2`` per half, and the rule ``D / (2 cos theta) >= base_r +
    min_bumper + layer_h tan(theta)`` gives ``D >= D0 / (1 - sqrt(3) layer_h k)`` with
    ``D0 = 2 (base_r + min_bumper)``.  Returns ``1 / (1 - sqrt(3) layer_h k_max)``
    (k_max = largest |principal curvature|, smoothed, capped), so curved regions get
    proportionally larger cells and flat regions the smallest the rule allows.
    """
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    try:
        _, _, k1, k2, _ = igl.principal_curvature(V, F, radius=5)
        k = np.maximum(np.abs(k1), np.abs(k2))
        k = np.where(np.isfinite(k), k, 0.0)
    except Exception:  # noqa: BLE001 - curvature is only a density hint
        k = np.zeros(len(V))
    A = igl.adjacency_matrix(F).astype(float)
    deg = np.asarray(A.sum(axis=1)).ravel()
    for _ in range(smooth):
        k = 0.5 * k + 0.5 * (A @ k) / np.maximum(deg, 1)
    x = np.clip(np.sqrt(3) * params.layer_h * k, 0.0, 0.6)
    return 1.0 / (1.0 - x)


class FlatDomain:
    """Dense target mesh with its conformal flattening, for CVT remeshing.

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    """

    def __init__(self, V, F, params: UnitCell = UNIT_CELL, adaptive: bool = False):
        from .flatten import cetm

        self.V = np.asarray(V, float)
        self.F = np.asarray(F, dtype=np.int64)
        UV, u, _ = cetm(self.V, self.F)
        self.UV = UV
        self.u = u
        self.area3 = 0.5 * igl.doublearea(self.V, self.F)
        # target spacing factor per dense vertex: 1 on flat parts, larger where curved
        self.spacing = (required_spacing(self.V, self.F, params) if adaptive
                        else np.ones(len(self.V)))
        self.wface = self.area3 / self.spacing[self.F].mean(axis=1) ** 2
        self.area = float(self.wface.sum())  # "effective" area in units of flat spacing
        self.UV3 = np.c_[UV, np.zeros(len(UV))]
        # quadrature: 4 points per dense face (midpoint subdivision centroids), weight = 3D area/4
        P = UV[self.F]
        m = (P + np.roll(P, -1, axis=1)) / 2  # edge midpoints
        q = [(P[:, k] + m[:, k] + m[:, (k + 2) % 3]) / 3 for k in range(3)]
        q.append(m.mean(axis=1))
        self.quad = np.concatenate(q)
        self.quad_w = np.tile(self.wface / 4, 4)
        loop = igl.boundary_loop(self.F)
        self.loop = loop
        seg3 = np.linalg.norm(self.V[np.roll(loop, -1)] - self.V[loop], axis=1)
        seg3 = seg3 / (0.5 * (self.spacing[loop] + self.spacing[np.roll(loop, -1)]))
        self.loop_s = np.r_[0, np.cumsum(seg3)]
        self.perimeter = float(self.loop_s[-1])
        self.boundary_density = BOUNDARY_DENSITY

    def boundary_points(self, k: int) -> np.ndarray:
        """``k`` flat boundary points equally spaced in 3D arc length (over the spacing)."""
        s = np.linspace(0, self.perimeter, k, endpoint=False)
        loopc = np.r_[self.loop, self.loop[:1]]
        P = self.UV[loopc]
        return np.c_[np.interp(s, self.loop_s, P[:, 0]), np.interp(s, self.loop_s, P[:, 1])]

    def lift(self, P2) -> np.ndarray:
        """3D points for flat points (barycentric in the dense flat triangle)."""
        P2 = np.asarray(P2, float)
        _, fi, C = igl.point_mesh_squared_distance(np.c_[P2, np.zeros(len(P2))], self.UV3,
                                                   self.F)
        T = self.UV[self.F[fi]]
        e1, e2, w = T[:, 1] - T[:, 0], T[:, 2] - T[:, 0], C[:, :2] - T[:, 0]
        det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        b1 = (w[:, 0] * e2[:, 1] - w[:, 1] * e2[:, 0]) / det
        b2 = (e1[:, 0] * w[:, 1] - e1[:, 1] * w[:, 0]) / det
        b0 = 1 - b1 - b2
        X = self.V[self.F[fi]]
        return b0[:, None] * X[:, 0] + b1[:, None] * X[:, 1] + b2[:, None] * X[:, 2]

    def remesh(self, n: int, iterations: int = LLOYD_ITERATIONS, seed: int = 0):
        """Stencil with about ``n`` vertices (before ear removal).

        Returns
        -------
        V : (k, 3) float, mm
        F : (f, 3) int
        """
        h = edge_for_count(self.area, self.perimeter, n)
        nb = max(int(round(self.boundary_density * self.perimeter / h)), 6)
        ni = max(n - nb, 1)
        B = self.boundary_points(nb)
        rng = np.random.default_rng(seed)
        pick = rng.choice(len(self.F), size=ni, p=self.wface / self.wface.sum())
        r1, r2 = rng.random(ni), rng.random(ni)
        flip = r1 + r2 > 1
        r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
        T = self.UV[self.F[pick]]
        X = T[:, 0] + r1[:, None] * (T[:, 1] - T[:, 0]) + r2[:, None] * (T[:, 2] - T[:, 0])
        w = self.quad_w
        for _ in range(iterations):
            sites = np.vstack([B, X])
            _, owner = cKDTree(sites).query(self.quad)
            owner = owner - nb
            ok = owner >= 0
            W = np.bincount(owner[ok], weights=w[ok], minlength=ni)
            Sx = np.bincount(owner[ok], weights=w[ok] * self.quad[ok, 0], minlength=ni)
            Sy = np.bincount(owner[ok], weights=w[ok] * self.quad[ok, 1], minlength=ni)
            has = W > 0
            X[has] = np.c_[Sx[has] / W[has], Sy[has] / W[has]]
        P2 = np.vstack([B, X])
        seg = np.c_[np.arange(nb), (np.arange(nb) + 1) % nb]
        t = tr.triangulate({"vertices": P2, "segments": seg}, "pYQ")
        if len(t["vertices"]) != len(P2):
            raise InputError("remeshing: the flat domain boundary self-intersects",
                             fix="check the input surface (it folds onto itself when flattened)")
        F2 = t["triangles"].astype(np.int64)
        A = 0.5 * ((P2[F2[:, 1], 0] - P2[F2[:, 0], 0]) * (P2[F2[:, 2], 1] - P2[F2[:, 0], 1])
                   - (P2[F2[:, 1], 1] - P2[F2[:, 0], 1]) * (P2[F2[:, 2], 0] - P2[F2[:, 0], 0]))
        F2[A < 0] = F2[A < 0][:, ::-1]
        V3 = self.lift(P2)
        return remove_ears(V3, F2)


def _max_cell_length(V, F, params):
    """Max flat cell length of the CETM layout (scaling rules incl. the actual flat gaps)."""
    from .flatten import cetm
    from .layout import build_layout

    try:
        UV, _, _ = cetm(V, F)
        return float(build_layout(V, UV, F, params).central_length.max())
    except InputError:
        return np.inf


def edge_for_count(area: float, perimeter: float, n: int) -> float:
    """Edge length h of a regular triangle mesh with ``n`` vertices on a disk of the given
    area and perimeter: ``n = 2 A / (sqrt(3) h^2) + P / (2 h)`` (Euler's formula)."""
    a, b = 2 * area / np.sqrt(3), perimeter / 2
    x = (-b + np.sqrt(b * b + 4 * a * n)) / (2 * a)  # x = 1/h
    return float(1.0 / x)


def _scale3d_of(V, F, params):
    from .layout import scale_3d, unit_cells

    return scale_3d(V, F, unit_cells(F), params)[0]


def _regular_count(area, params: UnitCell, perimeter=0.0):
    """Vertices of a regular mesh whose centroid spacing just meets the flat min-bumper rule."""
    D = 2 * (params.base_r + params.min_bumper)  # centroid distance
    h = D * np.sqrt(3)  # edge
    return int(round(2 * area / (np.sqrt(3) * h**2) + perimeter / (2 * h)))


def _pick(tried: dict, params: UnitCell, margin: float = 0.5):
    """Best candidate: scale3d closest to 1 among those whose quick layout keeps every cell
    ``margin`` below the length limit; else below the limit; else the shortest max length."""
    for lim in (params.max_cell_length - margin, params.max_cell_length):
        ok = [k for k in tried if tried[k][1] <= lim]
        if ok:
            return min(ok, key=lambda k: (round(abs(np.log(tried[k][0])), 3), tried[k][1], k))
    return min(tried, key=lambda k: (tried[k][1], k))


def remesh_surface(V, F, *, vertices=None, seed=None, target_bases=None,
                   params: UnitCell = UNIT_CELL, candidates: int = 3, seeds: int = 4,
                   method: str = "cvt", dense: bool | None = None):
    """Remesh a target surface into a stencil.

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    vertices : int, optional
        Vertex count override; otherwise searched (see module docstring).
    seed : int, optional
        Seed of the CVT initialisation; otherwise ``seeds`` seeds are tried per count
        (the irregularity of a CVT triangulation, hence the longest cell, varies a lot
        from one seed to the next).
    target_bases : int, optional
        Start of the search (about 2 N).
    params : UnitCell
    candidates : int
        Counts tried around the predicted best (+-5 % steps).
    seeds : int
        Seeds tried per count when ``seed`` is not given.
    method : {"cvt", "pymeshlab"}
    dense : bool, optional
        Resample the input finely with pymeshlab first (default: when the input's
        triangles are poor, min angle < 15 deg, or it has fewer than 2000 faces).

    Returns
    -------
    V2 : (k, 3) float, mm
    F2 : (f, 3) int
    info : dict
        ``vertices``, ``seed``, ``estimate_paper``, ``scale3d``, ``max_cell_length_mm``
        (quick layout) and ``candidates`` [[N, seed, scale3d, max cell length], ...].
        Candidates whose quick layout has cells longer than the limit are only used when
        none passes (then the shortest max length wins).
    """
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    A = surface_area(V, F)
    info = {"remeshed": True, "method": method, "area_mm2": round(A, 2),
            "estimate_paper": estimate_vertices(A)}
    if method not in ("cvt", "pymeshlab"):
        raise InputError(f"remesh method {method!r}", fix="use 'cvt' or 'pymeshlab'")
    if dense is None:
        minang = np.degrees(igl.internal_angles(V, F).min())
        dense = minang < 15.0 or len(F) < 2000
    if dense:
        V, F = resample_dense(V, F)
        info["dense_resampled_faces"] = int(len(F))
    if method == "cvt":
        dom = FlatDomain(V, F, params)
        make = dom.remesh
        perim = dom.perimeter
    else:
        def make(n, seed=0):
            L = np.sqrt(2 * A / (np.sqrt(3) * n))
            return remove_ears(*isotropic_remesh(V, F, L))
        loop = igl.boundary_loop(F)
        perim = float(np.linalg.norm(V[np.roll(loop, -1)] - V[loop], axis=1).sum())
        seeds = 1
    tried: dict = {}

    def trial(n, sd):
        n = max(int(n), 8)
        key = (n, int(sd))
        if key not in tried:
            V2, F2 = make(n, seed=int(sd))
            tried[key] = (_scale3d_of(V2, F2, params), _max_cell_length(V2, F2, params), V2, F2)
        return n

    seed_list = [int(seed)] if seed is not None else list(range(seeds))
    if vertices is not None:
        for sd in seed_list:
            trial(int(vertices), sd)
    else:
        n0 = int(target_bases / 2) if target_bases else _regular_count(A, params, perim)
        n = max(n0, 8)
        sd0 = seed_list[0]
        trial(n, sd0)
        for _ in range(4):  # secant steps on scale3d ~ sqrt(N)
            s3 = tried[(n, sd0)][0]
            if abs(np.log(s3)) < 0.03:
                break
            n = trial(round(n / s3**2), sd0)
        half = (candidates - 1) / 2
        for f in 1 + 0.05 * (np.arange(candidates) - half):
            for sd in seed_list:
                trial(round(n * f), sd)
    best = _pick(tried, params)
    s3, lmax, V2, F2 = tried[best]
    info.update(vertices=int(len(V2)), requested=int(best[0]), seed=int(best[1]),
                scale3d=round(float(s3), 5), max_cell_length_mm=round(float(lmax), 3),
                candidates=[[int(k[0]), int(k[1]), round(float(v[0]), 4), round(float(v[1]), 3)]
                            for k, v in sorted(tried.items())])
    return V2, F2, info


__all__ = ["surface_area", "estimate_vertices", "remove_ears", "isotropic_remesh",
           "resample_dense", "FlatDomain", "remesh_surface"]
