"""Stencil generation on real targets: regularity, the optimisation's closed form and
gradient, the vertex-count search, and the paper's petalled cover designed from its target."""

from __future__ import annotations

import re
import shutil
from dataclasses import replace

import autograd.numpy as anp
import igl
import numpy as np
import pytest
import stencil_oracle as oracle
from _shared import QUICK_SEARCH, quick_stencil_search, shared_file
from autograd import grad
from scipy.special import logsumexp

from pysolver.design import run_design, surfaces
from pysolver.design.flatten import cetm
from pysolver.design.layout import build_layout
from pysolver.design.mesh_input import load_input
from pysolver.design.stencil import candidates, optimise, remesh, search
from pysolver.design.stencil import objective as og
from pysolver.design.stencil.candidates import Candidate
from pysolver.design.stencil.count_search import CountSearch
from pysolver.errors import InputError
from pysolver.geometry import face_adjacency, face_centroids, signed_areas_2d, unit_cells
from pysolver.params import MODEL_FITS, STENCIL, UNIT_CELL


@pytest.fixture(scope="module")
def dome_domain():
    s = surfaces.builtin("dome")
    return remesh.FlatDomain(s.V, s.F, replace(STENCIL, grading=0.0))


def test_opposite_vertices_give_the_centroid_distance(dome_domain):
    P, F = dome_domain.stencil(60, seed=0)
    X = dome_domain.lift(P)
    cells = unit_cells(F, face_adjacency(F))
    o = optimise.opposite_vertices(F, cells)
    C = face_centroids(X, F)
    want = np.linalg.norm(C[cells.faces[:, 0]] - C[cells.faces[:, 1]], axis=1)
    got = np.linalg.norm(X[o[:, 0]] - X[o[:, 1]], axis=1) / 3
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_relaxed_stencil_is_regular_on_the_target(dome_domain):
    # grading 0: the spacing is uniform on the target, so 3D edges should be nearly equal
    # (the relaxation alone: flaps are merged after it, into triangles of >= 30 deg)
    keep_flaps = replace(dome_domain.settings, remove_flaps=False)
    dom = remesh.FlatDomain(dome_domain.V, dome_domain.F, keep_flaps)
    dom0 = remesh.FlatDomain(dome_domain.V, dome_domain.F,
                             replace(keep_flaps, relax_iterations=0))
    relaxed, plain, merged = [], [], []
    for seed in range(3):
        P, F = dom.stencil(70, seed=seed)
        relaxed.append(candidates.stencil_figures(dom.lift(P), F))
        P0, F0 = dom0.stencil(70, seed=seed)
        plain.append(candidates.stencil_figures(dom0.lift(P0), F0)["edge_spread"])
        P1, F1 = dome_domain.stencil(70, seed=seed)
        merged.append(candidates.stencil_figures(dome_domain.lift(P1), F1))
    spread = [r["edge_spread"] for r in relaxed]
    assert max(spread) <= 1.40, spread  # 95th / 5th percentile of 3D edge length
    assert min(r["min_angle_deg"] for r in relaxed) >= 35.0
    assert np.mean(spread) < np.mean(plain)  # the relaxation removes Lloyd's defects
    # merging the flaps keeps the stencil regular (the flat angle bound, a little less in 3D)
    assert max(r["edge_spread"] for r in merged) <= 1.40
    assert min(r["min_angle_deg"] for r in merged) >= STENCIL.flap_min_angle_deg - 2.0


def test_layout_logs_are_the_scaling_rules(dome_domain):
    P, F = dome_domain.stencil(60, seed=1)
    X = dome_domain.lift(P)
    cells = unit_cells(F, face_adjacency(F))
    o = optimise.opposite_vertices(F, cells)
    fa, fb = cells.faces[:, 0], cells.faces[:, 1]
    lay = build_layout(X, P, F, UNIT_CELL, enforce_gap=False)
    # with the flat layout given (no re-flattening), both rules in closed form: exact maxima
    log_s3, log_s2, log_d = oracle.layout_logs(P, X, F, fa, fb, o[:, 0], o[:, 1],
                                               UNIT_CELL, sharpness=None)
    assert np.exp(log_s3) == pytest.approx(lay.scale3d, rel=1e-8)
    assert np.exp(log_s2 + log_d) == pytest.approx(lay.central_length.max(), rel=1e-8)
    # smoothed maxima over-estimate by at most log(cells) / sharpness
    sm = oracle.layout_logs(P, X, F, fa, fb, o[:, 0], o[:, 1], UNIT_CELL, sharpness=60.0)
    assert 0 <= sm[0] - log_s3 <= np.log(len(fa)) / 60 + 1e-12
    # the optimiser's own forward pass (the hand-written one) gives the same logs
    geo = og.CellGeometry(P, X, F, fa, fb, o[:, 0], o[:, 1], STENCIL.opt_tiny)
    for sharp, want in ((None, (log_s3, log_s2, log_d)), (60.0, sm)):
        got = og.Scalings(geo, UNIT_CELL, sharp)
        np.testing.assert_allclose([got.log_s3, got.log_s2, got.log_d], want, rtol=1e-12)
    # the exact checks' smoothed values (scipy's log-sum-exp) are the gradient pass's to the
    # last bits
    checked = og.Scalings(geo, UNIT_CELL, 60.0, lse=logsumexp)
    np.testing.assert_allclose([checked.log_s3, checked.log_s2, checked.log_d], sm, rtol=1e-12)


def _assert_gradient_matches_fd(f, P, seed: int, rel: float, eps: float = 1e-6):
    """autograd's gradient of f at P against central differences along 3 random unit
    directions."""
    g = grad(f)(P)
    rng = np.random.default_rng(seed)
    for _ in range(3):
        d = rng.normal(size=P.shape)
        d /= np.linalg.norm(d)
        fd = (f(P + eps * d) - f(P - eps * d)) / (2 * eps)
        assert np.sum(g * d) == pytest.approx(fd, rel=rel, abs=1e-9)


def test_objective_gradient_matches_finite_differences(dome_domain):
    P, F = dome_domain.stencil(40, seed=2)
    X = dome_domain.lift(P)
    J = dome_domain.lift_jacobian(P)
    cells = unit_cells(F, face_adjacency(F))
    o = optimise.opposite_vertices(F, cells)
    fa, fb = cells.faces[:, 0], cells.faces[:, 1]

    def f(Q):  # the optimiser's inner objective: linearised lift, no barrier
        Xq = X + anp.einsum("nij,nj->ni", J, Q - P)
        a, b, c = oracle.layout_logs(Q, Xq, F, fa, fb, o[:, 0], o[:, 1], UNIT_CELL, 60.0)
        return a + b + c

    _assert_gradient_matches_fd(f, P, seed=0, rel=1e-5)


@pytest.mark.parametrize("pin,timed,slide", [(False, True, True), (True, False, True),
                                              (False, False, True), (True, True, False)],
                         ids=["timing", "pinned", "plain", "pinned-timing-rim-held"])
