"""The front door: CLI behaviour, atomic outputs, build locks, parameters."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from pysolver.cli import main
from pysolver.core.locks import build_lock
from pysolver.core.staging import atomic_dir
from pysolver.core.writes import atomic_write_text
from pysolver.errors import EXIT_BAD_INPUT, InputError, refuse_first
from pysolver.params import UNIT_CELL

REPO = Path(__file__).resolve().parent.parent


def test_unit_cell_closed_forms():
    # alpha = asin(th / 2r) + 7 deg = 37 deg; l - b = 4 cos 37 deg (SI Note 3).
    assert UNIT_CELL.alpha_deg == pytest.approx(37.0, abs=1e-12)
    assert UNIT_CELL.bracket_offset == pytest.approx(4 * math.cos(math.radians(37)), abs=1e-12)
    assert UNIT_CELL.layer_h == pytest.approx(2.3)
    assert UNIT_CELL.bracket_length(7.0) == pytest.approx(3.8054579598, abs=1e-9)


def test_cli_help_lists_every_stage(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    for stage in ("build", "design", "program", "render", "simulate", "report",
                  "compare-scan", "fit-material", "fit-membrane", "specimens"):
        assert stage in out


def test_cli_bad_input_exit_code_and_no_traceback():
    env = dict(os.environ, PYTHONPATH=str(REPO))
    r = subprocess.run([sys.executable, "-m", "pysolver.cli", "build", "no/such/mesh.obj"],
                       capture_output=True, text=True, env=env, cwd=REPO)
    assert r.returncode == EXIT_BAD_INPUT
    assert "does not exist" in r.stderr and "Fix:" in r.stderr
    assert "Traceback" not in r.stderr


def test_atomic_dir_keeps_previous_result_on_error(tmp_path):
    dst = tmp_path / "out"
    with atomic_dir(dst) as tmp:
        (tmp / "a.txt").write_text("complete")
    with pytest.raises(RuntimeError), atomic_dir(dst) as tmp:
        (tmp / "a.txt").write_text("half")
        raise RuntimeError("interrupted")
    assert (dst / "a.txt").read_text() == "complete"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_atomic_write_text(tmp_path):
    p = tmp_path / "x" / "f.json"
    atomic_write_text(p, "{}\n")
    assert p.read_text() == "{}\n"
    assert [q.name for q in p.parent.iterdir()] == ["f.json"]


def test_build_lock_excludes_same_shape_not_others(tmp_path):
    a, b = tmp_path / "petal", tmp_path / "dome"
    code = ("import sys; from pysolver.core.locks import build_lock\n"
            "try:\n"
            "    with build_lock(sys.argv[1]): print('got')\n"
            "except Exception as e: print('refused', e)\n")
    env = dict(os.environ, PYTHONPATH=str(REPO))
    with build_lock(a):
        r = subprocess.run([sys.executable, "-c", code, str(a)], capture_output=True,
                           text=True, env=env)
        assert r.stdout.startswith("refused") and "being built" in r.stdout
        r = subprocess.run([sys.executable, "-c", code, str(b)], capture_output=True,
                           text=True, env=env)
        assert r.stdout.startswith("got")
    with build_lock(a):
        pass


def test_input_error_is_value_error_with_fix():
    e = InputError("bad thing", fix="do this")
    assert isinstance(e, ValueError)
    assert "Fix: do this" in str(e)


def test_refuse_first_names_the_first_bad_row_and_the_count():
    calls = []

    def message(i, n):
        calls.append((i, n))
        return f"row {i}: bad ({n} in all)"

    refuse_first([False, False], message, fix="unused")
    refuse_first([], message)
    assert calls == []  # no bad row: no message is built, nothing is raised
    with pytest.raises(InputError) as e:
        refuse_first([False, True, False, True], message, fix="repair it")
    assert calls == [(1, 2)]
    assert e.value.problem == "row 1: bad (2 in all)" and e.value.fix == "repair it"
