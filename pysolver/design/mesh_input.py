"""Read and validate user target surfaces (OBJ, STL, PLY, OFF) and stencil OBJs.

:func:`load_input` returns an :class:`InputMesh`.  Every mesh is a **target surface**
(vertex order kept with ``process=False``; coincident corners are welded), a mesh with a
UV map (``vt`` rows, as modelling tools export them) included: its UV map is a texture
layout, not a flat stencil.  An OBJ is a **stencil** (one ``vt`` per ``v``, row-aligned or
one-to-one ``v/vt`` face corners; vertex and face order kept, ``UV`` its flat layout) only
when the user says so (``stencil=True``, ``--stencil``) or when it carries the marker line
morphshell writes into its own ``stencil.obj`` (:data:`STENCIL_MARKER`).

:func:`validate_surface` refuses, with an actionable message, anything that cannot be
a shell: empty or corrupt files, unsupported formats, NaN/inf, degenerate triangles,
non-manifold edges or vertices, inconsistent orientation, several components, closed
surfaces, holes and handles (the surface must be a topological disk), and sizes that
are implausible in millimetres.
"""

from __future__ import annotations

import dataclasses
import io
import logging
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import igl
import numpy as np

from ..core.inputs import check_input_file, read_input
from ..errors import InputError
from ..geometry import face_adjacency
from ..params import tol as TOL
from ..tables import STENCIL_MARKER, read_stencil

SUPPORTED = (".obj", ".stl", ".ply", ".off")
# a shell smaller or larger than this (bounding-box diagonal, mm) is probably in other units:
# refused (the remeshing would pick a nonsense vertex count from the area) ...
MIN_SIZE_MM, MAX_SIZE_MM = 20.0, 2000.0
# ... and outside this band it is suspicious: a warning (SizeWarning) offers --scale
WARN_MIN_SIZE_MM, WARN_MAX_SIZE_MM = 40.0, 600.0
# (factor, unit) a mesh exported in another unit needs to become millimetres
_UNITS = ((1000.0, "metres"), (25.4, "inches"), (10.0, "centimetres"), (0.1, "tenths of a mm"),
          (0.001, "micrometres"))


class SizeWarning(UserWarning):
    """The input surface's size is unusual for millimetres (possibly another unit)."""
_PLY_STANDARD = {"x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "alpha", "s", "t",
                 "u", "v", "texture_u", "texture_v"}


@dataclass
class InputMesh:
    """A loaded input.

    Attributes
    ----------
    V : (n, 3) float, mm (after ``scale``)
    F : (m, 3) int
    UV : (n, 2) float or None -- flat layout of a stencil OBJ
    vertex_attributes : dict of (n,) float -- PLY vertex properties (e.g. ``quality``)
    colors : (n, 3) float in 0..1, or None -- vertex colours
    path : Path
    kind : "stencil" or "mesh"
    notes : list of str
    scale : float -- factor applied to the file's coordinates (``scale``, or from ``size``)
    file_index : (n,) int or None -- index of each vertex in the file's own vertex list
        (before welding and removing unreferenced vertices), for per-vertex data given in
        file order (``--time-file``)
    file_vertices : int -- number of vertices in the file
    """

    V: np.ndarray
    F: np.ndarray
    UV: np.ndarray | None = None
    vertex_attributes: dict = field(default_factory=dict)
    colors: np.ndarray | None = None
    path: Path | None = None
    kind: str = "mesh"
    notes: list = field(default_factory=list)
    scale: float = 1.0
    file_index: np.ndarray | None = None
    file_vertices: int = 0

    def transformed(self, shift, scale: float) -> InputMesh:
        """Copy with ``V' = (V + shift) * scale`` (to follow the stencil's centring/scaling)."""
        return dataclasses.replace(self, V=(self.V + np.asarray(shift)) * scale,
                                   scale=self.scale * scale)


def _obj_has_vt(path: Path) -> bool:
    with open(path, errors="replace") as fh:
        for line in fh:
            if line.startswith("vt "):
                return True
    return False


def has_stencil_marker(path) -> bool:
    """Whether the OBJ's first line is the marker morphshell writes into ``stencil.obj``."""
    with open(path, errors="replace") as fh:
        return fh.readline().startswith(STENCIL_MARKER)