def test_hand_gradient_is_autograds(dome_domain, pin, timed, slide):
    """The optimiser's hand-written passes (``pysolver.design.stencil.objective``) give the
    value (to 1e-12) and gradient (to 1e-9) autograd takes of the oracle's statement of the
    rules (``tests/stencil_oracle.py``), at a point where the angle, clearance and timing
    penalties are active; and central differences agree with that gradient (1e-4)."""
    P, F = dome_domain.stencil(50, seed=3)
    z = dome_domain.lift(P)[:, 2]
    t = 30.0 + 2.0 * (z - z.min()) if timed else None
    rim = dome_domain.boundary_polygon(0.0) if slide else None
    prob = optimise.StencilObjective(dome_domain, P, F, UNIT_CELL, dome_domain.settings,
                                        t_vertex=t, pin=pin, rim=rim)
    assert (prob.rim is not None and len(prob.slides) > 0) == slide
    x0 = prob.start(P)
    x = x0 + 1.0 * np.random.default_rng(4).standard_normal(len(x0))
    w = 10 * dome_domain.settings.opt_clearance_weight
    hand = prob.linearised(P, w)
    auto = oracle.linearised(prob, P, w)
    fh, gh = hand(x)
    assert fh > prob.linearised(P, 0.0)(x)[0] + 1.0  # base centres short of clearance
    fa, ga = auto(x)
    assert fh == pytest.approx(fa, rel=1e-12)
    np.testing.assert_allclose(gh, ga, rtol=1e-9, atol=1e-9 * np.abs(ga).max())
    rng = np.random.default_rng(5)
    for _ in range(3):
        d = rng.normal(size=x.shape)
        d /= np.linalg.norm(d)
        eps = 1e-6
        fd = (hand(x + eps * d)[0] - hand(x - eps * d)[0]) / (2 * eps)
        assert np.dot(gh, d) == pytest.approx(fd, rel=1e-4, abs=1e-6)


def test_optimisation_shortens_the_longest_cell(dome_domain):
    P, F = dome_domain.stencil(70, seed=0)
    before = candidates.stencil_figures(dome_domain.lift(P), F)
    Q, info = optimise.optimize_stencil(dome_domain, P, F, UNIT_CELL, dome_domain.settings)
    after = candidates.stencil_figures(dome_domain.lift(Q), F)
    assert info["rounds"] >= 1
    assert after["max_cell_length_mm"] < before["max_cell_length_mm"] - 0.2
    A = og.signed_areas(Q, F)
    assert np.all(A > 0)  # no flat triangle flipped
    lay = build_layout(dome_domain.lift(Q), Q, F, UNIT_CELL, enforce_gap=False)
    clear = og.FlatTriangles(lay.UV, F).clearance
    assert clear.min() >= 2.3 - 0.05  # base centres keep clear of their triangle's edges
    bnd = np.asarray(igl.boundary_loop(F))
    assert len(bnd) and np.array_equal(Q[bnd], P[bnd])  # the rim stays where it was


def test_rim_curve_is_parametrised_by_arc_length():
    # a 2 x 1 rectangle: arc length 6 mm, corners at 0, 2, 3, 5
    rim = optimise.RimCurve(np.array([[0, 0], [2, 0], [2, 1], [0, 1.0]]))
    assert rim.total == pytest.approx(6.0, abs=1e-12)
    s = np.array([0.5, 2.25, 4.0, 5.5, 6.5])
    P = rim.point(s)
    np.testing.assert_allclose(P, [[0.5, 0], [2, 0.25], [1, 1], [0, 0.5], [0.5, 0]],
                               atol=1e-12)  # periodic: 6.5 is 0.5
    back, d = rim.project(P + [[0, -0.1], [0.1, 0], [0, 0.1], [-0.1, 0], [0, -0.1]])
    np.testing.assert_allclose(back, np.mod(s, 6.0), atol=1e-12)
    np.testing.assert_allclose(d, 0.1, atol=1e-12)
    np.testing.assert_allclose(rim.tangent(s[:4]), [[1, 0], [0, 1], [-1, 0], [0, -1]],
                               atol=1e-12)
    assert rim.shortest(5.5, 0.5) == pytest.approx(1.0)  # across the seam, the short way
    assert rim.shortest(0.5, 5.5) == pytest.approx(-1.0)


def test_rim_vertices_slide_along_their_curve(dome_domain):
    """Given the curve the CVT put the rim on, the rim vertices slide along it: they stay on
    it (to 1e-6 mm), some move, and the longest flat cell ends no longer than with the rim
    held (fixed rim points made each count's longest cell depend on where they fell)."""
    P, F = dome_domain.stencil(70, seed=0)
    C = dome_domain.boundary_polygon(0.0)
    Q0, _ = optimise.optimize_stencil(dome_domain, P, F, UNIT_CELL, dome_domain.settings)
    Q, info = optimise.optimize_stencil(dome_domain, P, F, UNIT_CELL, dome_domain.settings,
                                           rim=C)
    assert info["rounds"] >= 1
    bnd = np.asarray(igl.boundary_loop(F))
    _, d = optimise.RimCurve(C).project(Q[bnd])
    assert d.max() <= 1e-6
    assert np.linalg.norm(Q[bnd] - P[bnd], axis=1).max() > 0.1  # mm, in the plane
    assert np.all(og.signed_areas(Q, F) > 0)
    fixed = candidates.stencil_figures(dome_domain.lift(Q0), F)["max_cell_length_mm"]
    slid = candidates.stencil_figures(dome_domain.lift(Q), F)["max_cell_length_mm"]
    assert slid <= fixed + 0.02


def test_an_improving_round_is_kept_when_the_step_overshoots_a_soft_penalty():
    """The clearance is a soft penalty: L-BFGS may end beyond its hard limit.  The round is
    then backtracked toward its start (or solved again, stiffer), never thrown away.  (No
    landscape: the rounds are proximal, ``opt_prox``.)"""
    s = surfaces.builtin("dome")
    soft = replace(STENCIL, grading=0.0, opt_clearance_weight=0.01, opt_stiffen=1.0)
    dom = remesh.FlatDomain(s.V, s.F, soft)
    P, F = dom.stencil(70, seed=0)
    before = candidates.stencil_figures(dom.lift(P), F)
    start, _ = optimise.StencilObjective(dom, P, F, UNIT_CELL, soft).exact(P)
    Q, info = optimise.optimize_stencil(dom, P, F, UNIT_CELL, soft)
    h = info["history"]
    assert info["rounds"] == len(h) == soft.opt_rounds and all(r["kept"] for r in h)
    assert h[0]["step"] < 1.0 and "of the step" in h[0]["why"]    # the full step overshot
    assert all(r["clearance_shortfall"] <= soft.opt_clearance_slack for r in h)
    assert h[-1]["objective"] < h[0]["start"] == pytest.approx(start, abs=1e-6)
    after = candidates.stencil_figures(dom.lift(Q), F)
    assert after["max_cell_length_mm"] < before["max_cell_length_mm"] - 0.2
    # no halving allowed: the round is solved again with a stiffer penalty, and kept
    stiff = replace(soft, opt_backtracks=0, opt_stiffen=100.0)
    _, info = optimise.optimize_stencil(dom, P, F, UNIT_CELL, stiff)
    r = info["history"][0]
    assert r["kept"] and r["stiffened"] and r["step"] == 1.0
    assert r["clearance_shortfall"] <= stiff.opt_clearance_slack


@pytest.mark.parametrize("landscape, s3_rtol, cell_atol", [(False, 3e-3, 0.03),
                                                            (True, 3e-4, 3e-3)])
