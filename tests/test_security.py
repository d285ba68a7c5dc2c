"""Security, third pass (issue #43): no code from the working directory runs in a child
interpreter, no path read from a stamp reaches outside its folder, the studio's token is
seen by no other process or user, the studio refuses before it reads, and the low-severity
holes of the audit.  Each test fails on the code before the fix (``docs/threat-model.md``
lists them per boundary)."""

from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path

import pytest
from _shared import run_cli

from pysolver.child import PACKAGE_ROOT, python_argv

# ------------------------------------------------------------------------------ child Pythons

PLANTED = ("pyvista.py", "numpy.py", "runpy.py", "pysolver/__init__.py", "sim/__init__.py",
           "openscad_evaluator.py", "trimesh.py")
"""Modules a hostile working directory could hold: each writes a marker when imported."""


@pytest.fixture
def hostile_cwd(tmp_path, monkeypatch):
    """A working directory full of planted modules; yields the marker file they write."""
    cwd = tmp_path / "cwd"
    marker = tmp_path / "imported-from-cwd.txt"
    for name in PLANTED:
        p = cwd / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(f"open({str(marker)!r}, 'a').write({name!r} + '\\n')\n")
    monkeypatch.chdir(cwd)
    monkeypatch.setenv("PYTHONPATH", str(cwd))      # ignored by an isolated child too
    return marker


def _planted(marker: Path) -> list[str]:
    return marker.read_text().split() if marker.exists() else []


def test_a_child_python_imports_nothing_from_the_working_directory(hostile_cwd):
    code = ("import sys, numpy, pysolver, sim, runpy\n"
            "print(pysolver.__file__); print(repr(sys.path))")
    r = subprocess.run(python_argv(code=code), capture_output=True, text=True, check=True)
    assert _planted(hostile_cwd) == []
    first, path = r.stdout.splitlines()
    assert first == str(Path(PACKAGE_ROOT) / "pysolver" / "__init__.py")
    assert str(Path.cwd()) not in path and "''" not in path
    with pytest.raises(ValueError):
        python_argv("pysolver.x; import os")
    with pytest.raises(ValueError):
        python_argv()


def test_the_pyvista_probe_runs_no_planted_module(hostile_cwd):
    from sim.report.plots import _pyvista_status

    ok, why = _pyvista_status.__wrapped__()
    assert _planted(hostile_cwd) == []
    assert ok or "pyvista" in why


def test_a_fast_render_worker_runs_no_planted_module(hostile_cwd, tmp_path):
    from pysolver.render.fast import render_files

    scad = tmp_path / "part.scad"
    scad.write_text("cube([1, 2, 3]);\n")
    ans = render_files([(scad, tmp_path / "part.stl")], jobs=1)
    assert _planted(hostile_cwd) == []
    assert ans[0]["ok"], ans[0]["error"]            # the real worker ran
    assert (tmp_path / "part.stl").stat().st_size > 84


def test_a_studio_run_runs_no_planted_module(hostile_cwd, tmp_path):
    from pysolver.studio.server import Build, Job

    job = Job()
    job.state.update(state="running", started=time.time(), log=[])
    folder = tmp_path / "no-such-build"
    req = json.dumps({"folder": str(folder), "landscape": [1.0], "source": {}})
    job._run(Build(folder), req, ["start", "program", "report"], dict(Job.DEFAULT_S))
    assert _planted(hostile_cwd) == []
    state = job.snapshot()
    # the real rerun module answered: a named error about the folder, not an import failure
    assert state["state"] == "error" and f"{folder}/summary.json" in state["error"], state


# ------------------------------------------------------------------------------ stamps

SHAPE = "regular:rows=2,cols=2"


_cli = run_cli


