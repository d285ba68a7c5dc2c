"""The vertex-count search over one target (:class:`CountSearch`); its entry point is
:func:`pysolver.design.stencil.search.remesh_surface`.

A stencil's 3D size is not chosen directly: the layout's 3D rule scales it until its
tightest cell just keeps its bumpers (``pipeline.md`` §2.5), so the vertex count N fixes the
shell's size.  The search looks for N so that the shell keeps the size asked for
(3D scaling about 1) with every flat cell printable (``UnitCell.max_cell_length``).

**A function of the geometry.**  The same surface must give the same shell however its mesh
is labelled, placed or rounded, and on any machine (issue #42).  The search reads the target
in a canonical order (:func:`pysolver.geometry.canonical_order`: relabelled inputs give the
same stencil to the last bit) and, unless a symmetry leaves it undecided, in its own frame
(:func:`pysolver.geometry.canonical_pose`: a rigidly moved input then differs by the
round-off of its coordinates only, as on another CPU, where before it reordered every sum),
the stencils are seeded by position in a frame the target's shape sets
(:mod:`pysolver.design.stencil.remesh`: a rigid motion or a last-bit jitter moves them by as
little), and the search does not steer on one noisy start: each count is tried with
``StencilSearch.seeds`` CVT seeds, whose 3D scalings scatter by a few per cent (the tightest
cell decides it), as much as two rungs of the count's ladder.  We chose *several starts per
count* over one start with a converged objective because the scatter is not the optimiser's
(each start's rounds converge) but the starts' own: different triangulations of the same
surface are different local optima, and the count that a single start's scaling points to
moved with them (petal, relabelled: 172 to 233 bases).  Each start is itself a function of its
input, not of the machine: its rounds, and the polish's, run to a tight projected gradient
(``StencilSearch.opt_timing_gtol``; the polish's pinned rounds too), so that two CPU code paths
end a round at the same point and the next round does not set off toward another minimum (the
cover's candidates agree to six digits with and without AVX2).  So is the dense
resampling of a coarse or sliver-ridden user mesh
(:func:`~pysolver.design.stencil.remesh.resample_dense`, a midpoint subdivision: its points
are fixed linear combinations of the input's).

1. **Secant steps** on the mean log 3D scaling over the seeds (about ``sqrt(N)``) toward 1,
   from the paper's estimate ``0.38 A / 7^2`` times ``StencilSearch.count_start``, every
   count on one fixed geometric ladder (``StencilSearch.count_ladder``,
   :meth:`CountSearch.rung`); then the next rim inset when nothing is printable.  The count
   taken is the one tried whose mean scaling is nearest 1 among those with a start that
   would print at full size, not where the steps stopped (two counts' means can tie to the
   last bits: the nearest without such a start gave way to a fallback, and a rounding
   flipped the shell between 235 bases and a refusal).
2. **The pick** (:func:`pysolver.design.stencil.candidates.pick`, the one place the rule
   lives): among the seeds at that count that keep the size (:func:`~.candidates.at_size`:
   3D scaling within ``[min_scale3d, 1 / min_scale3d]``) and would print held at scale 1,
   the shortest longest cell per unit of scaling: the best of several starts.  Else the
   former rule: scaling closest to 1 among those that print with the margin
   (:func:`~.candidates.prints`), else within the limit.
3. **The rim** (:meth:`CountSearch.rim_fallback`): a narrow target whose inset region
   covers too little also gets the stencil reaching the rim, taken if it prints as well.
4. **The polish** (:meth:`CountSearch.converge`, :meth:`CountSearch.polish`): the pick
   optimised on until its rounds converge, then with its 3D scaling held at 1.  The size
   asked for is the size delivered: a stencil that prints at scale 1 is taken there, and
   when the pick's does not, the count's other seeds, then the next counts' starts are
   polished in turn (:meth:`CountSearch.alternates`, at most
   ``StencilSearch.polish_tries``).  A stencil that prints only off the size
   (:func:`~.candidates.full_size`) is refused by the design stage, naming a measured
   ``--size``.
5. **The trade** (:meth:`CountSearch.trade`), with a landscape the user gave: fewer, larger
   cells when they clamp markedly fewer cells, polished at full size too.
6. **The rim's scale** (``StencilSearch.rim_scale``, :mod:`.search`): when no stencil
   prints at size with the rim's lengths kept, the search runs again in the flattening
   whose boundary log-scale lowers the measured bound
   (:func:`pysolver.design.stencil.feasibility.rim_log_scale`), and its stencil is taken if it
   prints, or comes closer.

Every candidate's optimisation rounds (kept or not, and why) are recorded
(``info["optimisation"]``), and a stencil whose optimisation keeps no round is warned about.
Nothing is tuned per shape.  Measured stability: ``docs/results.md`` ("One surface, one
shell"), ``bench/bench_stability.py``.
"""

