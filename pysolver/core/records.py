"""JSON records: the project's one encoder.

Every JSON file morphshell writes (``design.json``, ``summary.json``, ``sim/summary.json``,
``report/report.json``, the tolerance and sweep records) goes through :func:`json_text`, so
numpy scalars and arrays, paths and non-finite numbers are written the same way everywhere.
The file itself is written by :func:`pysolver.core.writes.atomic_write_text` (or inside an
:func:`pysolver.core.staging.atomic_dir`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np


def json_default(o):
    """``json.dumps(default=...)``: numpy scalars as Python numbers, arrays as lists, paths
    as text.

    Raises
    ------
    TypeError
        Any other type (as :func:`json.dumps` itself would).
    """
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


def finite(o):
    """``o`` with every non-finite number (NaN, inf) replaced by None, recursively; numpy
    values, tuples and paths become their JSON types and dict keys text (strict JSON: no
    ``NaN`` token)."""
    if isinstance(o, dict):
        return {str(k): finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [finite(v) for v in o]
    if isinstance(o, np.ndarray):
        return finite(o.tolist())
    if isinstance(o, (bool, np.bool_)):
        return bool(o)
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, (float, np.floating)):
        x = float(o)
        return x if math.isfinite(x) else None
    if isinstance(o, Path):
        return str(o)
    return o


def json_text(obj, *, indent: int | None = 2, sort_keys: bool = True,
              strict: bool = False) -> str:
    """The text of a JSON record, ending with a newline.

    Parameters
    ----------
    obj
        Anything :func:`json_default` can encode.
    indent : int or None
        Indentation (None: one line).
    sort_keys : bool
        Keys in sorted order.
    strict : bool
        Non-finite numbers as ``null`` (:func:`finite`) rather than ``NaN``/``Infinity``.
    """
    return json.dumps(finite(obj) if strict else obj, indent=indent, sort_keys=sort_keys,
                      default=json_default) + "\n"


__all__ = ["json_default", "finite", "json_text"]
