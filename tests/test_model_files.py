"""Model files are user input (issue 13): a catalogue of bad bracket (material) and membrane model
files, each refused with exit code 2 and a message naming the file, the key (with its index) and
the rule; no traceback, nothing written, and the refusal comes before the design stage runs.
The committed models and a fresh fit of the shipped measurements pass the validator.
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pysolver.build import validate_model_files
from pysolver.errors import InputError
from pysolver.material.model import load_bracket_model
from pysolver.material.validate import validate_bracket_model_file
from pysolver.params import BRACKET_MODEL_FILE, MEMBRANE_MODEL_FILE
from pysolver.temporal.membrane_model import load_membrane_model, validate_membrane_model_file

REPO = Path(__file__).resolve().parent.parent
GOOD = json.loads(Path(BRACKET_MODEL_FILE).read_text())
GOOD_MEMBRANE = json.loads(Path(MEMBRANE_MODEL_FILE).read_text())
SMALL = "regular:rows=1,cols=2"


def _cli(args, cwd):
    """``python -m pysolver.cli ARGS`` in a subprocess, progress lines on (a started stage would
    show)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run([sys.executable, "-m", "pysolver.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, env=env, timeout=120)


def _main(args, cwd, capsys, monkeypatch):
    """The same CLI entry point in this process (the catalogue is long: no interpreter start per
    case); returns an object like ``subprocess.run``'s."""
    from types import SimpleNamespace

    from pysolver.cli import main

    monkeypatch.chdir(cwd)
    capsys.readouterr()
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return SimpleNamespace(returncode=code, stdout=out, stderr=err)


def _coef(d):
    return np.array(d["force_coefficients"]["data"], dtype=float)


def _with(**changes):
    """A copy of the committed model with nested keys changed (``"grid.step"`` style)."""

    def make(d):
        d = copy.deepcopy(d)
        for key, value in changes.items():
            *parents, last = key.split(".")
            node = d
            for p in parents:
                node = node[p]
            if value is _DROP:
                del node[last]
            else:
                node[last] = value(node[last]) if callable(value) else value
        return d

    return make


_DROP = object()


def _set_entry(index, value):
    def change(data):
        data = copy.deepcopy(data)
        node = data
        for i in index[:-1]:
            node = node[i]
        node[index[-1]] = value
        return data

    return change


def _grid_step(k, v):
    return lambda s: [v if i == k else x for i, x in enumerate(s)]


def _stiffness_zero_at(index):
    def change(data):
        c = np.array(data, dtype=float)
        c[index][0] = 0.0
        return c.tolist()

    return change


# (id, JSON text or a function of the committed model's dict, patterns the message must contain)
BRACKET_CASES = [
    ("json-list", lambda d: [d], [r"is a JSON list, not a JSON object"]),
    ("json-number", lambda d: 3.5, [r"is the JSON value 3\.5, not a JSON object"]),
    ("not-json", "{\"format\": ", [r"is not valid JSON \(.* line 1"]),
    ("other-format", _with(format="bracket_model"),
     [r"format is 'bracket_model', not 'morphshell\.bracket_model'"]),
    ("newer-format", _with(format_version=2), [r"format_version is 2; this morphshell reads"]),
    ("missing-grid", _with(grid=_DROP), [r": grid is missing \(a required key\)"]),
    ("missing-data", _with(**{"force_coefficients.data": _DROP}),
     [r"force_coefficients\.data is missing \(a required key\)"]),
    ("grid-step-short", _with(**{"grid.step": [0.05, 0.25]}),
     [r"grid\.step has 2 entries, expected 3"]),
    ("grid-num-float", _with(**{"grid.num": [8, 21, 20.5]}),
     [r"grid\.num is a list of 3; expected 3 whole numbers"]),
    ("grid-one-node", _with(**{"grid.num": [8, 21, 1]}),
     [r"grid\.num\[2\] = 1; the time axis needs at least 2 nodes"]),
    ("grid-step-zero", _with(**{"grid.step": _grid_step(1, 0.0)}),
     [r"grid\.step\[1\] = 0 mm; the bracket length grid step must be > 0"]),
    ("grid-not-monotone", _with(**{"grid.step": _grid_step(2, -6.0)}),
     [r"grid\.step\[2\] = -6 s; the time grid step must be > 0 \(grid nodes increase"]),
    ("grid-step-nan", _with(**{"grid.step": _grid_step(0, float("nan"))}),
     [r"grid\.step\[0\] is NaN; every value must be a finite number"]),
    ("negative-time", _with(**{"grid.min": [0.3, 0.805457959811, -6.0]}),
     [r"grid\.min\[2\] = -6 s; time in water starts at 0 s"]),
    ("wrong-shape", _with(**{"force_coefficients.data": lambda c: [[row[:20] for row in p]
                                                                   for p in c]}),
     [r"force_coefficients\.data has shape \(8, 21, 20, 4\); grid\.num = \[8, 21, 21\] needs "
      r"\(8, 21, 21, 4\)"]),
    ("ragged", _with(**{"force_coefficients.data": _set_entry((1, 2, 3), [1.0, 0.0, 0.0])}),
     [r"force_coefficients\.data\[1\]\[2\]\[3\] has shape \(3,\), its sibling "
      r"force_coefficients\.data\[1\]\[2\]\[0\] has \(4,\)"]),
    ("text-number", _with(**{"force_coefficients.data": _set_entry((0, 0, 0, 0), "1.0")}),
     [r"force_coefficients\.data\[0\]\[0\]\[0\]\[0\] is the text '1\.0', not a number"]),
    ("nan", _with(**{"force_coefficients.data": _set_entry((2, 3, 4, 1), float("nan"))}),
     [r"force_coefficients\.data\[2\]\[3\]\[4\]\[1\] is NaN \(h = 0\.4 mm, b = 1\.555 mm, "
      r"t = 24 s, coefficient of x\^2\)"]),
    ("infinity", _with(**{"force_coefficients.data": _set_entry((7, 20, 20, 3), float("inf"))}),
     [r"force_coefficients\.data\[7\]\[20\]\[20\]\[3\] is \+inf"]),
    ("negated-forces", _with(**{"force_coefficients.data": lambda c: (-np.array(c)).tolist()}),
     [r"the stiffness at zero compression F'\(0\) = c1 must be > 0 N/mm at every node "
      r"\(3528 nodes are not\)"]),
    ("zero-stiffness", _with(**{"force_coefficients.data": _stiffness_zero_at((4, 10, 2))}),
     [r"force_coefficients\.data\[4\]\[10\]\[2\]\[0\] = 0 N/mm \(h = 0\.5 mm, b = 3\.305 mm, "
      r"t = 12 s\): the stiffness at zero compression"]),
    ("forces-rise-with-time",
     _with(**{"force_coefficients.data": lambda c: np.array(c)[:, :, ::-1].tolist()}),
     [r"forces must fall with time in water"]),
    ("no-softening", _with(**{"force_coefficients.data": lambda c: np.repeat(
        np.array(c)[:, :, :1], 21, axis=2).tolist()}),
     [r"force_coefficients\.data hardly changes with time: the median of F\(t = 120 s\) / "
      r"F\(t = 0 s\) over the grid is 1, above 0\.5"]),
    ("plastic-fraction", _with(plastic_fraction=1.5),
     [r"plastic_fraction is 1\.5; it must be a number in \[0, 1\)"]),
    ("creep-model-nan", _with(**{"creep_model.wet.coefficients": _set_entry((3,), None)}),
     [r"creep_model\.wet\.coefficients\[3\] is null, not a number"]),
]


def _write_case(tmp_path: Path, name: str, make) -> Path:
    p = tmp_path / f"{name}.json"
    if isinstance(make, str):
        p.write_text(make)
    else:
        p.write_text(json.dumps(make(GOOD)))
    return p


def _tree_hash(folder: Path) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _assert_refused(r, path: Path, patterns) -> None:
    err = r.stderr
    assert r.returncode == 2, err
    assert "Traceback" not in err and "internal error" not in err, err
    assert f"material model file {str(path)!r}" in err, err
    for pat in patterns:
        assert re.search(pat, err), (pat, err)
    assert "Fix: " in err, err


@pytest.fixture(scope="module")
def design_dir(tmp_path_factory):
    """A small design folder (design stage only) for ``program`` and ``simulate``."""
    from pysolver.design import run_design

    d = tmp_path_factory.mktemp("design") / "small"
    run_design(SMALL, d, progress=False, plots=False)
    return d


@pytest.mark.parametrize("name,make,patterns", BRACKET_CASES, ids=[c[0] for c in BRACKET_CASES])
def test_build_refuses_bad_material_file(name, make, patterns, tmp_path, capsys, monkeypatch):
    bad = _write_case(tmp_path, name, make)
    before = _tree_hash(tmp_path)
    out = tmp_path / "out"
    r = _main(["build", "regular", "--material", bad, "--out", out, "--no-render", "--no-sim"],
              tmp_path, capsys, monkeypatch)
    _assert_refused(r, bad, patterns)
    assert "design ..." not in r.stderr, r.stderr        # refused before the design stage
    assert not out.exists()
    assert _tree_hash(tmp_path) == before                 # nothing written (no build/, staging)
    assert sorted(p.name for p in tmp_path.iterdir()) == [bad.name]


@pytest.mark.parametrize("name,make,patterns", BRACKET_CASES, ids=[c[0] for c in BRACKET_CASES])
def test_program_refuses_bad_material_file(name, make, patterns, tmp_path, design_dir, capsys,
                                          monkeypatch):
    bad = _write_case(tmp_path, name, make)
    before = _tree_hash(design_dir)
    r = _main(["--quiet", "program", design_dir, "--material", bad], tmp_path, capsys,
              monkeypatch)
    _assert_refused(r, bad, patterns)
    assert _tree_hash(design_dir) == before


@pytest.mark.parametrize("kind", ["folder", "missing", "not-utf8", "device"])
def test_bad_material_paths(kind, tmp_path, design_dir, capsys, monkeypatch):
    p = Path("/dev/null") if kind == "device" else tmp_path / "model.json"
    rule = {"folder": r"is a folder, not a file\.", "missing": r"does not exist\.",
            "not-utf8": r"is not UTF-8 text", "device": r"is not a regular file"}[kind]
    if kind == "folder":
        p.mkdir()
    elif kind == "not-utf8":
        p.write_bytes(b"{\"format\": \"\xff\xfe\"}")
    for args in (["build", "regular", "--out", tmp_path / "out", "--no-render", "--no-sim"],
                 ["program", design_dir],
                 ["simulate", design_dir, "--t-end", "1"]):
        r = _main([*args, "--material", p], tmp_path, capsys, monkeypatch)
        _assert_refused(r, p, [rule])
        assert not (tmp_path / "out").exists() and not (design_dir / "sim").exists()


def test_simulate_refuses_bad_material_before_reading_the_design(tmp_path, design_dir):
    bad = _write_case(tmp_path, "step0", _with(**{"grid.step": _grid_step(1, 0.0)}))
    r = _cli(["--quiet", "simulate", design_dir, "--material", bad], tmp_path)
    _assert_refused(r, bad, [r"grid\.step\[1\] = 0 mm"])
    assert not (design_dir / "sim").exists()


def test_api_loader_refuses_the_same_way(tmp_path):
    bad = _write_case(tmp_path, "nan", BRACKET_CASES[[c[0] for c in BRACKET_CASES]
                                                     .index("nan")][1])
    with pytest.raises(InputError, match=r"force_coefficients\.data\[2\]\[3\]\[4\]\[1\] is NaN"):
        load_bracket_model(bad)
    with pytest.raises(InputError, match=r"is NaN"):
        validate_model_files(bad)


# ------------------------------------------------------------------------------------------------
# membrane model


def _mem(**changes):
    return _with(**changes)


MEMBRANE_CASES = [
    ("json-list", lambda d: [d], [r"is a JSON list, not a JSON object"]),
    ("missing-terms", _mem(terms=_DROP), [r": terms is missing \(a required key\)"]),
    ("unknown-term", _mem(terms=["1", "b", "q", "d/b"]),
     [r"terms\[2\] = 'q' is not a known monomial"]),
    ("repeated-term", _mem(terms=["1", "b", "b", "d/b"]), [r"repeats a monomial"]),
    ("too-few-coefficients", _mem(coefficients=[2.0, 0.6, -0.5]),
     [r"coefficients has 3 entries, expected 4"]),
    ("nan-coefficient", _mem(coefficients=_set_entry((2,), float("nan"))),
     [r"coefficients\[2\] is NaN; every value must be a finite number"]),
    ("negative-residual", _mem(**{"fit.residual_rms_N": -0.1}),
     [r"fit\.residual_rms_N is -0\.1; it must be a finite number >= 0"]),
    ("boundary-factor", _mem(boundary_factor=0.0),
     [r"boundary_factor is 0\.0; it must be a number in \(0, 1\]"]),
    ("negated", _mem(coefficients=lambda c: [-v for v in c]),
     [r"coefficients give a membrane force F_mem = -[\d.]+ N at b0 = .* the membrane must "
      r"pull"]),
    ("grows-as-it-shortens", _mem(coefficients=lambda c: [c[0], c[1], -c[2], -c[3]]),
     [r"coefficients give a membrane force that grows .* must relax as it contracts"]),
    ("samples-lengths", _mem(**{"samples.d_mm": lambda v: v[:-1]}),
     [r"samples b0_mm, d_mm and force_N have different lengths"]),
]


@pytest.mark.parametrize("name,make,patterns", MEMBRANE_CASES,
                         ids=[c[0] for c in MEMBRANE_CASES])
def test_membrane_model_validator(name, make, patterns, tmp_path):
    p = tmp_path / f"{name}.json"
    p.write_text(json.dumps(make(GOOD_MEMBRANE)))
    with pytest.raises(InputError) as e:
        load_membrane_model(p)
    msg = str(e.value)
    assert msg.startswith(f"membrane model file {str(p)!r}"), msg
    for pat in patterns:
        assert re.search(pat, msg), (pat, msg)
    assert "Fix: " in msg


# ------------------------------------------------------------------------------------------------
# good files pass


def test_committed_models_pass():
    v = validate_bracket_model_file(BRACKET_MODEL_FILE)
    assert v["coef"].shape == (8, 21, 21, 4)
    np.testing.assert_array_equal(v["coef"], _coef(GOOD))
    m = validate_membrane_model_file(MEMBRANE_MODEL_FILE)
    assert m["terms"] == tuple(GOOD_MEMBRANE["terms"])
    validate_model_files()


def test_fresh_fit_passes(tmp_path):
    """A fit of the shipped measurements (default options) passes the validator."""
    from pysolver.fitting.material_fit import fit_material

    out = tmp_path / "fresh.json"
    fit_material(out_path=out, report_dir=tmp_path / "report", progress=False,
                 evaluate_options=False)
    v = validate_bracket_model_file(out)
    assert v["coef"].shape == (8, 21, 21, 4)


def test_material_model_records_its_brackets_and_other_brackets_are_refused(tmp_path):
    """The model file records the bracket height and width it was fitted for; a unit cell
    with other brackets is refused before any stage, with the fix (make material)."""
    import dataclasses
    import json

    from pysolver.material.model import check_bracket_geometry
    from pysolver.params import UNIT_CELL

    d = json.loads(BRACKET_MODEL_FILE.read_text())
    assert d["bracket"] == {"height_mm": UNIT_CELL.bracket_w,
                            "width_mm": [UNIT_CELL.thickness_min, UNIT_CELL.thickness_max]}
    validate_model_files()                                   # the committed pair fits
    taller = dataclasses.replace(UNIT_CELL, bracket_w=1.5)
    with pytest.raises(InputError, match=r"fitted for brackets 1 mm high.*1\.5 mm") as e:
        validate_model_files(unit=taller)
    assert "make material" in e.value.fix
    d["bracket"]["height_mm"] = 1.5                          # a model fitted for 1.5 mm
    other = tmp_path / "m.json"
    other.write_text(json.dumps(d))
    with pytest.raises(InputError, match="1.5 mm high"):
        validate_model_files(other)
    check_bracket_geometry(load_bracket_model(other), taller)  # matching brackets pass
    wider = dataclasses.replace(UNIT_CELL, thickness_max=0.8)
    with pytest.raises(InputError, match="widths 0.3-0.65 mm"):
        check_bracket_geometry(load_bracket_model(), wider)
