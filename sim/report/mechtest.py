"""The virtual mechanical tests' outputs: ``DIR/mechtest/`` (SI Note 6).

Files (names and columns are a contract, issue #44):

* ``<test>.csv``: ``strain_percent,stress_MPa`` (stretch, bend: the flexural strain and
  stress, compress) or ``displacement_mm,shear_stress_MPa`` (shear), one row per step;
* ``mechtest.png``: the curves, the peak of each marked;
* ``summary.json``: per test ``initial_slope`` (MPa per % or per mm), ``peak_stress_MPa``,
  ``peak_at`` (% or mm), ``limit`` (``bracket yield``, ``bumper contact``, ``brackets`` or
  ``membrane``), and what the test did (fixture bases, specimen size, steps converged).

Everything is computed before the first file is written; each file is written whole
(:func:`pysolver.core.writes.atomic_write_text`).
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 (after the backend)
import numpy as np  # noqa: E402

from pysolver.core.ownership import audit  # noqa: E402
from pysolver.core.records import json_text  # noqa: E402
from pysolver.core.writes import (  # noqa: E402
    atomic_write_bytes,
    atomic_write_text,
    make_dirs,
    remove_file,
)
from pysolver.errors import InputError  # noqa: E402
from pysolver.params import MECHTEST, TESTS, MechTest  # noqa: E402
from sim.model.mechtest import readings  # noqa: E402

OUT_NAME = "mechtest"
"""The tests' folder inside a design folder."""


def curve_csv(curve: dict) -> str:
    """A test's curve as CSV text (header = its two columns, ``%.9g`` floats)."""
    lines = [",".join(curve["columns"])]
    lines += [f"{x:.9g},{y:.9g}" for x, y in zip(curve["x"], curve["y"], strict=True)]
    return "\n".join(lines) + "\n"


def test_summary(curve: dict, consts: MechTest = MECHTEST) -> dict:
    """The readings of one curve and how it was made (for ``summary.json``)."""
    r = readings(curve, consts)
    unit = "MPa/mm" if curve["test"] == "shear" else "MPa/%"
    return {**r, "initial_slope_unit": unit,
            "peak_at_unit": "mm" if curve["test"] == "shear" else "%",
            "peak_force_N": float(np.max(curve["force_N"])),
            "steps": len(curve["x"]) - 1,
            "converged_steps": int(np.sum(curve["converged"])),
            "stopped": curve.get("stopped"),
            "a0_mm": curve["a0"], "b0_mm": curve["b0"], "axis_deg": curve["axis_deg"],
            "fixture_bases": curve["bases"]}


def plot_curves(curves: dict, summary: dict, title: str) -> bytes:
    """PNG of every curve (one panel per test), its peak marked."""
    n = len(curves)
    fig, axes = plt.subplots(1, n, figsize=(3.6 * n, 3.2), squeeze=False)
    for ax, (name, c) in zip(axes[0], curves.items(), strict=True):
        s = summary[name]
        ax.plot(c["x"], c["y"], "-", color="C0", lw=1.5, label="predicted")
        ax.plot([s["peak_at"]], [s["peak_stress_MPa"]], "o", color="C3",
                label=f"peak ({s['limit']})")
        ax.set_xlabel(c["columns"][0].replace("_", " "))
        ax.set_ylabel(c["columns"][1].replace("_", " "))
        ax.set_title(name)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()


