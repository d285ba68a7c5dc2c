"""Design-folder tables: round trips, validation messages, frames helpers."""

from __future__ import annotations

import numpy as np
import pytest

from pysolver import tables
from pysolver.errors import InputError
from pysolver.geometry import (
    apply_transform,
    flat_to_target,
    frames_to_rotation,
    matrix_to_rotvec,
    print_transform,
    rotvec_to_matrix,
    target_to_flat,
)


@pytest.fixture(scope="module")
def regular_design(tmp_path_factory):
    from pysolver.design import run_design

    out = tmp_path_factory.mktemp("regular")
    summary = run_design("regular", out, progress=False, plots=False)
    return out, summary


def _random_table(kind, n, rng):
    data = {}
    for c, k in tables.SCHEMAS[kind].items():
        if k == "float":
            data[c] = rng.uniform(0.1, 100.0, n) * rng.choice([1, 1e-3, 1e3], n)
        elif k == "int":
            data[c] = rng.integers(0, 3, n)
        elif k == "bool":
            data[c] = rng.integers(0, 2, n).astype(bool)
        else:
            data[c] = rng.choice(list(k), n)
    for idc in ("base_id", "cell_id", "vertex_id"):
        if idc in data and kind != "bumpers":
            data[idc] = np.arange(n)
    return data


@pytest.mark.parametrize("kind", list(tables.SCHEMAS))
def test_table_round_trip(tmp_path, kind):
    rng = np.random.default_rng(1)
    data = _random_table(kind, 17, rng)
    p = tables.write_table(tmp_path / f"{kind}.csv", kind, data)
    back = tables.read_table(p, kind)
    for c, k in tables.SCHEMAS[kind].items():
        if k == "float":
            np.testing.assert_allclose(back[c], data[c], rtol=1e-8)  # %.9g
        else:
            assert np.array_equal(back[c], data[c]), c
    text = p.read_text()
    assert text.endswith("\n") and "\r" not in text
    assert text.splitlines()[0] == ",".join(tables.SCHEMAS[kind])


def test_table_nan_only_where_allowed(tmp_path):
    rng = np.random.default_rng(2)
    data = _random_table("cells", 3, rng)
    data["t_min_s"][:] = np.nan
    p = tables.write_table(tmp_path / "cells.csv", "cells", data)
    assert np.all(np.isnan(tables.read_table(p, "cells")["t_min_s"]))
    data["t_star_s"][1] = np.nan
    tables.write_table(p, "cells", data)
    with pytest.raises(InputError, match=r"cells.csv:3: column t_star_s .*NaN"):
        tables.read_table(p, "cells")


@pytest.mark.parametrize("edit, match", [
    (lambda L: [L[0].replace("x_mm", "X")] + L[1:], "missing \\['x_mm'\\]"),
    (lambda L: ["y_mm,x_mm"] + L[1:], "out of order"),
    (lambda L: L[:1] + ["1.0,abc"] + L[2:], ":2: column y_mm = 'abc' is not a number"),
    (lambda L: L[:1] + ["1.0"] + L[2:], ":2: 1 fields, expected 2"),
    (lambda L: L[:1] + ["1.0,inf"] + L[2:], "infinite"),
])
def test_table_errors_name_the_problem(tmp_path, edit, match):
    p = tables.write_table(tmp_path / "support_frame.csv", "support_frame",
                           {"x_mm": [1.0, 2.0, 3.0], "y_mm": [0.0, 1.0, 0.0]})
    lines = p.read_text().splitlines()
    p.write_text("\n".join(edit(lines)) + "\n")
    with pytest.raises(InputError, match=match):
        tables.read_table(p, "support_frame")


def test_table_value_rules(tmp_path):
    rng = np.random.default_rng(3)
    data = _random_table("bumpers", 4, rng)
    p = tables.write_table(tmp_path / "bumpers.csv", "bumpers", data)
    txt = p.read_text().replace(",top,", ",middle,", 1).replace(",bottom,", ",middle,", 1)
    p.write_text(txt)
    with pytest.raises(InputError, match="layer = 'middle': must be one of"):
        tables.read_table(p, "bumpers")
    data = _random_table("time_landscape", 3, rng)
    data["time_s"][2] = -1
    p = tables.write_table(tmp_path / "t.csv", "time_landscape", data)
    with pytest.raises(InputError, match="time_s .* must be >= 0"):
        tables.read_table(p, "time_landscape")
    data["time_s"][2] = 1
    data["vertex_id"] = np.array([0, 2, 1])
    tables.write_table(p, "time_landscape", data)
    with pytest.raises(InputError, match="vertex_id = 2, expected 1"):
        tables.read_table(p, "time_landscape")
    with pytest.raises(InputError, match="file not found"):
        tables.read_table(tmp_path / "nope.csv", "cells")