def _read_trimesh(path: Path):
    import trimesh  # heavy: trimesh loads only for STL work

    ext = path.suffix.lower()
    # from the bytes, without a file resolver: the material and texture files an OBJ or a
    # PLY names (mtllib, map_Kd) are never opened (one could be a FIFO)
    data = io.BytesIO(read_input(path, "mesh file"))
    try:
        # process=False everywhere: trimesh's processing would silently drop the triangles
        # of NaN/inf vertices (an STL then shows up as a "hole"); corners are welded by
        # weld_vertices, the same way for every format
        log = logging.getLogger("trimesh")
        level, log.level = log.level, logging.CRITICAL  # (it logs the unread texture)
        try:
            m = trimesh.load(data, file_type=ext[1:], force="mesh", process=False)
        finally:
            log.setLevel(level)
    except Exception as e:  # noqa: BLE001 - any parser failure is a corrupt file
        raise InputError(f"{path}: cannot read the {ext[1:].upper()} file, it is corrupt or "
                         f"truncated ({type(e).__name__}: {e})",
                         fix="check that the file is a valid, complete mesh export") from None
    if not hasattr(m, "faces") or m.faces is None or len(m.faces) == 0:
        raise InputError(f"{path}: no triangles found: the file is empty, truncated or corrupt, "
                         "or holds only points",
                         fix="export the surface as a triangle mesh (and check the export "
                             "finished)")
    if ext == ".stl":
        bad = np.flatnonzero(~np.all(np.isfinite(np.asarray(m.vertices)), axis=1))
        if len(bad):
            tri = np.flatnonzero(np.isin(np.asarray(m.faces), bad).any(axis=1))
            raise InputError(f"{path}: {len(tri)} triangle(s) with NaN or infinite vertex "
                             f"coordinates (first: triangle {tri[0] if len(tri) else '?'})",
                             fix="repair or re-export the mesh")
    return m


def weld_vertices(V, F, tol: float = TOL.merge) -> tuple[np.ndarray, np.ndarray, int]:
    """Merge vertices that lie within ``tol`` of each other (on a grid of that size).

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    tol : float, mm

    Returns
    -------
    keep : (k,) int
        Index of the first vertex of each group, in the original order.
    F : (m, 3) int
        Faces re-indexed into ``V[keep]``.
    n_welded : int
        ``n - k``, the vertices merged away.
    """
    V = np.asarray(V, float)
    if len(V) == 0 or not np.all(np.isfinite(V)):
        return np.arange(len(V)), np.asarray(F), 0  # validate_surface names bad coordinates
    key = np.round(V / tol).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)           # groups in the order of their first vertex
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return first[order], rank[np.ravel(inverse)][np.asarray(F)], len(V) - len(first)


def size_factor(V, size: float, name: str = "surface") -> float:
    """Factor that makes the largest bounding-box extent of ``V`` equal to ``size`` mm.

    Parameters
    ----------
    V : (n, 3) float -- the file's coordinates (any unit)
    size : float, mm
    name : str -- file named in messages

    Returns
    -------
    factor : float

    Raises
    ------
    InputError
        Non-finite coordinates or a surface without extent.
    """
    V = np.asarray(V, float)
    bad = np.flatnonzero(~np.all(np.isfinite(V), axis=1)) if V.ndim == 2 else [0]
    if len(bad):
        raise InputError(f"{name}: {len(bad)} vertex coordinate(s) are NaN or infinite "
                         f"(first: vertex {bad[0]}), so --size cannot measure the surface",
                         fix="repair or re-export the mesh")
    extent = float(np.ptp(V, axis=0).max()) if len(V) else 0.0
    if not extent > 0:
        raise InputError(f"{name}: the surface has no extent (all vertices coincide)",
                         fix="re-export the mesh")
    return float(size) / extent


