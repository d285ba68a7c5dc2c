"""Data safety and hard edges (issue 13): morphshell never deletes or overwrites what it did
not make, and hostile or careless options get a named error, not damage.

Every case of the catalogue checks, through the real CLI: the exit code (2 for bad input),
a message naming the problem, no traceback, no file outside the output folder touched
(the surrounding folder is hashed before and after) and the previous good build intact.
The shells are the small ``regular`` patches, so the file runs in well under a minute.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from pysolver.cli import main
from pysolver.cli.parser import make_parser
from pysolver.core import staging
from pysolver.core.manifest import STAMP_NAME, start_stamp
from pysolver.core.ownership import claim_output, foreign_files
from pysolver.core.staging import atomic_dir, open_staging, staging_dir
from pysolver.core.writes import atomic_write_text
from pysolver.design.mesh_input import load_input
from pysolver.design.time_landscape import evaluate_expression, parse_expression
from pysolver.errors import EXIT_BAD_INPUT, InputError
from pysolver.params import DEFAULT_REFINE, LIMITS
from pysolver.stages import BuildOptions
from pysolver.tables import read_stencil

REPO = Path(__file__).resolve().parent.parent
SHAPE = "regular:rows=2,cols=2"          # 8 bases; design + program in about a second
FAST = ["--no-render", "--no-sim"]


def _tree(folder: Path) -> dict[str, str]:
    """{relative path: sha256} of every file under ``folder`` (hidden ones included)."""
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _cli(argv, capsys) -> tuple[int, str]:
    rc = main(["--quiet", *map(str, argv)])
    cap = capsys.readouterr()
    return rc, cap.err + cap.out


def _refused(rc: int, msg: str, *patterns: str) -> None:
    assert rc == EXIT_BAD_INPUT, msg
    assert "Traceback" not in msg
    for p in patterns:
        assert re.search(p, msg), f"{p!r} not in:\n{msg}"


@pytest.fixture
def room(tmp_path, monkeypatch):
    """A working folder holding a user's files and one good build (``build/<SHAPE>``)."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg-cache"))
    (tmp_path / "mydocs").mkdir()
    (tmp_path / "mydocs" / "thesis.tex").write_text("\\chapter{Shells}\n")
    (tmp_path / "notes.txt").write_text("a file\n")
    assert main(["--quiet", "build", SHAPE, *FAST]) == 0
    return tmp_path


def _check_untouched(room: Path, before: dict) -> None:
    after = _tree(room)
    assert after == before, {k for k in set(before) | set(after)
                             if before.get(k) != after.get(k)}


# ---------------------------------------------------------------- 1. --out never deletes


@pytest.mark.parametrize("case", ["foreign folder", "file", "symlink", "input inside",
                                  "own build with a user's file"])
def test_out_refuses_what_morphshell_did_not_make(room, capsys, case):
    if case == "foreign folder":
        args, pat = ["build", SHAPE, "--out", "mydocs"], r"mydocs is not a morphshell build"
    elif case == "file":
        args, pat = ["build", SHAPE, "--out", "notes.txt"], r"notes\.txt is a file"
    elif case == "symlink":
        os.symlink(room / "mydocs", room / "link")
        args, pat = ["build", SHAPE, "--out", "link"], r"link is a symbolic link.*\n.*Fix: "
    elif case == "input inside":
        (room / "proj").mkdir()
        V, _UV, F = read_stencil(room / "build" / SHAPE / "stencil.obj")
        trimesh.Trimesh(V, F, process=False).export(room / "proj" / "my_shell.obj")
        args, pat = ["design", "proj/my_shell.obj", "--out", "proj"], r"contains the input"
    else:
        (room / "build" / SHAPE / "my_notes.md").write_text("keep me\n")
        args, pat = ["build", SHAPE], r"holds files that morphshell did not write \(my_notes"
    before = _tree(room)
    rc, msg = _cli([*args, *(FAST if args[0] == "build" else [])], capsys)
    _refused(rc, msg, pat, r"Fix: " if case == "symlink" else r"Fix: .*never deletes")
    _check_untouched(room, before)