def test_stencil_round_trip_and_vt_indices(tmp_path):
    rng = np.random.default_rng(4)
    V = rng.normal(size=(5, 3)) * 10
    UV = rng.normal(size=(5, 2)) * 10
    F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4]])
    p = tables.write_stencil(tmp_path / "stencil.obj", V, UV, F)
    V2, UV2, F2 = tables.read_stencil(p)
    np.testing.assert_allclose(V2, V, rtol=1e-8)
    np.testing.assert_allclose(UV2, UV, rtol=1e-8)
    assert np.array_equal(F2, F)
    # v/vt corners with a permuted vt list -> reordered row-aligned
    perm = np.array([3, 0, 4, 1, 2])  # vt k = UV[perm[k]]
    inv = np.argsort(perm)
    lines = ["v {:.17g} {:.17g} {:.17g}".format(*tuple(v)) for v in V]
    lines += ["vt {:.17g} {:.17g}".format(*tuple(UV[k])) for k in perm]
    lines += ["f " + " ".join(f"{a + 1}/{inv[a] + 1}" for a in f) for f in F]
    (tmp_path / "s2.obj").write_text("\n".join(lines) + "\n")
    _, UV3, _ = tables.read_stencil(tmp_path / "s2.obj")
    np.testing.assert_allclose(UV3, UV)
    # a seam (one v with two vt) is refused
    lines[-1] = "f 1/2 4/3 5/1"
    (tmp_path / "s3.obj").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match="seam"):
        tables.read_stencil(tmp_path / "s3.obj")
    (tmp_path / "q.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    with pytest.raises(InputError, match="4 corners"):
        tables.read_stencil(tmp_path / "q.obj")


def test_round_sig9_matches_writer():
    x = np.array([1 / 3, -2.0 / 7 * 1e3, 12345.678901234])
    assert np.all(tables.round_sig9(x) == np.array([float(f"{v:.9g}") for v in x]))


def test_read_design_cross_checks(regular_design, tmp_path):
    out, summary = regular_design
    d = tables.read_design(out)
    assert d.n_bases == summary["counts"]["bases"] == 60
    assert d.n_cells == summary["counts"]["cells"]
    assert len(d.bumpers["base_id"]) == 4 * d.n_cells
    # tables agree with the stencil they were derived from (9 significant digits)
    Fc = d.V[d.F].mean(1)
    np.testing.assert_allclose(np.c_[d.bases["target_x_mm"], d.bases["target_y_mm"],
                                     d.bases["target_z_mm"]], Fc, atol=1e-6)
    # a corrupted cells.csv (two rows swapped) is caught
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(out, bad)
    lines = (bad / "cells.csv").read_text().splitlines()
    lines[1], lines[2] = lines[2], lines[1]
    (bad / "cells.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match="cell_id"):
        tables.read_design(bad)
    lines[1], lines[2] = lines[2], lines[1]
    f = lines[1].split(",")
    f[1], f[2] = f[2], f[1]  # swap base_a / base_b
    lines[1] = ",".join(f)
    (bad / "cells.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"cells.csv:2: \(base_a"):
        tables.read_design(bad)


# --------------------------------------------------------------------------------------
# frames


def test_print_transform():
    P = np.array([[1.0, 2.0, 0.0], [1.0, 2.0, 2.3], [0.0, 0.0, -2.3]])
    top = apply_transform(print_transform("top"), P)
    bottom = apply_transform(print_transform("bottom"), P)
    np.testing.assert_allclose(top, [[1, -2, 2.3], [1, -2, 0], [0, 0, 4.6]])
    np.testing.assert_allclose(bottom, [[1, 2, 2.3], [1, 2, 4.6], [0, 0, 0]])
    for layer in ("top", "bottom", 0, 1):
        T = print_transform(layer)
        assert np.isclose(np.linalg.det(T[:3, :3]), 1.0)  # proper rotation, no mirror
    # top layer: far face (z = 2.3) on the bed; bottom: far face (z = -2.3) on the bed
    assert apply_transform(print_transform(0), [[0, 0, 2.3]])[0, 2] == pytest.approx(0)
    assert apply_transform(print_transform(1), [[0, 0, -2.3]])[0, 2] == pytest.approx(0)
    with pytest.raises(ValueError):
        print_transform("middle")


def test_rotations():
    rng = np.random.default_rng(5)
    r = rng.normal(size=(20, 3))
    R = rotvec_to_matrix(r)
    np.testing.assert_allclose(np.einsum("kij,kj->ki", R, r), r, atol=1e-12)  # axis fixed
    np.testing.assert_allclose(rotvec_to_matrix(matrix_to_rotvec(R)), R, atol=1e-12)
    a, s, b, t = (rng.normal(size=(20, 3)) for _ in range(4))
    Q = frames_to_rotation(a, s, b, t)
    np.testing.assert_allclose(np.linalg.det(Q), 1.0)
    au = a / np.linalg.norm(a, axis=1, keepdims=True)
    bu = b / np.linalg.norm(b, axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum("kij,kj->ki", Q, au), bu, atol=1e-12)
    # the side goes into the plane spanned by b and t, on t's side
    side = np.einsum("kij,kj->ki", Q, s - np.sum(s * au, 1)[:, None] * au)
    n = np.cross(b, t)
    assert np.allclose(np.sum(side * n, 1), 0, atol=1e-9)
    assert np.all(np.sum(side * (t - np.sum(t * bu, 1)[:, None] * bu), 1) > 0)
    c_t, c_f = rng.normal(size=3), rng.normal(size=2)
    P = rng.normal(size=(7, 3))
    np.testing.assert_allclose(target_to_flat(flat_to_target(P, Q[0], c_t, c_f), Q[0], c_t, c_f),
                               P, atol=1e-12)
