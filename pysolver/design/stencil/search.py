"""The stencil search's entry point: :func:`remesh_surface`.

One *pass* (:func:`_one_pass`) is a vertex-count search (:class:`~.count_search.CountSearch`)
over the target with one set of settings, its pick polished and, for a landscape the user
gave, traded for fewer cells.  :func:`remesh_surface` runs at most four passes, each decided
in plain sight in its body rather than by the search calling itself:

1. the search as asked (the CVT spacing graded by the user's landscape when there is one);
2. when the graded stencil does not print, the same search spaced by the target alone
   (:func:`_ungraded_if_needed`);
3. with ``StencilSearch.rim_scale = "auto"``, when no stencil of the passes above prints at
   the size asked for, the search again with the rim's scale free
   (:func:`_with_rim_scale`), itself graded or not as in 1-2; the free stencil is taken when
   it prints at size or ranks higher.

The passes see the target in an order and a frame given by its geometry alone
(:func:`pysolver.geometry.canonical_order`, :func:`pysolver.geometry.canonical_pose`): the
search is a chain of choices whose branches can differ by a few per cent of bases, and a
relabelled or rigidly moved input must not choose another branch.  Read so, such an input
differs from the original by the round-off of its coordinates only, as a run on another CPU
does, unless a symmetry leaves the target's frame undecided (it is then read in the frame it
was given, and a rigid motion reorders the search's sums).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ...errors import InputError
from ...geometry import canonical_order, canonical_pose
from ...params import STENCIL, UNIT_CELL, StencilSearch, UnitCell
from ...params import tol as TOL
from ..time_landscape import interpolate_to_stencil
from .candidates import (
    Candidate,
    area_covered,
    at_size,
    full_size,
    laid_out,
    per_scale,
    prints,
    prints_at_full_size,
    stencil_figures,
)
from .count_search import CountSearch
from .feasibility import conformal_bound
from .remesh import estimate_vertices, needs_dense, resample_dense, surface_area


@dataclass(frozen=True)
class _Request:
    """What :func:`remesh_surface` was asked (its arguments but the settings), the target in
    canonical order: the same for every pass."""

    V: np.ndarray
    F: np.ndarray
    time: np.ndarray | None
    vertices: int | None
    seed: int | None
    target_bases: int | None
    params: UnitCell
    method: str
    dense: bool | None
    optimize: bool
    user_times: bool
    progress: object
    posed: bool = False


@dataclass
class _Pass:
    """One pass's result: the stencil ``V2`` (k, 3) mm, ``F2`` (f, 3), its ``info`` (as
    :func:`remesh_surface`'s) and the search that made it; ``refused_grading`` holds the
    figures of a graded stencil that did not print (the pass is then incomplete)."""

    V2: np.ndarray | None
    F2: np.ndarray | None
    info: dict
    search: CountSearch
    refused_grading: dict | None = None


def remesh_surface(V, F, *, vertices=None, seed=None, target_bases=None,
                   params: UnitCell = UNIT_CELL, settings: StencilSearch = STENCIL,
                   method: str = "cvt", dense: bool | None = None, optimize: bool = True,
                   time=None, user_times: bool = False, progress=None):
    """Remesh a target surface into a stencil, searching the vertex count.

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    vertices : int, optional
        Vertex count N; otherwise searched (:mod:`pysolver.design.stencil.count_search`).
    seed : int, optional
        Seed of the CVT initialisation; otherwise ``settings.seeds`` seeds are tried.
    target_bases : int, optional
        Start of the search (about 2 N); default ``count_start`` x the paper's estimate.
    params : UnitCell
    settings : StencilSearch
    method : {"cvt", "pymeshlab"}
    dense : bool, optional
        Resample the input finely first (midpoint subdivision,
        :func:`~pysolver.design.stencil.remesh.resample_dense`; default: when the input's
        triangles are poor, min angle < 15 deg, or it has fewer than 2000 faces).
    optimize : bool
        Run the stencil optimisation (:mod:`pysolver.design.stencil.optimise`).
    time : (n,) float, s, optional
        The time landscape at the vertices of V; the optimisation then also evens the
        cells' speeds against it (``StencilSearch.opt_timing_weight``).
    user_times : bool
        The landscape's seconds are the user's (not mapped later onto what the cells can
        reach): the CVT spacing follows it (``StencilSearch.timing_grading``, redone
        without when that is not printable), and with the vertex count searched, fewer
        vertices are also tried (``StencilSearch.trade_counts``) and taken when they clamp
        markedly fewer cells by the estimate, at a 3D scaling of at least
        ``trade_min_scale3d``; recorded in ``info["timing_grading"]`` and ``info["trade"]``.
    progress : callable, optional
        Called with one line per tried candidate.

    Returns
    -------
    V2 : (k, 3) float, mm
    F2 : (f, 3) int
    info : dict
        How the stencil was made (``design.json`` → ``summary.remesh``, every key in
        ``docs/design-folder.md``): ``vertices``, ``requested``, ``seed``, ``rim_inset_mm``,
        ``at_size`` (:func:`~.candidates.at_size` of the stencil returned: False when no
        printable stencil keeps the size asked for; the design stage then refuses it), the
        figures (:func:`~.candidates.stencil_figures`) ``before_optimisation`` /
        ``after_optimisation``, ``candidates``, ``optimisation``
        (:meth:`~.count_search.CountSearch.records`), ``polish``, ``rim``
        (:meth:`~.count_search.CountSearch.rim_fallback`), ``rim_scale``,
        ``timing_grading``, ``trade`` (:meth:`~.count_search.CountSearch.trade`),
        ``pose`` (the frame the search ran in), ``warnings``.
    """
    # a function of the geometry: not of the labels (the order), nor of where it lies (the pose)
    V, F, time, _ = canonical_order(V, F, time)
    R, c, posed = canonical_pose(V, F)
    if posed:
        V, F, time, _ = canonical_order((V - c) @ R, F, time)
    if settings.rim_scale not in ("auto", "kept", "free"):
        raise InputError(f"StencilSearch.rim_scale={settings.rim_scale!r}",
                         fix='use "auto", "kept" or "free"')
    req = _Request(V=V, F=F, time=time, vertices=vertices, seed=seed,
                   target_bases=target_bases, params=params, method=method, dense=dense,
                   optimize=optimize, user_times=user_times, progress=progress, posed=posed)
    done, used, graded = _ungraded_if_needed(req, settings)
    V2, F2, info = _with_rim_scale(req, used, done)
    if graded is not None:  # (whichever rim was taken, the grading was not)
        info["timing_grading"] = graded
    info["pose"] = "principal axes" if posed else "as given (a symmetry leaves it undecided)"
    return (V2 @ R.T + c if posed else V2), F2, info


def _ungraded_if_needed(req: _Request, settings: StencilSearch):
    """A pass with ``settings``, and when its time-graded stencil does not print, a pass
    spaced by the target alone (passes 1-2 of the module docstring).

    Returns
    -------
    done : _Pass -- complete
    used : StencilSearch -- the settings of ``done``
    graded : dict or None -- the ``timing_grading`` record of a grading refused
    """
    done = _one_pass(req, settings)
    if done.refused_grading is None:
        return done, settings, None
    chosen = done.refused_grading
    done.search.say(f"time-graded stencil: longest flat cell {chosen['max_cell_length_mm']:.2f}"
                    f" mm, scale3d {chosen['scale3d']:.3f}: searching again without")
    used = replace(settings, timing_grading=0.0)
    return _one_pass(req, used), used, {
        "grading": settings.timing_grading, "taken": False,
        "max_cell_length_mm": chosen["max_cell_length_mm"], "scale3d": chosen["scale3d"]}


def _one_pass(req: _Request, settings: StencilSearch) -> _Pass:
    """One count search with ``settings``: its pick polished (and traded), ``info`` complete
    but for ``rim_scale``; or, when the CVT spacing was graded by the landscape and the
    stencil does not print, the pass with ``refused_grading`` set."""
    V, F, time, params = req.V, req.F, req.time, req.params
    A = surface_area(V, F)
    info = {"remeshed": True, "method": req.method, "area_mm2": round(A, 2),
            "estimate_paper": estimate_vertices(A)}
    V, F, time = _search_target(V, F, time, req.method, req.dense, settings, info)
    graded = (req.method == "cvt" and req.user_times and time is not None
              and settings.timing_grading > 0)
    search = CountSearch(V, F, time, params=params, settings=settings, method=req.method,
                         optimize=req.optimize, graded=graded, progress=req.progress,
                         posed=req.posed)
    seeds = ([int(req.seed)] if req.seed is not None
             else [0] if req.method == "pymeshlab"  # (it has no seed)
             else list(range(settings.seeds)))
    best, rim = search.search(req.vertices, seeds, (
        int(req.target_bases / 2) if req.target_bases
        else round(settings.count_start * estimate_vertices(A))))
    best, V2, F2, before, chosen = _polish_and_trade(
        search, best, info, seeds,
        trade=req.user_times and time is not None and req.vertices is None)
    if graded and not (prints(chosen, params)
                       and chosen["scale3d"] >= settings.trade_min_scale3d):
        return _Pass(None, None, info, search, refused_grading=chosen)
    info["timing_grading"] = {"grading": settings.timing_grading if graded else 0.0,
                              "taken": bool(graded)}
    _record(info, search, best, (V2, F2, before), chosen, rim, req.optimize, A)
    return _Pass(V2, F2, info, search)


def _with_rim_scale(req: _Request, settings: StencilSearch, kept: _Pass):
    """The stencil of ``kept`` with its rim's scale recorded (``info["rim_scale"]``, and
    ``info["rim_log_scale"]``, (k,) per stencil vertex, when free); with
    ``rim_scale="auto"`` and no stencil printable at size, the stencil of the passes with the
    rim's scale free when it prints at size or ranks higher (:func:`_free_rim`), unless the
    measured bound excludes that too (:func:`pysolver.design.stencil.feasibility.
    conformal_bound`: a hopeless search cut).

    Returns
    -------
    V2, F2, info : as :func:`remesh_surface`
    """
    search, info, params = kept.search, kept.info, req.params
    why = f"rim_scale={settings.rim_scale!r}"
    if settings.rim_scale == "auto" and search.dom is not None and req.vertices is None \
            and not _delivered(info, params):
        bound = conformal_bound(search.V, search.F, params)["bound_mm"]
        if bound <= params.max_cell_length:
            return _free_rim(req, settings, kept)
        why = (f"no stencil printed with the rim's lengths kept, and the bound excludes its "
               f"scale free too ({bound:.2f} mm)")
    free = search.dom is not None and search.dom.rim_u is not None
    info["rim_scale"] = {"scale": "free" if free else "kept", "why": why}
    if free:
        info["rim_log_scale"] = search.rim_scale_at(kept.V2)
    return kept.V2, kept.F2, info


def _delivered(info: dict, params: UnitCell) -> bool:
    """Whether the stencil a search returns (its ``info``, :func:`remesh_surface`) prints at
    the size asked for."""
    return bool(info["at_size"]) and prints(info, params)


def _free_rim(req: _Request, settings: StencilSearch, kept: _Pass):
    """No stencil of the pass ``kept`` printed at size with the rim's lengths kept: the passes
    again with the rim's scale free.  The free stencil is taken when it prints at size, or
    when neither does and it ranks higher: at size first, then by its longest flat cell per
    unit of 3D scaling (as :func:`~.candidates.pick`).  When the free search fails, the kept
    result stands.

    Returns
    -------
    V2, F2, info : as :func:`remesh_surface`; ``info["rim_scale"]`` says which was taken
    and why, with the other's figures.
    """
    info = kept.info
    kept.search.say("no stencil prints at size with the rim's lengths kept: searching again "
                    "with the rim's scale free")
    try:
        done, used, graded = _ungraded_if_needed(req, replace(settings, rim_scale="free"))
        V3, F3, free = _with_rim_scale(req, used, done)
    except InputError as e:  # (the kept result's refusal names measured alternatives)
        info["rim_scale"] = {"scale": "kept", "why": f"the search with the rim's scale free "
                             f"failed: {e.problem}"}
        return kept.V2, kept.F2, info
    if graded is not None:
        free["timing_grading"] = graded

    def rank(r):  # at size first, then the longest cell per unit of scaling (as pick)
        return (r["at_size"], -per_scale(r["after_optimisation"]))
    take = laid_out(free["after_optimisation"]) and (
        _delivered(free, req.params) or rank(free) > rank(info))
    figures = {k: info[k] for k in ("vertices", "scale3d", "max_cell_length_mm", "at_size")}
    if not take:
        info["rim_scale"] = {"scale": "kept", "why": "the rim's scale free printed no better",
                             "free": {k: free[k] for k in figures}}
        return kept.V2, kept.F2, info
    free["rim_scale"] = {"scale": "free", "why": "no stencil printed at size with the rim's "
                         "lengths kept", "kept": figures}
    kept.search.say(f"rim scale free: {free['vertices']} vertices, scale3d "
                    f"{free['scale3d']:.3f}, longest flat cell {free['max_cell_length_mm']:.2f}"
                    f" mm (kept: {info['max_cell_length_mm']:.2f} mm at {info['scale3d']:.3f})")
    return V3, F3, free


def _polish_and_trade(search: CountSearch, best, info: dict, seeds, trade: bool):
    """The pick polished (:meth:`CountSearch.polish`) and, for a landscape the user gave with
    the count searched, traded for fewer cells (:meth:`CountSearch.trade`); records both in
    ``info``.

    Returns
    -------
    best : Candidate -- the stencil returned
    V2, F2 : its vertices (mm) and faces
    before : (V, F) of the pick before its optimisation
    chosen : dict -- the figures of the stencil returned
    """
    tries = [best] + search.alternates(best)
    polished = {}
    for key in tries:
        if key in search.flat:
            search.converge(key)
        if not (key in search.flat and search.settings.opt_pin_weight > 0):
            break
        polished[key] = search.polish(key)
        if prints_at_full_size(polished[key][1], search.params, search.settings):
            best = key
            break  # (else the next start of the count, polished too)
    V2, F2, before = search.meshes[best]
    chosen = search.tried[best]
    if best in polished:
        V2, chosen, info["polish"] = polished[best]
    if trade and laid_out(chosen):
        kept = best, V2, F2, before, chosen, info.get("polish")
        best, V2, F2, chosen = search.trade(best, V2, F2, chosen, info, seeds=seeds)
        if best != kept[0] and "polish" in info:  # (the fewer cells, at full size too)
            if best in search.flat:
                search.converge(best)
                V2, chosen, info["polish"] = search.polish(best)
                before = search.meshes[best][2]
            if not (best in search.flat
                    and prints_at_full_size(chosen, search.params, search.settings)):
                info["trade"].update(taken=False, why="the fewer cells do not print at "
                                     "full size")
                best, V2, F2, before, chosen, info["polish"] = kept
    return best, V2, F2, before, chosen


def _search_target(V, F, time, method: str, dense, settings: StencilSearch, info: dict):
    """The target the count search remeshes: the input, or its dense resampling (when its
    triangles are poor or few, or ``dense``), with the landscape carried onto it (None when
    constant: programming then picks the constant itself).

    Returns
    -------
    V : (n, 3) float, mm
    F : (m, 3) int
    time : (n,) float, s, or None
    """
    if method not in ("cvt", "pymeshlab"):
        raise InputError(f"remesh method {method!r}", fix="use 'cvt' or 'pymeshlab'")
    if dense is None:
        dense = needs_dense(V, F, settings)
    if time is not None:
        time = np.asarray(time, float)
        if time.shape != (len(V),):
            raise InputError(f"time has shape {time.shape}, expected ({len(V)},): one value "
                             "per target vertex", fix="give the time landscape per vertex of V")
    if time is not None and np.ptp(time) <= TOL.time:
        time = None  # a constant landscape: programming picks the constant itself
    if dense:
        V2, F2 = resample_dense(V, F, settings.dense_faces)
        if time is not None:
            time = interpolate_to_stencil(time, V, F, V2)
        V, F = V2, F2
        info["dense_resampled_faces"] = int(len(F))
    return V, F, time


def _record(info: dict, search: CountSearch, best, stencil, chosen: dict, rim, optimize: bool,
            A: float):
    """Complete ``info`` (see :func:`remesh_surface`) for the stencil returned:
    ``stencil = (V2, F2, before)``, its key ``best`` and figures ``chosen``; ``A`` (mm^2) is
    the area of the target as given."""
    V2, F2, before = stencil
    if rim is None:
        rim = {"inset_mm": best.inset_mm, "area_covered": area_covered(V2, F2, A),
               "fallback": None, "why": ("the stencil reaches the target's rim"
                                         if best.inset_mm <= 0
                                         else "the inset stencil covers enough of the target")}
    else:
        rim["area_covered"] = area_covered(V2, F2, A)  # of the final stencil (polished, traded)
    records = search.records()
    info.update(vertices=int(len(V2)), requested=best.vertices, seed=best.seed,
                rim_inset_mm=best.inset_mm, rim=rim, scale3d=chosen["scale3d"],
                max_cell_length_mm=chosen["max_cell_length_mm"],
                at_size=bool(full_size(chosen, search.settings) if "polish" in info
                             else at_size(chosen, search.settings)),
                before_optimisation=(stencil_figures(*before, search.params,
                                                     u_boundary=search.rim_scale_at(before[0]))
                                     if optimize else None),
                after_optimisation=chosen,
                candidates=[[k.vertices, k.seed, k.inset_mm, v["scale3d"],
                             v["max_cell_length_mm"]]
                            for k, v in sorted(search.tried.items())],
                optimisation=records,
                warnings=[f"the stencil optimisation kept no round for the stencil chosen "
                          f"(N={best.vertices} seed={best.seed}: {r['rounds'][0]['why']})"
                          for r in records
                          if Candidate(r["vertices"], r["seed"], r["rim_inset_mm"]) == best
                          and r["rounds_kept"] == 0 and r["rounds"]])


__all__ = ["remesh_surface"]
