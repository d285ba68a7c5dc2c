"""The vertex-count search: which stencil of a target surface to print.

A stencil's 3D size is not chosen directly: the layout's 3D rule scales it until its
tightest cell just keeps its bumpers (``pipeline.md`` §2.5), so the vertex count N fixes the
shell's size.  :func:`remesh_surface` searches N so that the shell keeps the size asked for
(3D scaling about 1) with every flat cell printable (``UnitCell.max_cell_length``).

**A function of the geometry.**  The same surface must give the same shell however its mesh
is labelled, placed or rounded, and on any machine (issue #42).  The search reads the target
in a canonical order (:func:`pysolver.geometry.canonical_order`: relabelled inputs give the
same stencil to the last bit), the stencils are seeded by position in a frame the target's
shape sets (:mod:`pysolver.design.remesh`: a rigid motion or a last-bit jitter moves them by
as little), and the search does not steer on one noisy start: each count is tried with
``StencilSearch.seeds`` CVT seeds, whose 3D scalings scatter by a few per cent (the tightest
cell decides it), as much as two rungs of the count's ladder.  We chose *several starts per
count* over one start with a converged objective because the scatter is not the optimiser's
(each start's rounds converge) but the starts' own: different triangulations of the same
surface are different local optima, and the count that a single start's scaling points to
moved with them (petal, relabelled: 172 to 233 bases).

1. **Secant steps** on the mean log 3D scaling over the seeds (about ``sqrt(N)``) toward 1,
   from the paper's estimate ``0.38 A / 7^2`` times ``StencilSearch.count_start``, every
   count on one fixed geometric ladder (``StencilSearch.count_ladder``,
   :meth:`CountSearch.rung`); then the next rim inset when nothing is printable.  The count
   taken is the one tried whose mean scaling is nearest 1, not where the steps stopped.
2. **The pick** (:func:`_pick`): among the seeds at that count that keep the size
   (:func:`at_size`: 3D scaling within ``[min_scale3d, 1 / min_scale3d]``) and would print
   held at scale 1, the shortest longest cell per unit of scaling: the best of several
   starts.  Else the former rule: scaling closest to 1 with the longest flat cell ``margin``
   below the limit, else within it.
3. **The rim** (:func:`_rim_fallback`): a narrow target whose inset region covers too little
   also gets the stencil reaching the rim, taken if it prints as well.
4. **The polish** (:meth:`CountSearch.converge`, :meth:`CountSearch.polish`): the pick
   optimised on until its rounds converge, then with its 3D scaling held at 1.  The size
   asked for is the size delivered: a stencil that prints at scale 1 is taken there, and
   when the pick's does not, the count's other seeds are polished in turn
   (:meth:`CountSearch.alternates`).  A stencil that prints only off the size
   (:func:`full_size`) is refused by the design stage, naming a measured ``--size``.
5. **The trade** (:func:`_trade`), with a landscape the user gave: fewer, larger cells when
   they clamp markedly fewer cells, polished at full size too.
6. **The rim's scale** (``StencilSearch.rim_scale``, :func:`_free_rim`): when no stencil
   prints at size with the rim's lengths kept, the search runs again in the flattening
   whose boundary log-scale lowers the measured bound
   (:func:`pysolver.design.feasibility.rim_log_scale`), and its stencil is taken if it
   prints, or comes closer.

Every candidate's optimisation rounds (kept or not, and why) are recorded
(``info["optimisation"]``), and a stencil whose optimisation keeps no round is warned about.
Nothing is tuned per shape.  Measured stability: ``docs/results.md`` ("One surface, one
shell"), ``bench/bench_stability.py``.
"""

from __future__ import annotations

from dataclasses import replace

import igl
import numpy as np

from ..errors import InputError
from ..geometry import canonical_order
from ..params import STENCIL, UNIT_CELL, StencilSearch, UnitCell
from ..params import tol as TOL
from .feasibility import conformal_bound, rim_log_scale
from .flatten import cetm
from .layout import build_layout
from .remesh import (
    FlatDomain,
    RimInsetError,
    estimate_vertices,
    isotropic_remesh,
    needs_dense,
    remove_ears,
    resample_dense,
    surface_area,
)
from .stencil_opt import estimated_clamping, layout_timing_terms, optimize_stencil
from .time_landscape import cell_target_times, interpolate_to_stencil

# --------------------------------------------------------------------------------------
# measuring and choosing stencils


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
        cells whose time the estimate of :func:`~pysolver.design.stencil_opt.estimated_clamping`
        puts out of reach.
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


def _laid_out(c: dict) -> bool:
    return c.get("max_cell_length_mm") is not None


def at_size(c: dict, settings: StencilSearch = STENCIL) -> bool:
    """Whether a laid-out candidate keeps the size asked for: its 3D scaling within
    ``[min_scale3d, 1 / min_scale3d]``."""
    return (_laid_out(c) and settings.min_scale3d <= c["scale3d"]
            <= 1.0 / settings.min_scale3d)