def load_input(path, scale: float = 1.0, validate: bool = True,
               size: float | None = None, stencil: bool = False) -> InputMesh:
    """Load a target surface or a stencil OBJ.

    Parameters
    ----------
    path : str or Path
    scale : float
        Factor applied to the coordinates (e.g. 10 for a mesh in cm).
    validate : bool
        Run :func:`validate_surface` (after scaling: the size check sees millimetres).
    size : float, mm, optional
        Scale the coordinates instead so that the largest bounding-box extent is ``size``
        mm (for unitless meshes); exclusive with ``scale`` (``scale`` must then be 1).
    stencil : bool
        The OBJ is a finished stencil (``--stencil``): its ``vt`` is its flat layout.
        Without it, only an OBJ that carries morphshell's stencil marker is one; any other
        mesh with a UV map is a target surface and its ``vt`` rows are ignored.

    Returns
    -------
    InputMesh
    """
    path = Path(path)
    ext = _check_mesh_file(path)
    notes = []
    has_vt = ext == ".obj" and _obj_has_vt(path)
    if has_vt and not (stencil or has_stencil_marker(path)):
        notes.append("UV map (vt) ignored: a mesh with a UV map is a target surface "
                     "(give --stencil to use its triangles and vt as a finished stencil)")
    elif has_vt:
        try:
            return _load_stencil_obj(path, scale, size, validate)
        except InputError as e:
            if "seam" not in e.problem or stencil:
                raise
            notes.append("vt ignored: the texture layout has seams (not a stencil)")
    m = _read_trimesh(path)
    V = np.asarray(m.vertices, float) * scale
    file_index = np.arange(len(V))
    F = np.asarray(m.faces, dtype=np.int64)
    attrs, colors = _vertex_data(m, ext, len(V))
    # weld coincident corners (an STL, or an OBJ/PLY/OFF triangle soup, stores every
    # triangle corner separately), then drop unreferenced vertices, keeping the vertex order
    keep, F, n_welded = weld_vertices(V, F)
    if n_welded:
        notes.append(f"{n_welded} coincident vertices welded")
        V, file_index, attrs, colors = _vertex_subset(keep, V, file_index, attrs, colors)
    used = np.unique(F)
    if len(used) < len(V):
        notes.append(f"{len(V) - len(used)} unreferenced vertices removed")
        remap = -np.ones(len(V), dtype=np.int64)
        remap[used] = np.arange(len(used))
        F = remap[F]
        V, file_index, attrs, colors = _vertex_subset(used, V, file_index, attrs, colors)
    if size is not None:  # measured on the vertices the faces use
        scale = size_factor(V, size, str(path))
        V = V * scale
    mesh = InputMesh(V, F, None, attrs, colors, path, "mesh", notes, scale, file_index,
                     int(len(m.vertices)))
    if validate:
        validate_surface(mesh.V, mesh.F, str(path))
    return mesh


def _vertex_subset(sel, V, file_index, attrs: dict, colors):
    """The vertices ``sel`` of a mesh, with their file indices and per-vertex data."""
    return (V[sel], file_index[sel], {k: v[sel] for k, v in attrs.items()},
            None if colors is None else colors[sel])


def _check_mesh_file(path: Path) -> str:
    """Refuse a missing, special, empty or unsupported mesh file; its lower-case suffix."""
    if not path.exists():
        raise InputError(f"{path}: file not found",
                         fix="check the path, or use a built-in shape (morphshell shapes)")
    check_input_file(path, "mesh file")  # a FIFO or a device would block the reader
    if not path.is_file():
        raise InputError(f"{path}: is a directory, not a mesh file",
                         fix="give the path of a mesh file (OBJ, STL, PLY, OFF)")
    ext = path.suffix.lower()
    if ext not in SUPPORTED:
        raise InputError(f"{path}: unsupported format {ext or '(no extension)'!r}",
                         fix=f"export the surface as one of {', '.join(SUPPORTED)}")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: empty file", fix="re-export the mesh")
    return ext


def _load_stencil_obj(path: Path, scale: float, size, validate: bool) -> InputMesh:
    """An OBJ with ``vt`` read as a stencil (its vertex and face order kept)."""
    V, UV, F = read_stencil(path)
    if size is not None:
        scale = size_factor(V, size, str(path))
    mesh = InputMesh(V * scale, F, None if UV is None else UV * scale, path=path,
                     kind="stencil" if UV is not None else "mesh", scale=scale,
                     file_index=np.arange(len(V)), file_vertices=len(V))
    if validate:
        validate_surface(mesh.V, mesh.F, str(path))
    return mesh