def test_proximal_rounds_do_not_hang_on_last_bits(landscape, s3_rtol, cell_atol):
    """Every unpinned round converges, with a proximal term (``opt_prox``), to a minimum
    rather than to where an iteration budget stops L-BFGS's path, and the objective is
    smooth where L-BFGS goes (``opt_fold_floor_deg``, ``timing_compression_floor``):
    targets jittered by 1e-9 of their size give the same stencil, without a landscape or
    with the dome's own (the timing term's rounds, in their trust region, to
    ``opt_timing_gtol`` with ``opt_timing_prox``).  Without, within 0.3 % in 3D scaling (a
    fifth of the count ladder's spacing) and 0.03 mm in the longest flat cell: measured
    1.130224-1.130595 and 0.003 mm; with the rounds of before (two of 50 iterations in a
    trust region, ``opt_prox=0``), 1.146-1.172 and 0.25 mm.  With, within 3e-4 and 0.003
    mm: measured 1.130044-1.130048 and 1e-4 mm; with the rounds of before (budgeted,
    clearance weight 1000, no smooth floors), 1.12934-1.13031 and 0.009 mm."""
    s = surfaces.builtin("dome:size=0.7")
    figs = []
    for seed in (0, 1, 2):
        jitter = 1e-9 * np.ptp(s.V, axis=0).max() if seed else 0.0
        V = s.V + jitter * np.random.default_rng(seed).standard_normal(s.V.shape)
        dom = remesh.FlatDomain(V, s.F, STENCIL)
        P, F = dom.stencil(60, seed=0)
        t = s.time(dom.lift(P)) if landscape else None
        Q, info = optimise.optimize_stencil(dom, P, F, UNIT_CELL, STENCIL, t_vertex=t,
                                               rim=dom.boundary_polygon(0.0))
        assert info["rounds"] == STENCIL.opt_rounds
        assert all(h["lbfgs_converged"] for h in info["history"])
        figs.append(candidates.stencil_figures(dom.lift(Q), F))
    s3 = [f["scale3d"] for f in figs]
    cell = [f["max_cell_length_mm"] for f in figs]
    assert max(s3) / min(s3) - 1 <= s3_rtol, s3
    assert max(cell) - min(cell) <= cell_atol, cell


def test_accept_step_backtracks_to_an_oriented_improving_point(dome_domain):
    P, F = dome_domain.stencil(40, seed=0)
    prob = optimise.StencilObjective(dome_domain, P, F, UNIT_CELL, dome_domain.settings)
    f0, short0 = prob.exact(P)
    free = prob.free
    # a step that turns triangles over: the full step is refused, a short one is not
    Pn = P.copy()
    Pn[free] = P[free] + 40.0 * np.random.default_rng(0).standard_normal((len(free), 2))
    step, Q = optimise.accept_step(prob, P, Pn, np.inf, short0)
    assert step["kept"] and step["step"] < 1.0
    assert np.all(og.signed_areas(Q, F) > 0)
    assert np.allclose(Q, P + step["step"] * (Pn - P))
    # nothing on the segment lowers the objective: refused, with the reason
    step, Q = optimise.accept_step(prob, P, P, f0, short0)
    assert not step["kept"] and Q is None and "does not fall" in step["why"]


def test_candidate_and_the_printing_rules():
    """A candidate is its (vertices, seed, inset) whatever the number types it was made with,
    ordered as that tuple (the search's ties); "prints with the margin" is at least
    ``margin`` below the limit, inclusive, and never for a failed layout; the module's
    examples run."""
    import doctest

    a = Candidate(np.int64(96), np.int32(1), 0)
    assert a == Candidate(96, 1, 0.0) and hash(a) == hash(Candidate(96, 1, 0.0))
    assert type(a.vertices) is int and type(a.inset_mm) is float
    assert sorted([Candidate(96, 2, 0.0), Candidate(96, 1, 4.0), Candidate(80, 5, 0.0)]) == [
        Candidate(80, 5, 0.0), Candidate(96, 1, 4.0), Candidate(96, 2, 0.0)]
    lim, m = UNIT_CELL.max_cell_length, STENCIL.margin
    assert candidates.prints({"scale3d": 1.0, "max_cell_length_mm": lim - m}, UNIT_CELL, m)
    assert not candidates.prints({"scale3d": 1.0, "max_cell_length_mm": lim - m + 1e-9},
                                 UNIT_CELL, m)
    assert candidates.prints({"scale3d": 1.0, "max_cell_length_mm": lim}, UNIT_CELL)
    assert not candidates.prints({"scale3d": None, "max_cell_length_mm": None}, UNIT_CELL)
    assert [candidates.tier({"scale3d": 1.0, "max_cell_length_mm": L}, UNIT_CELL, m)
            for L in (lim - m, lim, lim + 0.01)] == [0, 1, 2]
    res = doctest.testmod(candidates)
    assert res.attempted >= 3 and res.failed == 0


def _k(n):
    """The candidate of ``n`` vertices, seed 0, no rim inset."""
    return Candidate(n, 0, 0.0)


def test_pick_keeps_the_size_before_the_margin():
    P = UNIT_CELL
    small = {"scale3d": 0.70, "max_cell_length_mm": 8.0}   # prints with the margin, 30 % small
    tight = {"scale3d": 0.99, "max_cell_length_mm": 9.4}   # prints, at size, inside the margin
    far = {"scale3d": 0.90, "max_cell_length_mm": 7.0}
    tried = {_k(60): small, _k(130): tight, _k(100): far}
    assert candidates.pick(tried, P, 0.3, STENCIL) == _k(130)
    assert candidates.pick(tried, P, 0.3) == _k(100)  # (without the size rule)
    assert not candidates.at_size(small) and candidates.at_size(tight)
    assert not candidates.at_size({"scale3d": 1.06, "max_cell_length_mm": 8.0})
    off = {k: v for k, v in tried.items() if k != _k(130)}
    assert candidates.pick(off, P, 0.3, STENCIL) == _k(100)  # nothing at size


def test_pick_takes_the_nearest_count_whose_starts_print_at_full_size():
    """The counts ranked by their mean scaling (nearest 1 first): when the first has no start
    that would print held at scale 1, the pick is the next count's best start, not a
    fallback elsewhere.  (The peer top's counts 120 and 152 tied to 3e-4 in mean log scaling;
    taking 120, with no such start, fell back to 193 bases, which did not hold at scale 1, and
    a rounding flipped the design between 235 bases and a refusal.)"""
    P = UNIT_CELL
    wide = {"scale3d": 1.006, "max_cell_length_mm": 11.05}  # at size, too long at scale 1
    good = {"scale3d": 0.952, "max_cell_length_mm": 8.76}
    better = {"scale3d": 0.960, "max_cell_length_mm": 8.30}
    other = {"scale3d": 1.033, "max_cell_length_mm": 8.07}
    tried = {Candidate(120, 0, 0.0): wide, Candidate(152, 0, 0.0): good,
             Candidate(152, 1, 0.0): better, Candidate(193, 0, 0.0): other}
    for first in ((120, 152, 193), (152, 120, 193)):
        assert candidates.pick(tried, P, 0.3, STENCIL, {0.0: first}) == Candidate(152, 1, 0.0)
    assert candidates.pick(tried, P, 0.3, STENCIL, {0.0: (193, 152)}) == Candidate(193, 0, 0.0)


def test_a_failed_polish_tries_the_next_counts_starts():
    """When the pick does not hold at scale 1, the other seeds of its count are polished, then
    the starts of the next counts (nearest a mean scaling of 1 first) that keep the size and
    would print held at 1; at most ``polish_tries`` in all, the pick included."""
    from types import SimpleNamespace

    def fig(s3, L):
        return {"scale3d": s3, "max_cell_length_mm": L}

    tried = {Candidate(193, 1, 0.0): fig(1.03, 8.07), Candidate(193, 0, 0.0): fig(1.02, 8.5),
             Candidate(182, 1, 0.0): fig(0.96, 8.06), Candidate(152, 1, 0.0): fig(0.95, 8.76),
             Candidate(152, 0, 0.0): fig(0.94, 8.0),    # off the size band
             Candidate(120, 0, 0.0): fig(1.0, 11.0),    # too long held at 1
             Candidate(152, 1, 2.0): fig(0.99, 8.0)}    # another rim inset
    search = SimpleNamespace(settings=STENCIL, params=UNIT_CELL, tried=tried,
                             flat=dict.fromkeys(tried), centres={0.0: (120, 152, 193, 182)})
    got = CountSearch.alternates(search, Candidate(193, 1, 0.0))
    assert got == [Candidate(193, 0, 0.0), Candidate(152, 1, 0.0), Candidate(182, 1, 0.0)]
    search.settings = replace(STENCIL, polish_tries=2)
    assert CountSearch.alternates(search, Candidate(193, 1, 0.0)) == [Candidate(193, 0, 0.0)]