def full_size(c: dict, settings: StencilSearch = STENCIL) -> bool:
    """Whether a laid-out stencil is delivered at the size asked for: its 3D scaling within
    ``polish_tolerance`` of 1 (the polish holds it there).  :func:`at_size`'s wider band is
    where the count search looks; only a stencil at full size is printed without the user
    asking for another size (``--size``)."""
    return _laid_out(c) and abs(np.log(c["scale3d"])) <= settings.polish_tolerance


def prints_at_full_size(c: dict, params: UnitCell, settings: StencilSearch = STENCIL) -> bool:
    """Whether a polished stencil's figures ``c`` print at the size asked for: at full size
    (:func:`full_size`) with its longest flat cell within the limit."""
    return full_size(c, settings) and c["max_cell_length_mm"] <= params.max_cell_length


def _pick(tried: dict, params: UnitCell, margin: float,
          settings: StencilSearch | None = None, centres: dict | None = None):
    """Best candidate.  Given ``centres`` (rim inset mm -> the count the secant found), the
    candidates of that count (one per seed) that keep the size asked for and would print
    held at scale 1 (:func:`_per_scale` within the limit) come first, the shortest longest
    cell per unit of 3D scaling taken: the best of several starts, which is what the polish
    delivers, and no longer a choice among the seeds' scatter in scaling.  Otherwise: 3D
    scaling closest to 1 among those whose longest flat cell keeps
    ``margin`` below the limit; else below the limit; else the shortest longest cell per
    unit of 3D scaling (what the polish, holding the scaling, keeps: the longest cell alone
    favours the candidates that happen to be small, and its ties between candidates far
    apart in scaling moved with the last bits).  Given ``settings``, candidates that keep
    the size asked for (:func:`at_size`) come first: a printable stencil far under the size
    is never preferred to one at size.  Candidates whose layout failed are never picked
    (None if all failed)."""
    tried = {k: c for k, c in tried.items() if _laid_out(c)}
    if not tried:
        return None
    if centres:
        here = [k for k, c in tried.items() if centres.get(k[2]) == k[0]
                and at_size(c, settings or STENCIL)
                and _per_scale(c) <= params.max_cell_length]
        if here:
            return min(here, key=lambda k: (_per_scale(tried[k]), k))
    pools = [tried]
    if settings is not None:
        pools.insert(0, {k: c for k, c in tried.items() if at_size(c, settings)})
    for pool in pools:
        for lim in (params.max_cell_length - margin, params.max_cell_length):
            ok = [k for k, c in pool.items() if c["max_cell_length_mm"] <= lim]
            if ok:
                return min(ok, key=lambda k: (round(abs(np.log(pool[k]["scale3d"])), 3),
                                              pool[k]["max_cell_length_mm"], k))
    pool = pools[0] or tried
    return min(pool, key=lambda k: (_per_scale(pool[k]), k))


def _per_scale(c: dict) -> float:
    """A laid-out candidate's longest flat cell per unit of 3D scaling (mm): what the
    polish, holding the scaling, keeps."""
    return c["max_cell_length_mm"] / c["scale3d"]


def _covered(V, F, area: float) -> float:
    """Fraction of the target's area ``area`` (mm^2) the stencil ``V, F`` covers (its own 3D
    area over the target's; the stencil's flat triangles are chords of the target)."""
    return round(surface_area(V, F) / area, 4)


def _tier(c: dict, params: UnitCell, margin: float) -> int:
    """0 when the longest flat cell keeps ``margin`` (mm) below the limit, 1 when it is within
    the limit, 2 otherwise (or when the layout failed)."""
    if not _laid_out(c):
        return 2
    L = c["max_cell_length_mm"]
    return 0 if L <= params.max_cell_length - margin else 1 if L <= params.max_cell_length else 2


