"""Built-in procedural target shapes (generated in code) and their default time landscapes.

Names: ``regular``, ``mechtest`` (SI Note 6's test specimen), ``petal``, ``saddle``, ``dome``,
``weave``, ``spiral``; an option may follow a colon: ``"weave:large"`` (551 bases, the
benchmark size), or ``"dome:size=1.5"`` (linear size factor, more bases).  See :func:`builtin`.

A :class:`Surface` is either a dense target surface (then the pipeline remeshes and
flattens it) or a ready stencil (``UV`` given, e.g. ``regular``).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import triangle as tr

from ..errors import InputError
from ..params import UNIT_CELL
from ..params import tol as TOL
from .time_landscape import interpolate_to_stencil


@dataclass
class Surface:
    """A target surface.

    Attributes
    ----------
    name : str
    V : (n, 3) float, mm
    F : (m, 3) int
    UV : (n, 2) float or None
        Flat layout when the surface is already a stencil (no remesh / flattening).
    time : callable((k, 3) float, mm) -> (k,) float, s, or None
        Default time landscape as a function of points on the target in its own frame (the
        coordinates of ``V``, mm); the design maps the stencil's frame back to it
        (:class:`~pysolver.design.time_landscape.DesignLandscape`).
    central_length : float, mm, or None
        Flat central length override (test patches).
    target_bases : int or None
        Suggested number of bases (remeshing search start).
    description : str
    options : dict
    """

    name: str
    V: np.ndarray
    F: np.ndarray
    UV: np.ndarray | None = None
    time: Callable | None = None
    central_length: float | None = None
    target_bases: int | None = None
    description: str = ""
    options: dict = field(default_factory=dict)


# --------------------------------------------------------------------------------------
# helpers


def regular_grid(nx: int, ny: int, edge: float = 1.0):
    """Rectangular patch of equilateral triangles.

    Parameters
    ----------
    nx, ny : int
        Vertices per row and number of rows.
    edge : float
        Triangle edge length.

    Returns
    -------
    UV : (nx * ny, 2) float
    F : (2 (nx - 1) (ny - 1), 3) int, CCW
    """
    j, i = np.mgrid[0:ny, 0:nx]
    x = edge * (i + 0.5 * (j % 2))
    y = edge * np.sqrt(3) / 2 * j
    UV = np.c_[x.ravel(), y.ravel()]
    vid = lambda ii, jj: jj * nx + ii  # noqa: E731
    F = []
    for jj in range(ny - 1):
        for ii in range(nx - 1):
            a, b = vid(ii, jj), vid(ii + 1, jj)
            c, d = vid(ii, jj + 1), vid(ii + 1, jj + 1)
            if jj % 2 == 0:
                F += [[a, b, c], [b, d, c]]
            else:
                F += [[a, d, c], [a, b, d]]
    F = np.array(F, dtype=np.int64)
    P = UV[F]
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    cw = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    F[cw] = F[cw][:, [0, 2, 1]]
    return UV, F


def _disk_mesh(boundary_xy: np.ndarray, max_area: float) -> tuple[np.ndarray, np.ndarray]:
    """Quality triangulation of a simple polygon (Shewchuk's Triangle, ``pq30a``)."""
    n = len(boundary_xy)
    seg = np.c_[np.arange(n), (np.arange(n) + 1) % n]
    t = tr.triangulate({"vertices": boundary_xy, "segments": seg}, f"pq30a{max_area:.6f}Q")
    P, F = t["vertices"], t["triangles"].astype(np.int64)
    # CCW in xy
    e1, e2 = P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]]
    cw = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    F[cw] = F[cw][:, ::-1]
    return P, F


def _resample_closed(P: np.ndarray, spacing: float) -> np.ndarray:
    """Resample a closed polyline at roughly uniform arc length."""
    Q = np.vstack([P, P[:1]])
    s = np.r_[0, np.cumsum(np.linalg.norm(np.diff(Q, axis=0), axis=1))]
    k = max(int(np.ceil(s[-1] / spacing)), 8)
    t = np.linspace(0, s[-1], k, endpoint=False)
    return np.c_[np.interp(t, s, Q[:, 0]), np.interp(t, s, Q[:, 1])]