def _vertex_data(m, ext: str, n: int):
    """The per-vertex data of a loaded mesh: the scalar properties of a PLY's vertices
    (other than positions, normals, colours) and the vertex colours (0..1), or None."""
    attrs = {}
    raw = getattr(m, "metadata", {}).get("_ply_raw") if ext == ".ply" else None
    if raw is not None and "vertex" in raw:
        data = raw["vertex"]["data"]
        names = getattr(getattr(data, "dtype", None), "names", None) or ()
        for nm in names:
            if nm not in _PLY_STANDARD and data[nm].ndim == 1 and len(data[nm]) == n:
                attrs[nm] = np.asarray(data[nm], float)
    colors = None
    vis = getattr(m, "visual", None)
    if vis is not None and getattr(vis, "kind", None) == "vertex":
        colors = np.asarray(vis.vertex_colors, float)[:, :3] / 255.0
    return attrs, colors


def boundary_loops(F) -> list[np.ndarray]:
    """All boundary loops (vertex index arrays, in face orientation order), longest first.

    Hand-written walk over the directed boundary edges (this libigl build has only
    ``boundary_loop``, which returns the longest loop).  Assumes manifold vertices.
    """
    F = np.asarray(F, dtype=np.int64)
    ff = face_adjacency(F)
    i, j = np.nonzero(ff < 0)
    nxt = dict(zip(F[i, (j + 1) % 3].tolist(), F[i, (j + 2) % 3].tolist(), strict=True))
    loops, seen = [], set()
    for start in sorted(nxt):
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen:
            seen.add(v)
            loop.append(v)
            v = nxt[v]
        loops.append(np.array(loop, dtype=np.int64))
    return sorted(loops, key=len, reverse=True)


def _fmt_pt(p) -> str:
    return f"({p[0]:.1f}, {p[1]:.1f}, {p[2]:.1f})"


def _unit_candidates(diag: float, lo: float, hi: float) -> list[tuple[float, str]]:
    """Units (factor, name) that would bring a diagonal ``diag`` into ``[lo, hi]`` mm."""
    return [(k, u) for k, u in _UNITS if lo <= diag * k <= hi]


def _scale_fix(diag: float, cands) -> str:
    """``re-run with --scale K (Python: scale=K) if the mesh is in <unit> (D mm across), ...``"""
    opts = [f"--scale {k:g} (Python: scale={k:g}) if the mesh is in {u} (it would be "
            f"{diag * k:.0f} mm across)" for k, u in cands]
    return ("re-run with " + "; or ".join(opts) + "; or --size MM (the largest extent in mm) "
            "if the mesh has no unit; or scale it in your modeller")


def check_size(V, name: str = "surface") -> float:
    """Refuse sizes that cannot be millimetres, warn about suspicious ones.

    A surface whose bounding-box diagonal is outside ``[MIN_SIZE_MM, MAX_SIZE_MM]`` is
    refused; outside ``[WARN_MIN_SIZE_MM, WARN_MAX_SIZE_MM]`` a :class:`SizeWarning` is
    issued.  Both name the size and the ``--scale`` factor of the probable unit(s).

    Returns
    -------
    diag : float, mm
    """
    diag = float(np.linalg.norm(np.ptp(np.asarray(V, float), axis=0)))
    if MIN_SIZE_MM <= diag <= MAX_SIZE_MM:
        if not WARN_MIN_SIZE_MM <= diag <= WARN_MAX_SIZE_MM:
            small = diag < WARN_MIN_SIZE_MM
            cands = [c for c in _unit_candidates(diag, WARN_MIN_SIZE_MM, WARN_MAX_SIZE_MM)
                     if (c[0] > 1) == small]
            if cands:
                warnings.warn(
                    f"{name}: the surface is {diag:.3g} mm across (bounding-box diagonal), "
                    f"{'small' if small else 'large'} for a printed shell if the coordinates "
                    "are millimetres; " + _scale_fix(diag, cands), SizeWarning, stacklevel=3)
        return diag
    if diag < MIN_SIZE_MM:
        cands = (_unit_candidates(diag, WARN_MIN_SIZE_MM, WARN_MAX_SIZE_MM)
                 or _unit_candidates(diag, MIN_SIZE_MM, MAX_SIZE_MM)
                 or [max(_UNITS[:3], key=lambda ku: min(diag * ku[0], MAX_SIZE_MM))])
        raise InputError(f"{name}: the surface is only {diag:.3g} mm across (bounding-box "
                         "diagonal): coordinates must be millimetres and a shell of 7 mm unit "
                         f"cells needs at least {MIN_SIZE_MM:g} mm; the mesh is probably in "
                         + " or ".join(u for _, u in cands),
                         fix=_scale_fix(diag, cands))
    cands = [c for c in _unit_candidates(diag, WARN_MIN_SIZE_MM, WARN_MAX_SIZE_MM) if c[0] < 1] \
        or [(0.001, "micrometres")]
    raise InputError(f"{name}: the surface is {diag:.4g} mm across; that is implausibly "
                     "large for a printed shell (coordinates must be millimetres)",
                     fix=_scale_fix(diag, cands))


