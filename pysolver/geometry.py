"""Geometry every stage uses: mesh topology, frames and rotations, rigid fits.

Frames and rotations are the one place where sign conventions live.

* :func:`print_transform` maps the flat shell frame to the print frame of a
  layer (``docs/design-folder.md``, "Print frame").
* :func:`rotvec_to_matrix` / :func:`matrix_to_rotvec` convert rotation vectors
  (angle-axis, rad) to matrices and back (Rodrigues, Supplementary Eq. 1).
* :func:`frames_to_rotation` is the "two orthonormal frames" rotation used to
  orient every base: it maps a direction pair (axis, side) of one frame onto
  the pair of another frame (the reference's ``vectors2rotation``).
* :func:`flat_to_target` / :func:`target_to_flat` apply a base's rigid pose.

All rotations act on column vectors: ``p' = R @ p``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import InputError
from .params import UNIT_CELL, layer_sign
from .params import tol as TOL


def print_transform(layer, layer_h: float = UNIT_CELL.layer_h) -> np.ndarray:
    """4x4 homogeneous transform from the flat shell frame to a layer's print frame.

    The print bed is z = 0 with the far face (brackets) down.  Bottom layer:
    ``(x, y, z + layer_h)``; top layer, turned over about x: ``(x, -y, layer_h - z)``.

    Parameters
    ----------
    layer : {"top", "bottom", 0, 1}
        Layer name or index (0 = top, 1 = bottom).
    layer_h : float, mm
        Layer height (base_th + base_p = 2.3 mm).

    Returns
    -------
    T : (4, 4) float
        Apply as ``(T @ [x, y, z, 1])[:3]``.
    """
    s = layer_sign(layer)
    T = np.eye(4)
    if s > 0:
        T[1, 1] = -1.0
        T[2, 2] = -1.0
    T[2, 3] = layer_h
    return T


def apply_transform(T: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to points ``P : (n, 3)``; returns ``(n, 3)``."""
    P = np.asarray(P, dtype=float)
    return P @ T[:3, :3].T + T[:3, 3]


