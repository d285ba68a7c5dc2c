"""Unit-cell specimens (issue #9): grid, STL measurements, labels, library edits.

One module-scoped ``make_specimens(lengths=(5, 9))`` (8 specimens of the authors'
grid) in a temp folder.  Tolerances: bracket thickness and central length 0.02 mm
(measured on sections of the STL), labels read back exactly from sections of the
raised and engraved relief.
"""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest
from _shared import section_width

from pysolver.errors import InputError
from pysolver.params import UNIT_CELL
from pysolver.render import load_stl
from pysolver.render.scad_io import SCAD_DIR
from pysolver.render.specimens import (
    make_specimens,
    plate_layout,
    specimen_grid,
    specimen_labels,
)

U = UNIT_CELL
ALPHA = math.radians(U.alpha_deg)
HALF_H, GAP, LABEL_H, LABEL_SIZE, LENGTH = 2.5, 0.05, 0.3, 3.0, 40.0   # scad/specimen.scad
TOP = 2 * HALF_H + GAP


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    root = tmp_path_factory.mktemp("specimens")
    s = make_specimens(root / "out", lengths=(5, 9), cache_dir=root / "cache", progress=False)
    return dict(root=root, s=s, meshes=[load_stl(sp["stl"]) for sp in s["specimens"]])


# ------------------------------------------------------------------------------------------
# section helpers (as in test_render.py)


def _slice(mesh, z):
    import trimesh

    return np.asarray(trimesh.intersections.mesh_plane(mesh, [0, 0, 1], [0, 0, z]))[:, :, :2]


def _loops(seg):
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    P = seg.reshape(-1, 2)
    keys, inv = np.unique(np.round(P / 1e-6).astype(np.int64), axis=0, return_inverse=True)
    inv = inv.ravel()
    e = inv.reshape(-1, 2)
    A = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(len(keys),) * 2)
    _n, lab = connected_components(A, directed=False)
    pts = np.zeros((len(keys), 2))
    pts[inv] = P
    return [pts[lab == c] for c in range(lab.max() + 1)]


def _fit_circle(P):
    A = np.c_[2 * P, np.ones(len(P))]
    sol, *_ = np.linalg.lstsq(A, (P ** 2).sum(1), rcond=None)
    return sol[:2], math.sqrt(sol[2] + sol[:2] @ sol[:2])


def _inside(seg, pts):
    """Even-odd point-in-section test: (k,) bool for (k, 2) points."""
    p, q = seg[:, 0], seg[:, 1]
    out = []
    for x, y in pts:
        crosses = (p[:, 1] > y) != (q[:, 1] > y)
        xs = p[:, 0] + (y - p[:, 1]) * (q[:, 0] - p[:, 0]) / np.where(crosses, q[:, 1] - p[:, 1], 1)
        out.append(int(np.sum(crosses & (xs > x))) % 2 == 1)
    return np.array(out)


# seven-segment glyphs as drawn by scad/label.scad (cell 0.5 size wide, advance 0.62 size)
GLYPHS = {"0": "abcdef", "1": "bc", "2": "abdeg", "3": "abcdg", "4": "bcfg", "5": "acdfg",
          "6": "acdefg", "7": "abc", "8": "abcdefg", "9": "abcdfg", "L": "def", "H": "bcefg",
          "-": "g", ".": "p"}


def _read_label(seg, centre, text, mirrored=False, engraved=False):
    """Read a seven-segment label from a section: which segments are lit at each glyph slot.

    The glyph slots (positions) come from the expected text; what is read is which
    segments carry relief, decoded back to characters.
    """
    s, t = LABEL_SIZE, 0.5
    w, hh = 0.5 * s, s / 2
    probes = {"a": (w / 2, s - t / 2), "b": (w - t / 2, 0.75 * s), "c": (w - t / 2, 0.25 * s),
              "d": (w / 2, t / 2), "e": (t / 2, 0.25 * s), "f": (t / 2, 0.75 * s),
              "g": (w / 2, hh), "p": (t / 2, t / 2)}
    adv = [0.3 * s if ch == "." else 0.62 * s for ch in text]
    x0 = -(sum(adv) - 0.12 * s) / 2
    read = ""
    for ch, a in zip(text, adv, strict=True):
        keys = ["p"] if ch == "." else list("abcdefg")
        pts = np.array([[x0 + probes[k][0], probes[k][1] - s / 2] for k in keys])
        if mirrored:
            pts[:, 0] = -pts[:, 0]
        lit = _inside(seg, pts + centre)
        if engraved:
            lit = ~lit
        segs = "".join(k for k, on in zip(keys, lit, strict=True) if on)
        read += next((c for c, g in GLYPHS.items() if g == segs), "?")
        x0 += a
    return read


def _label_centres(l):
    x0, x1 = l / 2 + U.base_r, LENGTH / 2 - 4.0 - 1.0
    xm = (x0 + x1) / 2
    return np.array([-xm, 0.0]), np.array([xm, 0.0])


# ------------------------------------------------------------------------------------------


def test_default_grid_is_the_authors():
    g = specimen_grid()
    assert len(g) == 20
    assert [h for l, h in g if l == 6] == [0.3, 0.4, 0.5, 0.6]
    assert [h for l, h in g if l == 8] == [0.35, 0.45, 0.55, 0.65]
    assert specimen_grid((7.5,), (0.4,)) == [(7.5, 0.4)]


@pytest.mark.parametrize("kw, match", [
    (dict(lengths=(3.0,)), "central length"),
    (dict(lengths=(20.0,)), "central length"),
    (dict(lengths=(7,), thicknesses=(1.2,)), "thickness"),
])
def test_grid_rejects_unprintable_values(kw, match):
    with pytest.raises(InputError, match=match):
        specimen_grid(**kw)