def _rim_fallback(best, tried: dict, meshes: dict, area: float, params: UnitCell,
                  settings: StencilSearch, search_rim, centres=None, region=None):
    """The stencil without a rim inset as a measured alternative to an inset stencil.

    When the inset's region covers less than ``settings.min_area_covered`` of the target
    (``region``: :meth:`pysolver.design.remesh.FlatDomain.region_covered`, a function of
    the target; without it, the chosen stencil's own cover),
    ``search_rim()`` searches the counts without an inset; its best candidate
    replaces ``best`` only if it prints at least as well (:func:`_tier`, never worse than the
    inset stencil and never beyond the limit).

    Parameters
    ----------
    best : (int, int, float)
        Key (N, seed, inset mm) of the chosen inset stencil in ``tried`` and ``meshes``.
    tried, meshes : dict
        Figures (:func:`stencil_figures`) and meshes of every candidate, by key; filled by
        ``search_rim``.
    area : float, mm^2
        The target's area.
    params : UnitCell
    settings : StencilSearch
    search_rim : callable
        Searches the vertex count with inset 0 (adds its candidates to ``tried``).
    centres : dict, optional
        Rim inset (mm) -> the count the secant found there (:func:`_pick`).
    region : float, optional
        Fraction of the target's area inside the inset curve.

    Returns
    -------
    best : (int, int, float)
        The key chosen.
    rim : dict
        ``inset_mm``, ``min_area_covered``, ``inset_area_covered`` (of the inset stencil),
        ``inset_region_covered`` (what the decision measured),
        ``fallback`` (None when not searched, else ``requested``, ``seed``, ``scale3d``,
        ``max_cell_length_mm``, ``area_covered``, ``taken``) and ``why``.
    """
    own = _covered(*meshes[best][:2], area)
    cov = own if region is None else region
    rim = {"inset_mm": float(best[2]), "min_area_covered": settings.min_area_covered,
           "inset_area_covered": own, "inset_region_covered": cov, "fallback": None}
    if cov >= settings.min_area_covered:
        rim["why"] = (f"the inset region covers {100 * cov:.0f} % of the target (at least "
                      f"{100 * settings.min_area_covered:.0f} %)")
        return best, rim
    try:
        search_rim()
    except RimInsetError:  # (inset 0 never splits the target; kept for symmetry)
        pass
    alt = _pick({k: c for k, c in tried.items() if k[2] == 0.0}, params, settings.margin,
                centres=centres)
    if alt is None:
        rim["why"] = (f"the inset region covers {100 * cov:.0f} % of the target; no stencil "
                      "without the inset could be laid out")
        return best, rim
    c, c0 = tried[alt], tried[best]
    taken = _tier(c, params, settings.margin) <= min(_tier(c0, params, settings.margin), 1)
    rim["fallback"] = {"requested": int(alt[0]), "seed": int(alt[1]),
                       "scale3d": c["scale3d"], "max_cell_length_mm": c["max_cell_length_mm"],
                       "area_covered": _covered(*meshes[alt][:2], area), "taken": bool(taken)}
    if taken:
        rim["why"] = (f"the inset region covers {100 * cov:.0f} % of the target (under "
                      f"{100 * settings.min_area_covered:.0f} %); the stencil reaching the rim "
                      f"prints (longest flat cell {c['max_cell_length_mm']:.2f} mm, "
                      f"{c0['max_cell_length_mm']:.2f} mm with the inset)")
        rim["inset_mm"] = 0.0
        return alt, rim
    rim["why"] = (f"the inset region covers {100 * cov:.0f} % of the target (under "
                  f"{100 * settings.min_area_covered:.0f} %), but the stencil reaching the rim "
                  f"prints worse (longest flat cell {c['max_cell_length_mm']:.2f} mm, "
                  f"{c0['max_cell_length_mm']:.2f} mm with the inset; limit "
                  f"{params.max_cell_length:.2f} mm, margin {settings.margin:.2f} mm)")
    return best, rim


def _trade(best, V2, F2, chosen, trial, tried, meshes, params, settings, info, progress,
           seeds=None):
    """Fewer, larger (faster) cells for a landscape that asks for early times.

    Tries ``settings.trade_counts`` x the chosen count (each of ``seeds``, default the
    chosen one; same inset) and takes, among every stencil tried with fewer vertices, the
    one with the lowest estimated clamped fraction among those that are printable with
    the margin, keep a 3D scaling of at least ``trade_min_scale3d`` and clamp at least
    ``trade_gain`` fewer cells than the chosen stencil.  Records ``info["trade"]``.
    """
    n0, sd, inset = best
    limit = params.max_cell_length - settings.margin
    for f in settings.trade_counts:
        for s in (seeds or [sd]):
            trial(round(n0 * f), s, inset)
    est0 = chosen["clamped_estimate"]
    ok = [k for k, c in tried.items()
          if k[2] == inset and k[0] < n0 and _laid_out(c)
          and c["max_cell_length_mm"] <= limit and c["scale3d"] >= settings.trade_min_scale3d
          and c["clamped_estimate"] <= est0 - settings.trade_gain]
    record = {"vertices": int(n0), "scale3d": chosen["scale3d"], "clamped_estimate": est0,
              "tried": [[k[0], k[1], tried[k]["scale3d"], tried[k].get("clamped_estimate")]
                        for k in sorted(tried) if k[2] == inset and k[0] < n0],
              "taken": False}
    if ok:
        k = min(ok, key=lambda k: (tried[k]["clamped_estimate"], -k[0]))
        V2, F2, _ = meshes[k]
        record.update(taken=True, to_vertices=int(k[0]), to_scale3d=tried[k]["scale3d"],
                      to_clamped_estimate=tried[k]["clamped_estimate"])
        best, chosen = k, tried[k]
    info["trade"] = record
    if progress is not None:
        after = (f", N={best[0]} ~{100 * chosen['clamped_estimate']:.0f} % at "
                 f"{chosen['scale3d']:.3f}" if ok else "")
        progress(("fewer, larger cells for the landscape: " if ok else "kept the count: ")
                 + f"N={n0} clamps ~{100 * est0:.0f} % of cells at scale3d "
                 f"{record['scale3d']:.3f}" + after)
    return best, V2, F2, chosen




# --------------------------------------------------------------------------------------
# the search


