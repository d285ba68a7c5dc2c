"""Test-session settings: the order in which ``make test`` hands the files to its workers.

``make test`` runs ``pytest -n 2 --dist loadfile --no-loadscope-reorder``: each file runs
whole on one worker, and the workers take the files in collection order.  The wall time is
bounded below by the longest file and by half the total, so the longest files go first
(longest-first scheduling) and the many short ones fill in behind them.  :data:`LONGEST`
lists them, longest first (measured with ``pytest -n 2 --dist loadfile --durations=0``,
summed per file); the others keep pytest's order.  A stale list only costs balance, never
a test.
"""

from __future__ import annotations

from pathlib import Path

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