def test_out_accepts_new_empty_and_own_folders(room, capsys):
    (room / "empty").mkdir()
    for out in ("fresh/deeper", "empty", f"build/{SHAPE}"):
        rc, msg = _cli(["build", SHAPE, "--out", out, *FAST], capsys)
        assert rc == 0, msg
        assert (room / out / STAMP_NAME).is_file()
        assert foreign_files(room / out) == []
    assert (room / "mydocs" / "thesis.tex").is_file()
    # nothing but the output folders themselves appears: no lock, no staging left over
    assert sorted(p.name for p in (room / "build").iterdir()) == [SHAPE]
    assert sorted(p.name for p in (room / "fresh").iterdir()) == ["deeper"]


def test_claim_output_lists_nested_stamps(tmp_path):
    out = tmp_path / "o"
    (out / "stl").mkdir(parents=True)
    (out / "a.csv").write_text("x\n")
    (out / "stl" / "top.stl").write_text("solid\n")
    assert len(foreign_files(out)) == 2   # (the folder stl, and a.csv)
    with pytest.raises(InputError, match="not a morphshell build folder"):
        claim_output(out)
    shutil.rmtree(out)
    out.mkdir()
    start_stamp(out)
    atomic_write_text(out / "a.csv", "x\n")
    with atomic_dir(out / "stl") as tmp:
        (tmp / "top.stl").write_text("solid\n")
    assert foreign_files(out) == []
    (out / "stl" / "side.stl").write_text("solid\n")
    assert foreign_files(out) == [out / "stl" / "side.stl"]
    (out / "stl" / "side.stl").unlink()
    assert claim_output(out) == out


def test_other_outputs_are_claimed_too(room, capsys):
    (room / "model.json").write_text('{"mine": true}\n')
    before = _tree(room)
    for args, pat in ((["fit-material", "--out", "model.json"], r"model\.json exists and is "
                       "not a model file morphshell wrote"),
                      (["fit-material", "--report", "mydocs"], r"mydocs is not a morphshell"),
                      (["fit-membrane", "--report", "mydocs"], r"mydocs is not a morphshell"),
                      (["specimens", "--out", "mydocs"], r"mydocs is not a morphshell"),
                      (["coupon", "--out", "mydocs"], r"mydocs is not a morphshell"),
                      (["calibrate-time", "coupon.csv", "--out", "model.json"],
                       r"model\.json exists and is not a model file morphshell wrote")):
        rc, msg = _cli(args, capsys)
        _refused(rc, msg, pat)
    _check_untouched(room, before)


# ---------------------------------------------------------------- 2. skipped stages


def test_skipped_render_keeps_unchanged_stls_and_says_when_it_drops_them(tmp_path, capsys,
                                                                          monkeypatch):
    monkeypatch.chdir(tmp_path)
    # (the fast renderer: the subject is what a skipped render keeps, not the renderer)
    assert main(["--quiet", "build", SHAPE, "--no-sim", "--time", "60",
                 "--renderer", "fast"]) == 0
    out = tmp_path / "build" / SHAPE
    stls = {k: v for k, v in _tree(out).items() if k.startswith(("stl/", "scad/"))}
    assert "stl/top.stl" in stls and any(k.startswith("scad/") for k in stls)
    assert main(["build", SHAPE, "--no-sim", "--no-render", "--time", "60"]) == 0
    assert "render not run: kept the previous scad, stl" in capsys.readouterr().err
    assert {k: v for k, v in _tree(out).items() if k.startswith(("stl/", "scad/"))} == stls
    assert foreign_files(out) == []
    # a different landscape changes the thicknesses: the old STLs are dropped, and it is said
    assert main(["build", SHAPE, "--no-sim", "--no-render", "--time", "70"]) == 0
    err = capsys.readouterr().err
    assert re.search(r"render not run: the previous scad/, stl/ no longer match the design "
                     r"and are dropped; re-run without --no-render", err), err
    assert not (out / "stl").exists()


# ---------------------------------------------------------------- 3. time expressions


