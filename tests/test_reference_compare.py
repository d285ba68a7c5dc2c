"""The comparison with a reference design (``pysolver.temporal.reference_compare``), self-contained.

The real comparison (the reference's cover stencil and cells, in ``../shared``, which is not
project data) is ``bench/bench_reference.py``; here the mechanism is checked on tables made
in the test: face-pair matching in any row order and face order, the +normal layer = top,
and that a mismatch shows.
"""

from __future__ import annotations

import numpy as np
import pytest

from pysolver.errors import InputError
from pysolver.temporal.reference_compare import (
    match_cells,
    read_reference_cells,
    thickness_correlation,
)


def _cells(seed=0, n=60):
    rng = np.random.default_rng(seed)
    pairs = set()
    while len(pairs) < n:
        i, j = sorted(rng.choice(100, 2, replace=False).tolist())
        pairs.add((i, j))
    a = np.array(sorted(pairs))
    return {"base_a": a[:, 0], "base_b": a[:, 1],
            "thickness_top_mm": rng.uniform(0.3, 0.65, n),
            "thickness_bottom_mm": rng.uniform(0.3, 0.65, n),
            "t_star_s": rng.uniform(30, 80, n), "boundary": rng.random(n) < 0.3}


def _write_ref(path, cells, order, swap_faces, swap_layers=False):
    top, bot = cells["thickness_top_mm"], cells["thickness_bottom_mm"]
    if swap_layers:
        top, bot = bot, top
    rows = ["cell,face_a,face_b,thickness_pos_normal_mm,thickness_neg_normal_mm,t_star_s"]
    for k, i in enumerate(order):
        a, b = int(cells["base_a"][i]), int(cells["base_b"][i])
        if swap_faces[k]:
            a, b = b, a
        rows.append(f"{k},{a},{b},{top[i]:.9g},{bot[i]:.9g},{cells['t_star_s'][i]:.9g}")
    path.write_text("\n".join(rows) + "\n")
    return path


def test_identical_designs_correlate_exactly_in_any_order(tmp_path):
    c = _cells()
    rng = np.random.default_rng(1)
    order = rng.permutation(len(c["base_a"]))
    ref = read_reference_cells(_write_ref(tmp_path / "r.csv", c, order,
                                          rng.random(len(order)) < 0.5))
    idx = match_cells(c["base_a"], c["base_b"], ref["face_a"], ref["face_b"])
    assert np.array_equal(order[idx], np.arange(len(order)))
    r = thickness_correlation(c, ref)
    assert r["pearson"] == pytest.approx(1.0, abs=1e-12)
    assert r["pearson_top"] == pytest.approx(1.0, abs=1e-12)
    assert r["rms_diff_mm"] < 1e-8 and r["t_star_max_abs_diff_s"] < 1e-6
    assert not r["same_order"]


def test_swapped_layers_show(tmp_path):
    """+normal must be compared with top: a reference with the layers swapped correlates
    only by chance (independent random thicknesses here)."""
    c = _cells(seed=2, n=200)
    order = np.arange(200)
    ref = read_reference_cells(_write_ref(tmp_path / "r.csv", c, order, np.zeros(200, bool),
                                          swap_layers=True))
    r = thickness_correlation(c, ref)
    assert r["same_order"]
    assert abs(r["pearson_top"]) < 0.3 and abs(r["pearson_bottom"]) < 0.3


def test_bad_reference_tables_are_named(tmp_path):
    c = _cells()
    p = tmp_path / "r.csv"
    p.write_text("cell,face_a,face_b,thickness_pos_normal_mm,t_star_s\n0,1,2,0.4,30\n")
    with pytest.raises(InputError, match="missing column"):
        read_reference_cells(p)
    p.write_text("cell,face_a,face_b,thickness_pos_normal_mm,thickness_neg_normal_mm,t_star_s\n"
                 "0,1,2,0.4,x,30\n")
    with pytest.raises(InputError, match=r"r.csv:2: a value is not a number"):
        read_reference_cells(p)
    ref = read_reference_cells(_write_ref(p, c, np.arange(len(c["base_a"]) - 1),
                                          np.zeros(len(c["base_a"]), bool)))
    with pytest.raises(InputError, match="no row for the cell of faces"):
        match_cells(c["base_a"], c["base_b"], ref["face_a"], ref["face_b"])
