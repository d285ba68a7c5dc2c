"""Command-line options shared by the benchmarks against ``../shared/reference-shapes``."""

from __future__ import annotations

import argparse
from pathlib import Path


def reference_options(doc: str, root: Path) -> argparse.Namespace:
    """Parse ``--shared`` (the reference shapes, beside the clone) and ``--out`` (figures).

    Parameters
    ----------
    doc : str
        The benchmark's module docstring (its first line describes the command).
    root : Path
        The repository root.
    """
    ap = argparse.ArgumentParser(description=doc.split("\n")[0])
    ap.add_argument("--shared", type=Path, default=root.parent / "shared" / "reference-shapes")
    ap.add_argument("--out", type=Path, default=root / "build" / "bench")
    return ap.parse_args()