def _parse_options(spec: str) -> tuple[str, dict]:
    name, _, rest = spec.partition(":")
    opts: dict = {}
    for tok in filter(None, rest.split(",")):
        if "=" in tok:
            k, v = tok.split("=", 1)
            try:
                # integers stay integers: counts such as regular:rows=2 or petal:petals=6
                vals = [int(x) if x.strip().lstrip("+-").isdigit() else float(x)
                        for x in v.strip("()[] ").split(";")]
            except ValueError:
                raise InputError(f"shape option {tok!r}: value must be a number "
                                 "(or numbers separated by ';')") from None
            opts[k.strip()] = vals[0] if len(vals) == 1 else tuple(vals)
        else:
            opts[tok.strip()] = True
    return name.strip(), opts


def _time_on_dense(V, F, t_dense):
    """Time function of points near the surface: interpolate per-vertex times of the dense
    source mesh (closest point, barycentric) -- robust where arms overlap in space."""

    def time(X):

        return interpolate_to_stencil(t_dense, V, F, np.asarray(X, float))

    return time


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


# --------------------------------------------------------------------------------------
# regular test patch


def regular(rows: int = 6, cols: int = 5, central_length: float = 7.0) -> Surface:
    """Flat patch of identical unit cells (Supplementary Note 6 mechanical test patch).

    Equilateral triangles in ``rows`` strips of ``2 cols`` triangles (first edge
    horizontal).  Target = the flat patch, scaled later by the 3D min-bumper rule (so
    the bumpers just touch); flat layout = the same mesh scaled so every central length
    is ``central_length`` (7 mm): 60 bases, about 59 x 60 mm, 0.5 mm brackets.
    """
    a = central_length * np.sqrt(3)  # edge of the flat layout (mm); the target is rescaled
    h = a * np.sqrt(3) / 2
    P = []
    for r in range(rows + 1):
        off = (r % 2) * a / 2
        P += [(i * a + off, r * h) for i in range(cols + 1)]
    P = np.array(P)
    idx = lambda r, i: r * (cols + 1) + i
    F = []
    for r in range(rows):
        for i in range(cols):
            p0, p1, q0, q1 = idx(r, i), idx(r, i + 1), idx(r + 1, i), idx(r + 1, i + 1)
            if r % 2 == 0:
                F += [(p0, p1, q0), (p1, q1, q0)]
            else:
                F += [(p0, q1, q0), (p0, p1, q1)]
    F = np.array(F, dtype=np.int64)
    used = np.unique(F)
    remap = -np.ones(len(P), dtype=np.int64)
    remap[used] = np.arange(len(used))
    P, F = P[used], remap[F]
    V = np.c_[P, np.zeros(len(P))]
    return Surface("regular", V, F, UV=P.copy(), time=lambda X: np.full(len(X), 60.0),
                   central_length=central_length,
                   description="flat test patch of identical 7 mm unit cells, 0.3 mm bumpers",
                   options=dict(rows=rows, cols=cols))


