"""Automatic sequencing landscape: which part of a target must close first.

Where the target lies over itself (the petals of a closed bud), a constant time landscape
makes every part close at once and the parts jam halfway.  The SI's answer is a time
landscape that closes the part underneath before the one on top: the paper's cover shell
closes its three petals at about 30, 48 and 78 s.  This module draws such a landscape from
the target alone:

1. **Facing pairs.**  Two vertices face each other when they are close in space
   (``reach_mm``) but far apart on the surface (over ``detour`` times further).
2. **Parts.**  The surface splits into lobes: watershed basins of the geodesic distance to
   the rim, merged across wide necks (0-dimensional persistence).  A pinwheel of petals gives
   one part per petal and one for the hub.
3. **Stacking.**  For each pair of parts that face each other, the generalized winding
   number of the target decides which one lies outside: the side of the outer sheet that
   faces away from the inner one is open (winding number near 0), the inner sheet's is
   enclosed.
4. **Order.**  Parts underneath close first: the parts take levels along the longest path of
   the "is under" graph (a cycle, which no order can satisfy, loses its weakest edge and is
   reported), spread evenly over ``times_s``; parts that face nothing close in the middle.

Every part closes at one time, as the paper's own cover landscape does.
"""

from __future__ import annotations

import igl
import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from ..core.machine import available_memory
from ..errors import InputError
from ..params import SEQUENCING, Sequencing

__all__ = ["edge_graph", "facing_pairs", "surface_parts", "stacking_order",
           "sequencing_landscape"]

_SOURCES_PER_SWEEP = 64  # Dijkstra rows at a time: bounds memory at 64 x n distances
_VOTES = 64  # facing pairs that vote on which of two parts lies outside


def _edges(F):
    """(k, 2) int unique edges (sorted ends) and (k,) int how many faces use each."""
    E = np.sort(np.asarray(F)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(E, axis=0, return_counts=True)


def edge_graph(V, F) -> sp.csr_matrix:
    """Edge-length graph of a triangle mesh.

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int

    Returns
    -------
    G : (n, n) sparse float, mm -- symmetric, ``G[i, j]`` = length of edge ij
    """
    V = np.asarray(V, float)
    E, _ = _edges(F)
    w = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    n = len(V)
    return sp.coo_matrix((np.r_[w, w], (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])),
                         shape=(n, n)).tocsr()


def check_pair_memory(tree, n_faces: int, reach: float,
                      settings: Sequencing = SEQUENCING) -> int:
    """Estimate the vertex pairs within ``reach`` (from a sample of vertices) and refuse a
    mesh whose pair search would not fit in memory, before it starts (the pairs grow with
    the square of the mesh density).

    Parameters
    ----------
    tree : scipy.spatial.cKDTree -- of the (n, 3) vertices, mm
    n_faces : int
    reach : float, mm

    Returns
    -------
    int -- estimated number of pairs

    Raises
    ------
    InputError
        Naming the faces, the memory needed and available, and the number of faces that
        would fit.
    """
    n = tree.n
    idx = np.unique(np.linspace(0, n - 1, min(n, settings.estimate_samples)).astype(int))
    per_vertex = tree.query_ball_point(tree.data[idx], reach, return_length=True) - 1
    pairs = int(n * float(np.mean(per_vertex)) / 2) if n else 0
    need = pairs * settings.bytes_per_pair
    budget = settings.memory_fraction * available_memory()
    if need > budget:
        fit = int(n_faces * np.sqrt(budget / need))
        raise InputError(
            f"the input mesh has {n_faces} faces, too dense for the sequencing landscape: "
            f"finding which parts of the target face each other would hold about "
            f"{pairs:.3g} vertex pairs ({need / 1e9:.1f} GB), and {budget / 1e9:.1f} GB of "
            "memory may be used.",
            fix=f"decimate the mesh to at most {fit} faces (the design's stencil has at most a "
                "few thousand vertices, so nothing is lost; e.g. MeshLab's Quadric Edge "
                "Collapse Decimation), or give the time landscape (--time or --time-file), "
                "which skips this step.")
    return pairs