def test_plate_layout_fits_and_overflows():
    sizes = [(40, 6)] * 10
    plates = plate_layout(sizes, (100, 20), spacing=3)
    assert [len(p) for p in plates] == [4, 4, 2]     # 2 per row, 2 rows per plate
    for p in plates:
        for _i, x, y in p:
            assert 0 <= x and x + 40 <= 100 and 0 <= y and y + 6 <= 20
    with pytest.raises(InputError, match="does not fit"):
        plate_layout([(250, 6)], (200, 200))


def test_labels_format():
    assert specimen_labels(7, 0.45) == ("L7", "H.45")
    assert specimen_labels(8.5, 0.3) == ("L8.5", "H.3")


def test_specimens_are_watertight_two_halves(made):
    s = made["s"]
    assert s["count"] == 8 and s["rendered"] == 8
    for sp, mesh in zip(s["specimens"], made["meshes"], strict=True):
        assert mesh.is_watertight and mesh.is_volume
        assert sp["watertight"] and sp["bodies"] == 2      # the halves are separate solids
        assert mesh.bounds[0, 2] == pytest.approx(0, abs=1e-5)
        assert mesh.bounds[1, 2] == pytest.approx(TOP + LABEL_H, abs=1e-4)
        assert mesh.bounds[:, 0] == pytest.approx([-LENGTH / 2, LENGTH / 2], abs=1e-4)
    for plate in s["plates"]:
        assert plate["watertight"] and plate["bodies"] == 2 * plate["count"]
        lo, hi = np.array(plate["bbox_mm"])
        assert np.all(lo >= -1e-6) and np.all(hi[:2] <= np.array(s["build_area_mm"]) + 1e-6)
    assert sum(p["count"] for p in s["plates"]) == s["count"]


def test_bracket_thickness_and_central_length_from_sections(made):
    for sp, mesh in zip(made["s"]["specimens"], made["meshes"], strict=True):
        l, h = sp["l_mm"], sp["h_mm"]
        # central length: the bases' inner half-discs stick out of the handles
        centres = []
        for P in _loops(_slice(mesh, HALF_H - 0.5)):          # lower half, above its brackets
            arc = P[np.abs(P[:, 0]) < l / 2 - 1e-3]
            if len(arc) > 5:
                c, r = _fit_circle(arc)
                assert r == pytest.approx(U.base_r, abs=0.01)
                centres.append(c)
        assert len(centres) == 2
        assert abs(centres[0][0] - centres[1][0]) == pytest.approx(l, abs=0.02)
        # thickness: width of each of the 4 arms at mid-length, in both halves
        for z in (U.bracket_w / 2, TOP - U.bracket_w / 2):
            seg = _slice(mesh, z)
            for cx, d in ((-l / 2, 0.0), (l / 2, math.pi)):
                for k in (-1, 1):
                    u = np.array([math.cos(d + k * ALPHA), math.sin(d + k * ALPHA)])
                    m = np.array([cx, 0]) + (U.base_r + l / (2 * math.cos(ALPHA))) / 2 * u
                    width = section_width(seg, m, np.array([-u[1], u[0]]))
                    assert width == pytest.approx(h, abs=0.02), (l, h, z)


def test_labels_read_back_from_the_stl(made):
    for sp, mesh in zip(made["s"]["specimens"], made["meshes"], strict=True):
        expect = sp["labels"]
        top = _slice(mesh, TOP + LABEL_H / 2)                 # raised relief only
        bottom = _slice(mesh, LABEL_H / 2)                    # engraved in the bed face
        for text, c in zip(expect, _label_centres(sp["l_mm"]), strict=True):
            assert _read_label(top, c, text) == text
            assert _read_label(bottom, c, text, mirrored=True, engraved=True) == text


def test_specimens_csv_and_cache(made):
    lines = (made["root"] / "out" / "specimens.csv").read_text().splitlines()
    assert lines[0].startswith("l_mm,h_mm,label_left,label_right,stl,plate")
    assert len(lines) == 1 + made["s"]["count"]
    assert lines[1].split(",")[:4] == ["5", "0.3", "L5", "H.3"]
    again = make_specimens(made["root"] / "out2", lengths=(5, 9),
                           cache_dir=made["root"] / "cache", progress=False)
    assert again["rendered"] == 0 and again["cached"] == 8


def test_editing_the_bracket_module_changes_the_specimen(made, tmp_path):
    lib = tmp_path / "scad"
    shutil.copytree(SCAD_DIR, lib)
    src = (lib / "bracket.scad").read_text()
    sig = "module bracket(dir, l, h, height=BRACKET_W,"
    (lib / "bracket.scad").write_text(src.replace(sig, "module bracket(dir, l, h, height=1.2,"))
    s = make_specimens(tmp_path / "out", lengths=(5,), thicknesses=(0.3,), scad_dir=lib,
                       cache_dir=made["root"] / "cache", progress=False)
    assert s["rendered"] == 1
    edited = load_stl(s["specimens"][0]["stl"])
    original = made["meshes"][0]                              # same l = 5, h = 0.3
    u = np.array([math.cos(ALPHA), math.sin(ALPHA)])
    m = np.array([-2.5, 0]) + (U.base_r + 5 / (2 * math.cos(ALPHA))) / 2 * u
    w = np.array([-u[1], u[0]])
    assert section_width(_slice(edited, 1.1), m, w) == pytest.approx(0.3, abs=0.02)
    assert section_width(_slice(original, 1.1), m, w) is None