def test_size_refusal_names_measured_alternatives():
    """A target that prints only far under its size is refused; the fix names a smaller
    --size and --min-bumper 0.1, each searched again."""
    from pysolver.design.stencil.alternatives import size_refusal

    info = {"requested": 60, "seed": 0, "scale3d": 0.70, "max_cell_length_mm": 8.2,
            "at_size": False,
            "candidates": [[60, 0, 0.0, 0.70, 8.2], [130, 0, 0.0, 0.99, 10.4],
                           [80, 0, 0.0, 0.82, 9.9]]}
    calls = []

    def search(factor, params):
        calls.append((round(factor, 4), params.min_bumper))
        ok = factor < 1
        return {"requested": 62, "seed": 0, "scale3d": 1.0 if ok else 0.93,
                "max_cell_length_mm": 8.4 if ok else 9.0, "at_size": ok}
    e = size_refusal(info, UNIT_CELL, search, extent_mm=120.0)
    assert "3D scaling 0.700" in e.problem and "30 % under" in e.problem
    assert calls == [(0.7, 0.3), (1.0, 0.1)]          # --size 84, then the 0.1 mm bumper
    assert "--size 84 (tried: prints" in e.fix
    assert "--min-bumper 0.1 (tried: does not print at this size" in e.fix


def test_design_refuses_a_stencil_off_the_size_asked_for(tmp_path, monkeypatch):
    from pysolver.design import pipeline

    quick_stencil_search(monkeypatch)   # the subject is the refusal, not the optimisation
    real = pipeline.remesh_surface
    seen = []

    def off_size(V, F, **kw):
        V2, F2, info = real(V, F, **{**kw, "vertices": 40, "seed": 0})
        seen.append(kw["params"].min_bumper)
        return V2, F2, dict(info, at_size=len(seen) > 2, scale3d=0.7)
    monkeypatch.setattr(pipeline, "remesh_surface", off_size)
    with pytest.raises(InputError, match="no printable stencil keeps the size") as e:
        run_design("dome", tmp_path / "d", progress=False, plots=False)
    assert "--size" in e.value.fix and "--min-bumper 0.1" in e.value.fix
    assert not (tmp_path / "d" / "cells.csv").exists()


def test_count_search_picks_a_printable_neighbour():
    s = surfaces.builtin("dome")
    lim = 8.8  # tight enough that some counts fail (unoptimised stencils: 8.3-9.0 mm)
    params = replace(UNIT_CELL, max_cell_length=lim)
    V2, F2, info = search.remesh_surface(s.V, s.F, params=params, seed=0, optimize=False,
                                         settings=replace(STENCIL, candidates=(0.8, 0.9, 1.1)))
    cands = info["candidates"]
    assert info["max_cell_length_mm"] <= lim
    n = info["requested"]
    same = [c for c in cands if c[2] == info["rim_inset_mm"]]
    counts = sorted(c[0] for c in same)
    k = counts.index(n)
    neighbours = [c for c in same if c[0] in counts[max(k - 1, 0):k + 2] and c[0] != n]
    assert any(c[4] > lim for c in neighbours), cands  # a neighbouring count does not print
    # among the printable candidates, the chosen one keeps the target's size best
    ok = [c for c in cands if c[4] <= lim - STENCIL.margin] or [c for c in cands if c[4] <= lim]
    assert abs(np.log(info["scale3d"])) <= min(abs(np.log(c[3])) for c in ok) + 1e-3
    lay = build_layout(V2, cetm(V2, F2)[0], F2, params)
    assert lay.central_length.max() <= lim + 1e-6


def test_pick_prefers_size_among_printable_and_never_a_failed_layout():
    P = UNIT_CELL  # limit 9.5, margin 0.3
    ok = {"scale3d": 1.2, "max_cell_length_mm": 8.0}
    near = {"scale3d": 1.01, "max_cell_length_mm": 9.4}  # printable, but inside the margin
    failed = {"scale3d": None, "max_cell_length_mm": None, "error": "flipped"}
    assert candidates.pick({_k(1): ok, _k(2): near, _k(3): failed}, P, 0.3) \
        == _k(1)
    assert candidates.pick({_k(2): near, _k(3): failed}, P, 0.3) == _k(2)
    long_ = {"scale3d": 1.0, "max_cell_length_mm": 9.9}
    longer = {"scale3d": 1.0, "max_cell_length_mm": 10.5}
    assert candidates.pick({_k(4): longer, _k(5): long_}, P, 0.3) == _k(5)
    # nothing prints: the shortest longest cell per unit of scaling, at size first
    small = {"scale3d": 0.950, "max_cell_length_mm": 9.70}  # (10.21 mm per unit)
    large = {"scale3d": 1.009, "max_cell_length_mm": 9.72}  # (9.63 mm per unit)
    tiny = {"scale3d": 1.10, "max_cell_length_mm": 9.9}     # (9.00 mm per unit, not at size)
    assert candidates.pick({_k(6): small, _k(7): large, _k(8): tiny}, P,
                              0.3, STENCIL) == _k(7)
    assert candidates.pick({_k(3): failed}, P, 0.3) is None


def test_paper_cover_designs_printable_from_its_target(tmp_path):
    """The paper's petalled shell (reference: 567 bases, flat cells 5.6-8.44 mm) from its
    unitless target surface, at the reference's size and 0.1 mm minimal bumper."""
    src = shared_file("reference-shapes", "cover_src.obj")
    m = load_input(src, scale=38.5)
    V = m.V - m.V.mean(axis=0)
    V *= 106.0 / np.ptp(V, axis=0).max()
    params = replace(UNIT_CELL, min_bumper=0.1)
    s = run_design(surfaces.Surface("cover", V, m.F), tmp_path, params=params,
                   progress=False, plots=False)
    assert s["checks"]["ok"]
    assert s["cell_length_mm"]["max"] <= 9.5
    assert 0.85 * 567 <= s["counts"]["bases"] <= 1.15 * 567
    assert s["scale"]["scale3d"] == pytest.approx(1.0, abs=0.06)  # keeps the asked size
    r = s["remesh"]
    assert r["after_optimisation"]["max_cell_length_mm"] < r["before_optimisation"][
        "max_cell_length_mm"]


def test_unprintable_target_names_the_region_and_a_measured_fix(tmp_path, monkeypatch):
    params = replace(UNIT_CELL, max_cell_length=6.0)  # far below what the dome needs
    quick_stencil_search(monkeypatch)   # the subject is the refusal, not the optimisation
    with pytest.raises(InputError) as e:
        run_design("dome", tmp_path / "d", params=params, vertices=60, seed=0,
                   progress=False, plots=False)
    text = str(e.value)
    assert "longer than 6.0 mm" in text and "on the target" in text
    assert re.search(r"at \(-?\d+\.\d, -?\d+\.\d, -?\d+\.\d\)", text)  # where, mm
    assert "--min-bumper 0.1" in text and "--vertices" in text  # measured alternatives
    assert not (tmp_path / "d" / "cells.csv").exists()  # nothing half-written


