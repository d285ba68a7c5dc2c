"""Virtual mechanical tests (SI Note 6, issue #44): the specimen shape, the fixtures' energy,
a closed-form stiffness, the output contract and bad input.

Fast: one tiny specimen (a strip of a few bases) simulated for a few seconds of morph.
"""

from __future__ import annotations

import csv
import json
import subprocess

import numpy as np
import pytest

from pysolver.core.child import python_argv
from pysolver.design.surfaces import builtin
from pysolver.mechanics.energies import State
from pysolver.params import MECHTEST, UNIT_CELL
from sim.model.mechtest import Holds, initial_slope, readings

# ------------------------------------------------------------------------------------------------
# the specimen


def test_mechtest_shape_is_the_si_specimen_size():
    """Morphed (flat lengths x the bumper-contact shrink) ~ 60 x 55 mm, every base kept
    inside, every triangle equilateral with 7 mm between neighbouring centroids."""
    s = builtin("mechtest")
    shrink = (2 * UNIT_CELL.base_r + 2 * UNIT_CELL.min_bumper) / 7.0
    C = s.UV[s.F].mean(axis=1) * shrink
    r = UNIT_CELL.base_r
    ext = np.ptp(C, axis=0) + 2 * r
    assert ext[0] <= 60.0 + 1e-9 and ext[1] <= 55.0 + 1e-9
    assert ext[0] > 60.0 - 7.0 and ext[1] > 55.0 - 7.0  # within a cell of the rectangle
    e = np.linalg.norm(s.UV[s.F[:, 1]] - s.UV[s.F[:, 0]], axis=1)
    np.testing.assert_allclose(e, 7.0 * np.sqrt(3), rtol=1e-9)


def test_mechtest_angle_turns_the_pattern():
    """angle=0: a unit cell (normal of a triangle edge) along y; angle=30: along x."""
    for angle, axis in ((0.0, 1), (30.0, 0)):
        s = builtin(f"mechtest:angle={angle}")
        d = s.UV[s.F[:, 1]] - s.UV[s.F[:, 0]]
        normals = np.c_[-d[:, 1], d[:, 0]] / np.linalg.norm(d, axis=1)[:, None]
        assert np.isclose(np.abs(normals[:, axis]).max(), 1.0, atol=1e-9)


def test_mechtest_bad_size_is_refused():
    from pysolver.errors import InputError

    with pytest.raises(InputError, match="positive"):
        builtin("mechtest:width=-1")


# ------------------------------------------------------------------------------------------------
# the fixture's energy


def _random_state(m, rng):
    from pysolver.mechanics.energies import rodrigues

    return State(rng.normal(size=(m, 3)), rodrigues(0.3 * rng.normal(size=(m, 3))),
                 np.zeros((0, 3)))


def test_holds_gradient_matches_finite_differences():
    """Two-sided and one-sided holds: the reduced gradient is the derivative of the energy
    (translations; rotations as small turns R <- exp([w]x) R), to 1e-5 relative."""
    from pysolver.mechanics.energies import rodrigues

    rng = np.random.default_rng(4)
    m = 3
    s = _random_state(m, rng)
    body = np.array([0, 0, 1, 2, 2])
    local = rng.normal(size=(5, 3))
    target = rng.normal(size=(5, 3))
    K = np.stack([np.eye(3) * 7.0] * 3 + [np.outer([0, 0, 1], [0, 0, 1]) * 5.0] * 2)
    normal = np.zeros((5, 3))
    normal[3:] = [0, 0, 1]
    target[3:, 2] = 10.0  # both one-sided holds pressed: active
    h = Holds(body, local, target, K, normal)
    E, g, H = h.evaluate(s, None, None, True)
    eps = 1e-6
    for b in range(m):
        for d in range(6):
            sp, sm = s.copy(), s.copy()
            if d < 3:
                sp.c[b, d] += eps
                sm.c[b, d] -= eps
            else:
                w = np.zeros(3)
                w[d - 3] = eps
                sp.R[b] = rodrigues(w[None])[0] @ s.R[b]
                sm.R[b] = rodrigues(-w[None])[0] @ s.R[b]
            fd = (h.energy(sp, None) - h.energy(sm, None)) / (2 * eps)
            assert fd == pytest.approx(g[b, d], rel=1e-5, abs=1e-6)
    assert H.shape == (m, 6, 6)
    np.testing.assert_allclose(H, np.transpose(H, (0, 2, 1)), atol=1e-9)


