"""Read and validate user target surfaces (OBJ, STL, PLY, OFF) and stencil OBJs.

:func:`load_input` returns an :class:`InputMesh`.  An OBJ with one ``vt`` per ``v``
(row-aligned, or one-to-one ``v/vt`` face corners) is a **stencil**: its vertex and
face order are kept and ``UV`` is its flat layout.  Everything else is a target surface
(vertex order kept with ``process=False``; STL vertices are merged).

:func:`validate_surface` refuses, with an actionable message, anything that cannot be
a shell: empty or corrupt files, unsupported formats, NaN/inf, degenerate triangles,
non-manifold edges or vertices, inconsistent orientation, several components, closed
surfaces, holes and handles (the surface must be a topological disk), and sizes that
are implausible in millimetres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import igl
import numpy as np

from .errors import InputError

SUPPORTED = (".obj", ".stl", ".ply", ".off")
# a shell smaller or larger than this (bounding-box diagonal, mm) is probably in other units
MIN_SIZE_MM, MAX_SIZE_MM = 20.0, 2000.0
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
    """

    V: np.ndarray
    F: np.ndarray
    UV: np.ndarray | None = None
    vertex_attributes: dict = field(default_factory=dict)
    colors: np.ndarray | None = None
    path: Path | None = None
    kind: str = "mesh"
    notes: list = field(default_factory=list)

    def transformed(self, shift, scale: float) -> InputMesh:
        """Copy with ``V' = (V + shift) * scale`` (to follow the stencil's centring/scaling)."""
        return InputMesh((self.V + np.asarray(shift)) * scale, self.F, self.UV,
                         self.vertex_attributes, self.colors, self.path, self.kind, self.notes)


def _obj_has_vt(path: Path) -> bool:
    with open(path, errors="replace") as fh:
        for line in fh:
            if line.startswith("vt "):
                return True
    return False


def _read_trimesh(path: Path):
    import trimesh

    ext = path.suffix.lower()
    try:
        m = trimesh.load(str(path), force="mesh", process=(ext == ".stl"))
    except Exception as e:  # noqa: BLE001 - any parser failure is a corrupt file
        raise InputError(f"{path}: cannot read the {ext[1:].upper()} file ({type(e).__name__}: "
                         f"{e})", fix="check that the file is a valid, complete mesh export") \
            from None
    if not hasattr(m, "faces") or m.faces is None or len(m.faces) == 0:
        raise InputError(f"{path}: no triangles found (empty or point-cloud file)",
                         fix="export the surface as a triangle mesh")
    return m


def load_input(path, scale: float = 1.0, validate: bool = True) -> InputMesh:
    """Load a target surface or a stencil OBJ.

    Parameters
    ----------
    path : str or Path
    scale : float
        Factor applied to the coordinates (e.g. 10 for a mesh in cm).
    validate : bool
        Run :func:`validate_surface`.

    Returns
    -------
    InputMesh
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: file not found")
    ext = path.suffix.lower()
    if ext not in SUPPORTED:
        raise InputError(f"{path}: unsupported format {ext or '(no extension)'!r}",
                         fix=f"export the surface as one of {', '.join(SUPPORTED)}")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: empty file", fix="re-export the mesh")
    notes = []
    if ext == ".obj" and _obj_has_vt(path):
        from .tables import read_stencil

        try:
            V, UV, F = read_stencil(path)
            mesh = InputMesh(V * scale, F, None if UV is None else UV * scale, path=path,
                             kind="stencil" if UV is not None else "mesh")
            if validate:
                validate_surface(mesh.V, mesh.F, str(path))
            return mesh
        except InputError as e:
            if "seam" not in e.problem:
                raise
            notes.append("vt ignored: the texture layout has seams (not a stencil)")
    m = _read_trimesh(path)
    V = np.asarray(m.vertices, float) * scale
    F = np.asarray(m.faces, dtype=np.int64)
    attrs = {}
    raw = getattr(m, "metadata", {}).get("_ply_raw") if ext == ".ply" else None
    if raw is not None and "vertex" in raw:
        data = raw["vertex"]["data"]
        names = getattr(getattr(data, "dtype", None), "names", None) or ()
        for nm in names:
            if nm not in _PLY_STANDARD and data[nm].ndim == 1 and len(data[nm]) == len(V):
                attrs[nm] = np.asarray(data[nm], float)
    colors = None
    vis = getattr(m, "visual", None)
    if vis is not None and getattr(vis, "kind", None) == "vertex":
        colors = np.asarray(vis.vertex_colors, float)[:, :3] / 255.0
    # drop unreferenced vertices (keeping the order of the others)
    used = np.unique(F)
    if len(used) < len(V):
        notes.append(f"{len(V) - len(used)} unreferenced vertices removed")
        remap = -np.ones(len(V), dtype=np.int64)
        remap[used] = np.arange(len(used))
        V, F = V[used], remap[F]
        attrs = {k: v[used] for k, v in attrs.items()}
        colors = None if colors is None else colors[used]
    mesh = InputMesh(V, F, None, attrs, colors, path, "mesh", notes)
    if validate:
        validate_surface(mesh.V, mesh.F, str(path))
    return mesh


def boundary_loops(F) -> list[np.ndarray]:
    """All boundary loops (vertex index arrays, in face orientation order), longest first.

    Hand-written walk over the directed boundary edges (this libigl build has only
    ``boundary_loop``, which returns the longest loop).  Assumes manifold vertices.
    """
    from .layout import face_adjacency

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


def validate_surface(V, F, name: str = "surface") -> None:
    """Check that (V, F) is one connected, oriented, manifold topological disk in mm.

    Raises
    ------
    InputError
        Naming the problem and where it is, with a fix.
    """
    from .layout import face_adjacency

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
    diag = float(np.linalg.norm(np.ptp(V, axis=0)))
    if diag < MIN_SIZE_MM:
        k = 10.0 if diag * 10 >= MIN_SIZE_MM else 1000.0
        raise InputError(f"{name}: the surface is only {diag:.3g} mm across (bounding-box "
                         "diagonal); coordinates must be millimetres",
                         fix=f"give scale={k:g} (the mesh is probably in "
                             f"{'cm' if k == 10 else 'm'}) or scale it in your modeller")
    if diag > MAX_SIZE_MM:
        raise InputError(f"{name}: the surface is {diag:.4g} mm across; that is implausibly "
                         "large for a printed shell (coordinates must be millimetres)",
                         fix="give scale=0.1 or 0.001 if the mesh is in 0.1 mm or micrometres, "
                             "or scale it down")
    dup = np.any(F[:, [0, 1, 2]] == F[:, [1, 2, 0]], axis=1)
    area2 = igl.doublearea(V, F)
    degenerate = np.flatnonzero(dup | (area2 <= 1e-10 * diag**2))
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
    ff = face_adjacency(F)  # raises on non-manifold edges / inconsistent orientation
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
            msgs.append(f"hole around {_fmt_pt(c)} (cut from it to the rim near "
                        f"{_fmt_pt(V[j])})")
        raise InputError(f"{name}: the surface has {b - 1} hole(s): " + "; ".join(msgs),
                         fix="fill the holes, or cut from each hole to the outer boundary so "
                             "the surface becomes a disk")


def _nonmanifold_vertices(F, ff, n) -> np.ndarray:
    """Vertices whose incident faces are not connected through shared edges (bow-ties)."""
    import scipy.sparse as sp
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


__all__ = ["InputMesh", "load_input", "validate_surface", "boundary_loops", "SUPPORTED"]