def test_stencil_whose_bases_reach_across_edges_is_named():
    from synthetic import regular_grid

    from pysolver.temporal.membrane_model import layout_membrane

    UV, F = regular_grid(6, 6, edge=7.0 * np.sqrt(3))  # cells of 7 mm: fine
    layout_membrane(UV, F, MODEL_FITS.membrane_fit_max_area)
    UV = UV.copy()
    mid = int(np.argmin(np.linalg.norm(UV - UV.mean(axis=0), axis=1)))
    nb = [v for f in F if mid in f for v in f if v != mid]
    far = max(nb, key=lambda v: np.linalg.norm(UV[v] - UV[mid]))
    UV[mid] += 0.85 * (UV[far] - UV[mid])  # two obtuse slivers around the moved vertex
    with pytest.raises(InputError, match="reach across its edges"):
        layout_membrane(UV, F, MODEL_FITS.membrane_fit_max_area)


def _timing_terms(dom, P, F, t_vertex, settings=STENCIL):
    X = dom.lift(P)
    cells = unit_cells(F, face_adjacency(F))
    o = optimise.opposite_vertices(F, cells)
    fa, fb = cells.faces[:, 0], cells.faces[:, 1]
    rim = np.any(face_adjacency(F) < 0, axis=1)
    bnd = (rim[fa] | rim[fb]).astype(float)
    t_star = 0.5 * (t_vertex[cells.verts[:, 0]] + t_vertex[cells.verts[:, 1]])
    return X, cells, o, fa, fb, bnd, np.log(t_star)


def test_timing_misfit_restates_the_cells_of_the_layout(dome_domain):
    # the optimiser's bracket length and compression are the layout's, in closed form
    from pysolver.design.cellnodes import bracket_nodes, collision_lengths
    P, F = dome_domain.stencil(60, seed=1)
    t = np.full(len(P), 60.0)
    X, cells, o, fa, fb, bnd, log_ts = _timing_terms(dome_domain, P, F, t)
    lay = build_layout(X, P, F, UNIT_CELL, enforce_gap=False)
    b0 = UNIT_CELL.bracket_length(lay.central_length)
    x = b0 - collision_lengths(bracket_nodes(lay.V, lay.UV, lay.F, UNIT_CELL,
                                             ff=lay.ff, rotvec=lay.rotvec)[0], lay.cells).mean(1)
    log_s3, log_s2, _ = oracle.layout_logs(P, X, F, fa, fb, o[:, 0], o[:, 1],
                                           UNIT_CELL, sharpness=None)
    got = oracle.timing_misfit(P, X, F, fa, fb, o[:, 0], o[:, 1], bnd, log_ts, log_s3,
                               log_s2, UNIT_CELL, STENCIL)
    # the optimiser's forward pass, at the same (exact) scalings, is the oracle's
    geo = og.CellGeometry(P, X, F, fa, fb, o[:, 0], o[:, 1], STENCIL.opt_tiny)
    hand, _ = og.timing(geo, og.Scalings(geo, UNIT_CELL, None), bnd, log_ts, UNIT_CELL,
                        STENCIL)
    assert hand == pytest.approx(float(got), rel=1e-12)

    def est(m):
        return m[0] + m[1] * np.log(b0) + m[2] * np.log(x) + m[3] * bnd
    mg = STENCIL.timing_margin
    want = np.mean(np.maximum(est(STENCIL.timing_fastest) - log_ts + mg, 0) ** 2
                   + np.maximum(log_ts - est(STENCIL.timing_slowest) + mg, 0) ** 2)
    # the flat length is the layout's; the contact length is restated as s3 D / cos(t) -
    # (l - b), which the bracket nodes' own distances (off the cell axis) undercut by up to
    # 0.03 mm, so x and the misfit agree to a few per cent
    cos_t, _, D, d = oracle.cell_geometry(P, X, F, fa, fb, o[:, 0], o[:, 1])
    L = np.exp(log_s2) * d
    np.testing.assert_allclose(L, lay.central_length, rtol=1e-7)
    x_opt = L - np.exp(log_s3) * D / cos_t
    assert np.all(np.abs(x_opt - x) <= 0.03)
    assert float(got) == pytest.approx(want, rel=0.1)


def test_timing_misfit_gradient_matches_finite_differences(dome_domain):
    P, F = dome_domain.stencil(40, seed=2)
    z = dome_domain.lift(P)[:, 2]
    t = 30.0 + 2.0 * (z - z.min())  # a landscape the cells cannot all meet
    X, cells, o, fa, fb, bnd, log_ts = _timing_terms(dome_domain, P, F, t)
    J = dome_domain.lift_jacobian(P)

    def f(Q):
        Xq = X + anp.einsum("nij,nj->ni", J, Q - P)
        a, b, _ = oracle.layout_logs(Q, Xq, F, fa, fb, o[:, 0], o[:, 1], UNIT_CELL, 60.0)
        return oracle.timing_misfit(Q, Xq, F, fa, fb, o[:, 0], o[:, 1], bnd, log_ts, a, b,
                                    UNIT_CELL, STENCIL)

    assert f(P) > 0
    _assert_gradient_matches_fd(f, P, seed=1, rel=1e-4)


def test_optimisation_suits_the_cells_to_the_time_landscape(dome_domain):
    P, F = dome_domain.stencil(70, seed=0)
    z = dome_domain.lift(P)[:, 2]
    t = 30.0 + 2.0 * (z - z.min())
    off = replace(dome_domain.settings, opt_timing_weight=0.0)

    def misfit(Q):
        X, cells, o, fa, fb, bnd, log_ts = _timing_terms(dome_domain, Q, F, t)
        a, b, _ = oracle.layout_logs(Q, X, F, fa, fb, o[:, 0], o[:, 1], UNIT_CELL, None)
        return float(oracle.timing_misfit(Q, X, F, fa, fb, o[:, 0], o[:, 1], bnd, log_ts,
                                          a, b, UNIT_CELL, STENCIL))

    Q0, _ = optimise.optimize_stencil(dome_domain, P, F, UNIT_CELL, off, t_vertex=t)
    Q1, info = optimise.optimize_stencil(dome_domain, P, F, UNIT_CELL, dome_domain.settings,
                                            t_vertex=t)
    assert info["rounds"] >= 1
    assert misfit(Q1) < 0.7 * misfit(Q0), (misfit(P), misfit(Q0), misfit(Q1))
    assert np.all(og.signed_areas(Q1, F) > 0)
    # the cap: the trade stays printable, within 0.1 mm of the count search's margin (the
    # cap is exact at each round's start and smooth within it; measured 9.27 mm, cap 9.2)
    lay = build_layout(dome_domain.lift(Q1), Q1, F, UNIT_CELL, enforce_gap=False)
    assert lay.central_length.max() <= UNIT_CELL.max_cell_length - STENCIL.margin + 0.1


def test_constant_landscape_leaves_the_optimisation_as_it_was(dome_domain):
    # programming picks the achievable constant itself, so the timing term stays out
    P, F = dome_domain.stencil(40, seed=3)
    Q0, _ = optimise.optimize_stencil(dome_domain, P, F, UNIT_CELL, dome_domain.settings)
    Q1, _ = optimise.optimize_stencil(dome_domain, P, F, UNIT_CELL, dome_domain.settings,
                                         t_vertex=np.full(len(P), 60.0))
    assert np.array_equal(Q0, Q1)


def test_constant_landscape_through_the_search_is_no_landscape():
    # interpolating a constant leaves round-off (1e-14 s) that must not switch the term on
    # (the optimisation at the smaller budget: its subject is the landscape, not the result)
    s = surfaces.builtin("dome")
    kw = dict(vertices=50, seed=0, settings=replace(STENCIL, **QUICK_SEARCH))
    V0, F0, _ = search.remesh_surface(s.V, s.F, **kw)
    V1, F1, _ = search.remesh_surface(s.V, s.F, time=np.full(len(s.V), 60.0), **kw)
    assert np.array_equal(F0, F1) and np.array_equal(V0, V1)


