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

import io
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 (after the backend)
import numpy as np  # noqa: E402

from pysolver.core.writes import atomic_write_bytes, atomic_write_text, make_dirs  # noqa: E402
from pysolver.params import MECHTEST, MechTest  # noqa: E402
from pysolver.records import json_text  # noqa: E402
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


def write_mechtest(folder, curves: dict, info: dict, consts: MechTest = MECHTEST) -> dict:
    """Write ``folder/mechtest/``: one CSV per test, ``mechtest.png``, ``summary.json``.

    Parameters
    ----------
    folder : path-like -- the design folder
    curves : dict -- test name -> :func:`sim.model.mechtest.run_test` result
    info : dict -- about the dried shell (recorded in the summary)

    Returns
    -------
    dict -- the summary written
    """
    out = Path(folder) / OUT_NAME
    summary = {name: test_summary(c, consts) for name, c in curves.items()}
    png = plot_curves(curves, summary, f"{Path(folder).name}: virtual mechanical tests "
                                       "(SI Note 6)")
    texts = {f"{name}.csv": curve_csv(c) for name, c in curves.items()}
    record = {"tests": summary, "shell": info}
    make_dirs(out)
    for name, text in texts.items():
        atomic_write_text(out / name, text)
    atomic_write_bytes(out / "mechtest.png", png)
    old = out / "summary.json"
    if old.is_file() and set(curves) != set(_json_tests(old)):
        record["tests"] = {**_json_tests(old), **summary}  # tests run before stay listed
    atomic_write_text(old, json_text(record, sort_keys=True))
    return record


def _json_tests(path: Path) -> dict:
    """The tests of an earlier ``summary.json`` (only entries that are objects)."""
    try:
        tests = json.loads(path.read_text()).get("tests")
    except (ValueError, OSError, AttributeError):
        return {}
    return {k: v for k, v in (tests or {}).items() if isinstance(v, dict)}


__all__ = ["OUT_NAME", "curve_csv", "test_summary", "plot_curves", "write_mechtest"]
