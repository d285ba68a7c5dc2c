"""Nothing half-written (issue #8): a build killed mid-stage leaves the previous complete
output folder or none, never a mix; a re-run recovers; one build per shape at a time.

The builds run the real CLI in a subprocess (its own process group, so the SIGKILL also
takes its OpenSCAD children) on the small ``regular`` shapes.
"""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from pysolver.core import manifest, staging
from pysolver.core.locks import build_lock
from pysolver.core.manifest import start_stamp
from pysolver.core.staging import atomic_dir, recover_stale, replace_dir
from pysolver.errors import EXIT_BAD_INPUT

REPO = Path(__file__).resolve().parent.parent
SMALL = "regular:rows=1,cols=2"          # 4 bases: renders 19 parts in a few seconds
# (its 3 cells are all boundary cells, which the temporal stage may refuse to program: the
# builds here keep the uniform design thickness, --no-program)


def _cmd(args):
    return [sys.executable, "-m", "pysolver.cli", *map(str, args)]


def _env():
    return dict(os.environ, PYTHONPATH=str(REPO))


def _run(args, cwd):
    return subprocess.run(_cmd(args), capture_output=True, text=True, env=_env(), cwd=cwd,
                          timeout=300)


def _snapshot(folder: Path) -> dict:
    """{relative path: sha256} of every file below ``folder``."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _kill_when(args, cwd, marker: str, timeout=240.0) -> str:
    """Start the CLI, SIGKILL its whole process group as soon as ``marker`` appears on
    stderr; returns the stderr read so far."""
    proc = subprocess.Popen(_cmd(args), stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                            text=True, env=_env(), cwd=cwd, start_new_session=True)
    seen, lines = threading.Event(), []

    def reader():
        for line in proc.stderr:
            lines.append(line)
            if marker in line:
                seen.set()

    t = threading.Thread(target=reader, daemon=True)
    t.start()
    try:
        assert seen.wait(timeout), "marker never seen:\n" + "".join(lines)
        assert proc.poll() is None, "the build ended before it could be killed"
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)     # the group started above, by its id
        proc.wait(timeout=60)
        t.join(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    return "".join(lines)


def _visible(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))


def test_kill_during_render_keeps_the_previous_complete_build(tmp_path):
    r = _run(["--quiet", "build", SMALL, "--no-program", "--no-render", "--no-sim"], tmp_path)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "build" / SMALL
    before = _snapshot(out)
    assert "summary.json" in before and "cells.csv" in before
    # (the fast renderer: the subject is the folder swap, not the parts' renderer)
    fast = ["--renderer", "fast"]
    _kill_when(["build", SMALL, "--no-program", "--no-sim", *fast], tmp_path,
               f"{SMALL}: render ...")
    assert _snapshot(out) == before                  # the old complete folder, untouched
    assert _visible(tmp_path / "build") == [SMALL]   # no half-written sibling
    # a re-run with the same inputs resumes the staging folder and completes
    r = _run(["build", SMALL, "--no-program", "--no-sim", *fast], tmp_path)
    assert r.returncode == 0, r.stderr
    assert "resuming the interrupted build" in r.stderr
    after = _snapshot(out)
    assert {f"stl/{k}.stl" for k in ("top", "bottom", "actuated")} <= set(after)
    for table in ("bases.csv", "cells.csv", "bumpers.csv", "stencil.obj"):
        assert after[table] == before[table], table  # and reproduces the same tables


def test_kill_during_design_leaves_no_output(tmp_path):
    _kill_when(["build", "regular", "--no-render", "--no-sim"], tmp_path, "regular: design ...")
    build = tmp_path / "build"
    assert not (build / "regular").exists()
    assert _visible(build) == []


def test_killed_design_command_is_cleaned_up_by_the_next_run(tmp_path):
    _kill_when(["design", "regular"], tmp_path, "[design] regular: load")
    build = tmp_path / "build"
    assert not (build / "regular").exists()
    r = _run(["--quiet", "design", "regular"], tmp_path)
    assert r.returncode == 0, r.stderr
    assert (build / "regular" / "cells.csv").is_file()
    assert [p.name for p in build.iterdir() if p.name.startswith(".regular")] == []


def test_replace_interrupted_between_its_renames_is_recovered(tmp_path):
    """``replace_dir`` moves the old folder aside, then the new one in: killed in between,
    ``dst`` is absent and the old complete folder waits aside; the next run (under the
    lock) puts it back, and removes stale temporary folders (tests/test_ownership.py has
    the user's look-alike folders)."""
    dst = tmp_path / "petal"
    with atomic_dir(dst) as tmp:
        (tmp / "summary.json").write_text("old complete\n")
    tok = manifest.new_token()
    aside = manifest.make_private(tmp_path, f".petal.old-{tok}", role="old", token=tok,
                                 **{"for": "petal"})
    os.replace(dst, aside / "petal")                  # the state after the first rename
    with pytest.raises(RuntimeError), atomic_dir(dst, keep_on_error=True) as tmp:
        (tmp / "cells.csv").write_text("half\n")     # a killed atomic_dir's temp folder
        raise RuntimeError
    with build_lock(dst):
        done = recover_stale(dst)
    assert (dst / "summary.json").read_text() == "old complete\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["petal"]
    assert len(done) == 3
    new = tmp_path / "new"
    new.mkdir()
    (new / "summary.json").write_text("new complete\n")
    start_stamp(new)
    staging.seal(new)
    replace_dir(new, dst)
    assert (dst / "summary.json").read_text() == "new complete\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["petal"]


def test_lock_refuses_a_second_build_of_the_same_shape_not_others(tmp_path):
    from pysolver.design import run_design

    run_design("regular:rows=1,cols=2", tmp_path / "src", progress=False, plots=False)
    (tmp_path / "patch.obj").write_bytes((tmp_path / "src" / "stencil.obj").read_bytes())
    with build_lock(tmp_path / "build" / "regular"):  # "another build of regular" runs
        r = _run(["--quiet", "build", "regular", "--no-render", "--no-sim"], tmp_path)
        assert r.returncode == EXIT_BAD_INPUT
        assert "Traceback" not in r.stderr
        assert "build/regular is being built by pid" in r.stderr
        assert "builds of other shapes may run concurrently" in r.stderr
        assert not (tmp_path / "build" / "regular").exists()
        assert not (tmp_path / "build" / ".staging" / "regular").exists()
        r = _run(["--quiet", "build", "patch.obj", "--no-render", "--no-sim", "--no-program"],
                 tmp_path)
        assert r.returncode == 0, r.stderr             # a different shape proceeds
        assert (tmp_path / "build" / "patch" / "summary.json").is_file()