def check_targets(folder, tests) -> Path:
    """Refuse, before any test runs, when a file ``morphshell mechtest`` would write (or the
    ``mechtest`` folder itself) is not morphshell's: a user's file, one changed since
    morphshell wrote it, a link or a folder it did not make.

    Parameters
    ----------
    folder : path-like -- the (stamped) design folder
    tests : iterable of str -- the tests to run

    Returns
    -------
    Path -- ``folder/mechtest``, absolute

    Raises
    ------
    InputError
        Naming every such file and the fix; nothing is written.
    """
    folder = Path(folder).absolute()
    out = folder / OUT_NAME
    targets = {out / f"{t}.csv" for t in tests} | {out / "mechtest.png", out / "summary.json"}
    bad = [(p, why) for p, why in audit(folder) if p == out or p in targets]
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        bad.insert(0, (out, "a symbolic link" if out.is_symlink() else "not a folder"))
    if bad:
        listing = "; ".join(f"{p}: {why}" for p, why in bad)
        raise InputError(f"mechtest would overwrite what morphshell did not write ({listing})",
                         fix=f"move those files out of {out} (morphshell never overwrites "
                             "a file it did not write) and run the tests again")
    return out


def _kept_tests(out: Path, info: dict, curves: dict) -> tuple[dict, dict]:
    """The tests of an earlier run that stay listed beside the new ones: those made from the
    same dried shell (``shell`` record) along the same axis, whose CSV is still there;
    returns their summaries and curves (read back from their CSVs, for the plot)."""
    old = _json_record(out / "summary.json")
    axis = {c["axis_deg"] for c in curves.values()}
    if old.get("shell") != json.loads(json_text(info, sort_keys=True)):
        return {}, {}
    kept, again = {}, {}
    for name, entry in (old.get("tests") or {}).items():
        if name in curves or name not in TESTS or not isinstance(entry, dict) or \
                {entry.get("axis_deg")} != axis:
            continue
        curve = _read_curve(out / f"{name}.csv")
        if curve is not None and {"peak_at", "peak_stress_MPa", "limit"} <= set(entry):
            kept[name], again[name] = entry, curve
    return kept, again


def _read_curve(path: Path) -> dict | None:
    """A test's CSV read back (``columns``, ``x``, ``y``), ``None`` if unreadable."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
        x, y = (np.array([float(r[i]) for r in rows[1:]]) for i in (0, 1))
    except (OSError, ValueError, IndexError):
        return None
    return {"columns": rows[0][:2], "x": x, "y": y}


def write_mechtest(folder, curves: dict, info: dict, consts: MechTest = MECHTEST) -> dict:
    """Write ``folder/mechtest/``: one CSV per test, ``mechtest.png``, ``summary.json``.

    Every target is checked (:func:`check_targets`) and everything computed before the
    first file is written.  Tests of an earlier run stay listed (and plotted) only when
    made from the same dried shell along the same axis; the CSVs of the others are removed,
    so that the folder always describes one shell.

    Parameters
    ----------
    folder : path-like -- the design folder
    curves : dict -- test name -> :func:`sim.model.mechtest.run_test` result
    info : dict -- about the dried shell (recorded in the summary)

    Returns
    -------
    dict -- the summary written
    """
    out = check_targets(folder, curves)
    summary = {name: test_summary(c, consts) for name, c in curves.items()}
    kept, kept_curves = _kept_tests(out, info, curves) if out.is_dir() else ({}, {})
    tests = {**kept, **summary}
    png = plot_curves({**kept_curves, **curves}, tests,
                      f"{Path(folder).name}: virtual mechanical tests (SI Note 6)")
    texts = {f"{name}.csv": curve_csv(c) for name, c in curves.items()}
    record = {"tests": dict(sorted(tests.items())), "shell": info}
    make_dirs(out)
    for name, text in texts.items():
        atomic_write_text(out / name, text)
    for name in TESTS:
        if name not in tests:
            remove_file(out / f"{name}.csv")  # of another shell or axis; a user's file stays
    atomic_write_bytes(out / "mechtest.png", png)
    atomic_write_text(out / "summary.json", json_text(record, sort_keys=True))
    return record


def _json_record(path: Path) -> dict:
    """An earlier ``summary.json`` (``{}`` when missing or not a JSON object)."""
    try:
        rec = json.loads(path.read_text())
    except (ValueError, OSError):
        return {}
    return rec if isinstance(rec, dict) else {}


__all__ = ["OUT_NAME", "check_targets", "curve_csv", "test_summary", "plot_curves",
           "write_mechtest"]
