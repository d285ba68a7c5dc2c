"""The ``Examples`` sections of each stage's entry point run, as written (doctests).

The examples form one chain on one tiny design (a patch of eight bases): design, program,
simulate (10 s), report, compare-scan, tolerance (two samples), each continuing on the
``folder`` of the one before, then a build of its own.  They share one namespace, in which
``tmp`` is a scratch folder.  About 15 s in all.
"""

from __future__ import annotations

import doctest
import importlib

import pytest

CHAIN = (
    ("pysolver.design.pipeline", "run_design"),
    ("pysolver.temporal.program", "program_design"),
    ("sim.model.simulate", "simulate_design"),
    ("sim.report.report", "make_report"),
    ("sim.report.scan", "compare_scan"),
    ("pysolver.tolerance.analysis", "tolerance_analysis"),
    ("pysolver.build", "build"),
)
"""(module, function) of the entry point of every stage, in the order the examples run."""


def _docstring(module: str, name: str) -> str:
    return getattr(importlib.import_module(module), name).__doc__ or ""


@pytest.mark.parametrize("module,name", CHAIN)
def test_every_entry_point_has_examples(module, name):
    doc = _docstring(module, name)
    assert "Examples\n    --------" in doc and ">>> " in doc, f"{module}.{name}: no Examples"


def test_the_examples_run(tmp_path):
    parser = doctest.DocTestParser()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    globs = {"tmp": tmp_path}
    for module, name in CHAIN:
        test = parser.get_doctest(_docstring(module, name), globs, f"{module}.{name}", module, 0)
        test.globs = globs                       # one namespace: the chain's ``folder``
        result = runner.run(test, clear_globs=False)
        assert result.failed == 0, f"the Examples of {module}.{name} failed (see above)"