@pytest.mark.parametrize("expr, pat", [
    ("60 + 0*sign(x, x) + 0*sign(y, y)", r"sign\(\) takes exactly 1 argument, got 2"),
    ("60 + sign(x, out=x)", r"takes no keyword arguments"),
    ("maximum(x, 1, x)", r"maximum\(\) takes exactly 2 arguments, got 3"),
    ("x.__class__", r"Attribute is not allowed"),
    ("x[0] + 60", r"Subscript is not allowed"),
    ("__import__('os').system('true')", r"only the listed functions may be called"),
    ("(lambda: 60)()", r"only the listed functions|Lambda is not allowed"),
    ("exp + 60", r"exp is a function"),
    ("'60'", r"only numbers are allowed"),
    ("-" * 1990 + "x", r"cannot be (parsed|evaluated)|syntax error"),
    ("60" + " + x" * 600, r"longer than 2000 characters"),
])
def test_time_expression_is_a_closed_language(expr, pat):
    with pytest.raises(InputError, match=pat):
        evaluate_expression(expr, np.ones((4, 3)))


def test_time_expression_cannot_write_into_the_geometry(room, capsys):
    V = np.random.default_rng(1).normal(size=(20, 3)) * 30.0
    V0 = V.copy()
    t = evaluate_expression("where(z > 0, 40 + 0.1*r, clip(60 - z, 45, 75)) + 0*hypot(x, y)", V)
    assert np.array_equal(V, V0)
    expect = np.where(V0[:, 2] > 0, 40 + 0.1 * np.hypot(V0[:, 0], V0[:, 1]),
                      np.clip(60 - V0[:, 2], 45, 75))
    np.testing.assert_allclose(t, expect, rtol=0, atol=1e-12)
    assert isinstance(parse_expression("0 < z < 5"), object)
    before = _tree(room)
    rc, msg = _cli(["build", SHAPE, "--time", "60 + 0*sign(x, x) + 0*sign(y, y)", *FAST],
                   capsys)
    _refused(rc, msg, r"sign\(\) takes exactly 1 argument")
    _check_untouched(room, before)


