"""A candidate stencil, its figures, and the rules that choose among candidates.

A candidate of the count search is named by a :class:`Candidate` (vertex count, CVT seed,
rim inset) and measured by its *figures* (:func:`stencil_figures`: a dict, recorded as it is
in ``design.json``).  The rules the search applies to figures are stated here once:

* :func:`laid_out` -- the layout rules gave the stencil a layout;
* :func:`at_size` -- its 3D scaling keeps the size asked for (the band the search looks in);
* :func:`full_size` -- its 3D scaling is 1 within the polish's tolerance;
* :func:`prints` -- its longest flat cell is within the limit, or ``margin`` below it
  ("prints with the margin");
* :func:`pick` -- the pick among the candidates tried (the count search's choice).

Examples
--------
>>> from pysolver.params import UNIT_CELL
>>> c = {"scale3d": 0.99, "max_cell_length_mm": UNIT_CELL.max_cell_length - 0.1}
>>> prints(c, UNIT_CELL), prints(c, UNIT_CELL, margin=0.5), at_size(c)
(True, False, True)
>>> sorted([Candidate(120, 1, 0.0), Candidate(96, 2, 0.0), Candidate(96, 0, 1.5)])[0]
Candidate(vertices=96, seed=0, inset_mm=1.5)
"""

from __future__ import annotations

from dataclasses import dataclass

import igl
import numpy as np

from ...errors import InputError
from ...params import STENCIL, UNIT_CELL, StencilSearch, UnitCell
from ..flatten import cetm
from ..layout import build_layout
from ..time_landscape import cell_target_times
from .optimise import estimated_clamping, layout_timing_terms
from .remesh import surface_area


@dataclass(frozen=True, order=True)
class Candidate:
    """One stencil the count search tried: its vertex count, CVT seed and rim inset.

    Ordered as the tuple ``(vertices, seed, inset_mm)``: the search's ties are broken by it.

    Attributes
    ----------
    vertices : int
        The vertex count asked for (the stencil may have a few fewer: ears removed).
    seed : int
        The CVT initialisation's seed.
    inset_mm : float, mm
        How far inside the target's rim the stencil's rim lies (0: on the rim).
    """

    vertices: int
    seed: int
    inset_mm: float

    def __post_init__(self):
        object.__setattr__(self, "vertices", int(self.vertices))
        object.__setattr__(self, "seed", int(self.seed))
        object.__setattr__(self, "inset_mm", float(self.inset_mm))


def stencil_figures(V, F, params: UnitCell = UNIT_CELL, time=None,
                    settings: StencilSearch = STENCIL, u_boundary=None) -> dict:
    """Layout margins and regularity of a stencil (its CETM layout after both scaling rules).

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    params : UnitCell
    time : (n,) float, s, optional
        The time landscape at the stencil's vertices: adds ``clamped_estimate``.
    settings : StencilSearch
    u_boundary : (n,) float, optional
        The layout's boundary log-scale (:func:`pysolver.design.flatten.cetm`; default 0).

    Returns
    -------
    dict
        ``scale3d``; ``max_cell_length_mm``; (both None, and ``error``, when the layout fails);
        ``bumper_mm`` [min, max] target bumper length beyond the rim; ``edge_spread``
        (95th / 5th percentile of the 3D edge length, after scaling), ``min_angle_deg``
        (smallest 3D triangle angle); with ``time``, ``clamped_estimate``: the fraction of
        cells whose time the estimate of
        :func:`~pysolver.design.stencil.optimise.estimated_clamping` puts out of reach.
    """
    V = np.asarray(V, float)
    F = np.asarray(F, dtype=np.int64)
    E = igl.edges(F)
    edge = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    out = {"edge_spread": round(float(np.percentile(edge, 95) / np.percentile(edge, 5)), 4),
           "min_angle_deg": round(float(np.degrees(igl.internal_angles(V, F).min())), 2)}
    try:
        UV, _, _ = cetm(V, F, u_boundary=u_boundary)
        lay = build_layout(V, UV, F, params)
    except InputError as e:
        out.update(scale3d=None, max_cell_length_mm=None, bumper_mm=None,
                   error=str(e).splitlines()[0])
        return out
    bump = lay.bumpers.length - params.base_r
    out.update(scale3d=round(float(lay.scale3d), 6),
               max_cell_length_mm=round(float(lay.central_length.max()), 4),
               bumper_mm=[round(float(bump.min()), 4), round(float(bump.max()), 4)])
    if time is not None:
        c = lay.cells
        t_star = cell_target_times(np.asarray(time, float), c.verts[:, 0], c.verts[:, 1])
        out["clamped_estimate"] = round(estimated_clamping(
            *layout_timing_terms(lay), t_star, params, settings), 4)
    return out


def area_covered(V, F, area: float) -> float:
    """Fraction of the target's area ``area`` (mm^2) the stencil ``V`` (n, 3) mm, ``F``
    (m, 3) covers (its own 3D area over the target's; the stencil's flat triangles are chords
    of the target), rounded to 4 digits."""
    return round(surface_area(V, F) / area, 4)


# --------------------------------------------------------------------------------------
# the rules, each stated once