@pytest.mark.parametrize(("n", "held"), [(50, 1.0), (70, 1.0)])
def test_pinned_optimisation_holds_the_size_and_shortens_the_cell_per_scale(dome_domain, n,
                                                                           held):
    """The count search's last pass: the 3D scaling held at 1 (to 0.5 %), the longest flat
    cell per unit of scaling shorter than before."""
    P, F = dome_domain.stencil(n, seed=0)
    before = candidates.stencil_figures(dome_domain.lift(P), F)
    Q, info = optimise.optimize_stencil(dome_domain, P, F, UNIT_CELL, dome_domain.settings,
                                           pin=True, pin_scale3d=held)
    after = candidates.stencil_figures(dome_domain.lift(Q), F)
    assert info["rounds"] >= 1
    assert after["scale3d"] == pytest.approx(held, abs=0.005)
    assert (after["max_cell_length_mm"] / after["scale3d"]
            < before["max_cell_length_mm"] / before["scale3d"] - 0.2)
    assert np.all(og.signed_areas(Q, F) > 0)


def test_estimated_clamping_counts_the_times_out_of_the_estimated_range():
    # three cells with b0 = 4 mm and x = 1 mm: fastest / slowest from the fitted laws
    central = np.full(3, 4.0 + UNIT_CELL.bracket_offset)
    contact = central - 1.0
    bnd = np.zeros(3)
    lo, hi = og.log_time_range(central, contact, bnd, UNIT_CELL, STENCIL)
    c, a, e = STENCIL.timing_fastest[:3]
    # log x = 0, but for the compression's smooth floor: x_f log(1 + exp(1 mm / x_f))
    xf = STENCIL.timing_compression_floor
    log_x = np.log(xf * np.log1p(np.exp(1.0 / xf)))
    assert 0 < log_x < 1e-4
    assert lo[0] == pytest.approx(c + a * np.log(4.0) + e * log_x)
    t_in, t_early, t_late = np.exp(0.5 * (lo[0] + hi[0])), np.exp(lo[0]) / 2, np.exp(hi[0]) * 2
    f = optimise.estimated_clamping(central, contact, bnd, [t_in, t_early, t_late])
    assert f == pytest.approx(2 / 3)


@pytest.mark.parametrize("name", ["dome", "petal"])
def test_timing_estimates_restate_temporal_programming(name, tmp_path, tmp_path_factory):
    """The optimiser's closed-form fastest and slowest times (``timing_fastest`` /
    ``timing_slowest``, fitted by ``bench/fit_timing_estimate.py``: sigma 0.22 in log t)
    against the times temporal programming computes from the material and membrane models,
    on a built-in design: the median residual within the fit's spread between designs
    (0.16 in log t for the fastest, and -0.17 on the petal the search of issue #42 chose,
    which was not among the fit's designs; the slowest's uncensored cells, those under 119.5 s,
    are the faster ones, so they sit below it: -0.01 to -0.22), and a robust spread (MAD)
    under 0.3.  (The former coefficients, fitted on ``../shared``'s cover and stand before the
    printed bumpers' clearance was programmed, fail the slowest's bound on these designs:
    medians +0.28 (dome) and +0.44 (petal) against 0.05; their fastest, +0.14 and -0.01,
    stays within its band.  A few long rim cells close early at any thickness, 2.5 in log t
    under the slowest estimate on petal: hence the robust statistics.)  The slowest estimate
    is of the latest time *both* layers reach (one compression per cell, the intersection of
    the layers' ranges); programming now reaches later times with the slower layer alone
    (:func:`pysolver.temporal.cell_time.time_ranges`), so it is compared with the earlier of
    the layers' latest times, and stays a conservative bound for the optimiser."""
    from _shared import designed

    from pysolver import tables
    from pysolver.temporal import program_design
    folder = tmp_path / name
    shutil.copytree(designed(name, tmp_path_factory), folder)
    program_design(folder, progress=False, picture=False, fit_landscape=True)
    V, UV, F = tables.read_stencil(folder / "stencil.obj")
    lay = build_layout(V, UV, F, tables.read_unit_cell(folder))
    cells = tables.read_table(folder, "cells")
    np.testing.assert_allclose(lay.central_length, cells["central_length_mm"], atol=1e-6)
    lo, hi = og.log_time_range(*optimise.layout_timing_terms(lay))
    for est, t, bias in ((lo, cells["t_min_s"], (-0.2, 0.16)),
                         (hi, _both_layers_latest(folder, cells), (-0.3, 0.05))):
        ok = (t > 0.5) & (t < 119.5)  # (at the ends of the bracket model's range: bounds)
        r = np.log(t[ok]) - est[ok]
        med, mad = np.median(r), 1.4826 * np.median(np.abs(r - np.median(r)))
        assert ok.sum() > 0.5 * len(t) and bias[0] <= med <= bias[1], (ok.sum(), med)
        assert mad <= 0.3, mad


def _both_layers_latest(folder, cells):
    """The latest time (s) that both layers of each cell reach with their thickest
    brackets, as the program stage of ``folder`` programmes them (its membrane factors and
    the printed bumpers' closing lengths)."""
    import json

    from pysolver.temporal import both_layers_latest, closing_lengths

    factor = json.loads((folder / "temporal.json").read_text())["membrane_factor"]
    return both_layers_latest(cells, factor, closing_lengths(folder, cells))


class _Tried(CountSearch):
    """A count search over made-up candidates: ``trial`` takes the figures of count ``n`` from
    ``cands`` (no stencil is made), meshes are named ``"V<n>"``."""

    def __init__(self, tried: dict, settings=STENCIL, cands=None, area=1.0):
        self.settings, self.params, self.progress = settings, UNIT_CELL, None
        self.tried, self.cands, self.area, self.centres = dict(tried), cands or {}, area, {}
        self.meshes = {k: (f"V{k.vertices}", f"F{k.vertices}", None) for k in tried}

    def trial(self, n, sd, inset, given=False):
        k = Candidate(n, sd, inset)
        self.tried[k], self.meshes[k] = self.cands[n], (f"V{n}", f"F{n}", None)
        return n


def test_trade_takes_fewer_vertices_only_for_a_real_gain_at_a_kept_size():
    S = replace(STENCIL, trade_counts=(0.9, 0.8), trade_min_scale3d=0.93, trade_gain=0.03)
    chosen = {"scale3d": 1.0, "max_cell_length_mm": 8.4, "clamped_estimate": 0.14}
    cands = {90: {"scale3d": 0.95, "max_cell_length_mm": 8.9, "clamped_estimate": 0.07},
             80: {"scale3d": 0.90, "max_cell_length_mm": 9.1, "clamped_estimate": 0.03}}
    first = Candidate(100, 0, 1.0)

    def run(cands, chosen=chosen):
        info = {}
        best, V2, F2, ch = _Tried({first: chosen}, S, cands).trade(first, "V100", "F100",
                                                                    chosen, info)
        return best, V2, ch, info["trade"]

    # 80 clamps least but shrinks the shell below 0.93: 90 is taken
    best, V2, ch, rec = run(cands)
    assert best == Candidate(90, 0, 1.0) and V2 == "V90" and rec["taken"]
    assert rec["to_vertices"] == 90 and [r[0] for r in rec["tried"]] == [80, 90]
    # a gain under trade_gain keeps the chosen stencil
    small = {**cands, 90: dict(cands[90], clamped_estimate=0.12)}
    best, V2, ch, rec = run(small)
    assert best == first and V2 == "V100" and not rec["taken"]
    # a candidate that does not print with the margin (beyond limit - margin) is never taken
    long_ = {**cands, 90: dict(cands[90], max_cell_length_mm=9.3)}
    assert run(long_)[0] == first


