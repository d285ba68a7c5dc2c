"""Simulation check report (sim.report) on synthetic design folders.

The helper :func:`make_synthetic_design` writes a complete design folder that
follows ``docs/design-folder.md`` and the frames.npz contract, for a flat
triangular lattice that morphs into a spherical cap, without running the
simulator: every base moves from its flat pose to its target pose (times a
global rigid motion, as the simulator's frame is not the target frame), each
base at its own pace set by the programmed t* of its cells.  Variants break it
on purpose (wrong final shape, bent the wrong way, interpenetrating bases,
non-converged steps).  The other report tests import it from here.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pysolver.errors import InputError
from pysolver.geometry import (
    base_rotations,
    face_adjacency,
    face_centroids,
    face_normals,
    fold_angles_deg,
    unit_cells,
)
from pysolver.params import PHYSICS_DEFAULT, UNIT_CELL
from pysolver.tables import write_stencil, write_table

MODES = ("good", "flat", "wrong_way", "collide", "nonconverged")


def lattice(n):
    """Flat equilateral triangle lattice with n x n vertices, 2 (n-1)^2 CCW faces, unit edge."""
    j, i = np.mgrid[0:n, 0:n]
    x = i + 0.5 * (j % 2)
    y = j * np.sqrt(3) / 2
    UV = np.c_[x.ravel(), y.ravel()]
    F = []
    for r in range(n - 1):
        for c in range(n - 1):
            a, b = r * n + c, r * n + c + 1
            d, e = (r + 1) * n + c, (r + 1) * n + c + 1
            if r % 2 == 0:
                F += [[a, b, d], [b, e, d]]
            else:
                F += [[a, b, e], [a, e, d]]
    return UV - UV.mean(axis=0), np.array(F, dtype=np.int64)


def make_synthetic_design(folder, *, n=6, edge=12.0, sphere_r=60.0, contraction=0.8,
                          mode="good", dt=2.0, t_end=100.0, seed=0, noise_mm=0.02,
                          membrane=True):
    """Write a synthetic design folder with ``sim/frames.npz``; returns a dict of its arrays.

    Parameters
    ----------
    folder : Path
    n : int
        Lattice vertices per side; ``2 (n-1)^2`` bases (n = 11 gives 200).
    edge : float, mm
        Flat lattice edge (flat centre distance of neighbours = edge / sqrt(3)).
    sphere_r : float, mm
        Radius of the target spherical cap.
    contraction : float
        Target in-plane contraction (target arc length = contraction x flat length).
    mode : one of MODES
    dt, t_end : float, s
        Frame step and end time (frame 0 = flat rest at t = 0, frame k at (k - 1) dt).
    noise_mm : float, mm
        Random noise on the final base centres.
    """
    assert mode in MODES
    rng = np.random.default_rng(seed)
    folder = Path(folder)
    (folder / "sim").mkdir(parents=True, exist_ok=True)
    UV, F = lattice(n)
    UV = UV * edge
    # target: azimuthal-equidistant map of the contracted flat layout onto a sphere (dome, +z)
    rad = np.linalg.norm(UV, axis=1) * contraction
    phi = np.arctan2(UV[:, 1], UV[:, 0])
    th = rad / sphere_r
    V = np.c_[sphere_r * np.sin(th) * np.cos(phi), sphere_r * np.sin(th) * np.sin(phi),
              sphere_r * np.cos(th)]
    V -= V.mean(axis=0)
    ff = face_adjacency(F)
    cells = unit_cells(F, ff)
    Fc, C2, N = face_centroids(V, F), face_centroids(UV, F), face_normals(V, F)
    R_t, ref = base_rotations(V, UV, F, ff)
    m, nc = len(F), len(cells.faces)
    landscape = 30.0 + 40.0 * np.linalg.norm(UV, axis=1) / np.linalg.norm(UV, axis=1).max()
    a, b = cells.faces[:, 0], cells.faces[:, 1]
    central = np.linalg.norm(C2[b] - C2[a], axis=1)
    target_len = np.linalg.norm(Fc[b] - Fc[a], axis=1)
    t_star = landscape[cells.verts].mean(axis=1)
    boundary_face = (ff < 0).any(axis=1)
    write_stencil(folder / "stencil.obj", V, UV, F)
    write_table(folder, "time_landscape", {"vertex_id": np.arange(len(V)), "time_s": landscape})
    write_table(folder, "bases", {
        "base_id": np.arange(m), "v0": F[:, 0], "v1": F[:, 1], "v2": F[:, 2],
        "flat_x_mm": C2[:, 0], "flat_y_mm": C2[:, 1],
        "target_x_mm": Fc[:, 0], "target_y_mm": Fc[:, 1], "target_z_mm": Fc[:, 2],
        "normal_x": N[:, 0], "normal_y": N[:, 1], "normal_z": N[:, 2],
        **dict(zip(("rot_x_rad", "rot_y_rad", "rot_z_rad"),
                   Rotation.from_matrix(R_t).as_rotvec().T, strict=True)),
        "ref_slot": ref, "boundary": boundary_face,
        "alignment": np.isin(np.arange(m), np.flatnonzero(boundary_face)[::7]),
    })
    thick_top = np.clip(0.30 + 0.35 * (t_star - 30) / 40, 0.3, 0.65)
    write_table(folder, "cells", {
        "cell_id": np.arange(nc), "base_a": a, "base_b": b,
        "slot_a": cells.slots[:, 0], "slot_b": cells.slots[:, 1],
        "vertex_a": cells.verts[:, 0], "vertex_b": cells.verts[:, 1],
        "boundary": cells.boundary, "central_length_mm": central,
        "bracket_length_mm": central - UNIT_CELL.bracket_offset,
        "target_length_mm": target_len, "fold_angle_deg": fold_angles_deg(Fc, N, cells),
        "collision_length_top_mm": target_len - 3.3, "collision_length_bottom_mm": target_len - 3.1,
        "t_star_s": t_star, "thickness_top_mm": thick_top,
        "thickness_bottom_mm": np.clip(thick_top + 0.05, 0.3, 0.65),
        "t_min_s": np.full(nc, 10.0), "t_max_s": np.full(nc, 110.0), "clamped": np.zeros(nc),
    })
    # bumpers (one per layer and base of each cell; the report reads the folder with the one
    # design-folder reader, which wants every table) and a support frame around the layout
    k = 4 * nc
    cid = np.repeat(np.arange(nc), 4)
    side = np.tile([0, 1], 2 * nc)
    write_table(folder, "bumpers", {
        "base_id": np.where(side == 0, a[cid], b[cid]), "layer": np.tile(["top", "top", "bottom",
                                                                          "bottom"], nc),
        "slot": np.where(side == 0, cells.slots[cid, 0], cells.slots[cid, 1]), "cell_id": cid,
        "neighbour": np.where(side == 0, b[cid], a[cid]), "dir_deg": np.zeros(k),
        "plane_px": np.zeros(k), "plane_py": np.zeros(k), "plane_pz": np.zeros(k),
        "plane_nx": np.ones(k), "plane_ny": np.zeros(k), "plane_nz": np.zeros(k),
        "cut": np.full(k, "straight"), "length_mm": np.repeat(target_len - 3.3, 4),
    })
    lo, hi = UV.min(axis=0) - 5.0, UV.max(axis=0) + 5.0
    write_table(folder, "support_frame", {"x_mm": np.array([lo[0], hi[0], hi[0], lo[0]]),
                                          "y_mm": np.array([lo[1], lo[1], hi[1], hi[1]])})
    # ---- frames
    t = np.r_[0.0, np.arange(0.0, t_end, dt)]
    nf = len(t)
    t_sim = t_star + rng.normal(0.0, 2.0, nc)                  # simulated cell completion
    if mode == "flat":
        t_sim[:] = np.inf
    base_T = np.zeros(m)
    cnt = np.zeros(m)
    np.add.at(base_T, a, t_sim)
    np.add.at(base_T, b, t_sim)
    np.add.at(cnt, a, 1)
    np.add.at(cnt, b, 1)
    base_T = np.where(cnt > 0, base_T / np.maximum(cnt, 1), 50.0)
    G = Rotation.from_rotvec([0.1, -0.05, 0.3])               # simulator frame != target frame
    g_shift = np.array([1.0, -2.0, 3.0])
    final_C = Fc.copy()
    final_R = R_t.copy()
    if mode == "wrong_way":
        D = np.diag([1.0, 1.0, -1.0])
        final_C = Fc @ D
        final_R = D @ R_t @ D
    final_C = G.apply(final_C) + g_shift + rng.normal(0.0, noise_mm, (m, 3))
    final_rv = (G * Rotation.from_matrix(final_R)).as_rotvec()
    flat3 = np.c_[C2, np.zeros(m)]
    lam = np.clip(t[:, None] / base_T[None, :], 0.0, 1.0)    # (nf, m) progress per base
    lam = lam * lam * (3 - 2 * lam)
    lam[0] = 0.0
    C = flat3[None] + lam[..., None] * (final_C - flat3)[None]
    R = Rotation.from_rotvec((lam[..., None] * final_rv[None]).reshape(-1, 3)).as_matrix()
    R = R.reshape(nf, m, 3, 3)
    if mode == "collide":
        # push a far base into base 0 from the middle of the morph on
        far = int(np.argmax(np.linalg.norm(C2 - C2[0], axis=1)))
        k0 = nf // 2
        C[k0:, far] = C[k0:, 0] + R[k0:, 0, :, 0] * 1.0      # 1 mm apart: deep overlap
        R[k0:, far] = R[k0:, 0]
    # membrane: stencil vertices (in the gaps) + face centroids (inside the bases)
    vlam = np.zeros((nf, len(V)))
    vc = np.zeros(len(V))
    for k in range(3):
        np.add.at(vlam.T, F[:, k], lam.T)
        np.add.at(vc, F[:, k], 1)
    vlam /= vc
    v_final = G.apply(V if mode != "wrong_way" else V * [1, 1, -1]) + g_shift
    uv3 = np.c_[UV, np.zeros(len(V))]
    Mv = uv3[None] + vlam[..., None] * (v_final - uv3)[None]
    mem = np.concatenate([Mv, C], axis=1)
    cid = len(V) + np.arange(m)
    tri = np.concatenate([np.c_[F[:, 0], F[:, 1], cid], np.c_[F[:, 1], F[:, 2], cid],
                          np.c_[F[:, 2], F[:, 0], cid]])
    # brackets: 4 springs per cell collide one after the other around the cell's completion
    stagger = np.array([0.0, 0.5, 1.0, 1.5])
    collided = (t[:, None, None] >= t_sim[None, :, None] - stagger[None, None, ::-1])
    collided[0] = False
    b0 = (central - UNIT_CELL.bracket_offset)[None, :, None]
    bl = b0 - np.clip(t[:, None, None] / np.where(np.isfinite(t_sim), t_sim, 1e9)[None, :, None],
                      0, 1) * 1.0
    conv = np.ones(nf, bool)
    res = np.full(nf, 1e-8)
    if mode == "nonconverged":
        conv[[5, 6]] = False
        res[[5, 6]] = 0.05
    up = np.array([0.0, 0.0, UNIT_CELL.layer_h])
    frames = dict(
        t=t, base_center=C, base_rotation=R, membrane_vertices=mem if membrane else None,
        membrane_triangles=tri, bracket_length=np.broadcast_to(bl, (nf, nc, 4)).copy(),
        collided=collided, newton_iterations=rng.integers(2, 8, nf).astype(float),
        residual=res, wall_s=np.full(nf, 0.01), converged=conv,
        marker_top=C + np.einsum("fbij,j->fbi", R, up),
        marker_bottom=C - np.einsum("fbij,j->fbi", R, up))
    frames = {k: v for k, v in frames.items() if v is not None}
    np.savez_compressed(folder / "sim" / "frames.npz", **frames)
    return {"V": V, "UV": UV, "F": F, "Fc": Fc, "C2": C2, "t": t, "t_sim": t_sim,
            "t_star": t_star, "frames": frames, "cells": cells}


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    d = tmp_path_factory.mktemp("good")
    syn = make_synthetic_design(d, mode="good")
    # the program stage's record of each cell's predicted timing sd (the report's bars)
    sd = np.linspace(1.0, 3.0, len(syn["t_star"])).tolist()
    (d / "temporal.json").write_text(json.dumps({"t_sd_predicted_s": sd}))
    return d


def _report(d, **kw):
    from sim.report import make_report

    kw.setdefault("image_px", 160)
    kw.setdefault("gif_frames", 6)
    kw.setdefault("progress", False)
    return make_report(d, **kw)


def test_good_morph_passes_and_report_is_complete(good):
    from sim.report import SECTIONS

    r = _report(good)
    assert r["verdict"] == "PASS", r["reasons"]
    sh = r["metrics"]["shape"]
    # final centres = target + 0.02 mm noise, after an arbitrary rigid motion: RMS ~ 0.035 mm
    assert sh["rms_mm"] < 0.06 and sh["normal_rms_deg"] < 1.0
    tm = r["metrics"]["timing"]
    # simulated completion = t* + N(0, 2 s), up to the 2 s frame step (+1.5 s stagger)
    assert tm["n_never"] == 0 and tm["rms_s"] < 4.0 and tm["spearman"] > 0.9
    assert r["metrics"]["collisions"]["base_base"]["count"] == 0
    assert r["metrics"]["collisions"]["membrane_base"]["count"] == 0
    out = good / "report"
    page = (out / "index.html").read_text()
    for s in SECTIONS:
        assert f"id='{s}'" in page, s
    names = [v for k, v in r["files"].items() if isinstance(v, str)] + r["files"]["renders"]
    assert len(names) >= 10
    embedded = [n for n in names if not n.endswith((".gif", ".pdf"))]
    for name in names:
        p = out / name
        assert p.exists() and p.stat().st_size > 500, name
    for name in embedded:        # the GIF is a file beside the page; the page has the viewer
        assert f'data-file="{name}"' in page, name
    # every image is embedded: the page opens offline (no src= pointing to a file)
    assert len(re.findall(r'src="data:image/(png|gif|svg\+xml);base64,', page)) == len(embedded)
    assert not re.search(r'src="(?!data:)', page)
    js = json.loads((out / "report.json").read_text())
    assert js["verdict"] == "PASS" and js["files"]["animation"] == "morph.gif"
    assert js["timing_sd_predicted_s"] == pytest.approx({"mean": 2.0, "max": 3.0})
    assert "predicted completion sd of a print" in page
    # renders at the requested times (nearest frame) and the end
    assert js["render_frames"]["times_s"] == [0.0, 2.0, 30.0, 50.0, 80.0, 98.0]
    # GIF: at most 60 frames and 480 px
    import imageio.v3 as iio

    gif = iio.imread(out / "morph.gif", index=None)
    assert gif.shape[0] == 6 and gif.shape[2] <= 480
    assert not list(good.glob(".report.tmp-*"))


@pytest.mark.parametrize("mode,check", [("flat", "shape"), ("wrong_way", "shape"),
                                        ("collide", "collisions"), ("nonconverged", "solver")])
def test_broken_morphs_fail(tmp_path, mode, check):
    from pysolver.params import ReportThresholds
    from sim.report import decide, load_sim, shape_metrics

    # wrong_way: a shallow dome (sag 1.9 mm over 55 mm, folds 2 deg) bent the other way: the
    # centres are only a WARN, the reversed folds are the FAIL
    make_synthetic_design(tmp_path, mode=mode, sphere_r=150.0 if mode == "wrong_way" else 60.0)
    r = _report(tmp_path, renderer="matplotlib" if mode == "flat" else "auto")
    assert r["verdict"] == "FAIL"
    assert any(x["level"] == "FAIL" and x["check"] == check for x in r["reasons"]), r["reasons"]
    if mode == "wrong_way":
        sh, fo = r["metrics"]["shape"], r["metrics"]["fold"]
        assert sh["rms_pct"] < 5.0 and sh["normal_rms_deg"] < 15.0
        assert fo["n_folded"] > 0 and fo["flipped_fraction"] == 1.0
        fails = [x for x in r["reasons"] if x["level"] == "FAIL"]
        assert len(fails) == 1 and "wrong way" in fails[0]["message"]
        # without the fold check the centres and normals alone would only WARN
        sd = load_sim(tmp_path)
        sh = shape_metrics(sd.frames["base_center"][-1], sd.frames["base_rotation"][-1],
                           sd.target, sd.target_normals)
        m = dict(r["metrics"], shape=sh)
        m.pop("fold")
        assert decide(m, ReportThresholds())[0] == "WARN"
    if mode == "collide":
        ev = r["metrics"]["collisions"]["base_base"]["first"]
        nf = r["metrics"]["n_frames"]
        assert 0 in ev["pair"] and ev["frame"] == nf // 2 and ev["depth_mm"] > 0.9
        assert (tmp_path / "report" / "collision_frame.png").exists()
    if mode == "flat":
        assert r["renderer"] == "matplotlib"
        assert r["metrics"]["timing"]["n_completed"] == 0


def test_colliding_morph_switches_the_build_to_contact(tmp_path, good):
    """The build's escalation rule is the report's collision rule: a morph in which
    non-neighbouring bases pass through each other (the "collide" fixture) is simulated again
    with barrier contact; a clean one keeps the reference model."""
    from pysolver.simulator import contact_if_needed
    from sim.report import base_base_collisions

    make_synthetic_design(tmp_path, mode="collide")
    hit = base_base_collisions(tmp_path)
    assert hit["count"] == _report(tmp_path)["metrics"]["collisions"]["base_base"]["count"] >= 1
    physics, got = contact_if_needed(tmp_path, "collide", progress=False)
    # contact is added to the simulator's default physics (issue #32: the printing clearance)
    assert physics is not None and got == hit
    assert physics.switched_on() == [*PHYSICS_DEFAULT.switched_on(), "contact"]
    assert base_base_collisions(good)["count"] == 0
    assert contact_if_needed(good, "good", progress=False)[0] is None


def test_build_simulates_again_with_contact_when_parts_collide(tmp_path, monkeypatch):
    """The whole build: a morph whose far parts pass through each other (the "collide"
    fixture stands in for the design and the plain simulation) is simulated again with
    contact; summary.json records the switch and the report the physics of its frames."""
    from pysolver.build import build
    from sim.model.physics import physics_json

    calls = []

    def fake_design(source, out, **kw):
        make_synthetic_design(Path(out), mode="collide")
        return {}

    def fake_simulate(folder, *, physics=None, **kw):
        calls.append(physics)
        if physics is not None:  # the contact run keeps the parts apart
            make_synthetic_design(Path(folder), mode="good")
            p = Path(folder) / "sim" / "frames.npz"
            fr = dict(np.load(p))
            fr["physics"] = np.array(physics_json(physics))
            np.savez_compressed(p, **fr)
        return {}

    # (the stages the runners imported; pysolver.stages.runners looks them up when it runs)
    monkeypatch.setattr("pysolver.stages.runners.run_design", fake_design)
    monkeypatch.setattr("pysolver.stages.runners.simulate_design", fake_simulate)
    s = build("regular", out=tmp_path / "b", program=False, render=False, progress=False)
    with_contact = [*PHYSICS_DEFAULT.switched_on(), "contact"]
    assert [c.switched_on() if c else None for c in calls] == [None, with_contact]
    assert s["stages"]["simulate"]["contact"]["collisions"]["count"] >= 1
    r = json.loads((tmp_path / "b" / "report" / "report.json").read_text())
    assert r["verdict"] == "PASS" and r["metrics"]["physics"] == with_contact
    assert any("contact" in n for n in r["notes"])
    # what the check can promise, from the printed shell's scan (issue #32), and in the page
    from pysolver.params import SCAN_AGREEMENT
    # (simulated with contact on top of the default physics: the promise says so)
    assert any(n.startswith(SCAN_AGREEMENT.promise()) and "not with the physics of this" in n
               for n in r["notes"])
    assert "1.44 mm mean (2.2 % of its span)" in SCAN_AGREEMENT.promise()
    page = (tmp_path / "b" / "report" / "index.html").read_text()
    assert "What this check can promise" in page


def test_thresholds_validate_and_tighten(good):
    from pysolver.params import ReportThresholds

    with pytest.raises(InputError):
        ReportThresholds(shape_rms_fail_pct=-1)
    with pytest.raises(InputError):
        ReportThresholds.coerce({"no_such_limit": 1})
    with pytest.raises(InputError):
        ReportThresholds(shape_rms_warn_pct=6.0, shape_rms_fail_pct=5.0)
    # a timing limit below the synthetic 2 s scatter turns the good morph into a WARN
    r = _report(good, thresholds={"timing_rms_warn_s": 0.5}, out_dir=good / "report_strict",
                renderer="matplotlib")
    assert r["verdict"] == "WARN"
    assert [x["check"] for x in r["reasons"]] == ["timing"]


def test_bad_frames_are_refused(tmp_path):
    from sim.report import load_frames

    make_synthetic_design(tmp_path, n=4)
    p = tmp_path / "sim" / "frames.npz"
    with np.load(p) as z:
        fr = {k: z[k] for k in z.files}
    fr.pop("collided")
    np.savez(tmp_path / "bad.npz", **fr)
    with pytest.raises(InputError, match="collided"):
        load_frames(tmp_path / "bad.npz")
    with pytest.raises(InputError, match="bases"):
        load_frames(p, n_bases=3)
    with pytest.raises(InputError, match="not found"):
        load_frames(tmp_path / "none.npz")


def test_completion_times_first_frame_all_four():
    from sim.model.collisions import completion_times

    t = np.array([0.0, 0.5, 1.0, 1.5])
    c = np.zeros((4, 2, 4), bool)
    c[1:, 0, :3] = True          # cell 0: 3 springs from t = 0.5 ...
    c[3, 0, 3] = True            # ... the 4th at t = 1.5
    c[2:, 1, :2] = True          # cell 1 never completes
    np.testing.assert_array_equal(completion_times(t, c), [1.5, np.nan])