def test_one_sided_hold_lets_go():
    """A support pushes only: pulled away from it, the point feels nothing."""
    s = State(np.zeros((1, 3)), np.eye(3)[None], np.zeros((0, 3)))
    h = Holds([0], [[0, 0, 0]], [[0, 0, -1.0]], [np.diag([0, 0, 100.0])], [[0, 0, 1.0]])
    assert h.evaluate(s, None, None, True)[0] == 0.0
    h.target[:] = [0, 0, 1.0]
    E, g, _ = h.evaluate(s, None, None, True)
    assert E == pytest.approx(50.0) and g[0, 2] == pytest.approx(-100.0)


# ------------------------------------------------------------------------------------------------
# readings


def _curve(x, y, test="stretch", brackets=None, energy=None):
    n = len(x)
    return {"x": np.asarray(x, float), "y": np.asarray(y, float), "test": test,
            "max_bracket_N": np.zeros(n) if brackets is None else np.asarray(brackets),
            "energy": energy or [{"bumper contact": 0.0, "brackets": 0.0,
                                  "membrane": float(i)} for i in range(n)]}


def test_initial_slope_of_a_line_and_of_a_knee():
    x = np.linspace(0, 10, 51)
    assert initial_slope(x, 0.03 * x, "stretch") == pytest.approx(0.03, rel=1e-12)
    y = np.where(x < 3, 0.05 * x, 0.15)  # flat after 3 %: the 2 % window sees the line only
    assert initial_slope(x, y, "stretch") == pytest.approx(0.05, rel=1e-12)


def test_peak_stops_at_the_first_bracket_past_its_tested_load():
    x = np.arange(6.0)
    y = np.array([0, 1, 2, 3, 4, 5.0])
    br = np.array([0.1, 1, 2, 2.6, 3, 4])  # passes 2.5 N at step 3
    r = readings(_curve(x, y, brackets=br))
    assert r["limit"] == "bracket yield" and r["peak_at"] == 3.0 and r["yield_step"] == 3
    r = readings(_curve(x, y))
    assert r["limit"] == "membrane" and r["peak_at"] == 5.0 and r["yield_step"] is None


# ------------------------------------------------------------------------------------------------
# a tiny specimen, end to end (closed form and contract)


