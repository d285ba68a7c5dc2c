"""The latex margin kept at the rim of a fabricated shell (SI Note 5 steps 6-7; issues #18, #32).

Glue is spread on the latex around the lattice "in order to freeze it", then the sheet is
released from stretch 3 to about 2 and the shell is cut out, "keeping a tiny amount of
degenerated latex at the border".  :func:`rim_margin` adds that margin to a flat membrane mesh
and :func:`margin_rest` gives its rest state: frozen by the glue at the flat shape (no
pre-stress, ``rim_stretch`` = 1) and holding the latex of the sheet stretched by ``tau``.  The
shell model (:func:`.model.build_model`, ``PhysicsOptions.rim``) and the ``F_mem`` correction
of the design (:func:`pysolver.temporal.membrane_model.cell_membrane_factors`) both use them.
"""

from __future__ import annotations

import numpy as np


def rim_margin(xy, tris, body, base_xy, base_r, width):
    """Add the latex margin kept at the border when the shell is cut out (SI Note 5 step 7).

    The outer boundary loop of the membrane mesh (the CCW loop of largest area) is offset
    outward by ``width`` (vertex normals = normalised sum of the two edge normals, the offset
    divided by the cosine of the half turn, at most 2 ``width``) and the strip is split into
    two triangles per edge.  New vertices lying inside a base disc are glued to that base
    (the margin runs under the boundary bases), the others are free.

    Parameters
    ----------
    xy : (v, 2) float, mm
    tris : (t, 3) int, CCW
    body : (v,) int -- base of each vertex, -1 free
    base_xy : (m, 2) float, mm -- flat base centres
    base_r : float, mm
    width : float, mm

    Returns
    -------
    xy, tris, body : the membrane with the strip appended (old ids unchanged)
    margin : (t',) bool -- triangle belongs to the margin
    """
    e = np.r_[tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]
    key = np.minimum(e[:, 0], e[:, 1]) * len(xy) + np.maximum(e[:, 0], e[:, 1])
    uk, cnt = np.unique(key, return_counts=True)
    bnd = e[np.isin(key, uk[cnt == 1])]  # directed boundary edges, interior on the left
    nxt = -np.ones(len(xy), dtype=np.int64)
    nxt[bnd[:, 0]] = bnd[:, 1]
    seen = np.zeros(len(xy), bool)
    best, best_area = None, -np.inf
    for v0 in bnd[:, 0]:
        if seen[v0]:
            continue
        loop = [v0]
        seen[v0] = True
        while nxt[loop[-1]] != v0 and not seen[nxt[loop[-1]]]:
            loop.append(int(nxt[loop[-1]]))
            seen[loop[-1]] = True
        P = xy[loop]
        area = 0.5 * np.sum(P[:, 0] * np.roll(P[:, 1], -1) - np.roll(P[:, 0], -1) * P[:, 1])
        if area > best_area:
            best, best_area = np.array(loop), area
    P = xy[best]
    d = np.roll(P, -1, axis=0) - P
    n = np.c_[d[:, 1], -d[:, 0]] / np.linalg.norm(d, axis=1)[:, None]  # outward edge normals
    vn = n + np.roll(n, 1, axis=0)
    vn /= np.linalg.norm(vn, axis=1)[:, None]
    cos_half = np.maximum(np.einsum("ij,ij->i", vn, n), 0.5)
    off = P + vn * (width / cos_half)[:, None]
    k = len(best)
    new = len(xy) + np.arange(k)
    a, b = best, np.roll(best, -1)
    na, nb = new, np.roll(new, -1)
    strip = np.r_[np.c_[a, na, nb], np.c_[a, nb, b]]
    dist = np.linalg.norm(off[:, None, :] - base_xy[None], axis=2)
    inside = dist.min(axis=1) < base_r
    nbody = np.where(inside, dist.argmin(axis=1), -1)
    margin = np.r_[np.zeros(len(tris), bool), np.ones(len(strip), bool)]
    return np.r_[xy, off], np.r_[tris, strip], np.r_[body, nbody], margin


def margin_rest(margin, tau, rim_stretch):
    """Rest state of the membrane triangles with the rim margin.

    The membrane's triangles rest at the flat mesh divided by the sheet's pre-stretch
    ``tau``.  The margin's rest is the flat mesh divided by ``rim_stretch`` (1: frozen by
    the glue at its flat shape), and it holds the latex of the sheet stretched by ``tau``:
    its rest area is scaled by ``(rim_stretch / tau)^2``, so its material (thickness times
    rest area) is the stretched sheet's, ``membrane_h / tau^2`` per flat area.

    Parameters
    ----------
    margin : (t,) bool -- triangle belongs to the margin
    tau : float -- the sheet's pre-stretch
    rim_stretch : float -- pre-stretch the margin keeps (1 <= rim_stretch)

    Returns
    -------
    stretch : (t,) float -- divisor of the flat edge vectors giving the rest shape
    area_factor : (t,) float -- factor on the rest area of that shape (1 off the margin)
    """
    margin = np.asarray(margin, bool)
    stretch = np.where(margin, float(rim_stretch), float(tau))
    area_factor = np.where(margin, (float(rim_stretch) / float(tau)) ** 2, 1.0)
    return stretch, area_factor


__all__ = ["rim_margin", "margin_rest"]