class CountSearch:
    """The vertex-count search over one target: every candidate stencil tried.

    A class because the candidates (figures, meshes, optimised flat points and their
    optimisation records, by key ``(N, seed, inset mm)``) are shared by the secant steps, the
    pick, the rim fallback, the polish and the trade.

    Parameters
    ----------
    V : (n, 3) float, mm -- the target (dense-resampled when needed)
    F : (m, 3) int
    time : (n,) float, s, or None -- the landscape at V (None: constant)
    params : UnitCell
    settings : StencilSearch
    method : {"cvt", "pymeshlab"}
    optimize : bool
    graded : bool -- the CVT spacing follows the landscape
    progress : callable or None
    """

    def __init__(self, V, F, time, *, params: UnitCell, settings: StencilSearch,
                 method: str, optimize: bool, graded: bool, progress=None):
        self.V, self.F, self.time = V, F, time
        self.params, self.settings = params, settings
        self.method, self.optimize, self.progress = method, optimize, progress
        self.area = surface_area(V, F)
        self.tried: dict = {}
        self.meshes: dict = {}
        self.flat: dict = {}  # key -> optimised flat points, time at them
        self.optimisation: dict = {}  # key -> optimise_stencil's info
        self.centres: dict = {}  # rim inset (mm) -> the count the secant found
        self.dom = None
        if method == "cvt":
            h = rim_log_scale(V, F, params, settings) if settings.rim_scale == "free" else None
            self.dom = FlatDomain(V, F, settings, time=time if graded else None,
                                  rim_log_scale=h)
            # insets in mm: a fraction of the edge of the smallest regular cell the
            # min-bumper rule allows (fixed, so that the 3D scaling stays monotone in N)
            edge = np.sqrt(3) * 2 * (params.base_r + params.min_bumper)
            self.insets = tuple(round(float(f) * edge, 4) for f in settings.rim_insets)
        else:
            self.insets = (0.0,)
        if not len(self.insets):
            raise InputError("settings.rim_insets is empty",
                             fix="give at least one inset (0 = none)")

    def say(self, line: str) -> None:
        if self.progress is not None:
            self.progress(line)

    # -- candidates ------------------------------------------------------------------
    def make(self, n: int, sd: int, inset: float):
        """The stencil of ``n`` vertices, CVT seed ``sd``, rim inset (mm), optimised.

        Returns
        -------
        V2 : (k, 3) float, mm
        F2 : (f, 3) int
        before : (V, F) of the stencil before the optimisation
        """
        if self.dom is None:  # pymeshlab's isotropic remeshing in 3D
            L = np.sqrt(2 * self.area / (np.sqrt(3) * n))
            V2, F2 = remove_ears(*isotropic_remesh(self.V, self.F, L))
            return V2, F2, (V2, F2)
        P, F2 = self.dom.stencil(n, seed=sd, inset=inset)
        before = (self.dom.lift(P), F2)
        if self.optimize and not self.hopeless(*before):
            t_P = None if self.time is None else self.dom.interpolate(self.time, P)
            P, opt = optimize_stencil(self.dom, P, F2, self.params, self.settings,
                                      t_vertex=t_P, rim=(self.dom.boundary_polygon(inset)
                                                         if self.settings.opt_slide_rim
                                                         else None))
            self.flat[(n, sd, float(inset))] = (P, t_P)
            self.optimisation[(n, sd, float(inset))] = opt
        return self.dom.lift(P), F2, before

    def hopeless(self, V2, F2) -> bool:
        """Whether a stencil before optimisation is so far from the size asked for that the
        optimisation (which moves its scaling by up to about a fifth) cannot make it the
        pick: ``|log scale3d| > hopeless_log_scale``.  Its figures are then taken as they
        are, for the secant steps only.  (Its longest cell is no such test: a target that
        prints nowhere is refused naming the closest stencil tried, which must be optimised.)"""
        c = stencil_figures(V2, F2, self.params, settings=self.settings,
                            u_boundary=self.rim_scale_at(V2))
        return not _laid_out(c) or abs(np.log(c["scale3d"])) > self.settings.hopeless_log_scale

    def rim_scale_at(self, V2):
        """(k,) float or None: the boundary log-scale of the layout of a stencil ``V2``
        (k, 3) mm (:meth:`pysolver.design.remesh.FlatDomain.rim_scale_at`)."""
        return None if self.dom is None else self.dom.rim_scale_at(V2)

    def figures(self, V2, F2) -> dict:
        t2 = None if self.time is None else interpolate_to_stencil(self.time, self.V, self.F,
                                                                   V2)
        return stencil_figures(V2, F2, self.params, time=t2, settings=self.settings,
                               u_boundary=self.rim_scale_at(V2))

    def rung(self, n) -> int:
        """The count of the ladder (``StencilSearch.count_ladder``) nearest ``n``."""
        q = np.log(self.settings.count_ladder)
        return max(int(round(np.exp(q * round(np.log(max(float(n), 1.0)) / q)))), 8)

    def trial(self, n, sd, inset, given: bool = False) -> int:
        """Make and measure candidate ``(n, sd, inset)`` once (later calls reuse it); a
        searched count (not ``given``) is snapped to the ladder (:meth:`rung`)."""
        n = max(int(n), 8) if given else self.rung(n)
        key = (n, int(sd), float(inset))
        if key in self.tried:
            return n
        V2, F2, before = self.make(n, int(sd), inset)
        c = self.tried[key] = self.figures(V2, F2)
        self.meshes[key] = (V2, F2, before)
        what = (f"scale3d {c['scale3d']:.3f}, longest flat cell {c['max_cell_length_mm']:.2f} mm"
                if _laid_out(c) else f"no layout ({c['error']})")
        if c.get("clamped_estimate") is not None:
            what += f", ~{100 * c['clamped_estimate']:.0f} % of cells clamped"
        opt = self.optimisation.get(key)
        if self.optimize and self.dom is not None and opt is None:
            what += " (not optimised: hopeless)"
        self.say(f"N={n} seed={sd} rim inset {inset:g} mm: {what}")
        if opt is not None and opt["rounds"] == 0:
            why = opt["history"][0]["why"] if opt["history"] else "no interior vertex"
            self.say(f"warning: N={n} seed={sd}: the stencil optimisation kept no round ({why})")
        return n

    # -- the count -------------------------------------------------------------------
    def log_scale(self, n: int, seeds, inset: float):
        """The mean log 3D scaling of the candidates of count ``n`` over ``seeds`` (None when
        none was laid out): what the secant steers on.  One seed's scaling scatters by a few
        per cent around the trend in N (the tightest cell decides it), as much as two rungs
        of the ladder; the mean over the seeds is a smoother function of N."""
        s3 = [self.tried[(n, int(sd), float(inset))]["scale3d"] for sd in seeds]
        s3 = [x for x in s3 if x is not None]
        return float(np.mean(np.log(s3))) if s3 else None

    def secant(self, inset: float, start: int, seeds) -> int:
        """Secant steps of N toward a 3D scaling of 1 (``scale3d ~ N^k``, k = 1/2 for a
        uniform mesh, else the slope of the last two), on the mean over ``seeds``
        (:meth:`log_scale`), until a step stays on its rung; returns the last N tried
        (every seed tried there).  There is no stop at a tolerance on the scaling: a mean
        1e-4 either side of it sent the search on or not (the dome at 0.7 under one BLAS
        thread against two), and the count taken is the nearest 1 of those tried anyway."""
        st = self.settings
        pts = []  # (log N, mean log scale3d)
        n = self.rung(start)
        for sd in seeds:
            self.trial(n, sd, inset)
        for _ in range(st.count_steps):
            ls = self.log_scale(n, seeds, inset)
            if ls is None:
                break
            pts.append((np.log(n), ls))
            k = 0.5
            if len(pts) >= 2 and abs(pts[-1][0] - pts[-2][0]) > st.count_secant_min:
                k = float(np.clip((pts[-1][1] - pts[-2][1]) / (pts[-1][0] - pts[-2][0]),
                                  0.25, 1.0))
            n_next = self.rung(n * np.exp(-ls / k))
            if n_next == n:
                break  # (the step is within half a rung)
            for sd in seeds:
                self.trial(n_next, sd, inset)
            n = n_next
        return n

    def search_inset(self, inset: float, vertices, seeds, start: list) -> None:
        """All candidates of one rim inset: the given count with every seed, or the secant
        steps with every seed and ``candidates`` around their result (``start`` holds the
        count to start from, updated; the count found is ``self.centres[inset]``)."""
        st = self.settings
        if vertices is not None:
            for sd in seeds:
                self.trial(int(vertices), sd, inset, given=True)
            self.centres[float(inset)] = max(int(vertices), 8)
            return
        n = start[0] = self.secant(inset, start[0], seeds)
        visited = sorted({k[0] for k in self.tried if k[2] == float(inset)
                          and self.log_scale(k[0], seeds, inset) is not None
                          and all((k[0], int(sd), float(inset)) in self.tried for sd in seeds)})
        if visited:  # (the count whose mean scaling is nearest 1, not where the steps ended)
            n = min(visited, key=lambda m: (abs(self.log_scale(m, seeds, inset)), m))
        self.centres[float(inset)] = n
        for f in st.candidates:
            for sd in seeds:
                self.trial(round(n * f), sd, inset)

    def search(self, vertices, seeds, start: int):
        """Every inset in turn until one gives a candidate printable with the margin at
        size, then the rim fallback; returns the key picked and the rim record.  Refuses a
        target none of whose stencils could be laid out."""
        st, limit = self.settings, self.params.max_cell_length
        start = [start]
        for inset in self.insets:
            try:
                self.search_inset(inset, vertices, seeds, start)
            except RimInsetError:
                continue
            if any(at_size(c, st) and c["max_cell_length_mm"] <= limit - st.margin
                   for c in self.tried.values()):
                break
        best = _pick(self.tried, self.params, st.margin, st, self.centres)
        if best is None:
            why = "; ".join(sorted({c["error"] for c in self.tried.values() if "error" in c}))
            why = why or "every rim inset splits the target"
            raise InputError(f"no stencil of this target could be laid out ({why})",
                             fix="check the target (it may fold sharply or be too small for "
                                 "4 mm bases), or give --vertices")
        rim = None
        if best[2] > 0:
            def rim_search():
                if not any(k[2] == 0.0 for k in self.tried):
                    self.search_inset(0.0, vertices, seeds, start)
            region = None if self.dom is None else self.dom.region_covered(best[2])
            best, rim = _rim_fallback(best, self.tried, self.meshes, self.area, self.params,
                                      st, rim_search, self.centres, region)
            self.say(f"rim: {rim['why']}")
        return best, rim

    def converge(self, best) -> None:
        """The pick optimised on until its rounds converge (``opt_converge_rounds``,
        ``opt_round_tol``): its figures then no longer depend on where the candidate's
        rounds stopped.  Updates the candidate's stencil, figures and record in place.
        (The rim stays where the candidate's rounds slid it: sliding it on here lowered
        petal's 3D scaling from 0.982 to 0.954, and the pick was taken for its scaling.)"""
        st = self.settings
        V2, F2, before = self.meshes[best]
        P, t_P = self.flat[best]
        P, opt = optimize_stencil(self.dom, P, F2, self.params, st, t_vertex=t_P,
                                  converge=True)
        old = self.tried[best]
        Vc = self.dom.lift(P)
        c = self.figures(Vc, F2)
        limit = self.params.max_cell_length
        if old["max_cell_length_mm"] <= limit - st.margin:
            limit -= st.margin  # (a pick within the margin stays within it)
        if not opt["rounds"] or not _laid_out(c) or (at_size(old, st) and not at_size(c, st)) \
                or c["max_cell_length_mm"] > max(old["max_cell_length_mm"], limit):
            return  # (the objective fell, but the figures the pick took it for did not hold)
        self.flat[best] = (P, t_P)
        self.meshes[best] = (Vc, F2, before)
        self.tried[best] = c
        first = self.optimisation[best]
        self.optimisation[best] = {
            "rounds": first["rounds"] + opt["rounds"], "converged": opt["converged"],
            "history": first["history"] + [{**h, "round": len(first["history"]) + h["round"]}
                                           for h in opt["history"]]}
        self.say(f"N={best[0]} seed={best[1]} converged in {len(opt['history'])} more "
                 f"round(s): scale3d {c['scale3d']:.3f}, longest flat cell "
                 f"{c['max_cell_length_mm']:.2f} mm")

    def polish(self, best):
        """The chosen stencil optimised again with its 3D scaling held at 1 (the longest flat
        cell per unit of scaling).  The size asked for is the size delivered: the stencil
        held at 1 is kept whenever it prints (its longest flat cell within the limit), even
        when the pick, at another scaling, had a shorter cell.  When it does not print, it
        is still kept if it is nearer the size at no longer cell; otherwise the pick stays,
        and the design stage refuses it with measured alternatives (a smaller ``--size``)
        unless it is at full size (:func:`full_size`).  (Holding a smaller scaling instead,
        0.969, made the petal and the peer top print 3 % under the size asked for.)

        Returns
        -------
        V2 : (k, 3) float, mm -- the stencil kept
        chosen : dict -- its figures
        record : dict -- ``scale3d``, ``max_cell_length_mm`` of the polished stencil,
            ``kept`` (it is the stencil returned), ``held`` (the stencil returned is within
            ``polish_tolerance`` of scale 1), ``rounds``
        """
        st, limit = self.settings, self.params.max_cell_length
        V2, F2, _ = self.meshes[best]
        chosen = self.tried[best]
        Vp, fig, opt = self._pinned(best, 1.0)
        L0 = chosen["max_cell_length_mm"]
        if _laid_out(fig) and (fig["max_cell_length_mm"] <= limit or (
                abs(np.log(fig["scale3d"])) <= abs(np.log(chosen["scale3d"]))
                and fig["max_cell_length_mm"] <= L0)):
            V2, chosen = Vp, fig
        held = full_size(chosen, st)
        record = {"scale3d": fig["scale3d"], "max_cell_length_mm": fig["max_cell_length_mm"],
                  "kept": chosen is fig, "held": bool(held), "rounds": opt["history"]}
        what = (f"scale3d {fig['scale3d']:.3f}, longest flat cell "
                f"{fig['max_cell_length_mm']:.2f} mm" if _laid_out(fig) else "no layout")
        self.say(f"N={best[0]} seed={best[1]} held at scale 1: {what} "
                 + ("(kept)" if chosen is fig else "(dropped)")
                 + ("" if held else f"; could not hold the scaling at 1 (the stencil kept "
                                    f"is at {chosen['scale3d']:.3f})"))
        return V2, chosen, record

    def _pinned(self, best, scale3d: float):
        """The pick ``best`` optimised with its 3D scaling held at ``scale3d``: its vertices
        (mm), figures and :func:`optimize_stencil`'s info."""
        P, t_P = self.flat[best]
        P, opt = optimize_stencil(self.dom, P, self.meshes[best][1], self.params,
                                  self.settings, t_vertex=t_P, pin=True, converge=True,
                                  pin_scale3d=scale3d)
        Vp = self.dom.lift(P)
        return Vp, self.figures(Vp, self.meshes[best][1]), opt

    def alternates(self, best) -> list:
        """The other starts (seeds) of the count and rim inset of ``best`` that keep the size
        asked for, shortest longest cell per unit of scaling first: polished in turn when
        the polish of ``best`` does not print at full size."""
        at = [k for k, c in self.tried.items() if k != best and k[0] == best[0]
              and k[2] == best[2] and k in self.flat and at_size(c, self.settings)]
        return sorted(at, key=lambda k: (_per_scale(self.tried[k]), k))

    def records(self) -> list:
        """Every candidate's optimisation rounds, for ``design.json``."""
        return [{"vertices": k[0], "seed": k[1], "rim_inset_mm": k[2],
                 "rounds_kept": v["rounds"], "rounds": v["history"]}
                for k, v in sorted(self.optimisation.items())]


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
        Vertex count N; otherwise searched (module docstring).
    seed : int, optional
        Seed of the CVT initialisation; otherwise ``settings.seeds`` seeds are tried.
    target_bases : int, optional
        Start of the search (about 2 N); default ``count_start`` x the paper's estimate.
    params : UnitCell
    settings : StencilSearch
    method : {"cvt", "pymeshlab"}
    dense : bool, optional
        Resample the input finely with pymeshlab first (default: when the input's
        triangles are poor, min angle < 15 deg, or it has fewer than 2000 faces).
    optimize : bool
        Run the stencil optimisation (:mod:`pysolver.design.stencil_opt`).
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
        ``at_size`` (:func:`at_size` of the stencil returned: False when no printable stencil
        keeps the size asked for; the design stage then refuses it), the figures
        (:func:`stencil_figures`) ``before_optimisation`` / ``after_optimisation``,
        ``candidates``, ``optimisation`` (:meth:`CountSearch.records`), ``polish``, ``rim``
        (:func:`_rim_fallback`), ``timing_grading``, ``trade`` (:func:`_trade`), ``warnings``.
    """
    V, F, time, _ = canonical_order(V, F, time)  # (a function of the geometry, not the labels)
    if settings.rim_scale not in ("auto", "kept", "free"):
        raise InputError(f"StencilSearch.rim_scale={settings.rim_scale!r}",
                         fix='use "auto", "kept" or "free"')
    call = dict(V=V, F=F, vertices=vertices, seed=seed, target_bases=target_bases,
                params=params, method=method, dense=dense, optimize=optimize, time=time,
                user_times=user_times, progress=progress)
    A = surface_area(V, F)
    info = {"remeshed": True, "method": method, "area_mm2": round(A, 2),
            "estimate_paper": estimate_vertices(A)}
    V, F, time = _search_target(V, F, time, method, dense, settings, info)
    graded = method == "cvt" and user_times and time is not None and settings.timing_grading > 0
    search = CountSearch(V, F, time, params=params, settings=settings, method=method,
                         optimize=optimize, graded=graded, progress=progress)
    seeds = ([int(seed)] if seed is not None
             else [0] if method == "pymeshlab"  # (it has no seed)
             else list(range(settings.seeds)))
    best, rim = search.search(vertices, seeds, (
        int(target_bases / 2) if target_bases
        else round(settings.count_start * estimate_vertices(A))))
    best, V2, F2, before, chosen = _polish_and_trade(
        search, best, info, seeds, trade=user_times and time is not None and vertices is None)
    if graded and not (chosen["max_cell_length_mm"] <= params.max_cell_length
                       and chosen["scale3d"] >= settings.trade_min_scale3d):
        return _without_grading(call, settings, chosen, search)
    info["timing_grading"] = {"grading": settings.timing_grading if graded else 0.0,
                              "taken": bool(graded)}
    _record(info, search, best, (V2, F2, before), chosen, rim, optimize, A)
    return _rim_scale(call, settings, (V2, F2, info), search)


def _rim_scale(call: dict, settings: StencilSearch, result, search: CountSearch):
    """A search's ``result = (V2, F2, info)`` with its rim's scale recorded
    (``info["rim_scale"]``, and ``info["rim_log_scale"]``, (k,) per stencil vertex, when
    free); with ``rim_scale="auto"`` and no stencil printable at size, the search again with
    the rim's scale free (:func:`_free_rim`), unless the measured bound excludes that too
    (:func:`pysolver.design.feasibility.conformal_bound`: a hopeless search cut)."""
    V2, F2, info = result
    why = f"rim_scale={settings.rim_scale!r}"
    if settings.rim_scale == "auto" and search.dom is not None and call["vertices"] is None \
            and not _delivered(info, call["params"]):
        bound = conformal_bound(search.V, search.F, call["params"])["bound_mm"]
        if bound <= call["params"].max_cell_length:
            return _free_rim(call, settings, result, search)
        why = (f"no stencil printed with the rim's lengths kept, and the bound excludes its "
               f"scale free too ({bound:.2f} mm)")
    free = search.dom is not None and search.dom.rim_u is not None
    info["rim_scale"] = {"scale": "free" if free else "kept", "why": why}
    if free:
        info["rim_log_scale"] = search.rim_scale_at(V2)
    return V2, F2, info


def _delivered(info: dict, params: UnitCell) -> bool:
    """Whether the stencil a search returns (its ``info``, :func:`remesh_surface`) prints at
    the size asked for."""
    return bool(info["at_size"]) and info["max_cell_length_mm"] <= params.max_cell_length


def _free_rim(call: dict, settings: StencilSearch, kept, search: CountSearch):
    """No stencil of the search with the rim's lengths kept printed at size: the search
    again with the rim's scale free (``call``: the arguments of :func:`remesh_surface`;
    ``kept = (V2, F2, info)`` its result).  The free stencil is taken when it prints at size,
    or when neither does and it ranks higher: at size first, then by its longest flat cell
    per unit of 3D scaling (as :func:`_pick`).  When the free search fails, the kept
    result stands.

    Returns
    -------
    V2, F2, info : as :func:`remesh_surface`; ``info["rim_scale"]`` says which was taken
    and why, with the other's figures.
    """
    V2, F2, info = kept
    search.say("no stencil prints at size with the rim's lengths kept: searching again with "
               "the rim's scale free")
    try:
        V3, F3, free = remesh_surface(**call, settings=replace(settings, rim_scale="free"))
    except InputError as e:  # (the kept result's refusal names measured alternatives)
        info["rim_scale"] = {"scale": "kept", "why": f"the search with the rim's scale free "
                             f"failed: {e.problem}"}
        return V2, F2, info
    def rank(r):  # at size first, then the longest cell per unit of scaling (as _pick)
        return (r["at_size"], -_per_scale(r["after_optimisation"]))
    take = _laid_out(free["after_optimisation"]) and (
        _delivered(free, call["params"]) or rank(free) > rank(info))
    figures = {k: info[k] for k in ("vertices", "scale3d", "max_cell_length_mm", "at_size")}
    if not take:
        info["rim_scale"] = {"scale": "kept", "why": "the rim's scale free printed no better",
                             "free": {k: free[k] for k in figures}}
        return V2, F2, info
    free["rim_scale"] = {"scale": "free", "why": "no stencil printed at size with the rim's "
                         "lengths kept", "kept": figures}
    search.say(f"rim scale free: {free['vertices']} vertices, scale3d {free['scale3d']:.3f}, "
               f"longest flat cell {free['max_cell_length_mm']:.2f} mm (kept: "
               f"{info['max_cell_length_mm']:.2f} mm at {info['scale3d']:.3f})")
    return V3, F3, free


def _polish_and_trade(search: CountSearch, best, info: dict, seeds, trade: bool):
    """The pick polished (:meth:`CountSearch.polish`) and, for a landscape the user gave with
    the count searched, traded for fewer cells (:func:`_trade`); records both in ``info``.

    Returns
    -------
    best : (int, int, float) -- the key of the stencil returned
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
    if trade and _laid_out(chosen):
        kept = best, V2, F2, before, chosen, info.get("polish")
        best, V2, F2, chosen = _trade(best, V2, F2, chosen, search.trial, search.tried,
                                      search.meshes, search.params, search.settings, info,
                                      search.progress, seeds=seeds)
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