def _tree(folder: Path) -> dict:
    """Every file under ``folder`` with its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and not p.is_symlink()}


@pytest.fixture
def design(tmp_path, monkeypatch, capsys):
    """A design folder made by ``morphshell design`` (``tmp_path/X``)."""
    monkeypatch.chdir(tmp_path)
    assert _cli(["design", SHAPE, "--out", "X"], capsys)[0] == 0
    return tmp_path / "X"


def _edit_stamp(folder: Path, **changes) -> None:
    from pysolver.atomic import STAMP_NAME

    p = folder / STAMP_NAME
    p.write_text(json.dumps(dict(json.loads(p.read_text()), **changes)))


DEAD_PID = 2 ** 30   # above any pid_max: a writer that is gone


@pytest.mark.parametrize("how", ["absolute", "dotdot", "link"])
def test_a_stamp_naming_a_path_outside_its_folder_deletes_nothing(design, tmp_path, capsys,
                                                                   how):
    """Hole 3: a ``pending`` entry (a killed writer's temporary file) that points outside the
    folder, by an absolute path, by ``..`` or through a link, made ``morphshell program``
    delete it.  Now the folder is refused as damaged (exit 2), and nothing is deleted."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    victim = elsewhere / ".victim.tmp-0123456789abcdef"
    victim.write_text("the user's")
    entry = {"absolute": str(victim), "dotdot": f"../elsewhere/{victim.name}",
             "link": f"sub/{victim.name}"}[how]
    if how == "link":
        (design / "sub").symlink_to(elsewhere)
    _edit_stamp(design, pending={entry: DEAD_PID})
    before = _tree(design)
    rc, msg = _cli(["program", design], capsys)
    assert victim.read_text() == "the user's"
    assert _tree(design) == before
    assert rc == 2 and "damaged" in msg and "Traceback" not in msg, msg
    assert entry in msg and "Fix:" in msg


@pytest.mark.parametrize("key, value", [
    ("files", {"../../etc/passwd": ["0" * 64, 1]}),
    ("dirs", ["/tmp"]),
    ("prev", {"a/./b": ["0" * 64, 1]}),
    ("pending", {"cells.csv": DEAD_PID}),     # not a temporary file's name
    ("files", {"cells.csv": "sha"}),
])
def test_every_path_a_stamp_names_is_checked(design, capsys, key, value):
    from pysolver.atomic import DamagedFolder, read_stamp

    _edit_stamp(design, **{key: value})
    with pytest.raises(DamagedFolder):
        read_stamp(design)
    before = _tree(design)
    rc, msg = _cli(["program", design], capsys)
    assert rc == 2 and "damaged" in msg and _tree(design) == before, msg


@pytest.mark.parametrize("text", ['{"made_by": "morphshell", "vers', "[1, 2]", ""])
def test_a_damaged_stamp_is_reported_as_damaged(design, capsys, text):
    """LOW: a truncated stamp was reported as "no stamp" or "not made by morphshell"."""
    from pysolver.atomic import STAMP_NAME

    (design / STAMP_NAME).write_text(text)
    before = _tree(design)
    for argv in (["program", design], ["design", SHAPE, "--out", design]):
        rc, msg = _cli(argv, capsys)
        assert rc == 2 and "is damaged" in msg, msg
        assert "no .morphshell-build stamp" not in msg and "not a morphshell" not in msg
    assert _tree(design) == before


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to give a file to another user")
def test_another_users_lock_file_is_never_deleted(design, tmp_path, capsys):
    """LOW: root removed other users' ``*.morphshell-lock`` files beside ``--out`` (they hold
    ``pid N`` and no live process locks them, which looked stale)."""
    theirs = tmp_path / ".Y.morphshell-lock"
    theirs.write_text("pid 1234")
    os.chown(theirs, 65534, 65534)              # nobody's
    mine = tmp_path / ".Z.morphshell-lock"
    mine.write_text("pid 1234")
    assert _cli(["design", SHAPE, "--out", "X2"], capsys)[0] == 0
    assert theirs.read_text() == "pid 1234" and not mine.exists()


def test_a_long_out_name_is_refused_with_the_right_fix(tmp_path, monkeypatch, capsys):
    """LOW: a 240-character ``--out`` failed on the lock file's name ("remove the lock file
    if it is a link or a folder"); the name itself is the problem, and nothing is made."""
    monkeypatch.chdir(tmp_path)
    rc, msg = _cli(["design", SHAPE, "--out", "a" * 240], capsys)
    assert rc == 2 and "240 bytes long" in msg and "at most 233" in msg, msg
    assert "give a shorter folder name" in msg and "lock" not in msg.split("Fix:")[1]
    assert list(tmp_path.iterdir()) == []
    assert _cli(["design", SHAPE, "--out", "a" * 233], capsys)[0] == 0