def mechtest(width: float = 60.0, length: float = 55.0, angle: float = 0.0,
             central_length: float = 7.0) -> Surface:
    """SI Note 6's mechanical-test specimen: a flat rectangle of identical unit cells.

    The tester loads the specimen along its ``length`` (the flat y axis); ``angle`` turns
    the hexagonal pattern in the plane.  At ``angle = 0`` (the default, as the SI: "one of
    the three axes parallel to the edges of the hexagonal pattern") one of the three
    unit-cell directions is the y axis (the stencil's triangles have an edge along x); at
    ``angle = 30`` the load runs across the cells, along the triangles' edges.  The flat
    layout is the triangle lattice of ``central_length`` (7 mm) cells, scaled so that the
    *morphed* shell (every cell closed at its 0.3 mm bumpers, central length ``2 base_r +
    2 min_bumper``) is about ``width`` x ``length`` mm; a base is kept when its morphed
    disc lies inside that rectangle.  Build it with uniform 0.5 mm brackets
    (``--no-program``, SI Note 6).

    Parameters
    ----------
    width, length : float, mm
        Morphed size across and along the load (SI Note 6: 60 x 55 mm).
    angle : float, deg
        Turn of the hexagonal pattern from the SI's orientation.
    central_length : float, mm
        Flat central length of every unit cell.
    """
    if not (width > 0 and length > 0 and central_length > 0):
        raise InputError(f"mechtest: width, length and central_length must be positive "
                         f"(got {width}, {length}, {central_length})",
                         fix="e.g. 'mechtest:width=60,length=55'")
    U = UNIT_CELL
    shrink = (2 * U.base_r + 2 * U.min_bumper) / central_length  # morphed / flat lengths
    a = central_length * np.sqrt(3)  # flat triangle edge: centroids of neighbours are l apart
    W, L = width / shrink, length / shrink  # flat rectangle, mm
    n = int(np.ceil(1.5 * max(W, L) / a)) + 2
    j, i = np.mgrid[-n:n + 1, -n:n + 1]
    P = np.c_[(a * (i + 0.5 * j)).ravel(), (a * np.sqrt(3) / 2 * j).ravel()]
    th = np.deg2rad(angle)
    P = P @ np.array([[np.cos(th), np.sin(th)], [-np.sin(th), np.cos(th)]])
    k = 2 * n + 1
    vid = lambda ii, jj: jj * k + ii  # noqa: E731
    tri = []
    for jj in range(k - 1):
        for ii in range(k - 1):
            tri += [(vid(ii, jj), vid(ii + 1, jj), vid(ii, jj + 1)),
                    (vid(ii + 1, jj), vid(ii + 1, jj + 1), vid(ii, jj + 1))]
    F = np.array(tri, dtype=np.int64)
    C = P[F].mean(axis=1)
    r = U.base_r / shrink  # the morphed disc's radius, in flat lengths
    keep = (np.abs(C[:, 0]) <= W / 2 - r) & (np.abs(C[:, 1]) <= L / 2 - r)
    F = F[keep]
    used = np.unique(F)
    remap = -np.ones(len(P), dtype=np.int64)
    remap[used] = np.arange(len(used))
    P, F = P[used] - P[used].mean(axis=0), remap[F]
    V = np.c_[P, np.zeros(len(P))]
    return Surface("mechtest", V, F, UV=P.copy(), time=lambda X: np.full(len(X), 60.0),
                   central_length=central_length,
                   description=f"SI Note 6 test specimen: {width:g} x {length:g} mm of "
                               f"{central_length:g} mm cells, pattern turned {angle:g} deg",
                   options=dict(width=width, length=length, angle=angle))


__all__ = ["regular_grid", "Surface", "regular", "mechtest", "petal", "saddle", "dome", "weave",
           "spiral", "BUILTIN",
           "BUILTIN_SHAPES", "builtin", "check_spec", "is_builtin"]


# --------------------------------------------------------------------------------------
# dense procedural surfaces (remeshed and flattened by the pipeline)

DENSE_EDGE = 2.5  # mm, edge length of the dense source triangulations

def _dense(boundary_xy, edge=DENSE_EDGE):
    B = _resample_closed(np.asarray(boundary_xy, float), edge)
    return _disk_mesh(B, max_area=np.sqrt(3) / 4 * edge**2)


def dome(size: float = 1.0, radius: float = 50.0, cap_deg: float = 50.0) -> Surface:
    """Spherical cap (sphere radius 50 mm, polar angle 50 deg): about 110 bases.

    Default time landscape: the centre finishes first (40 s), the rim last (70 s).
    """
    R = radius * size
    beta = np.radians(cap_deg)
    rho = R * beta  # geodesic radius; azimuthal-equidistant parametrisation
    phi = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    P, F = _dense(np.c_[rho * np.cos(phi), rho * np.sin(phi)])
    g = np.hypot(P[:, 0], P[:, 1]) / R  # polar angle
    az = np.arctan2(P[:, 1], P[:, 0])
    V = np.c_[R * np.sin(g) * np.cos(az), R * np.sin(g) * np.sin(az), R * (np.cos(g) - 1)]
    # normals up (+z): the top layer is on the concave (inner) side

    def time(X):
        return 40.0 + 30.0 * np.clip(np.hypot(X[:, 0], X[:, 1]) / (R * np.sin(beta)), 0, 1)

    return Surface("dome", V, F, time=time, description=f"spherical cap R={R:g} mm, "
                   f"{cap_deg:g} deg", options=dict(size=size))