# --------------------------------------------------------------------------------------
# the rim inset and its fallback (a stencil reaching the rim, taken on measured merit)


def _bent_strip(width, length=110.0, radius=70.0):
    """A strip ``length`` x ``width`` mm bent around a cylinder of radius ``radius`` mm."""
    P, F = surfaces._dense(np.array([[0, -width / 2], [length, -width / 2],
                                     [length, width / 2], [0, width / 2]]))
    a = (P[:, 0] - length / 2) / radius
    return np.c_[radius * np.sin(a), P[:, 1], radius * (np.cos(a) - 1)], F


def test_narrow_strip_falls_back_to_the_rim_and_a_wide_one_keeps_the_inset():
    # 25 mm wide: a 4 mm inset leaves about 60 % of the area, so the stencil that reaches the
    # rim is searched too and, printable, taken
    V, F = _bent_strip(25.0)
    V2, F2, info = search.remesh_surface(V, F, seed=0, optimize=False, dense=False)
    rim = info["rim"]
    assert rim["inset_region_covered"] < STENCIL.min_area_covered
    assert rim["inset_area_covered"] < rim["inset_region_covered"]  # (chords cut corners)
    assert rim["fallback"]["taken"] and info["rim_inset_mm"] == 0.0 == rim["inset_mm"]
    assert info["max_cell_length_mm"] <= UNIT_CELL.max_cell_length
    assert rim["area_covered"] > STENCIL.min_area_covered
    assert "prints" in rim["why"]
    # deterministic: the same input gives the same stencil
    V3, F3, again = search.remesh_surface(V, F, seed=0, optimize=False, dense=False)
    assert np.array_equal(F2, F3) and np.array_equal(V2, V3) and again["rim"] == rim
    # 60 mm wide: the inset stencil covers enough; no fallback is searched
    V, F = _bent_strip(60.0)
    _, _, info = search.remesh_surface(V, F, seed=0, optimize=False, dense=False)
    assert info["rim_inset_mm"] > 0 and info["rim"]["fallback"] is None
    assert info["rim"]["inset_region_covered"] >= STENCIL.min_area_covered
    assert all(c[2] > 0 for c in info["candidates"])


def test_inset_region_cover_is_the_offset_rectangle():
    """A flat 40 x 60 mm rectangle lays out isometrically, and the curve 4 mm inside its rim
    is the 32 x 52 mm rectangle: the region covers 32 * 52 / (40 * 60) = 0.6933 of it, to
    the quadrature's resolution (four points per triangle of about 1 mm), and every
    relabelling and rigid motion of the target gives the same figure."""
    from pysolver.design.stencil.remesh import FlatDomain

    P, F = surfaces._dense(np.array([[0, 0], [60.0, 0], [60.0, 40.0], [0, 40.0]]))
    V = np.c_[P, np.zeros(len(P))]
    dom = FlatDomain(V, F, STENCIL)
    assert dom.region_covered(4.0) == pytest.approx(32 * 52 / 2400, abs=5e-3)
    assert dom.region_covered(0.0) == pytest.approx(1.0, abs=1e-9)
    rng = np.random.default_rng(3)
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    p = rng.permutation(len(V))
    inv = np.argsort(p)
    moved = FlatDomain(V[p] @ R.T + 5.0, inv[F][rng.permutation(len(F))], STENCIL)
    assert moved.region_covered(4.0) == pytest.approx(dom.region_covered(4.0), abs=1e-3)


def test_rim_fallback_never_trades_printability():
    """The stencil reaching the rim replaces a poorly covering inset stencil only when its
    longest flat cell prints at least as well (within limit - margin, or within the limit when
    the inset stencil is not within the margin either)."""
    lim, margin = UNIT_CELL.max_cell_length, STENCIL.margin
    square = (np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float),
              np.array([[0, 1, 2], [0, 2, 3]]))
    half = (square[0] * np.sqrt(0.5), square[1])  # covers half the target's area (1 mm^2)
    inset, rim = Candidate(100, 0, 4.0), Candidate(120, 0, 0.0)

    def choose(L_inset, L_rim):
        search = _Tried({inset: {"scale3d": 1.0, "max_cell_length_mm": L_inset},
                         rim: {"scale3d": 1.0, "max_cell_length_mm": L_rim}})
        search.meshes = {inset: half, rim: square}
        return search.rim_fallback(inset, None, None, [0], [100])

    best, info = choose(8.7, 9.0)
    assert best == rim and info["fallback"]["taken"] and info["fallback"]["area_covered"] == 1.0
    best, info = choose(8.7, lim - margin + 0.01)  # only within the limit: the inset stays
    assert best == inset and not info["fallback"]["taken"] and info["inset_mm"] == 4.0
    best, info = choose(lim - 0.1, lim - 0.05)  # neither keeps the margin: both print
    assert best == rim
    best, info = choose(lim - 0.1, lim + 0.2)  # unprintable: never
    assert best == inset and not info["fallback"]["taken"]
    best, info = choose(lim + 0.3, lim + 0.2)  # nothing prints: the inset search decides
    assert best == inset


def _interior_edges(F):
    E = igl.edges(F)
    rim = {tuple(sorted(e)) for e in igl.boundary_facets(F)[0].tolist()}
    return E[[tuple(sorted(e)) not in rim for e in E.tolist()]]


def test_time_graded_stencil_is_finer_where_the_landscape_is_late():
    # a flat 80 x 40 mm plate (conformal scale 0): its left half asked for 30 s, its right
    # half for 80 s; the spacing should follow (t / t_mean)^(-timing_grading)
    x, y = np.meshgrid(np.linspace(0, 80, 41), np.linspace(0, 40, 21), indexing="ij")
    V = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    q = (np.arange(40)[:, None] * 21 + np.arange(20)[None, :]).ravel()
    F = np.r_[np.c_[q, q + 21, q + 1], np.c_[q + 1, q + 21, q + 22]]
    t = np.where(V[:, 0] < 40, 30.0, 80.0)
    S = replace(STENCIL, timing_grading=0.3)
    dom = remesh.FlatDomain(V, F, S, time=t)
    P, F2 = dom.stencil(120, seed=0)
    E = _interior_edges(F2)  # (rim edges follow the boundary points and the merged flaps)
    mid = dom.lift(0.5 * (P[E[:, 0]] + P[E[:, 1]]))  # (on the plate: the plane's frame is
    L = np.linalg.norm(P[E[:, 0]] - P[E[:, 1]], axis=1)  # the shape's, flat_frame)
    early, late = L[mid[:, 0] < 30].mean(), L[mid[:, 0] > 50].mean()
    want = (80 / 30) ** -0.3                         # 0.745
    assert late / early == pytest.approx(want, rel=0.12)
    # without a landscape the same plate is uniform
    dom0 = remesh.FlatDomain(V, F, S)
    P0, F0 = dom0.stencil(120, seed=0)
    E0 = _interior_edges(F0)
    m0 = dom0.lift(0.5 * (P0[E0[:, 0]] + P0[E0[:, 1]]))
    L0 = np.linalg.norm(P0[E0[:, 0]] - P0[E0[:, 1]], axis=1)
    assert L0[m0[:, 0] > 50].mean() / L0[m0[:, 0] < 30].mean() == pytest.approx(1.0, abs=0.08)


