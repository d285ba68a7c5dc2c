"""Calibration loop (issue 9): re-fit from a user's measurement folder, design with that model.

The measurements are the ones shipped in ``data/material-measurements/`` (no skip without them).
The committed model must be a fit of those files: the input hashes it records are theirs, and a
fresh fit with the default options reproduces its coefficients to 1e-9 relative (today byte for
byte; the tolerance absorbs round-off of another BLAS/QP solver build).
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _shared import assert_fit_matches, designed

from pysolver.fitting.material_fit import fit_material
from pysolver.material import load_bracket_model
from pysolver.material.measurements import DEFAULT_DATA_DIR
from pysolver.params import BRACKET_MODEL_FILE
from pysolver.tables import read_cells
from pysolver.temporal import program as temporal

REPO = Path(__file__).resolve().parent.parent
REMOVED = "0.50_6"  # dry specimen h = 0.5 mm, l = 6 mm (and its wet series 0.5_6_*)
COMMITTED_BYTES = Path(BRACKET_MODEL_FILE).read_bytes()
"""The committed model as it was when this module was imported (before any fit ran)."""


def _copy_without_specimen(dst: Path) -> None:
    """Copy the shipped dry and wet CSVs, dropping every row of one (h, l) specimen."""
    dst.mkdir()
    for src in sorted(DEFAULT_DATA_DIR.glob("unit_cell_*.csv")):
        if "speed" in src.name:
            continue
        with open(src, newline="") as fi, open(dst / src.name, "w", newline="") as fo:
            r, w = csv.reader(fi), csv.writer(fo, lineterminator="\n")
            header = next(r)
            w.writerow(header)
            h_col, l_col = header.index("thickness_mm"), header.index("central_length_mm")
            for row in r:
                if abs(float(row[h_col]) - 0.5) < 1e-9 and abs(float(row[l_col]) - 6) < 1e-9:
                    continue
                w.writerow(row)


@pytest.fixture(scope="module")
def user_fit(tmp_path_factory):
    """Fit, through the CLI, from a copy of the shipped data with one specimen removed."""
    tmp = tmp_path_factory.mktemp("calib")
    data = tmp / "my_data"
    _copy_without_specimen(data)
    out = tmp / "my_model.json"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    r = subprocess.run([sys.executable, "-m", "pysolver.cli", "--quiet", "fit-material",
                        "--data", str(data), "--out", str(out), "--report", str(tmp / "report")],
                       capture_output=True, text=True, env=env, cwd=REPO, timeout=1200)
    assert r.returncode == 0, r.stderr
    return tmp, out, r.stdout


def test_fit_without_one_specimen_reports_it(user_fit):
    tmp, out, stdout = user_fit
    assert out.is_file()
    assert "missing from the standard design" in stdout and "[0.5, 6" in stdout
    report = json.loads((tmp / "report" / "fit_report.json").read_text())
    assert [0.5, 6.0] in [list(map(float, x)) for x in report["missing_specimens"]["dry"]]
    assert (tmp / "report" / "compare_models.png").is_file()


def test_user_model_differs_from_default_but_is_close(user_fit):
    """One specimen fewer changes the fit a little, not wholesale (force at a typical point)."""
    _, out, _ = user_fit
    a, b = load_bracket_model(), load_bracket_model(out)
    h, bl, t, x = 0.5, 2.8, 30.0, 0.5
    fa, fb = float(a.force(h, bl, t, x)), float(b.force(h, bl, t, x))
    assert fa != fb
    assert abs(fa - fb) / fa < 0.5


def test_user_fit_leaves_the_committed_model_untouched(user_fit):
    """Fitting a user's folder (--data) writes its own file, never the committed model."""
    assert Path(BRACKET_MODEL_FILE).read_bytes() == COMMITTED_BYTES


def test_shipped_measurements_are_the_committed_models_inputs():
    """The committed model records the SHA-256 of the files it was fitted from: the shipped
    ones (a clone on its own has them; nothing is looked up outside the project)."""
    assert DEFAULT_DATA_DIR == REPO / "data" / "material-measurements"
    recorded = json.loads(COMMITTED_BYTES)["provenance"]["inputs_sha256"]
    assert sorted(recorded) == ["unit_cell_dry_20181102.csv", "unit_cell_wet_20181119.csv"]
    for name, digest in recorded.items():
        assert hashlib.sha256((DEFAULT_DATA_DIR / name).read_bytes()).hexdigest() == digest, name
    assert (DEFAULT_DATA_DIR / "README.md").is_file()


def test_committed_model_is_a_fresh_fit_of_the_shipped_data(tmp_path):
    """``make material`` (fit_material with the default options) reproduces the committed model:
    same grid, coefficients within ``FIT_RTOL`` (1e-6) of each power's largest magnitude (a
    fit on another CPU differs in its last bits), same recorded inputs and fit options."""
    out = tmp_path / "fresh.json"
    fit_material(out_path=out, report_dir=tmp_path / "report", progress=False,
                 evaluate_options=False)
    fresh, committed = json.loads(out.read_text()), json.loads(COMMITTED_BYTES)
    assert np.shape(fresh["force_coefficients"]["data"]) == (8, 21, 21, 4)
    assert_fit_matches(fresh, committed)
    assert fresh["provenance"]["inputs_sha256"] == committed["provenance"]["inputs_sha256"]


def test_material_option_changes_thicknesses(user_fit, tmp_path, tmp_path_factory):
    """MATERIAL= is honoured end to end: another model gives other thicknesses."""
    _, out, _ = user_fit
    a, b = tmp_path / "a", tmp_path / "b"
    shutil.copytree(designed("dome", tmp_path_factory), a)   # one design, twice
    shutil.copytree(a, b)
    temporal.program_design(a, progress=False, fit_landscape=True, picture=False)
    temporal.program_design(b, material=str(out), progress=False, fit_landscape=True,
                            picture=False)
    ca, cb = read_cells(a / "cells.csv"), read_cells(b / "cells.csv")
    assert not np.allclose(ca["thickness_top_mm"], cb["thickness_top_mm"])
