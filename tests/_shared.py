"""Small helpers shared by several test files (meshes, section measurements)."""

from __future__ import annotations

import numpy as np
import trimesh


def flat_grid(n: int = 8, size: float = 40.0):
    """Flat n x n grid of right triangles, size x size mm, CCW (normals +z).

    Returns
    -------
    V : (n*n, 3) float, mm
    F : (2 (n-1)^2, 3) int
    """
    X, Y = np.meshgrid(np.linspace(0, size, n), np.linspace(0, size, n))
    V = np.c_[X.ravel(), Y.ravel(), np.zeros(n * n)]
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1
            F += [[a, b, d], [a, d, c]]
    return V, np.array(F)


def save_mesh(path, V, F):
    """Write a mesh as-is (no merging or repair) in the format of ``path``'s suffix."""
    trimesh.Trimesh(V, F, process=False).export(path)
    return path


def section_width(seg, m, w):
    """Width of a 2D section around point m along direction w: nearest wall crossings either side.

    seg : (k, 2, 2) float, mm -- the section's boundary segments; m : (2,) mm; w : (2,) unit.
    Returns the width in mm, or None if m is not enclosed along w.
    """
    p, d = seg[:, 0], seg[:, 1] - seg[:, 0]
    den = w[0] * d[:, 1] - w[1] * d[:, 0]
    ok = np.abs(den) > 1e-12
    r = p - m
    s = (r[:, 0] * d[:, 1] - r[:, 1] * d[:, 0]) / np.where(ok, den, 1)
    t = (r[:, 0] * w[1] - r[:, 1] * w[0]) / np.where(ok, den, 1)
    s = s[ok & (t >= -1e-9) & (t <= 1 + 1e-9)]
    if not (np.any(s > 0) and np.any(s < 0)):
        return None
    return s[s > 0].min() - s[s < 0].max()
