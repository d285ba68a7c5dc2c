"""Test-session settings: the order in which ``make test`` hands the files to its workers.

``make test`` runs ``pytest -n 2 --dist loadfile --no-loadscope-reorder``: each file runs
whole on one worker, and the workers take the files in collection order.  The wall time is
bounded below by the longest file and by half the total, so the longest files go first
(longest-first scheduling) and the many short ones fill in behind them.  :data:`LONGEST`
lists them, longest first (measured with ``pytest -n 2 --dist loadfile --durations=0``,
summed per file); the others keep pytest's order.  A stale list only costs balance, never
a test.

Each worker is one process on one core: numpy's OpenBLAS runs single-threaded in the test
session (``OPENBLAS_NUM_THREADS=1`` unless set; the workers and the subprocesses the tests
start inherit it).  Its default, one thread per core, spins two threads per worker on a
2-core machine: a design (``dome:size=0.7``) measured 49 s of CPU against 26 s with one
thread, the same figures.  That the thread count changes no result is itself tested
(``tests/test_stability.py`` designs with 1 and 2 BLAS threads, set explicitly).
"""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

LONGEST = (
    "test_stability.py",
    "test_temporal.py",
    "test_surfaces.py",
    "test_stencil.py",
    "test_builtin_stls.py",
    "test_calibration.py",
    "test_atomicity.py",
    "test_tolerance.py",
    "test_studio.py",
    "test_data_safety.py",
    "test_reproducibility.py",
    "test_model_files.py",
    "test_report_standalone.py",
)
"""The longest test files, longest first."""


def pytest_collection_modifyitems(session, config, items):
    rank = {name: k for k, name in enumerate(LONGEST)}
    items.sort(key=lambda item: rank.get(Path(str(item.fspath)).name, len(LONGEST)))