def saddle(size: float = 1.0, radius: float = 42.0, curvature_radius: float = 65.0) -> Surface:
    """Hyperbolic paraboloid z = (x^2 - y^2) / (2 rho) over a disc of radius 42 mm.

    Default time landscape: 40 s at the centre to 65 s at the rim.
    """
    Rd = radius * size
    rho = curvature_radius * size
    phi = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    P, F = _dense(np.c_[Rd * np.cos(phi), Rd * np.sin(phi)])
    V = np.c_[P, (P[:, 0] ** 2 - P[:, 1] ** 2) / (2 * rho)]

    def time(X):
        return 40.0 + 25.0 * np.clip(np.hypot(X[:, 0], X[:, 1]) / Rd, 0, 1)

    return Surface("saddle", V, F, time=time, description=f"saddle over a disc R={Rd:g} mm, "
                   f"rho={rho:g} mm", options=dict(size=size))


def petal(size: float = 1.0, petals: int = 6, r0: float = 34.0, small: float = 34.0,
          large: float = 50.0, bend_small: float = 50.0, bend_large: float = 85.0,
          notch: float = 1.2) -> Surface:
    """Flower: flat centre (radius 34 mm) and petals of two sizes (34 / 50 mm) that curl up.

    Petals alternate small / large (``petals`` must be even).  Each petal bends up along
    circular arcs; small petals close to 50 deg, large petals to 85 deg, so they stand
    almost upright around the small ones (191 bases).  Default time landscape: centre 35 s,
    small petals 45 s, large petals 75 s -- the small petals close first, then the large
    ones rise around them.  The petals are sectors of one disk and stay side by side: the
    sequence is the landscape's, they do not physically overlap as a real bud's do.
    """
    petals = int(petals)
    if petals % 2 or petals < 4:
        raise InputError(f"petal: petals={petals} must be even and >= 4")
    half = petals // 2
    r0, small, large = r0 * size, small * size, large * size
    wlarge = lambda phi: 0.5 + 0.5 * np.cos(half * phi)  # 1 on large petals, 0 on small
    plen = lambda phi: small + (large - small) * wlarge(phi)
    bend = lambda phi: np.radians(bend_small + (bend_large - bend_small) * wlarge(phi))
    phi = np.linspace(0, 2 * np.pi, 1200, endpoint=False)
    r = r0 + plen(phi) * np.abs(np.cos(petals * phi / 2)) ** notch
    P, F = _dense(np.c_[r * np.cos(phi), r * np.sin(phi)])
    rho = np.hypot(P[:, 0], P[:, 1])
    az = np.arctan2(P[:, 1], P[:, 0])
    s = np.maximum(rho - r0, 0.0)
    Rc = plen(az) / bend(az)  # arc radius: the petal tip reaches the bend angle
    rad = np.where(s > 0, r0 + Rc * np.sin(s / Rc), rho)
    z = np.where(s > 0, Rc * (1 - np.cos(s / Rc)), 0.0)
    V = np.c_[rad * np.cos(az), rad * np.sin(az), z]
    # faces CCW seen from +z in the flat domain: normal up = top layer on the inside

    tp = 45.0 + 30.0 * wlarge(az)  # small petals 45 s, large 75 s
    depth = _smoothstep((rho - 0.75 * r0) / (0.5 * r0))
    time = _time_on_dense(V, F, 35.0 + (tp - 35.0) * depth)

    return Surface("petal", V, F, time=time,
                   description=f"{petals}-petal flower, petals {small:g}/{large:g} mm",
                   options=dict(size=size, petals=petals))