def test_time_graded_search_falls_back_when_the_grading_is_unprintable():
    s = surfaces.builtin("dome")
    t = np.interp(s.V[:, 2], (s.V[:, 2].min(), s.V[:, 2].max()), (30.0, 80.0))
    # a grading far too steep for 9.5 mm cells: redone without, and printable (the
    # optimisation at the smaller budget: the subject is the fallback)
    _, _, info = search.remesh_surface(s.V, s.F, time=t, user_times=True, seed=0,
                                       settings=replace(STENCIL, timing_grading=3.0,
                                                        **QUICK_SEARCH))
    tg = info["timing_grading"]
    assert tg["taken"] is False and tg["grading"] == 3.0
    assert not (tg["max_cell_length_mm"] <= UNIT_CELL.max_cell_length
                and tg["scale3d"] >= STENCIL.trade_min_scale3d)
    assert info["max_cell_length_mm"] <= UNIT_CELL.max_cell_length


def _rim_triangle_count(F):
    count = np.bincount(np.asarray(F).ravel())
    return count[igl.boundary_loop(np.asarray(F))]


def _flap_left_for_a_reason(P, F, v, min_angle):
    area = signed_areas_2d
    pair = np.flatnonzero((F == v).any(axis=1))
    u = np.setdiff1d(F[pair[1]], F[pair[0]])[0]
    T = np.where(F[pair[0]] == v, u, F[pair[0]])[None]
    sense = np.sign(area(P, F).sum())
    folded = area(P, T)[0] * sense <= 0
    thin = np.degrees(igl.internal_angles(P, T).min()) < min_angle
    return folded or thin


def _disk(seed=3):
    from scipy.spatial import Delaunay

    # a disk: 24 rim points and jittered inner points, Delaunay-triangulated
    rng = np.random.default_rng(seed)
    a = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    rim = np.c_[np.cos(a), np.sin(a)] * 10.0
    inner = rng.uniform(-8.0, 8.0, (80, 2))
    inner = inner[np.linalg.norm(inner, axis=1) < 8.5]
    P = np.vstack([rim, inner])
    F = Delaunay(P).simplices
    F = np.where((signed_areas_2d(P, F) < 0)[:, None], F[:, ::-1], F)
    return remesh.remove_ears(P, F)


def test_flaps_are_merged_keeping_orientation_and_area():
    area = signed_areas_2d
    P, F = _disk()
    n_flaps = int((_rim_triangle_count(F) == 2).sum())
    assert n_flaps >= 2                                   # the input has flaps to merge
    P2, F2 = remesh.remove_flaps(P, F, min_angle_deg=20.0)
    removed = len(P) - len(P2)
    assert removed >= 1 and len(F) - len(F2) == removed   # one vertex, one face per flap
    assert (area(P2, F2) > 0).all()                       # orientation kept, nothing folds
    assert len(igl.boundary_loop(F2)) == len(igl.boundary_loop(F)) - removed
    # the rim is cut straight past each merged flap (convex there): only area is lost
    assert area(P2, F2).sum() < area(P, F).sum()
    # every flap left would fold or give a triangle thinner than asked
    count = np.bincount(F2.ravel(), minlength=len(P2))
    for v in igl.boundary_loop(F2):
        if count[v] == 2:
            assert _flap_left_for_a_reason(P2, F2, v, 20.0)
    # with no angle threshold only the merges that would fold are left
    P3, F3 = remesh.remove_flaps(P, F, min_angle_deg=0.0)
    count = np.bincount(F3.ravel(), minlength=len(P3))
    assert all(_flap_left_for_a_reason(P3, F3, v, 0.0)
               for v in igl.boundary_loop(F3) if count[v] == 2)


def test_a_flap_on_a_concave_rim_is_merged_across_the_dent():
    area = signed_areas_2d
    P, F = _disk()
    count = np.bincount(F.ravel(), minlength=len(P))
    v = next(int(x) for x in igl.boundary_loop(F) if count[x] == 2)
    loop = list(igl.boundary_loop(F))
    k = loop.index(v)
    a, b = loop[k - 1], loop[(k + 1) % len(loop)]
    # move v just inside the chord a-b: both its triangles keep their orientation
    inward = -(P[a] + P[b]) / np.linalg.norm(P[a] + P[b])
    P = P.copy()
    P[v] = 0.5 * (P[a] + P[b]) + 0.3 * inward
    assert (area(P, F) > 0).all()
    P2, F2 = remesh.remove_flaps(P, F, min_angle_deg=0.0)
    assert not np.any(np.all(P2 == P[v], axis=1))       # v dropped
    assert (area(P2, F2) > 0).all()
    # the rim now runs along the chord a-b, outside the dent
    ia, ib = (int(np.flatnonzero(np.all(P2 == P[x], axis=1))[0]) for x in (a, b))
    rim_edges = {tuple(sorted(e)) for e in igl.boundary_facets(F2)[0].tolist()}
    assert (min(ia, ib), max(ia, ib)) in rim_edges


def test_stencils_have_no_flaps_where_they_can_merge():
    s = surfaces.builtin("dome")
    dom = remesh.FlatDomain(s.V, s.F)
    P, F = dom.stencil(remesh.estimate_vertices(remesh.surface_area(s.V, s.F)), seed=0)
    count = np.bincount(F.ravel(), minlength=len(P))
    for v in igl.boundary_loop(F):
        if count[v] == 2:
            assert _flap_left_for_a_reason(P, F, v, STENCIL.flap_min_angle_deg)


def test_an_unknown_rim_scale_is_refused_naming_the_choices():
    s = surfaces.builtin("dome")
    with pytest.raises(InputError, match="rim_scale") as e:
        search.remesh_surface(s.V, s.F, settings=replace(STENCIL, rim_scale="loose"))
    assert '"auto", "kept" or "free"' in e.value.fix


def test_free_rim_search_is_taken_only_when_it_prints_or_ranks_higher(monkeypatch):
    """``_free_rim``: the free stencil replaces the kept one when it prints at full size, or
    when neither does and it is at full size with a shorter longest cell per unit of scaling
    (a stencil 3 % under the size asked for is not taken unasked, issue #42); a failed
    free search leaves the kept result (whose refusal names measured alternatives)."""
    class Search:
        dom = None

        def say(self, line):
            pass

    def fig(s3, L):  # (a polished stencil: at size means at full size)
        return {"scale3d": s3, "max_cell_length_mm": L, "at_size": candidates.full_size(
            {"scale3d": s3, "max_cell_length_mm": L})}

    def result(V, c, n):
        return search._Pass(V, "F", {"after_optimisation": c, "vertices": n, **c}, Search())

    req = search._Request(None, None, None, None, 0, None, UNIT_CELL, "cvt", False, True,
                          False, None)
    kept = fig(1.0, 9.72)

    def fails(req, settings):
        raise InputError("CETM did not converge", fix="remesh")
    monkeypatch.setattr(search, "_ungraded_if_needed", fails)
    V, _, info = search._free_rim(req, STENCIL, result("kept", kept, 182))
    assert V == "kept" and "failed" in info["rim_scale"]["why"]
    for free, taken in [(fig(0.995, 9.38), True),   # prints at full size
                        (fig(0.969, 9.38), False),  # prints, but 3 % under the size
                        (fig(0.80, 9.0), False),    # prints, but 20 % under the size
                        (fig(1.0, 9.6), True),      # neither prints: 9.6 < 9.72 per unit
                        (fig(0.96, 9.6), False)]:   # neither prints: 10.0 > 9.72 per unit
        monkeypatch.setattr(search, "_ungraded_if_needed", lambda req, settings, free=free: (
            result("free", free, 184), settings, None))
        V, _, info = search._free_rim(req, STENCIL, result("kept", kept, 182))
        assert (V == "free") == taken, free
        assert info["rim_scale"]["scale"] == ("free" if taken else "kept")