@pytest.fixture(scope="module")
def strip(tmp_path_factory):
    """A strip of bases, two rows: designed (uniform brackets) and simulated for 5 s."""
    out = tmp_path_factory.mktemp("mt") / "strip"
    cli = python_argv("pysolver.cli")
    for args in (["design", "regular:rows=2,cols=2", "--out", str(out), "--quiet"],
                 ["simulate", str(out), "--t-end", "5", "--quiet"]):
        r = subprocess.run(cli + args, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
    return out


def test_small_strain_stretch_is_linear_and_read_as_the_tester_did(strip):
    """A small pull of the clamps (the cells of this 5 s morph are open): the force is linear
    in the displacement (two steps agree to 2 %) and positive, and the curve is the tester's
    formulas of it: strain = 100 dL / clamped length, stress = F / (a0 b0) with a0 = two
    layers of 2.3 mm and the membrane (0.5 mm / 3^2), b0 the width across the load."""
    from sim.model.mechtest import dried_shell, run_test

    consts = MECHTEST.__class__(**{**MECHTEST.__dict__, "stretch_length": 4.0,
                                   "stretch_max": 0.002, "steps": 2})
    sh = dried_shell(strip, consts=consts)
    c = run_test(sh, "stretch", consts=consts, progress=False)
    F, d = np.asarray(c["force_N"]), np.asarray(c["displacement_mm"])
    assert abs(F[0]) < 1e-6
    k1, k2 = F[1] / d[1], (F[2] - F[1]) / (d[2] - d[1])
    assert k1 > 0 and k2 == pytest.approx(k1, rel=0.02)
    assert all(c["converged"])
    a0 = 2 * 2.3 + 0.5 / 9
    assert c["a0"] == pytest.approx(a0, rel=1e-12)
    np.testing.assert_allclose(c["x"], 100 * d / 4.0, rtol=1e-12)
    np.testing.assert_allclose(c["y"], F / (a0 * c["b0"]), rtol=1e-12)


def test_cli_contract(strip):
    """``morphshell mechtest DIR --test stretch --test shear`` writes the named CSVs, the
    PNG and the summary with the four readings; a bad test name exits 2."""
    r = subprocess.run(python_argv("pysolver.cli") + ["mechtest", str(strip), "--test",
                                   "shear", "--quiet", "--axis-deg", "0"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr  # a refusal ("too short") is a failure here
    with open(strip / "mechtest" / "shear.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["displacement_mm", "shear_stress_MPa"]
    assert len(rows) == MECHTEST.steps + 2
    s = json.loads((strip / "mechtest" / "summary.json").read_text())["tests"]["shear"]
    assert {"initial_slope", "peak_stress_MPa", "peak_at", "limit"} <= set(s)
    assert (strip / "mechtest" / "mechtest.png").stat().st_size > 1000


def test_cli_refuses_bad_input(tmp_path):
    r = subprocess.run(python_argv("pysolver.cli") + ["mechtest", str(tmp_path), "--test",
                                   "twist"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "invalid choice" in r.stderr
    r = subprocess.run(python_argv("pysolver.cli") + ["mechtest", str(tmp_path)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "error" in r.stderr
    assert not (tmp_path / "mechtest").exists()


def test_bearing_stiffness_matches_a_small_push(strip):
    """The report's first-order point-load stiffness equals a Newton solve of the dried
    shell pushed 1 micron down at the apex, standing on the same supports (within 5 %)."""
    from sim.model.mechtest import _stand, _up, bearing, dried_shell, solve

    sh = dried_shell(strip)
    b = bearing(sh)
    up = _up(sh)
    low, apex, face = _stand(sh, up)
    k, uu, s = MECHTEST.clamp_stiffness, np.outer(up, up), sh.state
    body = np.r_[low, low, apex]
    loc = np.r_[-face[low], np.zeros((len(low), 3)), face[[apex]]]
    K = np.r_[np.broadcast_to(k * uu, (len(low), 3, 3)),
              np.broadcast_to(MECHTEST.stabiliser_N_mm * (np.eye(3) - uu), (len(low), 3, 3)),
              (k * uu)[None]]
    P = s.c[body] + np.einsum("hij,hj->hi", s.R[body], loc)
    h = Holds(body, loc, P, K)
    sh.sim.energy.external = h
    push = 1e-3
    h.target[-1] -= push * up
    state, ok = solve(sh, s)
    force = float(h.gradients(state)[-1] @ up)
    sh.sim.energy.external = None
    deflection = push - force / k  # the nose's own penalty spring in series
    assert ok and b["point_stiffness_N_per_mm"] == pytest.approx(force / deflection, rel=0.05)
    assert b["weight_N"] > 0 and b["weight_sag_mm"] > 0


def test_a_failed_solve_stops_the_test():
    """Non-finite, twice unconverged, or a wild jump: the step is not kept."""
    from sim.model.mechtest import _lost

    rows = {"force_N": [0.0, 1.0, 2.0], "converged": [True, True, True]}
    assert not _lost(3.0, True, rows) and not _lost(3.0, False, rows)
    assert _lost(float("nan"), True, rows) and _lost(-50.0, False, rows)
    rows["converged"][-1] = False
    assert _lost(3.0, False, rows)


def test_the_dried_shell_keeps_the_morphs_equilibrium(strip):
    """Drying changes the brackets' stiffness, not their load (each keeps its last force;
    the plastic rest lengths replayed from the frames): the last frame of the morph is still
    in equilibrium, to the Newton tolerance's order (1e-6 N; here 1e-4 N)."""
    from sim.model.mechtest import dried_shell

    sh = dried_shell(strip, settle=False)
    sh.set_springs(sh.closed)
    _, g = sh.sim.energy.gradient(sh.state)
    m = sh.model.n_bases
    assert np.abs(g[: 6 * m].reshape(m, 6)[:, :3]).max() < 1e-4  # forces, N
    assert np.abs(g[6 * m:]).max() < 1e-4


# ------------------------------------------------------------------------------------------------
# the tester's formulas, the outputs' ownership and consistency (in process, no simulation)


def test_bend_conversions_match_the_testers_worked_example():
    """shell-tests/README.md: Fmax 25.28 N at s = 8.43 mm, span 40 mm, a0 = 4.8 mm,
    b0 = 60 mm give the peak 1.097 MPa at 15.17 % (to the README's 4 digits)."""
    from sim.model.mechtest import flexural_strain, flexural_stress

    assert flexural_stress(25.28, 4.8, 60.0, 40.0) == pytest.approx(1.097, abs=5e-4)
    assert flexural_strain(8.43, 4.8, 40.0) == pytest.approx(15.17, abs=5e-3)
    # linear in force and deflection: the bench's conversion back and forth is exact
    assert flexural_stress(2 * 25.28, 4.8, 60.0, 40.0) == pytest.approx(2 * 1.0972, rel=1e-3)


def _stamped(tmp_path):
    from pysolver.core.manifest import start_stamp

    folder = tmp_path / "design"
    folder.mkdir()
    start_stamp(folder)
    return folder


def test_a_users_file_is_refused_before_any_test_runs(tmp_path, monkeypatch, capsys):
    """A user's ``mechtest/summary.json``: exit 2 naming it, no test computed, and the
    earlier outputs (CSV, PNG) and the user's file unchanged, byte for byte."""
    import pysolver.simulator as gateway
    from pysolver.cli import main
    from pysolver.core.writes import atomic_write_bytes, atomic_write_text

    folder = _stamped(tmp_path)
    out = folder / "mechtest"
    atomic_write_text(out / "shear.csv", "displacement_mm,shear_stress_MPa\n0,0\n")
    atomic_write_bytes(out / "mechtest.png", b"old png")
    (out / "summary.json").write_text('{"mine": true}')
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def must_not_run(*a, **k):
        raise AssertionError("computed before checking the targets")

    monkeypatch.setattr(gateway, "mechtest", must_not_run)
    assert main(["mechtest", str(folder), "--test", "shear", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "summary.json" in err and "move" in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def _fake_curve(test: str, scale: float, axis: float = 90.0) -> dict:
    x = np.linspace(0.0, 2.0, 5)
    return {"test": test, "x": x, "y": scale * x, "columns": ["strain_percent", "stress_MPa"],
            "force_N": 10 * scale * x, "max_bracket_N": np.zeros(5),
            "energy": [{"brackets": float(i), "membrane": 0.0} for i in range(5)],
            "converged": [True] * 5, "a0": 4.656, "b0": 55.0, "axis_deg": axis,
            "bases": {}, "stopped": None}


def test_a_partial_rerun_keeps_only_tests_of_the_same_shell(tmp_path):
    """Same shell and axis: the earlier test stays listed and its CSV stays; another shell:
    the earlier test is dropped from the summary and its CSV removed."""
    from sim.report.mechtest import write_mechtest

    folder = _stamped(tmp_path)
    shell = {"t_end_s": 5.0, "physics": [], "material": "committed"}
    write_mechtest(folder, {"stretch": _fake_curve("stretch", 1.0)}, shell)
    rec = write_mechtest(folder, {"compress": _fake_curve("compress", 2.0)}, shell)
    assert set(rec["tests"]) == {"stretch", "compress"}
    assert rec["tests"]["stretch"]["initial_slope"] == pytest.approx(1.0, rel=1e-9)
    rec = write_mechtest(folder, {"compress": _fake_curve("compress", 3.0)},
                         {**shell, "t_end_s": 6.0})
    assert set(rec["tests"]) == {"compress"}
    assert not (folder / "mechtest" / "stretch.csv").exists()
    saved = json.loads((folder / "mechtest" / "summary.json").read_text())
    assert set(saved["tests"]) == {"compress"} and saved["shell"]["t_end_s"] == 6.0
    rec = write_mechtest(folder, {"stretch": _fake_curve("stretch", 1.0, axis=0.0)},
                         {**shell, "t_end_s": 6.0})
    assert set(rec["tests"]) == {"stretch"}  # another axis: compress dropped


def test_the_build_recorded_material_is_used_and_checked(tmp_path):
    """``summary.json``'s ``options.material``: a file is returned, none -> the committed
    model, a path to nothing or a non-string -> a clear InputError."""
    from pysolver.errors import InputError
    from sim.model.mechtest import recorded_material

    folder = tmp_path / "b"
    folder.mkdir()
    assert recorded_material(folder) is None
    model = tmp_path / "m.json"
    model.write_text("{}")
    for value, want in ((str(model), model), (None, None)):
        (folder / "summary.json").write_text(json.dumps({"options": {"material": value}}))
        assert recorded_material(folder) == want
    (folder / "summary.json").write_text(json.dumps({"options": {"material": str(model)}}))
    assert recorded_material(folder, {}) is None  # a running build's options come first
    assert recorded_material(folder, {"material": str(model)}) == model
    for value in (str(tmp_path / "gone.json"), ["x"]):
        (folder / "summary.json").write_text(json.dumps({"options": {"material": value}}))
        with pytest.raises(InputError, match="--material"):
            recorded_material(folder)


def test_what_it_bears_degrades_on_odd_frames_but_not_on_bugs(monkeypatch):
    """An IndexError/KeyError while loading odd frames: the section's error names it and
    where it was raised; any other exception (a bug) propagates."""
    import sim.report.report as rep

    def odd(*a, **k):
        return [][0]

    monkeypatch.setattr(rep, "dried_shell", odd)
    b = rep.what_it_bears("nowhere")
    assert b["error"].startswith("IndexError") and "test_mechtest.py:" in b["error"]

    def bug(*a, **k):
        raise TypeError("a bug")

    monkeypatch.setattr(rep, "dried_shell", bug)
    with pytest.raises(TypeError):
        rep.what_it_bears("nowhere")


def _bench(name: str = "bench_mechtest"):
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "bench" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_bench_refuses_a_physics_spec_that_is_not_switch_names(capsys):
    """``--physics ../../docs`` (a path out of build/) exits 2 before any folder is touched;
    known switch names pass."""
    from pysolver.errors import InputError

    b = _bench()
    assert b.check_spec("default,membrane-temperature") == "default,membrane-temperature"
    for bad in ("../../docs", "none;rm", "", "clearance,nonsense", "a/b"):
        with pytest.raises(InputError):
            b.check_spec(bad)
    assert b.main(["--physics", "none", "../../docs"]) == 2
    assert "not a list of physics switches" in capsys.readouterr().err


def test_bench_converts_with_the_testers_a0_b0():
    """A bend curve made with the tester's own a0, b0 and span is unchanged; one made with
    half the width reads half the stress (force = the same), strain as a0 scales."""
    b = _bench()
    tester = {"a0": 4.8, "b0": 60.0, "length": MECHTEST.bend_span}
    x, y = np.array([0.0, 5.0, 15.17]), np.array([0.0, 0.4, 1.097])
    same = {"a0_mm": 4.8, "b0_mm": 60.0}
    for got, want in zip(b.to_tester("bend", x, y, same, tester), (x, y), strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-12)
    xs, ys = b.to_tester("bend", x, y, {"a0_mm": 2.4, "b0_mm": 30.0}, tester)
    np.testing.assert_allclose(xs, 2 * x, rtol=1e-12)  # same deflection, twice the a0
    np.testing.assert_allclose(ys, y / 8, rtol=1e-12)  # b0 a0^2: 8 x larger
    st = {"a0": 4.8, "b0": 60.0, "length": MECHTEST.stretch_length}
    xs, ys = b.to_tester("stretch", x, y, {"a0_mm": 2.4, "b0_mm": 60.0}, st)
    np.testing.assert_allclose(xs, x, rtol=1e-12)
    np.testing.assert_allclose(ys, y / 2, rtol=1e-12)


def test_slope_bench_reads_past_a_seating_toe_and_takes_the_rig_off():
    """``bench/mechtest_slopes.py``: on a curve with a seating toe (quadratic to 2 %, then a
    line of slope 0.1 MPa/%) the steepest 2 % window is the line's (1e-9), where the 0-2 %
    slope reads half of it; on a curve without a toe the two agree.  The dry law with the
    rig's compliance ``c`` off has the stiffness ``c1 / (1 - 4 c c1)`` (1e-12), each ``c_k``
    scaled by ``s^k``, and the wet law (t > 0) is left as fitted."""
    b = _bench("mechtest_slopes")
    x = np.linspace(0, 12, 1201)
    y = np.where(x < 2, 0.025 * x**2, 0.1 * x - 0.1)
    slope, start = b.toe_free_slope(x, y, upto=12.0)
    assert slope == pytest.approx(0.1, rel=1e-9) and start >= 2.0
    assert initial_slope(x, y, "bend") == pytest.approx(0.05, rel=0.01)
    line = 0.03 * x
    assert b.toe_free_slope(x, line, 12.0)[0] == pytest.approx(initial_slope(x, line, "stretch"),
                                                              rel=1e-9)

    class Law:
        def coefficients(self, h, b_, t, eta=0.0):
            return np.tile([4.0, -0.5, 0.1, -0.01], (len(h), 1)) * (1.0 if t == 0 else 0.1)

    c = 0.03
    rig = b.RigOff(Law(), c)
    got = rig.coefficients(np.ones(2), np.ones(2), 0.0)
    s = 1 / (1 - 4 * c * 4.0)
    assert got[0, 0] == pytest.approx(4.0 / (1 - 4 * c * 4.0), rel=1e-12)
    np.testing.assert_allclose(got[1], np.array([4.0, -0.5, 0.1, -0.01]) * s ** np.arange(1, 5),
                               rtol=1e-12)
    np.testing.assert_allclose(rig.coefficients(np.ones(2), np.ones(2), 5.0),
                               Law().coefficients(np.ones(2), None, 5.0), rtol=0)
