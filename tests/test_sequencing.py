"""The automatic sequencing landscape: facing sheets against closed-form geodesics, parts
split at narrow necks, and the paper's cover ordered as its authors ordered it."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
import triangle
from _shared import shared_file
from scipy.stats import spearmanr

from pysolver.design.mesh_input import load_input
from pysolver.design.sequencing import facing_pairs, sequencing_landscape, surface_parts
from pysolver.params import SEQUENCING


def _strip(gap: float, arm: float = 40.0, width: float = 20.0, h: float = 1.5):
    """A strip folded into a U: two flat arms ``gap`` mm apart joined by a half cylinder.

    Returns V (n, 3) mm, F, and s (n,) mm: arc length along the strip (a developable
    surface: the geodesic between two points is ``hypot(ds, dy)``)."""
    bend = np.pi * gap / 2
    s = np.linspace(0.0, 2 * arm + bend, int(round((2 * arm + bend) / h)) + 1)
    y = np.linspace(0.0, width, int(round(width / h)) + 1)
    S, Y = np.meshgrid(s, y, indexing="ij")
    S, Y = S.ravel(), Y.ravel()
    a = np.clip((S - arm) / (gap / 2), 0.0, np.pi)  # angle round the bend
    X = np.where(S < arm, arm - S, np.where(S > arm + bend, S - arm - bend,
                                            -gap / 2 * np.sin(a)))
    Z = np.where(S < arm, 0.0, np.where(S > arm + bend, gap, gap / 2 * (1 - np.cos(a))))
    V = np.c_[X, Y, Z]
    ny = len(y)
    i, j = np.meshgrid(np.arange(len(s) - 1), np.arange(ny - 1), indexing="ij")
    q = (i * ny + j).ravel()
    F = np.r_[np.c_[q, q + ny, q + 1], np.c_[q + 1, q + ny, q + ny + 1]]
    return V, F, S, Y


def test_facing_pairs_of_a_folded_strip_against_closed_form_geodesics():
    reach, detour = SEQUENCING.reach_mm, SEQUENCING.detour
    V, F, S, Y = _strip(gap=6.0)
    pairs = facing_pairs(V, F, reach, detour)
    d = np.linalg.norm(V[:, None] - V[None], axis=2)
    geo = np.hypot(S[:, None] - S[None], Y[:, None] - Y[None])
    i, j = pairs.T
    assert len(pairs) > 100
    assert np.all(d[i, j] < reach)
    # the paths along edges are longer than the geodesic (at most by the grid's sqrt(2))
    assert np.all(geo[i, j] * np.sqrt(2) > detour * d[i, j])
    # every pair clearly beyond the rule (20 % margin either side) is found
    iu = np.triu_indices(len(V), 1)
    clear = (d[iu] < 0.8 * reach) & (geo[iu] > 1.2 * np.sqrt(2) * detour * d[iu])
    found = np.zeros((len(V), len(V)), bool)
    found[i, j] = True
    assert clear.sum() > 100 and np.all(found[iu][clear])
    # an unfolded strip faces nothing
    V_flat = np.c_[S, Y, np.zeros_like(S)]
    assert len(facing_pairs(V_flat, F, reach, detour)) == 0


def _dumbbell(neck_half_width: float, r: float = 30.0, spacing: float = 80.0):
    shape = shapely.union_all([shapely.Point(0, 0).buffer(r, 64),
                               shapely.Point(spacing, 0).buffer(r, 64),
                               shapely.box(0, -neck_half_width, spacing, neck_half_width)])
    ring = np.asarray(shape.exterior.coords)[:-1]
    n = len(ring)
    t = triangle.triangulate({"vertices": ring, "segments": np.c_[np.arange(n),
                                                                 (np.arange(n) + 1) % n]},
                             "pq30a4")
    V = np.c_[t["vertices"], np.zeros(len(t["vertices"]))]
    return V, t["triangles"]


@pytest.mark.parametrize("neck, parts", [(8.0, 2), (28.0, 1)])
def test_parts_split_at_narrow_necks(neck, parts):
    """Two 30 mm discs joined by a neck: apart when the neck's half-width is under
    ``saddle_ratio`` (0.75) of their radius, one part when it is wider."""
    V, F = _dumbbell(neck)
    part = surface_parts(V, F, SEQUENCING.saddle_ratio)
    left = part[np.argmin(np.linalg.norm(V[:, :2], axis=1))]
    right = part[np.argmin(np.linalg.norm(V[:, :2] - [80.0, 0.0], axis=1))]
    assert (left != right) == (parts == 2)
    # every part is one connected region: no vertex is cut off from its part's deepest point
    big = np.bincount(part)
    assert big.min() > 0.1 * len(V) or parts == 1


def test_flat_and_open_targets_get_no_sequence():
    V, F = _dumbbell(8.0)
    t, info = sequencing_landscape(V, F)
    assert t is None and info["facing_pairs"] == 0


def test_cover_petals_close_in_the_papers_order():
    """On the reference's own cover stencil, the landscape drawn from the target alone
    orders the petals as the paper's authors did (their landscape: 30, 48 and 78 s)."""
    src = shared_file("reference-shapes", "cover_reference_stencil.obj")
    m = load_input(src, validate=False, stencil=True)
    t_ref = np.loadtxt(src.parent / "cover_reference_time_landscape.csv", skiprows=1)
    t, info = sequencing_landscape(m.V, m.F)
    assert t is not None and len(t) == len(t_ref)
    assert np.corrcoef(t, t_ref)[0, 1] >= 0.9
    assert spearmanr(t, t_ref).statistic >= 0.85
    lo, hi = SEQUENCING.times_s
    assert t.min() == lo and t.max() == hi
    # deterministic
    t2, info2 = sequencing_landscape(m.V, m.F)
    assert np.array_equal(t, t2) and info == info2