def facing_pairs(V, F, reach: float, detour: float, G=None) -> np.ndarray:
    """Vertex pairs close in space but far apart on the surface.

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    reach : float, mm
        Largest distance in space.
    detour : float
        Smallest ratio of the path on the surface (along edges) to the distance in space.
    G : (n, n) sparse, optional
        :func:`edge_graph` of the mesh, if at hand.

    Returns
    -------
    pairs : (k, 2) int -- ``i < j``, sorted
    """
    V = np.asarray(V, float)
    tree = cKDTree(V)
    check_pair_memory(tree, len(np.asarray(F)), reach)
    G = edge_graph(V, F) if G is None else G
    pairs = tree.query_pairs(reach, output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros((0, 2), int)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    d = np.linalg.norm(V[pairs[:, 0]] - V[pairs[:, 1]], axis=1)
    path = np.empty(len(pairs))
    sources = np.unique(pairs[:, 0])
    for k in range(0, len(sources), _SOURCES_PER_SWEEP):
        chunk = sources[k:k + _SOURCES_PER_SWEEP]
        D = csgraph.dijkstra(G, indices=chunk, limit=detour * reach)
        sel = (pairs[:, 0] >= chunk[0]) & (pairs[:, 0] <= chunk[-1])
        path[sel] = D[np.searchsorted(chunk, pairs[sel, 0]), pairs[sel, 1]]
    return pairs[path > detour * d]


def _rim_distance(G, F) -> np.ndarray:
    """(n,) float, mm: distance along edges to the nearest rim vertex."""
    edges, count = _edges(F)
    rim = np.unique(edges[count == 1])
    if len(rim) == 0:  # a closed surface: no lobes
        return np.zeros(G.shape[0])
    return csgraph.dijkstra(G, indices=rim, min_only=True)


def surface_parts(V, F, saddle_ratio: float, G=None) -> np.ndarray:
    """Split the surface into lobes: the basins of the distance to the rim.

    Vertices are visited from the deepest inward (union-find).  Where two basins meet, the
    shallower one joins the deeper when the meeting point (the neck's half-width) is at least
    ``saddle_ratio`` of its own depth (its half-width); otherwise both stay parts of their
    own.  Written out here because watershed tools (scikit-image) work on pixel grids, not on
    the edges of a mesh.

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    saddle_ratio : float, in (0, 1]
    G : (n, n) sparse, optional -- :func:`edge_graph`

    Returns
    -------
    part : (n,) int -- parts numbered 0, 1, ... in the order of their deepest vertex
    """
    G = edge_graph(V, F) if G is None else G
    depth = _rim_distance(G, F)
    n = len(depth)
    parent = np.arange(n)
    peak = depth.copy()
    seen = np.zeros(n, bool)

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    indptr, indices = G.indptr, G.indices
    for v in np.lexsort((np.arange(n), -depth)):  # deepest first, ties by index
        roots = sorted({find(u) for u in indices[indptr[v]:indptr[v + 1]] if seen[u]},
                       key=lambda r: (-peak[r], r))
        seen[v] = True
        if not roots:
            continue
        main = roots[0]
        parent[v] = main
        for r in roots[1:]:
            if depth[v] >= saddle_ratio * peak[r]:
                parent[r] = main
    roots = np.array([find(v) for v in range(n)])
    order = {r: k for k, r in enumerate(sorted(set(roots.tolist()), key=lambda r: (-peak[r], r)))}
    return np.array([order[r] for r in roots])


def stacking_order(V, F, pairs, part, min_pairs: int):
    """Which part lies under which, from facing pairs.

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    pairs : (k, 2) int -- :func:`facing_pairs`
    part : (n,) int -- :func:`surface_parts`
    min_pairs : int -- fewer facing pairs between two parts are ignored

    Returns
    -------
    under : list of (inner, outer, pairs) -- part ``inner`` lies under part ``outer``
    within : int -- facing pairs inside one part (no per-part order can separate them)
    """
    V = np.asarray(V, float)
    a, b = part[pairs[:, 0]], part[pairs[:, 1]]
    within = int(np.sum(a == b))
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    under = []
    between = np.unique(np.c_[lo, hi][lo != hi], axis=0)
    for p, q in between.tolist():
        idx = np.flatnonzero((lo == p) & (hi == q))
        if len(idx) < min_pairs:
            continue
        vote = idx[np.linspace(0, len(idx) - 1, min(_VOTES, len(idx))).astype(int)]
        i, j = pairs[vote, 0], pairs[vote, 1]
        u = V[j] - V[i]
        eps = 0.25 * u  # a quarter of the way beyond each sheet, away from the other
        wi = np.abs(igl.winding_number(V, F, V[i] - eps))
        wj = np.abs(igl.winding_number(V, F, V[j] + eps))
        j_outer = wj < wi  # the open side is the outer sheet's
        q_outer = np.mean(np.where(part[j] == q, j_outer, ~j_outer)) >= 0.5
        under.append((p, q, len(idx)) if q_outer else (q, p, len(idx)))
    return under, within


def _levels(n_parts: int, under):
    """Longest-path levels of the "is under" graph, after dropping the weakest edge of each
    cycle (edges whose ends share a strongly connected component) until none is left.

    Returns
    -------
    level : (n_parts,) int, -1 for parts under or over nothing
    dropped : list of (inner, outer, pairs)
    """
    edges = sorted(under, key=lambda e: (-e[2], e[0], e[1]))  # strongest first
    dropped = []
    while edges:
        ij = np.array([e[:2] for e in edges]).T
        A = sp.coo_matrix((np.ones(len(edges)), (ij[0], ij[1])), shape=(n_parts, n_parts))
        _, scc = csgraph.connected_components(A, directed=True, connection="strong")
        in_cycle = [e for e in edges if scc[e[0]] == scc[e[1]]]
        if not in_cycle:
            break
        dropped.append(in_cycle[-1])
        edges.remove(in_cycle[-1])
    level = np.zeros(n_parts, int)
    for _ in range(n_parts):  # a DAG's longest paths settle within n_parts relaxations
        for p, q, _ in edges:
            level[q] = max(level[q], level[p] + 1)
    involved = {p for e in edges for p in e[:2]}
    level[[p for p in range(n_parts) if p not in involved]] = -1
    return level, dropped


def sequencing_landscape(V, F, settings: Sequencing = SEQUENCING):
    """A time landscape that closes the parts of a target underneath before those on top.

    Parameters
    ----------
    V : (n, 3) float, mm -- target surface
    F : (m, 3) int
    settings : pysolver.params.Sequencing

    Returns
    -------
    t : (n,) float, s, or None -- None when no part of the target lies over another
    info : dict -- ``parts``, ``order`` (list of [inner, outer, facing pairs]), ``levels``,
        ``dropped`` (edges of cycles), ``within`` (facing pairs no order separates),
        ``description``
    """
    V = np.asarray(V, float)
    F = np.asarray(F, np.int64)
    G = edge_graph(V, F)
    pairs = facing_pairs(V, F, settings.reach_mm, settings.detour, G=G)
    info = {"facing_pairs": int(len(pairs))}
    if len(pairs) < settings.min_pairs:
        return None, dict(info, description="no part of the target lies over another")
    part = surface_parts(V, F, settings.saddle_ratio, G=G)
    under, within = stacking_order(V, F, pairs, part, settings.min_pairs)
    n_parts = int(part.max()) + 1
    level, dropped = _levels(n_parts, under)
    info.update(parts=n_parts, order=[list(e) for e in under if e not in dropped],
                dropped=[list(e) for e in dropped], within=within)
    if level.max() <= 0:
        return None, dict(info, description="overlaps within single parts only: "
                                            "no order of parts separates them")
    t0, t1 = (float(x) for x in settings.times_s)
    t_level = t0 + (t1 - t0) * level / level.max()
    t_level[level < 0] = 0.5 * (t0 + t1)
    info["levels"] = level.tolist()
    info["part_times_s"] = t_level.round(3).tolist()
    info["description"] = (f"automatic sequencing: {n_parts} parts, "
                           f"{len(info['order'])} lie under others, closing "
                           f"{t0:g}-{t1:g} s in {level.max() + 1} steps")
    return t_level[part], info