def test_makefile_passes_values_without_shell_or_make_interpolation(tmp_path):
    """A quote, $(...) and backticks in TIME or ARGS are text: nothing runs."""
    pwn = tmp_path / "pwned"
    hostile = (f'30"; touch {pwn}-1; echo "$(shell touch {pwn}-2)`touch {pwn}-3`'
               f"$$(touch {pwn}-4)")
    r = subprocess.run(
        ["make", "-s", "-f", str(REPO / "Makefile"), "-o", ".venv/.installed",
         f"PY={sys.executable}", "design", "shape=regular", f"TIME={hostile}",
         f"ARGS=--quiet $(shell touch {pwn}-5) `touch {pwn}-6`"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
        env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert r.returncode != 0
    assert list(tmp_path.glob("pwned*")) == [], r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "build" / "regular").exists()


# ---------------------------------------------------------------- 4. permissions


def test_outputs_follow_the_umask(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    old = os.umask(0o022)
    try:
        assert main(["--quiet", "build", SHAPE, "--refine", "0", "--out", "shell"]) == 0
    finally:
        os.umask(old)
    out = tmp_path / "shell"
    paths = [out, *out.rglob("*")]
    assert {"summary.json", "report", "stl", "scad", "sim"} <= {p.name for p in paths}
    for p in paths:
        mode = stat.S_IMODE(p.stat().st_mode)
        assert mode == (0o755 if p.is_dir() else 0o644), (p, oct(mode))


# ---------------------------------------------------------------- 6. limits


@pytest.mark.parametrize("args, pat", [
    (["build", "dome", "--vertices", "10000000"], rf"--vertices 10000000 must be a whole "
                                                  rf"number from 4 to {LIMITS.max_vertices}"),
    (["build", "regular", "--vertices", "50"], r"--vertices 50 has no effect on regular"),
    (["build", "regular", "--refine", "1000"], r"--refine must be a whole number from 0 to"),
    (["build", "regular", "--jobs", "100000"], r"--jobs must be a whole number from 1 to"),
    (["build", "regular", "--t-end", "1e9"], r"--t-end must be a number of seconds"),
    (["build", "regular", "--dt", "1e-9"], r"--dt must be a number of seconds"),
    (["build", "regular", "--t-end", "3000", "--dt", "0.01"], r"simulation steps, more than"),
    (["build", "dome", "--scale", "1e300"], r"--scale 1e\+300 must be a positive number"),
])
def test_size_and_count_options_have_named_bounds(room, capsys, args, pat):
    before = _tree(room)
    rc, msg = _cli(args, capsys)
    _refused(rc, msg, pat)
    _check_untouched(room, before)


# ---------------------------------------------------------------- 7. leftovers, paths


def test_stale_locks_and_staging_are_cleaned_and_printed_paths_are_final(room, capsys):
    build = room / "build"
    (build / ".petal.morphshell-lock").write_text("pid 999999")   # a killed build's lock
    now = time.time()
    with pytest.MonkeyPatch.context() as mp:                          # two weeks ago
        mp.setattr(staging.time, "time", lambda: now - 2 * staging.STALE_STAGING_S)
        open_staging(staging_dir(build / "petal"), inputs_sha256="x")
    (staging_dir(build / "petal") / "cells.csv").write_text("half\n")
    open_staging(staging_dir(build / "dome"), inputs_sha256="y")     # a recent interrupted one
    rc = main(["build", SHAPE, "--refine", "0", "--no-render", "--out", "build/second"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert sorted(p.name for p in build.iterdir()) == [".dome.morphshell-staging", SHAPE,
                                                       "second"]
    text = cap.out + cap.err
    assert "morphshell-staging" not in text
    final = build / "second"
    assert re.search(rf"simulation check: (PASS|WARN)  \({re.escape(str(final))}/report/"
                     r"index\.html\)", text), text
    assert f"-> {final}" in text


def test_failed_build_leaves_nothing_and_says_what_failed(room, capsys):
    before = _tree(room)
    rc, msg = _cli(["build", SHAPE, "--time", "5", "--out", "elsewhere", *FAST], capsys)
    _refused(rc, msg, r"program stage: the time landscape is mostly infeasible",
             r"would need to finish sooner than their thinnest brackets \(0\.30 mm\) allow",
             r"nothing was written to .*elsewhere", r"add --debug to keep them",
             r"See temporal_feasibility\.png")
    assert "too late" not in msg
    _check_untouched(room, before)


# ---------------------------------------------------------------- 8. surprises


def test_one_refine_default_for_cli_api_and_make():
    build_sub = next(a for a in make_parser()._subparsers._group_actions[0].choices.values()
                     if a.prog.endswith(" build"))
    assert build_sub.get_default("refine") == DEFAULT_REFINE == 1
    assert BuildOptions().refine == DEFAULT_REFINE
    assert not re.search(r"^REFINE\s*\?=\s*\S", (REPO / "Makefile").read_text(), re.M)


def test_global_flags_work_after_the_subcommand(room, capsys):
    rc = main(["build", SHAPE, "--out", "notes.txt", "--quiet", "--debug", *FAST])
    err = capsys.readouterr().err
    assert rc == EXIT_BAD_INPUT
    assert "Traceback" in err and "notes.txt is a file" in err     # --debug after build
    rc = main(["design", SHAPE, "--out", "d2", "--quiet"])
    assert rc == 0 and capsys.readouterr().err == ""                # --quiet after design


@pytest.mark.filterwarnings("ignore::pysolver.design.mesh_input.SizeWarning")
def test_obj_and_stl_triangle_soups_are_welded_alike(room):
    V, _UV, F = read_stencil(room / "build" / SHAPE / "stencil.obj")
    soup = V[F].reshape(-1, 3)
    Fs = np.arange(len(soup)).reshape(-1, 3)
    got = {}
    for ext in ("obj", "stl", "ply", "off"):
        path = room / f"soup.{ext}"
        trimesh.Trimesh(soup, Fs, process=False).export(path)
        m = load_input(path)
        got[ext] = (len(m.V), len(m.F))
        assert f"{len(soup) - len(V)} coincident vertices welded" in " ".join(m.notes)
    assert set(got.values()) == {(len(V), len(F))}
