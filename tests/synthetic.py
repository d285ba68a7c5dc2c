"""Test fixtures: small synthetic shells and a stand-in bracket model (tests and benchmarks).

* :func:`regular_stencil` -- a rectangular patch of equilateral triangles (the reference's
  ``init_regular``), flat or mapped onto a spherical cap, scaled by
  :func:`pysolver.design.layout.build_layout` exactly as a design would be.
* :func:`single_cell_stencil` -- two triangles (one unit cell) with a chosen flat and target
  central length.
* :class:`StandInBracketModel` -- a smooth made-up force law with the interface of
  :class:`pysolver.material.model.BracketModel` (``coefficients(h, b, t, eta)``), used when a
  test must not depend on the fitted model file.  It is **not** a material model.
"""

from __future__ import annotations

import numpy as np

from pysolver.design.surfaces import regular_grid
from pysolver.params import UNIT_CELL


def cap_map(UV, radius: float, bulge: int = 1):
    """Map flat points onto a spherical cap (azimuthal equidistant; lengths ~ preserved).

    Parameters
    ----------
    UV : (n, 2) float
    radius : float
        Sphere radius (same unit as UV); ``inf`` gives the flat plane.
    bulge : int
        +1: the cap bulges toward +z (face normals of CCW faces point outward, so the
        top layer is on the convex side); -1: toward -z (top layer concave).

    Returns
    -------
    V : (n, 3) float
    """
    UV = np.asarray(UV, float)
    c = UV - UV.mean(axis=0)
    if not np.isfinite(radius):
        return np.c_[c, np.zeros(len(c))]
    rho = np.linalg.norm(c, axis=1)
    phi = rho / radius
    safe = np.where(rho > 0, rho, 1.0)
    xy = (radius * np.sin(phi) / safe)[:, None] * c
    z = bulge * (radius * np.cos(phi) - radius)
    return np.c_[xy, z]


def regular_stencil(nx: int = 5, ny: int = 4, *, central_length: float = 6.0,
                    radius: float = np.inf, bulge: int = 1):
    """A scaled regular stencil: flat layout plus a flat or spherical-cap target.

    The stencil goes through :func:`pysolver.design.layout.build_layout` (3D min-bumper scaling,
    flat layout scaled so that the shortest flat central length is ``central_length``).

    Returns
    -------
    layout : pysolver.design.layout.Layout
        ``V``, ``UV``, ``F`` (mm), ``rotvec``, ``cells`` ...
    """
    from pysolver.design.layout import build_layout

    UV, F = regular_grid(nx, ny, 1.0)
    V = cap_map(UV, radius, bulge)
    return build_layout(V, UV, F, central_length=central_length, enforce_gap=False)


def single_cell_stencil(flat_length: float = 6.0, target_length: float = 4.8):
    """Two equilateral triangles sharing an edge (one unit cell).

    Parameters
    ----------
    flat_length, target_length : float, mm
        Flat and target distance of the two face centroids (target is the flat rhombus
        scaled, so the cell is straight: no fold).

    Returns
    -------
    V : (4, 3) float, mm
    UV : (4, 2) float, mm
    F : (2, 3) int
    """
    e = flat_length * np.sqrt(3)  # centroid distance of two equilateral triangles = e / sqrt 3
    h = e * np.sqrt(3) / 2
    UV = np.array([[0.0, -e / 2], [0.0, e / 2], [-h, 0.0], [h, 0.0]])
    F = np.array([[0, 1, 2], [1, 0, 3]], dtype=np.int64)
    V = np.c_[UV * (target_length / flat_length), np.zeros(4)]
    return V, UV, F


def write_design(out_dir, layout, thickness=0.45, t_star: float = 60.0):
    """Write a design folder for a layout (tests, benchmarks): tables + stencil, no pictures.

    Parameters
    ----------
    out_dir : path-like
    layout : pysolver.design.layout.Layout
        E.g. from :func:`regular_stencil`.
    thickness : float or (c, 2) array, mm
        Bracket thickness per cell and layer (top, bottom).
    t_star : float, s
        Programmed time written to the tables (not used by the simulator).

    Returns
    -------
    pathlib.Path
    """
    from pathlib import Path

    from pysolver.design import write_design_tables
    from pysolver.design.cellnodes import bracket_nodes, collision_lengths

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    nt, _ = bracket_nodes(layout.V, layout.UV, layout.F, rotvec=layout.rotvec)
    coll = collision_lengths(nt, layout.cells)
    nc = len(layout.cells.faces)
    th = np.broadcast_to(np.asarray(thickness, float), (nc, 2)).copy()
    write_design_tables(out, layout, coll, np.full(len(layout.V), t_star), np.full(nc, t_star),
                        th)
    return out


class StandInBracketModel:
    """Made-up bracket force law with the fitted model's interface (tests only).

    ``F(x) = k (x - x^2 / (2 b))`` per bracket (monotone and concave on [0, b]) with stiffness
    ``k = k_dry (h / 0.45)^3 (2.8 / b)^2 / (1 + (t / T)^3)``, ``T = t_soft (h / 0.45)^2``:
    stiff when dry, softening in water, thicker brackets soften later.

    Parameters
    ----------
    k_dry : float, N/mm
        Dry stiffness of a 0.45 mm thick, 2.8 mm long bracket.
    t_soft : float, s
        Softening time of a 0.45 mm bracket.
    """

    def __init__(self, k_dry: float = 6.0, t_soft: float = 30.0):
        self.k_dry = float(k_dry)
        self.t_soft = float(t_soft)

    def stiffness0(self, h_mm, b_mm, t_s):
        h, b, t = np.broadcast_arrays(*(np.asarray(v, float) for v in (h_mm, b_mm, t_s)))
        T = self.t_soft * (h / 0.45) ** 2
        return self.k_dry * (h / 0.45) ** 3 * (2.8 / b) ** 2 / (1.0 + (t / T) ** 3)

    def coefficients(self, h_mm, b_mm, t_s, eta: float = 0.0):
        """Force coefficients of x^1..x^4, shape (..., 4); ``eta`` gives ``F(x / (1 - eta))``."""
        h, b, t = np.broadcast_arrays(*(np.asarray(v, float) for v in (h_mm, b_mm, t_s)))
        k = self.stiffness0(h, b, t)
        c = np.stack([k, -k / (2 * b), np.zeros_like(k), np.zeros_like(k)], axis=-1)
        if eta:
            c = c / (1.0 - eta) ** np.arange(1, 5)
        return c

    def force(self, h_mm, b_mm, t_s, x_mm, eta: float = 0.0):
        c = self.coefficients(h_mm, b_mm, t_s)
        x = np.asarray(x_mm, float) / (1.0 - eta)
        return x * (c[..., 0] + x * (c[..., 1] + x * (c[..., 2] + x * c[..., 3])))

    def __repr__(self) -> str:
        return f"StandInBracketModel(k_dry={self.k_dry}, t_soft={self.t_soft})"


def default_bracket_offset() -> float:
    """l - b = 2 base_r cos(alpha) (mm)."""
    return UNIT_CELL.bracket_offset


__all__ = ["regular_grid", "cap_map", "regular_stencil", "single_cell_stencil", "write_design",
           "StandInBracketModel"]
