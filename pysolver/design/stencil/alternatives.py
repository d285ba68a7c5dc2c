"""What would make a refused target printable: the alternatives a refusal names, measured.

A refusal of the design stage names only alternatives that were actually tried on this
target: the same stencil at the reference's 0.1 mm minimal bumper, a smaller ``--size`` searched
again (the size of the printable stencil the search found under the size asked for), and
the stencil the search found closest.  :func:`size_refusal` is the refusal of a target that
prints only far from the size asked for; :func:`printable_alternatives` the fix of one
whose longest cell is over the limit.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...errors import InputError
from ...params import REFERENCE_MIN_BUMPER_MM, STENCIL, StencilSearch, UnitCell
from ...params import tol as TOL
from .candidates import at_size, prints, stencil_figures
from .feasibility import describe_bound, target_bound


def _describe(info: dict) -> str:
    return (f"N={info['requested']} seed={info['seed']}, 3D scaling {info['scale3d']:.3f}, "
            f"longest flat cell {info['max_cell_length_mm']:.2f} mm")


def smaller_size(remesh_info: dict, params: UnitCell, settings: StencilSearch = STENCIL):
    """The factor on the target's size at which the search's best printable candidate under
    the size asked for would keep it: its 3D scaling (None when no candidate under the size
    prints)."""
    ok = [c for c in remesh_info.get("candidates") or []
          if c[4] is not None and c[4] <= params.max_cell_length and c[3] < settings.min_scale3d]
    if not ok:
        return None
    return float(max(ok, key=lambda c: c[3])[3])


def try_smaller_size(search, extent_mm: float, factor: float, params: UnitCell):
    """Search the target again at ``factor`` times its size.

    Parameters
    ----------
    search : callable
        ``search(factor, params) -> info`` runs the count search on the target scaled by
        ``factor`` (:func:`pysolver.design.stencil.search.remesh_surface`'s info).
    extent_mm : float, mm
        The target's largest bounding-box extent at the size asked for.
    factor : float

    Returns
    -------
    line : str
        ``--size X`` and what the search found there (printable at size or not).
    ok : bool
    """
    size = float(np.floor(extent_mm * factor))
    try:
        info = search(size / extent_mm, params)
    except InputError as e:
        return f"--size {size:.0f} was tried and cannot be laid out ({e.problem})", False
    ok = prints(info, params) and info.get("at_size", False)
    return (f"--size {size:.0f} (tried: " + ("prints, " if ok else "does not print, ")
            + _describe(info) + ")"), ok


def printable_alternatives(V, F, remesh_info: dict, params: UnitCell, search=None,
                           extent_mm=None, target=None, u_boundary=None) -> str:
    """What would make an unprintable remeshed stencil printable, measured, for the error's fix.

    Tries the same stencil at the reference's 0.1 mm minimal bumper, a smaller size (when the
    search found a printable candidate under the size asked for, or 0.8 of it otherwise; only
    with ``search``) and names the searched vertex count with the shortest longest cell.

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    remesh_info : dict
        :func:`pysolver.design.stencil.search.remesh_surface`'s info (``candidates``).
    params : UnitCell
    search : callable, optional
        See :func:`try_smaller_size`.
    extent_mm : float, mm, optional
        The target's largest extent (with ``search``).
    target : (V, F), optional
        The target surface: the fix then starts with its measured bound
        (:func:`pysolver.design.stencil.feasibility.target_bound`).
    u_boundary : (n,) float, optional
        The stencil's boundary log-scale, when its rim's scale is free.

    Returns
    -------
    fix : str
    """
    lines = []
    if target is not None:
        lines.append(describe_bound(target_bound(*target, params), params))
    low = REFERENCE_MIN_BUMPER_MM
    if params.min_bumper > low + TOL.rel:
        alt = stencil_figures(V, F, replace(params, min_bumper=low), u_boundary=u_boundary)
        if alt["max_cell_length_mm"] is not None:
            ok = prints(alt, params)
            lines.append(f"--min-bumper {low:g} (the reference's) gives a longest cell of "
                         f"{alt['max_cell_length_mm']:.2f} mm on this stencil"
                         + (" (printable)" if ok else ""))
    if search is not None and extent_mm is not None:
        f = smaller_size(remesh_info, params) or STENCIL.refusal_size_factor
        lines.append(try_smaller_size(search, extent_mm, f, params)[0])
    cands = [c for c in remesh_info.get("candidates") or [] if c[4] is not None]
    if cands:
        best = min(cands, key=lambda c: c[4])
        lines.append(f"of the stencils tried, --vertices {best[0]} --seed {best[1]} came "
                     f"closest ({best[4]:.2f} mm, scale {best[3]:.2f})")
    lines.append("a cut through the region named above splits the stretch the flattening "
                 "needs (SI Note 1)")
    return "; ".join(lines)


def size_refusal(remesh_info: dict, params: UnitCell, search, extent_mm: float,
                 settings: StencilSearch = STENCIL) -> InputError:
    """The refusal of a target whose printable stencils all miss the size asked for.

    Parameters
    ----------
    remesh_info : dict
        The count search's info (``at_size`` False, the stencil within the limit).
    params : UnitCell
    search : callable
        See :func:`try_smaller_size`.
    extent_mm : float, mm
    settings : StencilSearch

    Returns
    -------
    InputError
        Naming the 3D scaling reached and, measured, ``--size`` (searched again at the
        printable candidate's size) and ``--min-bumper 0.1`` (searched again).
    """
    s3 = remesh_info["scale3d"]
    lines = []
    f = smaller_size(remesh_info, params, settings) or (s3 if s3 < 1 else None)
    if f is not None:
        lines.append(try_smaller_size(search, extent_mm, f, params)[0])
    low = REFERENCE_MIN_BUMPER_MM
    if params.min_bumper > low + TOL.rel:
        try:
            info = search(1.0, replace(params, min_bumper=low))
            ok = prints(info, params) and at_size(info, settings)
            lines.append(f"--min-bumper {low:g} (tried: "
                         + ("prints at this size, " if ok else "does not print at this size, ")
                         + _describe(info) + ")")
        except InputError as e:
            lines.append(f"--min-bumper {low:g} was tried and cannot be laid out ({e.problem})")
    lines.append("a cut or a flatter target lets cells of the size asked for print")
    what = "under" if s3 < 1 else "over"
    return InputError(
        f"no printable stencil keeps the size asked for: the best one tried is at 3D scaling "
        f"{s3:.3f} (the shell {100 * abs(1 - s3):.0f} % {what} it; within "
        f"{100 * settings.polish_tolerance:.0f} % of 1 is needed: a shell is made smaller only "
        f"when --size asks), {_describe(remesh_info)}",
        fix="; ".join(lines))


__all__ = ["printable_alternatives", "size_refusal", "smaller_size", "try_smaller_size"]
