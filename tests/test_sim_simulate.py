"""simulate_design: output contract, checkpoint/resume, divergence, completion times, input errors.

Tolerances: a resumed run reproduces the uninterrupted one to 1e-9 mm.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from synthetic import StandInBracketModel, regular_stencil, write_design

from pysolver.errors import InputError, MorphshellError
from sim.model import simulate as S


@pytest.fixture()
def design(tmp_path):
    return write_design(tmp_path / "patch", regular_stencil(4, 3), thickness=0.4)


def test_frames_contract(design):
    summary = S.simulate_design(design, t_end=10.0, material=StandInBracketModel(),
                                progress=False)
    p = design / "sim" / "frames.npz"
    assert p.exists() and not (design / "sim" / "checkpoint.npz").exists()
    with np.load(p) as z:
        fr = {k: z[k] for k in z.files}
    nf = 21
    m, c = 12, 13
    nv, nt = len(fr["flat_membrane_vertices"]), len(fr["membrane_triangles"])
    shapes = {"t": (nf,), "base_center": (nf, m, 3), "base_rotation": (nf, m, 3, 3),
              "membrane_vertices": (nf, nv, 3), "membrane_triangles": (nt, 3),
              "bracket_length": (nf, c, 4), "collided": (nf, c, 4), "newton_iterations": (nf,),
              "residual": (nf,), "wall_s": (nf,), "converged": (nf,), "marker_top": (nf, m, 3),
              "marker_bottom": (nf, m, 3)}
    for k, s in shapes.items():
        assert fr[k].shape == s, k
    assert np.allclose(fr["t"], np.arange(nf) * 0.5)
    assert fr["collided"].dtype == bool and fr["converged"].all()
    R = fr["base_rotation"]
    assert np.allclose(R @ np.transpose(R, (0, 1, 3, 2)), np.eye(3), atol=1e-12)
    # marker tips: far-face centres, 2.3 mm from the base centre along the base normal
    d = fr["marker_top"] - fr["base_center"]
    assert np.allclose(np.linalg.norm(d, axis=2), 2.3)
    assert np.allclose(fr["marker_bottom"] - fr["base_center"], -d)
    assert summary["steps"] == nf and summary["converged_steps"] == nf
    js = json.loads((design / "sim" / "summary.json").read_text())
    assert js["steps"] == nf


def test_resume_from_checkpoint(design, monkeypatch, tmp_path):
    kw = dict(t_end=15.0, material=StandInBracketModel(), progress=False)
    ref_dir = write_design(tmp_path / "ref", regular_stencil(4, 3), thickness=0.4)
    S.simulate_design(ref_dir, **kw)
    with np.load(ref_dir / "sim" / "frames.npz") as z:
        ref = {k: z[k] for k in z.files}

    real_step = S.Simulation.step
    calls = {"n": 0}

    def interrupted(self):
        calls["n"] += 1
        if calls["n"] > 17:
            raise KeyboardInterrupt
        return real_step(self)

    monkeypatch.setattr(S.Simulation, "step", interrupted)
    with pytest.raises(KeyboardInterrupt):
        S.simulate_design(design, checkpoint_every=5, **kw)
    assert (design / "sim" / "checkpoint.npz").exists()
    assert not (design / "sim" / "frames.npz").exists()
    monkeypatch.setattr(S.Simulation, "step", real_step)
    calls["n"] = 0
    counted = {"n": 0}

    def counting(self):
        counted["n"] += 1
        return real_step(self)

    monkeypatch.setattr(S.Simulation, "step", counting)
    S.simulate_design(design, checkpoint_every=5, **kw)
    assert counted["n"] == 31 - 15  # resumed at the last checkpoint (step 15)
    with np.load(design / "sim" / "frames.npz") as z:
        for k in ("base_center", "membrane_vertices", "bracket_length", "collided"):
            assert np.allclose(z[k], ref[k], atol=1e-9, rtol=0), k


class _Breaking(StandInBracketModel):
    """Brackets that turn NaN after 3 s (a broken material file)."""

    def coefficients(self, h, b, t, eta=0.0):
        c = super().coefficients(h, b, t, eta=eta)
        return c * np.nan if np.max(t) > 3.0 else c


def test_divergence_keeps_frames_and_names_the_step(design):
    with pytest.raises(MorphshellError, match=r"step 7 \(t = 3.5 s\)"):
        S.simulate_design(design, t_end=10.0, material=_Breaking(), progress=False)
    with np.load(design / "sim" / "frames.npz") as z:
        assert len(z["t"]) == 7 and np.all(np.isfinite(z["base_center"]))


def test_missing_thickness_is_an_input_error(tmp_path):
    d = write_design(tmp_path / "x", regular_stencil(4, 3), thickness=0.4)
    txt = (d / "cells.csv").read_text().splitlines()
    head = txt[0].split(",")
    k = head.index("thickness_top_mm")
    row = txt[3].split(",")
    row[k] = "0"
    txt[3] = ",".join(row)
    (d / "cells.csv").write_text("\n".join(txt) + "\n")
    with pytest.raises(InputError, match=r"cells.csv:4"):
        S.simulate_design(d, t_end=1.0, material=StandInBracketModel(), progress=False)


def test_bad_time_step():
    with pytest.raises(InputError):
        S.SimSettings(t_end=10.2, dt=0.5).times()


def test_completion_times():
    t = np.arange(5) * 0.5
    col = np.zeros((5, 3, 4), dtype=bool)
    col[2:, 0] = True  # cell 0 complete at t = 1.0
    col[3:, 1, :2] = True  # cell 1: only the top layer
    col[4, 2, [1, 2]] = True  # cell 2 at t = 2.0: one spring per layer
    tl = S.completion_times({"t": t, "collided": col}, rule="layer")
    assert tl[0] == 1.0 and np.isnan(tl[1]) and tl[2] == 2.0
    ta = S.completion_times(t, col, rule="all")
    assert ta[0] == 1.0 and np.isnan(ta[1]) and np.isnan(ta[2])
    # default rule: all four springs collided or within the 0.05 mm printing clearance
    Lc = np.full((3, 4), 2.0)
    L = np.full((5, 3, 4), 3.0)
    L[4, 2] = [2.04, 2.0, 2.0, 2.049]  # cell 2: the uncollided springs within 0.05 mm at t = 2
    tc = S.completion_times({"t": t, "collided": col, "bracket_length": L,
                             "collision_length": Lc})
    assert tc[0] == 1.0 and np.isnan(tc[1]) and tc[2] == 2.0
    L[4, 2, 3] = 2.06  # one spring 0.06 mm short: not complete
    assert np.isnan(S.completion_times(t, col, bracket_length=L, collision_length=Lc)[2])
    assert np.array_equal(S.completion_times(t, col), ta, equal_nan=True)  # no lengths: "all"
    with pytest.raises(InputError):
        S.completion_times(t[:3], col)


def test_fast_and_reference_solver_paths_agree(tmp_path):
    """The ``fast`` path (one BLAS thread, the Hessian only when another Newton iteration
    follows, the round-off scale from the last evaluation) follows the same Newton path as the
    ``reference`` one: the same iterations per step, and the same frames to 1e-9 mm."""
    frames, stats = {}, {}
    for solver in ("fast", "reference"):
        d = write_design(tmp_path / solver, regular_stencil(5, 4), thickness=0.4)
        s = S.simulate_design(d, t_end=20.0, material=StandInBracketModel(), progress=False,
                              solver=solver, checkpoint_every=0)
        stats[solver] = s["linear_solver"]
        with np.load(d / "sim" / "frames.npz") as z:
            frames[solver] = {k: z[k] for k in ("base_center", "membrane_vertices",
                                                "newton_iterations")}
    f, r = frames["fast"], frames["reference"]
    np.testing.assert_array_equal(f["newton_iterations"], r["newton_iterations"])
    for k in ("base_center", "membrane_vertices"):
        np.testing.assert_allclose(f[k], r[k], rtol=0, atol=1e-9)
    assert stats["fast"]["factorizations"] == stats["reference"]["factorizations"] > 0
    assert stats["fast"]["solver"] == "fast" and stats["reference"]["solver"] == "reference"


def test_unknown_solver_is_a_named_error():
    with pytest.raises(InputError, match="solver 'quick' is not one of fast, reference"):
        S.SimSettings(solver="quick")


def _kabsch_turn(P, Q):
    """Angle (rad) of the best-fit rotation taking point set P onto Q (about centroids)."""
    U, _, Vt = np.linalg.svd((P - P.mean(0)).T @ (Q - Q.mean(0)))
    R = Vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
    w = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return float(np.arcsin(min(np.linalg.norm(w), 1.0)))


def test_round_off_does_not_turn_the_shell(tmp_path, monkeypatch):
    """The energy does not change when the whole shell turns, so round-off in the solves
    (another BLAS, another thread count: the ``reference`` path on a large shell) used to turn
    the result by up to 1e-4 rad (0.009 mm on the benchmark).  The simulator undoes each solve's
    net rotation: consecutive frames have no best-fit rotation between them (below 1e-12 rad;
    9e-6 rad per step without the gauge on this shell), and
    a run whose linear solves carry a relative error of 1e-9 (far more than any BLAS's
    round-off) ends within 1e-6 mm of the unperturbed run, with the same completion times."""
    from pysolver.mechanics import solver as SV

    def run(name):
        d = write_design(tmp_path / name, regular_stencil(5, 4), thickness=0.4)
        S.simulate_design(d, t_end=20.0, material=StandInBracketModel(), progress=False,
                          checkpoint_every=0, settle_mm=0.0)
        with np.load(d / "sim" / "frames.npz") as z:
            return {k: z[k] for k in z.files}

    a = run("plain")
    free = a["membrane_base"] < 0
    for k in range(1, len(a["t"])):
        P = np.concatenate([a["base_center"][k], a["membrane_vertices"][k][free]])
        Q = np.concatenate([a["base_center"][k - 1], a["membrane_vertices"][k - 1][free]])
        assert _kabsch_turn(P, Q) < 1e-12, k
    solve = SV.LinearSolver.solve
    rng = np.random.default_rng(0)

    def noisy(self, b):
        x = solve(self, b)
        return x * (1.0 + 1e-9 * rng.standard_normal(x.shape))

    monkeypatch.setattr(SV.LinearSolver, "solve", noisy)
    b = run("noisy")
    for k in ("base_center", "membrane_vertices"):
        np.testing.assert_allclose(b[k][-1], a[k][-1], rtol=0, atol=1e-6)
    ta, tb = S.completion_times(a), S.completion_times(b)
    np.testing.assert_array_equal(ta, tb)


def test_a_non_finite_prediction_is_solved_from_the_last_equilibrium(tmp_path, monkeypatch):
    """The predictor's energy is no longer evaluated beforehand: a start outside the energy's
    domain (NaN here) makes Newton stop at once, and the step is solved again from the
    previous equilibrium -- the same frames as a run without the predictor."""
    d = write_design(tmp_path / "p", regular_stencil(4, 3), thickness=0.4)
    kw = dict(t_end=5.0, material=StandInBracketModel(), progress=False, checkpoint_every=0,
              settle_mm=0.0)
    S.simulate_design(d, predictor=False, **kw)
    with np.load(d / "sim" / "frames.npz") as z:
        ref = z["base_center"].copy()

    def nan_prediction(self):
        s = self.state.copy()
        s.f = s.f * np.nan
        return s

    monkeypatch.setattr(S.Simulation, "_predict", nan_prediction)
    s = S.simulate_design(d, resume=False, **kw)
    assert s["converged_steps"] == s["steps"]
    with np.load(d / "sim" / "frames.npz") as z:
        np.testing.assert_allclose(z["base_center"], ref, rtol=0, atol=1e-9)