from __future__ import annotations

import numpy as np

from ...errors import InputError
from ...params import StencilSearch, UnitCell
from ..time_landscape import interpolate_to_stencil
from .candidates import (
    Candidate,
    area_covered,
    at_size,
    full_size,
    laid_out,
    per_scale,
    pick,
    prints,
    stencil_figures,
    tier,
    would_print_at_size,
)
from .feasibility import rim_log_scale
from .optimise import optimize_stencil
from .remesh import FlatDomain, RimInsetError, isotropic_remesh, remove_ears, surface_area


class CountSearch:
    """The vertex-count search over one target: every candidate stencil tried.

    A class because the candidates (figures, meshes, optimised flat points and their
    optimisation records, by :class:`~.candidates.Candidate`) are shared by the secant
    steps, the pick, the rim fallback, the polish and the trade.

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
    posed : bool -- V is in the target's own frame (:func:`pysolver.geometry.canonical_pose`
        decided it): the flat frame's mirror ties are broken by it
    """

    def __init__(self, V, F, time, *, params: UnitCell, settings: StencilSearch,
                 method: str, optimize: bool, graded: bool, progress=None,
                 posed: bool = False):
        self.V, self.F, self.time = V, F, time
        self.params, self.settings = params, settings
        self.method, self.optimize, self.progress = method, optimize, progress
        self.area = surface_area(V, F)
        self.tried: dict = {}
        self.meshes: dict = {}
        self.flat: dict = {}  # key -> optimised flat points, time at them
        self.optimisation: dict = {}  # key -> optimise_stencil's info
        self.centres: dict = {}  # rim inset (mm) -> counts, nearest scale 1 first
        self.dom = None
        if method == "cvt":
            h = rim_log_scale(V, F, params, settings) if settings.rim_scale == "free" else None
            self.dom = FlatDomain(V, F, settings, time=time if graded else None,
                                  rim_log_scale=h, posed=posed)
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
            self.flat[Candidate(n, sd, inset)] = (P, t_P)
            self.optimisation[Candidate(n, sd, inset)] = opt
        return self.dom.lift(P), F2, before

    def hopeless(self, V2, F2) -> bool:
        """Whether a stencil before optimisation is so far from the size asked for that the
        optimisation (which moves its scaling by up to about a fifth) cannot make it the
        pick: ``|log scale3d| > hopeless_log_scale``.  Its figures are then taken as they
        are, for the secant steps only.  (Its longest cell is no such test: a target that
        prints nowhere is refused naming the closest stencil tried, which must be optimised.)"""
        c = stencil_figures(V2, F2, self.params, settings=self.settings,
                            u_boundary=self.rim_scale_at(V2))
        return not laid_out(c) or abs(np.log(c["scale3d"])) > self.settings.hopeless_log_scale

    def rim_scale_at(self, V2):
        """(k,) float or None: the boundary log-scale of the layout of a stencil ``V2``
        (k, 3) mm (:meth:`pysolver.design.stencil.remesh.FlatDomain.rim_scale_at`)."""
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
        key = Candidate(n, sd, inset)
        if key in self.tried:
            return n
        V2, F2, before = self.make(n, int(sd), inset)
        c = self.tried[key] = self.figures(V2, F2)
        self.meshes[key] = (V2, F2, before)
        what = (f"scale3d {c['scale3d']:.3f}, longest flat cell {c['max_cell_length_mm']:.2f} mm"
                if laid_out(c) else f"no layout ({c['error']})")
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
        s3 = [self.tried[Candidate(n, sd, inset)]["scale3d"] for sd in seeds]
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
        count to start from, updated; ``self.centres[inset]`` holds the counts tried with
        every seed, the nearest a mean scaling of 1 first)."""
        st = self.settings
        if vertices is not None:
            for sd in seeds:
                self.trial(int(vertices), sd, inset, given=True)
            self.centres[float(inset)] = (max(int(vertices), 8),)
            return
        n = start[0] = self.secant(inset, start[0], seeds)
        visited = sorted({k.vertices for k in self.tried if k.inset_mm == float(inset)
                          and self.log_scale(k.vertices, seeds, inset) is not None
                          and all(Candidate(k.vertices, sd, inset) in self.tried
                                  for sd in seeds)})
        # the counts by how near 1 their mean scaling is, not where the steps ended: the pick
        # takes the nearest whose stencils would print at full size
        ranked = sorted(visited, key=lambda m: (abs(self.log_scale(m, seeds, inset)), m))
        if ranked:
            n = ranked[0]
        self.centres[float(inset)] = tuple(ranked) or (n,)
        for f in st.candidates:
            for sd in seeds:
                self.trial(round(n * f), sd, inset)

    def search(self, vertices, seeds, start: int):
        """Every inset in turn until one gives a candidate printable with the margin at
        size, then the rim fallback; returns the key picked and the rim record.  Refuses a
        target none of whose stencils could be laid out."""
        st = self.settings
        start = [start]
        for inset in self.insets:
            try:
                self.search_inset(inset, vertices, seeds, start)
            except RimInsetError:
                continue
            if any(at_size(c, st) and prints(c, self.params, st.margin)
                   for c in self.tried.values()):
                break
        best = pick(self.tried, self.params, st.margin, st, self.centres)
        if best is None:
            why = "; ".join(sorted({c["error"] for c in self.tried.values() if "error" in c}))
            why = why or "every rim inset splits the target"
            raise InputError(f"no stencil of this target could be laid out ({why})",
                             fix="check the target (it may fold sharply or be too small for "
                                 "4 mm bases), or give --vertices")
        rim = None
        if best.inset_mm > 0:
            region = None if self.dom is None else self.dom.region_covered(best.inset_mm)
            best, rim = self.rim_fallback(best, region, vertices, seeds, start)
            self.say(f"rim: {rim['why']}")
        return best, rim

    def rim_fallback(self, best: Candidate, region, vertices, seeds, start: list):
        """The stencil without a rim inset as a measured alternative to the inset pick.

        When the inset's region covers less than ``settings.min_area_covered`` of the target
        (``region``: :meth:`pysolver.design.stencil.remesh.FlatDomain.region_covered`, a
        function of the target; None: the pick's own cover), the counts are searched without
        an inset (:meth:`search_inset`, with ``vertices``, ``seeds`` and ``start`` as
        :meth:`search`'s); their pick replaces ``best`` only if it prints at least as well
        (:func:`~.candidates.tier`: never worse than the inset stencil and never beyond the
        limit).

        Returns
        -------
        best : Candidate
            The candidate chosen.
        rim : dict
            ``inset_mm``, ``min_area_covered``, ``inset_area_covered`` (of the inset
            stencil), ``inset_region_covered`` (what the decision measured), ``fallback``
            (None when not searched, else ``requested``, ``seed``, ``scale3d``,
            ``max_cell_length_mm``, ``area_covered``, ``taken``) and ``why``.
        """
        st, params = self.settings, self.params
        own = area_covered(*self.meshes[best][:2], self.area)
        cov = own if region is None else region
        rim = {"inset_mm": best.inset_mm, "min_area_covered": st.min_area_covered,
               "inset_area_covered": own, "inset_region_covered": cov, "fallback": None}
        if cov >= st.min_area_covered:
            rim["why"] = (f"the inset region covers {100 * cov:.0f} % of the target (at least "
                          f"{100 * st.min_area_covered:.0f} %)")
            return best, rim
        if not any(k.inset_mm == 0.0 for k in self.tried):
            try:
                self.search_inset(0.0, vertices, seeds, start)
            except RimInsetError:  # (inset 0 never splits the target; kept for symmetry)
                pass
        alt = pick({k: c for k, c in self.tried.items() if k.inset_mm == 0.0}, params,
                   st.margin, centres=self.centres)
        if alt is None:
            rim["why"] = (f"the inset region covers {100 * cov:.0f} % of the target; no "
                          "stencil without the inset could be laid out")
            return best, rim
        c, c0 = self.tried[alt], self.tried[best]
        taken = tier(c, params, st.margin) <= min(tier(c0, params, st.margin), 1)
        rim["fallback"] = {"requested": alt.vertices, "seed": alt.seed,
                           "scale3d": c["scale3d"], "max_cell_length_mm": c["max_cell_length_mm"],
                           "area_covered": area_covered(*self.meshes[alt][:2], self.area),
                           "taken": bool(taken)}
        lengths = (f"longest flat cell {c['max_cell_length_mm']:.2f} mm, "
                   f"{c0['max_cell_length_mm']:.2f} mm with the inset")
        under = (f"the inset region covers {100 * cov:.0f} % of the target (under "
                 f"{100 * st.min_area_covered:.0f} %)")
        if taken:
            rim["why"] = f"{under}; the stencil reaching the rim prints ({lengths})"
            rim["inset_mm"] = 0.0
            return alt, rim
        rim["why"] = (f"{under}, but the stencil reaching the rim prints worse ({lengths}; "
                      f"limit {params.max_cell_length:.2f} mm, margin {st.margin:.2f} mm)")
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
        # (a pick that prints with the margin stays within it)
        limit = self.params.max_cell_length - (st.margin if prints(old, self.params, st.margin)
                                               else 0.0)
        if not opt["rounds"] or not laid_out(c) or (at_size(old, st) and not at_size(c, st)) \
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
        self.say(f"N={best.vertices} seed={best.seed} converged in {len(opt['history'])} more "
                 f"round(s): scale3d {c['scale3d']:.3f}, longest flat cell "
                 f"{c['max_cell_length_mm']:.2f} mm")

    def polish(self, best):
        """The chosen stencil optimised again with its 3D scaling held at 1 (the longest flat
        cell per unit of scaling).  The size asked for is the size delivered: the stencil
        held at 1 is kept whenever it prints (its longest flat cell within the limit), even
        when the pick, at another scaling, had a shorter cell.  When it does not print, it
        is still kept if it is nearer the size at no longer cell; otherwise the pick stays,
        and the design stage refuses it with measured alternatives (a smaller ``--size``)
        unless it is at full size (:func:`~.candidates.full_size`).  (Holding a smaller
        scaling instead, 0.969, made the petal and the peer top print 3 % under the size asked for.)

        Returns
        -------
        V2 : (k, 3) float, mm -- the stencil kept
        chosen : dict -- its figures
        record : dict -- ``scale3d``, ``max_cell_length_mm`` of the polished stencil,
            ``kept`` (it is the stencil returned), ``held`` (the stencil returned is within
            ``polish_tolerance`` of scale 1), ``rounds``
        """
        st = self.settings
        V2, F2, _ = self.meshes[best]
        chosen = self.tried[best]
        Vp, fig, opt = self._pinned(best, 1.0)
        L0 = chosen["max_cell_length_mm"]
        if laid_out(fig) and (prints(fig, self.params) or (
                abs(np.log(fig["scale3d"])) <= abs(np.log(chosen["scale3d"]))
                and fig["max_cell_length_mm"] <= L0)):
            V2, chosen = Vp, fig
        held = full_size(chosen, st)
        record = {"scale3d": fig["scale3d"], "max_cell_length_mm": fig["max_cell_length_mm"],
                  "kept": chosen is fig, "held": bool(held), "rounds": opt["history"]}
        what = (f"scale3d {fig['scale3d']:.3f}, longest flat cell "
                f"{fig['max_cell_length_mm']:.2f} mm" if laid_out(fig) else "no layout")
        self.say(f"N={best.vertices} seed={best.seed} held at scale 1: {what} "
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
        """What is polished in turn when the polish of ``best`` does not print at full size:
        the other starts (seeds) of its count and rim inset that keep the size asked for, then
        the starts of the other counts of that inset (nearest a mean scaling of 1 first,
        ``self.centres``) that keep it and would print held at scale 1; within a count, the
        shortest longest cell per unit of scaling first; ``StencilSearch.polish_tries - 1``
        at most (``best`` itself is always polished)."""
        st, inset = self.settings, best.inset_mm
        ok = {k: c for k, c in self.tried.items()
              if k != best and k.inset_mm == inset and k in self.flat and at_size(c, st)}
        same = sorted((k for k in ok if k.vertices == best.vertices),
                      key=lambda k: (per_scale(ok[k]), k))
        rank = {n: i for i, n in enumerate(self.centres.get(inset, ()))}
        other = sorted((k for k, c in ok.items() if k.vertices != best.vertices
                        and k.vertices in rank and would_print_at_size(c, self.params, st)),
                       key=lambda k: (rank[k.vertices], per_scale(ok[k]), k))
        return (same + other)[:max(st.polish_tries - 1, 0)]

    def trade(self, best: Candidate, V2, F2, chosen: dict, info: dict, seeds=None):
        """Fewer, larger (faster) cells for a landscape that asks for early times.

        Tries ``settings.trade_counts`` x the chosen count (each of ``seeds``, default the
        chosen one; same inset) and takes, among every stencil tried with fewer vertices, the
        one with the lowest estimated clamped fraction among those that print with the
        margin (:func:`~.candidates.prints`), keep a 3D scaling of at least
        ``trade_min_scale3d`` and clamp at least ``trade_gain`` fewer cells than the chosen
        stencil.  Records ``info["trade"]``.

        Returns
        -------
        best : Candidate
        V2 : (k, 3) float, mm
        F2 : (f, 3) int
        chosen : dict -- the figures of the stencil returned
        """
        st, n0, inset = self.settings, best.vertices, best.inset_mm
        for f in st.trade_counts:
            for s in (seeds or [best.seed]):
                self.trial(round(n0 * f), s, inset)
        est0 = chosen["clamped_estimate"]
        fewer = [k for k in self.tried if k.inset_mm == inset and k.vertices < n0]
        ok = [k for k in fewer if prints(self.tried[k], self.params, st.margin)
              and self.tried[k]["scale3d"] >= st.trade_min_scale3d
              and self.tried[k]["clamped_estimate"] <= est0 - st.trade_gain]
        record = {"vertices": n0, "scale3d": chosen["scale3d"], "clamped_estimate": est0,
                  "tried": [[k.vertices, k.seed, self.tried[k]["scale3d"],
                             self.tried[k].get("clamped_estimate")] for k in sorted(fewer)],
                  "taken": False}
        if ok:
            k = min(ok, key=lambda k: (self.tried[k]["clamped_estimate"], -k.vertices))
            V2, F2, _ = self.meshes[k]
            record.update(taken=True, to_vertices=k.vertices, to_scale3d=self.tried[k]["scale3d"],
                          to_clamped_estimate=self.tried[k]["clamped_estimate"])
            best, chosen = k, self.tried[k]
        info["trade"] = record
        after = (f", N={best.vertices} ~{100 * chosen['clamped_estimate']:.0f} % at "
                 f"{chosen['scale3d']:.3f}" if ok else "")
        self.say(("fewer, larger cells for the landscape: " if ok else "kept the count: ")
                 + f"N={n0} clamps ~{100 * est0:.0f} % of cells at scale3d "
                 f"{record['scale3d']:.3f}" + after)
        return best, V2, F2, chosen

    def records(self) -> list:
        """Every candidate's optimisation rounds, for ``design.json``."""
        return [{"vertices": k.vertices, "seed": k.seed, "rim_inset_mm": k.inset_mm,
                 "rounds_kept": v["rounds"], "rounds": v["history"]}
                for k, v in sorted(self.optimisation.items())]


__all__ = ["CountSearch"]