def test_a_cycle_loses_its_weakest_edge_only():
    from pysolver.design.sequencing import _levels

    # 0 under 1 under 2 under 0 (a pinwheel no order satisfies), and 2 under 3
    level, dropped = _levels(5, [(0, 1, 50), (1, 2, 40), (2, 0, 10), (2, 3, 5)])
    assert dropped == [(2, 0, 10)]
    assert level.tolist() == [0, 1, 2, 3, -1]


def _three_parts(n: int = 90):
    """Cells of three sequenced parts (30 / 55 / 80 s) whose achievable ranges overlap
    around 55-60 s: the map that clamps fewest squeezes the parts within 14 s."""
    t_star = np.repeat([30.0, 55.0, 80.0], n // 3)
    t_lo = np.repeat([50.0, 52.0, 54.0], n // 3)
    t_hi = np.repeat([60.0, 62.0, 64.0], n // 3)
    return t_star, t_lo, t_hi


def test_fitted_sequenced_landscape_keeps_its_parts_apart():
    from pysolver.temporal.program import _achievable_summary

    t_star, t_lo, t_hi = _three_parts()
    free = _achievable_summary(t_star, t_lo, t_hi, 120.0)["suggested_map"]
    assert free["fraction_clamped"] == 0.0
    assert (free["a"], free["b"]) == (50.0, 64.0)   # the widest map that clamps none
    span = 2 * SEQUENCING.min_separation_s
    kept = _achievable_summary(t_star, t_lo, t_hi, 120.0, min_span=span)["suggested_map"]
    assert kept["min_span_s"] == span
    assert kept["b"] - kept["a"] >= span - 1e-9
    # the fewest clamped among maps that wide: one part, 30 of 90 cells, is out of range
    # (both ends of a 20 s map cannot sit in [50, 60] and [54, 64] at once)
    assert kept["fraction_clamped"] == pytest.approx(1 / 3)
    # a span no map can have within the model's range falls back to the free map
    wide = _achievable_summary(t_star, t_lo, t_hi, 120.0, min_span=500.0)["suggested_map"]
    assert wide["min_span_s"] == 0.0 and (wide["a"], wide["b"]) == (50.0, 64.0)


def test_sequenced_span_reads_the_design_levels(tmp_path):
    import json

    from pysolver.errors import InputError
    from pysolver.temporal.program import sequenced_span

    assert sequenced_span(tmp_path) == 0.0                      # no design.json
    (tmp_path / "design.json").write_text(json.dumps({"options": {"sequencing": None}}))
    assert sequenced_span(tmp_path) == 0.0                      # not sequenced
    (tmp_path / "design.json").write_text(
        json.dumps({"options": {"sequencing": {"levels": [0, 2, 1, 1]}}}))
    assert sequenced_span(tmp_path) == pytest.approx(2 * SEQUENCING.min_separation_s)
    (tmp_path / "design.json").write_text(
        json.dumps({"options": {"sequencing": {"levels": ["x", 1]}}}))
    with pytest.raises(InputError, match="levels"):
        sequenced_span(tmp_path)


def test_fitted_landscape_keeps_its_order_within_the_clamping_allowance():
    """The fit spends at most ``fit_clamped_fraction`` of the cells on width, and not for a
    few seconds of it; beyond the allowance it clamps fewest."""
    from pysolver.params import PROGRAMMING
    from pysolver.temporal.program import _achievable_summary

    n = 100
    t_star = np.linspace(30.0, 80.0, n)
    # 8 cells spread over the landscape reach only 58-62 s, the others 40-80 s: clamping none
    # squeezes the landscape into 4 s; allowing 7 % keeps all of 40-80 s
    t_lo, t_hi = np.full(n, 40.0), np.full(n, 80.0)
    t_lo[::13], t_hi[::13] = 58.0, 62.0
    m = _achievable_summary(t_star, t_lo, t_hi, 120.0)["suggested_map"]
    assert (m["a"], m["b"]) == (40.0, 80.0)
    mapped = 40.0 + (t_star - 30.0) * 40.0 / 50.0
    out = (mapped < t_lo) | (mapped > t_hi)   # 7 of the 8 (one maps into 58-62 s)
    assert m["fraction_clamped"] == pytest.approx(out.mean()) and out.sum() == 7
    assert m["fraction_clamped"] <= PROGRAMMING.fit_clamped_fraction
    # every cell reaches only 40-60 s and 5 reach nothing: the 40-60 s map (5 %) is taken,
    # not a map 2 s wider that clamps 4 % more
    t_lo, t_hi = np.full(n, 40.0), np.full(n, 60.0)
    t_lo[::20] = np.inf
    m = _achievable_summary(t_star, t_lo, t_hi, 120.0)["suggested_map"]
    assert (m["a"], m["b"]) == (40.0, 60.0) and m["fraction_clamped"] == pytest.approx(0.05)
    # 30 % reach nothing: over the allowance, the fewest clamped (then the widest)
    t_lo[::3] = np.inf
    m = _achievable_summary(t_star, t_lo, t_hi, 120.0)["suggested_map"]
    assert (m["a"], m["b"]) == (40.0, 60.0)
    assert m["fraction_clamped"] == pytest.approx(np.mean(~np.isfinite(t_lo)))