def validate_surface(V, F, name: str = "surface") -> None:
    """Check that (V, F) is one connected, oriented, manifold topological disk in mm.

    Raises
    ------
    InputError
        Naming the problem and where it is, with a fix.
    """
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) < 3:
        raise InputError(f"{name}: need 3D vertices, got array of shape {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
        raise InputError(f"{name}: need triangles, got faces of shape {F.shape}",
                         fix="triangulate the mesh")
    if F.min() < 0 or F.max() >= len(V):
        raise InputError(f"{name}: face index out of range")
    bad = np.flatnonzero(~np.all(np.isfinite(V), axis=1))
    if len(bad):
        raise InputError(f"{name}: {len(bad)} vertex coordinate(s) are NaN or infinite "
                         f"(first: vertex {bad[0]})", fix="repair or re-export the mesh")
    diag = check_size(V, name)
    dup = np.any(F[:, [0, 1, 2]] == F[:, [1, 2, 0]], axis=1)
    area2 = igl.doublearea(V, F)
    degenerate = np.flatnonzero(dup | (area2 <= TOL.input_degenerate * diag**2))
    if len(degenerate):
        raise InputError(f"{name}: {len(degenerate)} degenerate triangle(s) (zero area or "
                         f"repeated vertex), e.g. face {degenerate[0]} at "
                         f"{_fmt_pt(V[F[degenerate[0]]].mean(0))} mm",
                         fix="remove them (MeshLab: Cleaning and Repairing > Remove Zero Area "
                             "Faces / Merge Close Vertices)")
    ncomp, comp = igl.facet_components(F)
    if ncomp > 1:
        sizes = np.bincount(comp)
        raise InputError(f"{name}: {ncomp} separate pieces (faces per piece: "
                         f"{sorted(sizes.tolist(), reverse=True)[:6]})",
                         fix="keep one connected surface (delete the small pieces) or design "
                             "each piece separately")
    _check_edges(V, F, name)
    ff = face_adjacency(F)  # (after _check_edges: cannot raise any more)
    # non-manifold vertices (bow-ties): a vertex whose faces form several fans
    nm = _nonmanifold_vertices(F, ff, len(V))
    if len(nm):
        raise InputError(f"{name}: {len(nm)} non-manifold vertex/vertices (surfaces touching at "
                         f"a point), e.g. vertex {nm[0]} at {_fmt_pt(V[nm[0]])} mm",
                         fix="split the vertex or remove one of the touching parts "
                             "(MeshLab: Repair non Manifold Vertices)")
    loops = boundary_loops(F)
    n_edges = (3 * len(F) + int(np.sum(ff < 0))) // 2
    used = len(np.unique(F))
    chi = used - n_edges + len(F)
    b = len(loops)
    if b == 0:
        genus = (2 - chi) // 2
        low = V[np.argmin(V[:, 2])]
        raise InputError(f"{name}: the surface is closed (no boundary"
                         + (f", genus {genus}" if genus else "") + "); a shell must be a "
                         "disk-like open surface",
                         fix=f"cut it open, e.g. delete the faces around {_fmt_pt(low)} mm "
                             "(its lowest point) or cut it in half")
    genus = (2 - chi - b) // 2
    if genus > 0:
        raise InputError(f"{name}: the surface has {genus} handle(s) (genus {genus}); a shell "
                         "must be a topological disk",
                         fix="cut through each handle (a closed loop around it) so the "
                             "surface becomes a disk")
    if b > 1:
        outer = loops[0]
        msgs = []
        for lp in loops[1:4]:
            c = V[lp].mean(0)
            j = outer[np.argmin(np.linalg.norm(V[outer] - c, axis=1))]
            msgs.append(f"hole around {_fmt_pt(c)} mm (cut from it to the rim near "
                        f"{_fmt_pt(V[j])} mm)")
        raise InputError(f"{name}: the surface has {b - 1} hole(s): " + "; ".join(msgs),
                         fix="fill the holes, or cut from each hole to the outer boundary so "
                             "the surface becomes a disk")


def _check_edges(V, F, name: str) -> None:
    """Refuse edges shared by more than two triangles, and edges traversed twice in the same
    direction (inconsistent orientation), naming how many and where (mm)."""
    a = F[:, [1, 2, 0]].ravel()
    b = F[:, [2, 0, 1]].ravel()
    und = np.sort(np.c_[a, b], axis=1)
    uniq, cnt = np.unique(und, axis=0, return_counts=True)
    bad = np.flatnonzero(cnt > 2)
    if len(bad):
        e = uniq[bad[0]]
        raise InputError(f"{name}: {len(bad)} non-manifold edge(s) (shared by more than two "
                         f"triangles), e.g. edge ({e[0]}, {e[1]}) used by {cnt[bad[0]]} "
                         f"triangles at {_fmt_pt(V[e].mean(0))} mm",
                         fix="remove the extra (fin or overlapping) triangles so every edge "
                             "has at most two (MeshLab: Cleaning and Repairing > Repair non "
                             "Manifold Edges)")
    d_uniq, d_cnt = np.unique(np.c_[a, b], axis=0, return_counts=True)
    same = d_uniq[d_cnt > 1]
    if len(same):
        e = same[0]
        raise InputError(f"{name}: the faces are not consistently oriented (or the surface is "
                         f"non-orientable): {len(same)} edge(s) traversed twice in the same "
                         f"direction, e.g. edge ({e[0]}, {e[1]}) at {_fmt_pt(V[e].mean(0))} mm",
                         fix="re-orient the faces consistently (MeshLab: Normals, Curvatures "
                             "and Orientation > Re-Orient all faces coherently)")


def _nonmanifold_vertices(F, ff, n) -> np.ndarray:
    """Vertices whose incident faces are not connected through shared edges (bow-ties)."""
    import scipy.sparse as sp  # heavy: this scipy submodule loads only where it is used

    # heavy: this scipy submodule loads only where it is used
    from scipy.sparse.csgraph import connected_components

    m = len(F)
    # graph whose nodes are (face, corner) incidences, linked when adjacent faces share
    # the edge around that vertex
    inc_face = np.repeat(np.arange(m), 3)
    inc_vert = F.ravel()
    rows, cols = [], []
    for j in range(3):
        g = ff[:, j]
        ok = g >= 0
        # edge opposite corner j has endpoints F[:, j+1], F[:, j+2]; both are shared
        for k in ((j + 1) % 3, (j + 2) % 3):
            f_ok = np.flatnonzero(ok)
            v = F[f_ok, k]
            gk = np.argmax(F[g[f_ok]] == v[:, None], axis=1)
            rows.append(3 * f_ok + k)
            cols.append(3 * g[f_ok] + gk)
    rows = np.concatenate(rows)
    cols = np.concatenate(cols)
    G = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(3 * m, 3 * m))
    _, lab = connected_components(G, directed=False)
    fans = np.zeros(n, dtype=np.int64)
    pairs = np.unique(np.c_[inc_vert, lab], axis=0)
    np.add.at(fans, pairs[:, 0], 1)
    del inc_face
    return np.flatnonzero(fans > 1)


__all__ = ["InputMesh", "load_input", "size_factor", "validate_surface", "check_size",
           "boundary_loops",
           "SizeWarning", "SUPPORTED"]