def rotvec_to_matrix(r: np.ndarray) -> np.ndarray:
    """Rotation matrices from rotation vectors.

    Parameters
    ----------
    r : (3,) or (n, 3) float, rad
        Rotation vector: axis * angle (right-hand rule).

    Returns
    -------
    R : (3, 3) or (n, 3, 3) float
    """
    r = np.asarray(r, dtype=float)
    return Rotation.from_rotvec(r).as_matrix()


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (rad) from rotation matrices ``(3, 3)`` or ``(n, 3, 3)``."""
    return Rotation.from_matrix(np.asarray(R, dtype=float)).as_rotvec()


def _unit(v: np.ndarray, what: str) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(n < TOL.degenerate):
        raise InputError(f"frames_to_rotation: zero-length {what} vector",
                         fix="check for degenerate faces or coincident face centres")
    return v / n


def frames_to_rotation(axis_from, side_from, axis_to, side_to) -> np.ndarray:
    """Rotation taking the frame (axis_from, side_from) onto (axis_to, side_to).

    Each frame is made orthonormal: ``a = axis/|axis|``, ``b`` = side with its
    ``a`` component removed, ``c = a x b``.  Then ``R = [a' b' c'] [a b c]^T``,
    so ``R a = a'`` exactly and ``R b = b'`` (sides after orthogonalisation).

    Parameters
    ----------
    axis_from, side_from, axis_to, side_to : (3,) or (n, 3) float

    Returns
    -------
    R : (3, 3) or (n, 3, 3) float, rotation matrices (det +1)
    """
    args = [np.atleast_2d(np.asarray(x, dtype=float)) for x in
            (axis_from, side_from, axis_to, side_to)]
    single = np.ndim(axis_from) == 1

    def frame(ax, sd):
        a = _unit(ax, "axis")
        b = sd - np.sum(sd * a, axis=1, keepdims=True) * a
        b = _unit(b, "side (parallel to the axis)")
        c = np.cross(a, b)
        return np.stack([a, b, c], axis=2)  # columns a, b, c

    A = frame(args[0], args[1])
    B = frame(args[2], args[3])
    R = B @ np.transpose(A, (0, 2, 1))
    return R[0] if single else R


def flat_to_target(P_flat, R, c_target, c_flat) -> np.ndarray:
    """Map points of a base from the flat shell frame to the target frame.

    ``p_target = c_target + R (p_flat - (x_flat, y_flat, 0))``.

    Parameters
    ----------
    P_flat : (n, 3) float, mm
    R : (3, 3) float
    c_target : (3,) float, mm
        Target face centroid.
    c_flat : (2,) float, mm
        Flat face centroid.
    """
    c0 = np.array([c_flat[0], c_flat[1], 0.0])
    return (np.asarray(P_flat, float) - c0) @ np.asarray(R).T + np.asarray(c_target, float)


def target_to_flat(P_target, R, c_target, c_flat) -> np.ndarray:
    """Inverse of :func:`flat_to_target`: ``p_flat = R^T (p_target - c_target) + (x, y, 0)``."""
    c0 = np.array([c_flat[0], c_flat[1], 0.0])
    return (np.asarray(P_target, float) - np.asarray(c_target, float)) @ np.asarray(R) + c0


# ----------------------------------------------------------------------------------
# mesh topology: faces, unit cells (interior edges), boundary


def face_adjacency(F: np.ndarray) -> np.ndarray:
    """Face across the edge opposite each corner.

    Parameters
    ----------
    F : (m, 3) int
        Triangles.

    Returns
    -------
    ff : (m, 3) int
        ``ff[i, j]`` = face sharing edge ``(F[i,(j+1)%3], F[i,(j+2)%3])`` with
        face ``i``, or -1 on the boundary.

    Raises
    ------
    InputError
        If an edge is used by more than two faces or twice in the same direction
        (non-manifold or inconsistently oriented faces).
    """
    F = np.asarray(F, dtype=np.int64)
    m = len(F)
    a = F[:, [1, 2, 0]].ravel()  # slot j: edge from F[j+1] to F[j+2]
    b = F[:, [2, 0, 1]].ravel()
    face = np.repeat(np.arange(m), 3)
    slot = np.tile(np.arange(3), m)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    key = lo * (F.max() + 1 if m else 1) + hi
    order = np.lexsort((face, key))
    ks = key[order]
    ff = -np.ones((m, 3), dtype=np.int64)
    # groups of equal keys
    starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    counts = np.diff(np.r_[starts, len(ks)])
    if np.any(counts > 2):
        bad = order[starts[counts > 2][0]]
        raise InputError(
            f"non-manifold edge ({a[bad]}, {b[bad]}): shared by more than two triangles "
            f"({int(counts.max())})",
            fix="repair the mesh (e.g. MeshLab: Cleaning > Repair non-manifold edges)")
    two = starts[counts == 2]
    e0, e1 = order[two], order[two + 1]
    same_dir = a[e0] == a[e1]
    if np.any(same_dir):
        k = e0[same_dir][0]
        raise InputError(
            f"faces {face[k]} and {face[e1[same_dir][0]]} traverse edge ({a[k]}, {b[k]}) in the "
            "same direction: the faces are not consistently oriented (or the surface is "
            "non-orientable)",
            fix="re-orient the faces consistently (MeshLab: Re-orient all faces coherently)")
    ff[face[e0], slot[e0]] = face[e1]
    ff[face[e1], slot[e1]] = face[e0]
    return ff


_GENERIC_DIRECTION = np.array([1.0, np.sqrt(2.0), np.sqrt(3.0)]) / np.sqrt(6.0)


def canonical_order(V, F, values=None):
    """The mesh with its vertices and faces in an order given by its geometry alone.

    A mesh's labelling (the order of its vertices, of its faces, and where each face's
    corners start) is not part of the surface it describes.  Every stage that chooses
    (a seed, a start on the rim, a tie between equal candidates) reads its input in this
    order, so that the same surface, labelled otherwise, gives the same design to the last
    bit.  Vertices are sorted by their coordinates (x, then y, then z); vertices at the very
    same point (an unwelded seam) by the sorted coordinates of their faces' centroids.
    Each face starts at its lowest new index, keeping its orientation, and faces are sorted
    by their corners.

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    values : (n, ...) array, optional
        Per-vertex data carried along (a time landscape, in s).

    Returns
    -------
    V : (n, 3) float, mm -- ``V[order]``
    F : (m, 3) int
    values : (n, ...) array or None -- ``values[order]``
    order : (n,) int -- old index of each new vertex

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[1., 0, 0], [0, 0, 0], [0, 1, 0]])
    >>> Vc, Fc, _, order = canonical_order(V, np.array([[0, 2, 1]]))
    >>> order.tolist(), Fc.tolist()
    ([1, 0, 2], [[0, 1, 2]])
    """
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    # first along a direction of irrational slopes: coordinates on a grid do not tie on it,
    # so that a jitter of the last bits reorders few vertices (x, y, z break exact ties)
    keys = [V[:, 2], V[:, 1], V[:, 0], V @ _GENERIC_DIRECTION]
    dup = len(np.unique(V, axis=0)) < len(V)
    if dup:  # (the lexicographically first centroid of each vertex's faces breaks the tie)
        C = np.repeat(V[F].mean(axis=1), 3, axis=0)
        v = F.ravel()
        first = np.lexsort((C[:, 2], C[:, 1], C[:, 0], v))
        first = first[np.r_[True, v[first][1:] != v[first][:-1]]]
        K = np.full((len(V), 3), np.inf)
        K[v[first]] = C[first]
        keys = [K[:, 2], K[:, 1], K[:, 0]] + keys
    order = np.lexsort(keys)
    new = np.empty_like(order)
    new[order] = np.arange(len(order))
    G = new[F]
    shift = np.argmin(G, axis=1)
    G = np.take_along_axis(G, (shift[:, None] + np.arange(3)) % 3, axis=1)
    G = G[np.lexsort((G[:, 2], G[:, 1], G[:, 0]))]
    return V[order], G, (None if values is None else np.asarray(values)[order]), order


def canonical_pose(V, F, rel: float = TOL.pose_rel):
    """The rigid motion that moves a surface into a frame given by its shape alone.

    Where a surface lies in space is no more part of it than its labelling: the stencil
    search (:func:`pysolver.design.stencil.search.remesh_surface`) is run in this frame, so
    that the same surface moved rigidly is the same problem to the last bits of its
    coordinates, read in the same :func:`canonical_order`.  The frame is the surface's own:
    its area centroid at the origin, its principal axes of inertia along x, y, z (largest
    second moment first), each pointing where the area reaches further (positive third
    moment); the axis whose third moment is smallest is set by the right hand instead.  A
    surface with two equal principal moments (a surface of revolution) or two axes without a
    third moment (two mirror planes) has no such frame; it keeps the one it was given
    (``decided`` is False), as it would under any choice among its symmetries.  Written here
    because what a library offers (``trimesh``'s principal inertia) leaves the signs to the
    eigensolver.

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    rel : float
        :attr:`pysolver.params.Tolerances.pose_rel`.

    Returns
    -------
    R : (3, 3) float -- a rotation (det +1) whose columns are the axes; identity if undecided
    c : (3,) float, mm -- the area centroid; zero if undecided
    decided : bool

    The surface in the frame is ``(V - c) @ R``, and a point ``X`` of the frame is ``X @ R.T
    + c`` in the surface's.

    Examples
    --------
    >>> import numpy as np
    >>> from scipy.spatial.transform import Rotation
    >>> V = np.array([[0., 0, 0], [6, 0, 0], [0, 2, 0], [0, 0, 1]])
    >>> F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> R, c, ok = canonical_pose(V, F)
    >>> Q = Rotation.from_rotvec([0.3, -1.2, 2.0]).as_matrix()
    >>> R2, c2, _ = canonical_pose(V @ Q.T + 5.0, F)
    >>> ok, bool(np.allclose((V - c) @ R, (V @ Q.T + 5.0 - c2) @ R2))
    (True, True)
    """
    V = np.asarray(V, float)
    T = V[np.asarray(F, dtype=np.int64)]
    A = 0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1)
    area = float(A.sum())
    as_given = np.eye(3), np.zeros(3), False
    if not area > 0:
        return as_given
    c = A @ T.mean(axis=1) / area
    D = T - c
    s = D.sum(axis=1)
    # exact area moments of the flat triangles: second (A/12 (sum d d^T + s s^T)) ...
    M = (np.einsum("f,fij,fik->jk", A, D, D) + np.einsum("f,fj,fk->jk", A, s, s)) / 12.0
    w, E = np.linalg.eigh(M)
    w, E = w[::-1], E[:, ::-1]  # largest first
    if min(w[0] - w[1], w[1] - w[2]) <= rel * w[0]:
        return as_given
    # ... and third: A/10 times the sum of the ten cubic monomials of the corners' coordinates
    X = D @ E
    a, b, d = X[:, 0], X[:, 1], X[:, 2]
    cubic = (a**3 + b**3 + d**3 + a * a * (b + d) + b * b * (a + d) + d * d * (a + b)
             + a * b * d)
    skew = A @ cubic / 10.0 / (area * (w[0] / area) ** 1.5)
    by = np.argsort(-np.abs(skew), kind="stable")
    if abs(skew[by[1]]) <= rel:
        return as_given
    E = E * np.where(skew < 0, -1.0, 1.0)
    if np.linalg.det(E) < 0:
        E[:, by[2]] *= -1.0
    return E, c, True


@dataclass
class Cells:
    """Unit cells (interior edges) in the reference's face-major order.

    Attributes
    ----------
    faces : (c, 2) int
        ``(base_a, base_b)`` with ``base_a < base_b``.
    slots : (c, 2) int
        Slot of the shared edge in each base.
    verts : (c, 2) int
        Shared edge ``F[a,(slot_a+1)%3], F[a,(slot_a+2)%3]``.
    cell_of : (m, 3) int
        Cell id of (face, slot), -1 on the boundary.
    boundary : (c,) bool
        An endpoint of the shared edge is a boundary vertex (FFb).
    """

    faces: np.ndarray
    slots: np.ndarray
    verts: np.ndarray
    cell_of: np.ndarray
    boundary: np.ndarray


def unit_cells(F: np.ndarray, ff: np.ndarray | None = None) -> Cells:
    """Enumerate unit cells face-major (faces ascending, slots 0..2, neighbour > face).

    Parameters
    ----------
    F : (m, 3) int
    ff : (m, 3) int, optional
        From :func:`face_adjacency`.
    """
    F = np.asarray(F, dtype=np.int64)
    if ff is None:
        ff = face_adjacency(F)
    m = len(F)
    ii, jj = np.nonzero(ff > np.arange(m)[:, None])  # row-major = face-major order
    nb = ff[ii, jj]
    # slot in the neighbour that points back
    back = np.argmax(ff[nb] == ii[:, None], axis=1)
    cell_of = -np.ones((m, 3), dtype=np.int64)
    ids = np.arange(len(ii))
    cell_of[ii, jj] = ids
    cell_of[nb, back] = ids
    verts = np.stack([F[ii, (jj + 1) % 3], F[ii, (jj + 2) % 3]], axis=1)
    vb = boundary_vertex_mask(F, ff)
    boundary = vb[verts[:, 0]] | vb[verts[:, 1]]
    return Cells(faces=np.stack([ii, nb], 1), slots=np.stack([jj, back], 1), verts=verts,
                 cell_of=cell_of, boundary=boundary)


def boundary_vertex_mask(F: np.ndarray, ff: np.ndarray, n_vertices: int | None = None):
    """(n,) bool: vertex lies on a boundary edge."""
    F = np.asarray(F)
    n = int(F.max()) + 1 if n_vertices is None else n_vertices
    mask = np.zeros(n, dtype=bool)
    i, j = np.nonzero(ff < 0)
    mask[F[i, (j + 1) % 3]] = True
    mask[F[i, (j + 2) % 3]] = True
    return mask


def face_centroids(X: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(m, d) float: face centroids of ``X : (n, d)``."""
    return np.asarray(X, float)[np.asarray(F)].mean(axis=1)


def face_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(m, 3) float: unit normals ``(V1-V0) x (V2-V0)`` normalised; raises on degenerate faces."""
    P = np.asarray(V, float)[np.asarray(F)]
    N = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    n = np.linalg.norm(N, axis=1)
    scale = max(np.ptp(V, axis=0).max(), TOL.tiny)
    bad = np.flatnonzero(n <= TOL.degenerate * scale**2)
    if len(bad):
        raise InputError(f"{len(bad)} degenerate triangle(s) (zero area), e.g. face {bad[0]}",
                         fix="remove degenerate faces (MeshLab: Remove zero-area faces) or remesh")
    return N / n[:, None]


def signed_areas_2d(UV: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(m,) float: signed area of each flat triangle (positive = CCW)."""
    P = np.asarray(UV, float)[np.asarray(F)]
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


# ----------------------------------------------------------------------------------
# rigid poses and fits


def reference_slots(ff: np.ndarray) -> np.ndarray:
    """(m,) int: first slot with a neighbour (the reference neighbour); raises if none."""
    has = ff >= 0
    if not np.all(has.any(axis=1)):
        i = int(np.flatnonzero(~has.any(axis=1))[0])
        raise InputError(f"face {i} has no neighbour (an isolated triangle)",
                         fix="remove isolated triangles or use a connected surface")
    return np.argmax(has, axis=1)


def base_rotations(V, UV, F, ff=None):
    """Rotation of every base from its flat pose to its target pose.

    ``R_i`` maps flat +z onto the face normal ``n_i`` and the flat direction to the
    reference neighbour onto the 3D direction to it (orthogonalised against n_i).

    Returns
    -------
    R : (m, 3, 3) float
    ref_slot : (m,) int
    """
    F = np.asarray(F, dtype=np.int64)
    if ff is None:
        ff = face_adjacency(F)
    ref = reference_slots(ff)
    nb = ff[np.arange(len(F)), ref]
    Fc = face_centroids(V, F)
    C2 = face_centroids(UV, F)
    N = face_normals(V, F)
    m = len(F)
    z = np.tile([0.0, 0.0, 1.0], (m, 1))
    flat_dir = np.c_[C2[nb] - C2, np.zeros(m)]
    R = frames_to_rotation(z, flat_dir, N, Fc[nb] - Fc)
    return R, ref


def fold_angles_deg(Fc, N, cells: Cells) -> np.ndarray:
    """Signed fold angle (deg) per cell: angle between the normals, + when the fold closes
    toward the top (+normal) side, i.e. the top side is concave."""
    a, b = cells.faces[:, 0], cells.faces[:, 1]
    ang = np.degrees(np.arccos(np.clip(np.sum(N[a] * N[b], 1), -1, 1)))
    sgn = -np.sign(np.sum((N[b] - N[a]) * (Fc[b] - Fc[a]), 1))
    return ang * sgn


def rigid_fit(A, B, weights=None):
    """Rigid motion (rotation + translation, no scaling) taking ``A`` onto ``B`` (Kabsch).

    Minimises ``sum_i w_i |Q a_i + s - b_i|^2``.

    Parameters
    ----------
    A, B : (n, 3) float, mm
        Corresponding points, n >= 3 (n = 2 gives a rotation about the pair's axis
        chosen by scipy).
    weights : (n,) float, optional

    Returns
    -------
    Q : (3, 3) float
        Rotation matrix (det +1).
    s : (3,) float, mm
    """
    A = np.asarray(A, float)
    B = np.asarray(B, float)
    if A.shape != B.shape or A.ndim != 2 or A.shape[1] != 3 or len(A) < 2:
        raise InputError(f"rigid_fit: point sets of shapes {A.shape} and {B.shape}",
                         fix="pass two (n, 3) arrays of corresponding points, n >= 2")
    w = np.ones(len(A)) if weights is None else np.asarray(weights, float)
    w = w / w.sum()
    ca = w @ A
    cb = w @ B
    # scipy's align_vectors(a, b) finds R minimising sum w |a - R b|^2
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "optimal rotation is not uniquely defined"
        rot, _ = Rotation.align_vectors(B - cb, A - ca, weights=w)
    Q = rot.as_matrix()
    return Q, cb - Q @ ca


__all__ = ["print_transform", "apply_transform", "rotvec_to_matrix", "matrix_to_rotvec",
           "frames_to_rotation", "flat_to_target", "target_to_flat", "face_adjacency", "Cells",
           "unit_cells", "boundary_vertex_mask", "face_centroids", "face_normals",
           "signed_areas_2d", "reference_slots", "base_rotations", "fold_angles_deg",
           "rigid_fit"]
