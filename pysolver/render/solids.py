"""Solids of the render stage: STL meshes to and from manifold3d, unions, body counts."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..errors import ExternalToolError


def load_stl(path):
    """Load an STL as a vertex-merged trimesh."""
    import trimesh  # heavy: trimesh loads only for STL work

    return trimesh.load_mesh(str(path), file_type="stl", process=True)


def to_manifold(mesh, what: str = "mesh"):
    """manifold3d solid of a trimesh (float64 vertices).

    Raises
    ------
    ExternalToolError
        If the mesh is not a closed 2-manifold (a broken OpenSCAD output).
    """
    import manifold3d  # heavy: manifold3d loads only for STL booleans

    m = manifold3d.Manifold(manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(mesh.vertices, dtype=np.float64),
        tri_verts=np.ascontiguousarray(mesh.faces, dtype=np.uint64)))
    if m.status() != manifold3d.Error.NoError:
        raise ExternalToolError(f"{what} is not a closed 2-manifold ({m.status().name}).",
                                fix="delete the part cache folder and render again; if it "
                                    "persists, the library edit produces self-touching geometry.")
    return m


def from_manifold(m):
    """trimesh of a manifold3d solid."""
    import trimesh  # heavy: trimesh loads only for STL work

    mesh = m.to_mesh64()
    V = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    F = np.asarray(mesh.tri_verts, dtype=np.int64)
    return trimesh.Trimesh(V, F, process=False)


def as_float32(mesh):
    """A trimesh as an STL stores it: vertices rounded to float32 and welded where they then
    coincide, and the triangles that collapse there dropped (zero area).  Written as they
    were, the collapsed ones made non-manifold edges: two vertices of a spiral design's
    ``actuated.stl`` 1e-6 mm apart, where a V end of one node met the neighbour's rim
    (``EXPORT_SIMPLIFY_MM``).  Without a collapse the triangles are the same, in the same
    order."""
    import trimesh  # heavy: trimesh loads only for STL work

    V, inv = np.unique(np.asarray(mesh.vertices).astype(np.float32), axis=0,
                       return_inverse=True)
    F = inv.reshape(-1)[np.asarray(mesh.faces)]
    keep = (F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])
    return trimesh.Trimesh(V.astype(np.float64), F[keep], process=False)


def union(solids):
    """Boolean union of a list of manifold3d solids."""
    import manifold3d  # heavy: manifold3d loads only for STL booleans

    if not solids:
        return manifold3d.Manifold()
    return manifold3d.Manifold.batch_boolean(list(solids), manifold3d.OpType.Add)


def affine_rows(T):
    """3x4 list-of-rows of a 4x4 transform, for Manifold.transform."""
    return [list(map(float, row)) for row in np.asarray(T, float)[:3, :4]]


def count_bodies(m) -> int:
    """Separate solids of a manifold3d solid: its triangles joined across shared edges, the
    components that ``Manifold.decompose`` splits it into.  (Counted on the mesh because
    ``decompose`` builds every part as a new solid: 1.8 s for the 400 nodes of petal's
    ``actuated.stl``, 0.05 s here.)"""
    if m.is_empty():
        return 0
    mesh = from_manifold(m)
    adj = mesh.face_adjacency
    n = len(mesh.faces)
    graph = coo_matrix((np.ones(len(adj)), (adj[:, 0], adj[:, 1])), shape=(n, n))
    return int(connected_components(graph, directed=False)[0])


def describe_stl(path, m) -> dict:
    """Figures of one written STL: watertight (as re-read from the file), bodies, volume, bbox."""
    mesh = load_stl(path)
    return {"watertight": bool(mesh.is_watertight and mesh.is_volume),
            "bodies": count_bodies(m),
            "volume_mm3": float(m.volume()),
            "bbox_mm": np.asarray(mesh.bounds, float).round(6).tolist(),
            "triangles": int(len(mesh.faces))}


__all__ = ["load_stl", "to_manifold", "from_manifold", "as_float32", "union", "affine_rows",
           "count_bodies",
           "describe_stl"]
