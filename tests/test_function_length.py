"""No long functions: every function of the packages below fits in 80 lines (its ``def`` to
its last line, docstring included), read with ``ast``.

The one exception is a one-body assembly (a compiled or vectorised loop over elements that
writes an element's energy, gradient and Hessian out in one body), which says so in its
docstring ("one-body assembly").
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 80
PACKAGES = ("pysolver/design", "pysolver/temporal", "pysolver/mechanics", "pysolver/material",
            "pysolver/fitting", "pysolver/studio", "pysolver/params", "sim/model",
            "pysolver/geometry.py", "pysolver/tables.py")
# the simulator's stepper and collision checks are split elsewhere (issue #30, part A)
NOT_HERE = ("sim/model/simulate.py", "sim/model/collisions.py")
DECLARED = "one-body assembly"


def long_functions(source: str, name: str = "<source>") -> list[str]:
    """``file:line name (n lines)`` of every function over :data:`MAX_LINES` that does not
    declare itself a one-body assembly."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            n = node.end_lineno - node.lineno + 1
            if n > MAX_LINES and DECLARED not in (ast.get_docstring(node) or "").lower():
                out.append(f"{name}:{node.lineno} {node.name} ({n} lines)")
    return out


def _files():
    for entry in PACKAGES:
        p = ROOT / entry
        for f in ([p] if p.is_file() else sorted(p.rglob("*.py"))):
            rel = f.relative_to(ROOT).as_posix()
            if rel not in NOT_HERE:
                yield f, rel


def test_no_function_over_80_lines():
    files = list(_files())
    assert len(files) > 50
    bad = [line for f, rel in files for line in long_functions(f.read_text(encoding="utf-8"),
                                                               rel)]
    assert not bad, "functions over 80 lines (split them into steps):\n" + "\n".join(bad)


def test_the_length_check_can_fail():
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_LINES))
    src = f"def f():\n{body}\n"
    assert long_functions(src) == [f"<source>:1 f ({MAX_LINES + 1} lines)"]
    declared = f'def g():\n    """A one-body assembly."""\n{body}\n'
    assert long_functions(declared) == []