def laid_out(c: dict) -> bool:
    """Whether the figures ``c`` (:func:`stencil_figures`) are of a stencil that was laid out."""
    return c.get("max_cell_length_mm") is not None


def at_size(c: dict, settings: StencilSearch = STENCIL) -> bool:
    """Whether a laid-out candidate keeps the size asked for: its 3D scaling within
    ``[min_scale3d, 1 / min_scale3d]``."""
    return (laid_out(c) and settings.min_scale3d <= c["scale3d"]
            <= 1.0 / settings.min_scale3d)


def full_size(c: dict, settings: StencilSearch = STENCIL) -> bool:
    """Whether a laid-out stencil is delivered at the size asked for: its 3D scaling within
    ``polish_tolerance`` of 1 (the polish holds it there).  :func:`at_size`'s wider band is
    where the count search looks; only a stencil at full size is printed without the user
    asking for another size (``--size``)."""
    return laid_out(c) and abs(np.log(c["scale3d"])) <= settings.polish_tolerance


def prints(c: dict, params: UnitCell, margin: float = 0.0) -> bool:
    """Whether a laid-out candidate prints with the margin: its longest flat cell at least
    ``margin`` (mm; ``StencilSearch.margin`` where the search wants room, 0 for "within the
    limit") below ``UnitCell.max_cell_length``."""
    return laid_out(c) and c["max_cell_length_mm"] <= params.max_cell_length - margin


def prints_at_full_size(c: dict, params: UnitCell, settings: StencilSearch = STENCIL) -> bool:
    """Whether a polished stencil's figures ``c`` print at the size asked for: at full size
    (:func:`full_size`) with its longest flat cell within the limit (:func:`prints`)."""
    return full_size(c, settings) and prints(c, params)


def per_scale(c: dict) -> float:
    """A laid-out candidate's longest flat cell per unit of 3D scaling (mm): what the
    polish, holding the scaling, keeps."""
    return c["max_cell_length_mm"] / c["scale3d"]


def would_print_at_size(c: dict, params: UnitCell, settings: StencilSearch = STENCIL) -> bool:
    """Whether a candidate keeps the size asked for (:func:`at_size`) and would print held at
    scale 1 (:func:`per_scale` within the limit): what the pick and the polish's
    alternates look for."""
    return at_size(c, settings) and per_scale(c) <= params.max_cell_length


def tier(c: dict, params: UnitCell, margin: float) -> int:
    """0 when the candidate prints with ``margin`` (mm), 1 when within the limit, 2 otherwise
    (or when the layout failed)."""
    return 0 if prints(c, params, margin) else 1 if prints(c, params) else 2


def pick(tried: dict, params: UnitCell, margin: float,
         settings: StencilSearch | None = None, centres: dict | None = None):
    """The count search's pick among the candidates ``tried`` (:class:`Candidate` ->
    figures).

    Given ``centres`` (rim inset mm -> the counts the secant tried, the nearest a mean 3D
    scaling of 1 first), the candidates of the first of those counts that has any (one per
    seed) that keep the size asked for and would print held at scale 1 (:func:`per_scale`
    within the limit) come first, the shortest longest cell per unit of 3D scaling taken: the
    best of several starts, which is what the polish delivers, and no longer a choice among
    the seeds' scatter in scaling.  Otherwise: 3D scaling closest to 1
    among those that print with ``margin``; else within the limit; else the shortest longest
    cell per unit of 3D scaling (what the polish, holding the scaling, keeps: the longest
    cell alone favours the candidates that happen to be small, and its ties between
    candidates far apart in scaling moved with the last bits).  Given ``settings``,
    candidates that keep the size asked for (:func:`at_size`) come first: a printable
    stencil far under the size is never preferred to one at size.  Ties go to the smaller
    :class:`Candidate`.

    Returns
    -------
    Candidate or None
        None when no candidate was laid out (those whose layout failed are never picked).
    """
    tried = {k: c for k, c in tried.items() if laid_out(c)}
    if not tried:
        return None
    if centres:
        fit = [k for k, c in tried.items()
               if would_print_at_size(c, params, settings or STENCIL)]
        here = []
        for inset, counts in centres.items():
            first = next((n for n in counts
                          if any(k.inset_mm == inset and k.vertices == n for k in fit)), None)
            here += [k for k in fit if k.inset_mm == inset and k.vertices == first]
        if here:
            return min(here, key=lambda k: (per_scale(tried[k]), k))
    pools = [tried]
    if settings is not None:
        pools.insert(0, {k: c for k, c in tried.items() if at_size(c, settings)})
    for pool in pools:
        for m in (margin, 0.0):
            ok = [k for k, c in pool.items() if prints(c, params, m)]
            if ok:
                return min(ok, key=lambda k: (round(abs(np.log(pool[k]["scale3d"])), 3),
                                              pool[k]["max_cell_length_mm"], k))
    pool = pools[0] or tried
    return min(pool, key=lambda k: (per_scale(pool[k]), k))


__all__ = ["Candidate", "stencil_figures", "area_covered", "laid_out", "at_size", "full_size",
           "prints", "prints_at_full_size", "per_scale", "would_print_at_size", "tier", "pick"]