def _polygon_union(polys) -> np.ndarray:
    """Outline of the union of simple polygons (manifold3d CrossSection)."""
    from manifold3d import CrossSection  # heavy: manifold3d loads only for STL booleans

    cs = None
    for P in polys:
        c = CrossSection([np.asarray(P, float)])
        cs = c if cs is None else cs + c
    loops = cs.to_polygons()
    if len(loops) != 1:
        raise RuntimeError("procedural outline is not a single simple polygon")
    return np.asarray(loops[0], float)


def _lattice_disk(outline: np.ndarray, edge: float, angle_deg: float = 90.0):
    """Equilateral triangle lattice clipped to a polygon.

    Every face whose centroid lies inside ``outline`` is kept; then faces with fewer than
    two edge neighbours (teeth of a boundary that does not follow a lattice line; a base
    held by one unit cell only would be free to spin) are pruned until none is left.  An
    outline whose edges follow lattice lines is reproduced exactly.

    Parameters
    ----------
    outline : (k, 2) float, mm
        Simple polygon.
    edge : float, mm
        Lattice edge length.
    angle_deg : float, deg
        Direction of one lattice edge (the others are at +-60 deg).

    Returns
    -------
    P : (n, 2) float, mm
    F : (m, 3) int, counter-clockwise
    """
    # optional heavy dependency: matplotlib loads only when a picture is drawn
    from matplotlib.path import Path as _Path

    th = np.radians(angle_deg)
    e1 = edge * np.array([np.cos(th), np.sin(th)])
    e2 = edge * np.array([np.cos(th + np.pi / 3), np.sin(th + np.pi / 3)])
    ij = outline @ np.linalg.inv(np.c_[e1, e2]).T
    lo = np.floor(ij.min(axis=0)).astype(int) - 1
    hi = np.ceil(ij.max(axis=0)).astype(int) + 1
    I, J = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
    P = I.reshape(-1, 1) * e1 + J.reshape(-1, 1) * e2
    idx = np.arange(I.size).reshape(I.shape)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()
    F = np.r_[np.c_[a, b, c], np.c_[b, d, c]]  # counter-clockwise (e1 x e2 > 0)
    F = F[_Path(outline).contains_points(P[F].mean(axis=1))]
    while len(F):
        E = np.sort(np.r_[F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]], axis=1)
        _, inv, cnt = np.unique(E, axis=0, return_inverse=True, return_counts=True)
        n_nb = (cnt[inv.ravel()] == 2).reshape(3, -1).sum(axis=0)
        if n_nb.min() >= 2:
            break
        F = F[n_nb >= 2]
    used = np.unique(F)
    remap = np.full(len(P), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return P[used], remap[F]


def weave(size: float = 1.0, large: bool = False, edge: float = 13.0, rows: int | None = None,
          hub: int | None = None, bend_start: float | None = None, overshoot: float = 10.0,
          radii=None) -> Surface:
    """Three arms that curl over the hub and stack there, closing in order.

    A pinwheel of three straight arms at 120 deg around a hexagonal hub, on an
    equilateral lattice (``edge`` 13 mm).  Arm k bends up by half a turn along a cylinder
    of radius R_k = 30 / 39 / 48 mm and runs back over the hub, ``overshoot`` past the
    centre, at height 2 R_k: the three returning parts stack above the hub, arm 0
    lowest, arm 2 on top.  The stack forms in the order 0, 1, 2: a curling arm comes down
    onto its place from above, through the place of every arm above it, which must still
    be open.  Default time landscape: hub 30 s, arm 0 45 s, arm 1 65 s, arm 2 85 s.

    Clearance rather than timing keeps the arms apart.  With the fitted bracket material
    the lattice's unit cells (all 5.9 mm, see below) can only be programmed to finish
    within about 46-56 s, so the arms' programmed closing times are a few seconds apart
    and all three curl largely together.  The radii therefore differ by 9 mm: the
    returning parts end 18 mm apart (12 mm after the 3D scale of the stencil, ~0.69),
    2.4 times the 5.1 mm thickness of the shell, and the simulation finds no collision
    in the programmed order or with all arms at once.  (At 4 mm steps, R = 30 / 34 /
    38 mm, the order shows: at once, 9 base pairs collide while the arms curl; in order,
    only the final stack touches, 0.26 mm deep.)

    The surface is developable (flat hub, cylindrical bends) and its outline follows
    lattice lines, so the lattice itself is the stencil: no remeshing, no flattening, all
    unit cells alike.  The 3D scale is then set by the most curved arm (min-bumper rule)
    and gives every cell the same flat length, 5.9 mm.

    Default: 3 lattice rows per arm (34 mm), hub of 2 edges, bend start 28 mm: 255
    bases.  ``large=True`` (``"weave:large"``): 5 rows (56 mm), hub of 3 edges, bend
    start 40 mm, radii 38 / 48 / 58 mm: 551 bases, the benchmark size of the paper's
    self-interweaving shape (549 bases).
    """
    dflt = (5, 3, 40.0, (38.0, 48.0, 58.0)) if large else (3, 2, 28.0, (30.0, 39.0, 48.0))
    rows = int(dflt[0] if rows is None else rows)
    hub = int(dflt[1] if hub is None else hub)
    bend_start = dflt[2] if bend_start is None else bend_start
    radii = dflt[3] if radii is None else radii
    if rows < 2 or hub < 1:
        raise InputError(f"weave: rows={rows} must be >= 2 and hub={hub} >= 1 (lattice edges)")
    if len(np.atleast_1d(radii)) != 3:
        raise InputError("weave: radii must be three numbers (mm), e.g. radii=30;39;48")
    if bend_start < hub * edge:
        raise InputError(f"weave: bend_start={bend_start} mm must clear the hub "
                         f"({hub * edge:g} mm)")
    a, s0, over = (x * size for x in (edge, bend_start, overshoot))
    Rcs = np.array(radii, float) * size
    hr = a * np.sqrt(3) / 2  # spacing of the lattice lines along an arm
    width = rows * hr
    t_lo = -hr  # the arm strip spans lattice lines -1 .. rows - 1 (a pinwheel offset)
    ang = np.radians(90.0 + 120.0 * np.arange(3))
    A = np.c_[np.cos(ang), np.sin(ang)]  # arm axes (lattice directions)
    B = np.c_[-A[:, 1], A[:, 0]]  # lateral (left)
    total = 2 * s0 + np.pi * Rcs + over  # out, half turn, back past the centre
    ring = np.radians(90.0 + 60.0 * np.arange(6))
    polys = [hub * a * np.c_[np.cos(ring), np.sin(ring)]]
    for k in range(3):
        polys.append(np.array([B[k] * t_lo, A[k] * total[k] + B[k] * t_lo,
                               A[k] * total[k] + B[k] * (t_lo + width), B[k] * (t_lo + width)]))
    P, F = _lattice_disk(_polygon_union(polys), a)
    V, t_dense = _curl_arms(P, A, B, (t_lo, t_lo + width), s0, Rcs)
    return Surface("weave", V, F, UV=P.copy(), time=_time_on_dense(V, F, t_dense),
                   description="three-arm pinwheel on a lattice, arms stack over the hub "
                               "in order",
                   options=dict(size=size, large=bool(large)))


def _curl_arms(P, A, B, strip_t, s0: float, Rcs):
    """Bend the weave's flat lattice: arm ``k`` (axis ``A[k]``, lateral ``B[k]``, the points
    whose lateral coordinate lies in ``strip_t``) curls up from ``s0`` along a cylinder of
    radius ``Rcs[k]`` by half a turn and runs back flat.

    Returns
    -------
    V : (n, 3) float, mm -- the bent surface
    t_dense : (n,) float, s -- its landscape: hub 30 s, arms 45 / 65 / 85 s
    """
    V = np.c_[P, np.zeros(len(P))]
    t_dense = np.full(len(P), 30.0)
    best = np.full(len(P), -np.inf)
    for k, tk in enumerate((45.0, 65.0, 85.0)):
        s = P @ A[k]
        t = P @ B[k]
        strip = (t >= strip_t[0] - TOL.merge) & (t <= strip_t[1] + TOL.merge)
        inarm = strip & (s > s0)
        sp_ = s[inarm] - s0
        beta = np.minimum(sp_ / Rcs[k], np.pi)
        S = np.where(sp_ <= np.pi * Rcs[k], s0 + Rcs[k] * np.sin(beta), s0 - (sp_ - np.pi * Rcs[k]))
        V[inarm, :2] = S[:, None] * A[k] + t[inarm, None] * B[k]
        V[inarm, 2] = Rcs[k] * (1 - np.cos(beta))
        # time: the arm whose strip reaches farthest owns a point of the hub
        mine = strip & (s > best) & (s > 0)
        best[mine] = s[mine]
        t_dense[mine] = 30.0 + (tk - 30.0) * _smoothstep((s[mine] - 0.6 * s0) / (0.4 * s0))
    return V, t_dense


def spiral(size: float = 1.0, length: float = 280.0, width: float = 32.0,
           turns: float = 0.8) -> Surface:
    """A strip (280 x 32 mm) that curls into a spiral (curvature growing toward the tip).

    The centre line is a clothoid in the x-z plane: curvature proportional to arc length,
    total turning ``turns`` x 360 deg, so the tip rolls inside the first loop.  Default time
    landscape: the root finishes first (35 s), the tip last (80 s).
    """
    Ls, W = length * size, width * size
    outline = np.array([[0, -W / 2], [Ls, -W / 2], [Ls, W / 2], [0, W / 2]])
    P, F = _dense(outline)
    total = 2 * np.pi * turns
    kmax = 2 * total / Ls
    s_grid = np.linspace(0, Ls, 4001)
    beta = 0.5 * kmax * s_grid**2 / Ls
    ds = s_grid[1] - s_grid[0]
    cx = np.r_[0, np.cumsum(0.5 * (np.cos(beta[1:]) + np.cos(beta[:-1])) * ds)]
    cz = np.r_[0, np.cumsum(0.5 * (np.sin(beta[1:]) + np.sin(beta[:-1])) * ds)]
    X = np.interp(P[:, 0], s_grid, cx)
    Z = np.interp(P[:, 0], s_grid, cz)
    V = np.c_[X, P[:, 1], Z]

    time = _time_on_dense(V, F, 35.0 + 45.0 * P[:, 0] / Ls)

    return Surface("spiral", V, F, time=time,
                   description=f"{Ls:g} x {W:g} mm strip curling {turns:g} turns",
                   options=dict(size=size, turns=turns))


# --------------------------------------------------------------------------------------
# registry

BUILTIN = {"regular": regular, "mechtest": mechtest, "petal": petal, "saddle": saddle,
           "dome": dome,
           "weave": weave, "spiral": spiral}


class _ShapeNames(tuple):
    """Names of the built-in shapes; ``"weave:large" in BUILTIN_SHAPES`` is True too."""

    def __contains__(self, spec):
        return isinstance(spec, str) and is_builtin(spec)


BUILTIN_SHAPES = _ShapeNames(BUILTIN)


def is_builtin(spec: str) -> bool:
    """True if ``spec`` (``name`` or ``name:options``) names a built-in shape."""
    return _parse_options(str(spec))[0] in BUILTIN


def check_spec(spec: str) -> tuple[str, dict]:
    """Parse and check a built-in shape spec without building it (cheap, for early errors).

    Returns
    -------
    name : str
    options : dict

    Raises
    ------
    InputError
        Unknown shape, unknown option name, or a non-numeric value.
    """
    name, opts = _parse_options(str(spec))
    if name not in BUILTIN:
        raise InputError(f"unknown shape {name!r}", fix=f"use one of {', '.join(BUILTIN)}")
    known = list(inspect.signature(BUILTIN[name]).parameters)
    unknown = [k for k in opts if k not in known]
    if unknown:
        raise InputError(f"shape {spec!r}: bad option: unknown option(s) {unknown} for {name!r}",
                         fix=f"{name} takes: {', '.join(known)} (e.g. '{name}:{known[0]}=...')")
    return name, opts


def builtin(spec: str) -> Surface:
    """Make a built-in shape from ``"name"`` or ``"name:opt,key=value"``."""
    name, opts = check_spec(spec)
    try:
        surf = BUILTIN[name](**opts)
    except TypeError as e:
        raise InputError(f"shape {spec!r}: bad option ({e})") from None
    return surf