def _without_grading(call: dict, settings: StencilSearch, chosen: dict, search: CountSearch):
    """The graded spacing asked for cells the limit does not allow: the search again,
    spaced by the target alone (``call``: the arguments of :func:`remesh_surface`)."""
    search.say(f"time-graded stencil: longest flat cell {chosen['max_cell_length_mm']:.2f}"
               f" mm, scale3d {chosen['scale3d']:.3f}: searching again without")
    V2, F2, again = remesh_surface(**call, settings=replace(settings, timing_grading=0.0))
    again["timing_grading"] = {"grading": settings.timing_grading, "taken": False,
                               "max_cell_length_mm": chosen["max_cell_length_mm"],
                               "scale3d": chosen["scale3d"]}
    return V2, F2, again


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
        rim = {"inset_mm": float(best[2]), "area_covered": _covered(V2, F2, A),
               "fallback": None, "why": ("the stencil reaches the target's rim" if best[2] <= 0
                                         else "the inset stencil covers enough of the target")}
    else:
        rim["area_covered"] = _covered(V2, F2, A)  # of the final stencil (polished, traded)
    records = search.records()
    info.update(vertices=int(len(V2)), requested=int(best[0]), seed=int(best[1]),
                rim_inset_mm=float(best[2]), rim=rim, scale3d=chosen["scale3d"],
                max_cell_length_mm=chosen["max_cell_length_mm"],
                at_size=bool(full_size(chosen, search.settings) if "polish" in info
                             else at_size(chosen, search.settings)),
                before_optimisation=(stencil_figures(*before, search.params,
                                                     u_boundary=search.rim_scale_at(before[0]))
                                     if optimize else None),
                after_optimisation=chosen,
                candidates=[[k[0], k[1], k[2], v["scale3d"], v["max_cell_length_mm"]]
                            for k, v in sorted(search.tried.items())],
                optimisation=records,
                warnings=[f"the stencil optimisation kept no round for the stencil chosen "
                          f"(N={best[0]} seed={best[1]}: {r['rounds'][0]['why']})"
                          for r in records if (r["vertices"], r["seed"], r["rim_inset_mm"])
                          == best and r["rounds_kept"] == 0 and r["rounds"]])


__all__ = ["stencil_figures", "at_size", "full_size", "prints_at_full_size", "CountSearch",
           "remesh_surface"]
