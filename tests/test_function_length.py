"""No long functions: every function of the packages below fits in 80 lines (its ``def`` to
its last line, docstring included, but for the docstring's ``Examples`` section, which
teaches and is run by ``tests/test_examples.py``), read with ``ast``.

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


def _examples_lines(node) -> int:
    """Lines of the ``Examples`` section of a function's docstring and the blank line before
    it (0 without one)."""
    doc = ast.get_docstring(node, clean=False) or ""
    k = doc.find("Examples\n")
    return doc[k:].rstrip().count("\n") + 2 if k >= 0 else 0


def long_functions(source: str, name: str = "<source>") -> list[str]:
    """``file:line name (n lines)`` of every function over :data:`MAX_LINES` (less its
    ``Examples``) that does not declare itself a one-body assembly."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            n = node.end_lineno - node.lineno + 1 - _examples_lines(node)
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
    example = "\n".join(["    Examples", "    --------", *["    >>> 1"] * 20, "    "])
    taught = f'def h():\n    """Short.\n\n{example}"""\n{body}\n'
    untaught = f'def h():\n    """Short.\n    """\n{body}\n'
    assert long_functions(taught) == long_functions(untaught) == ["<source>:1 h (83 lines)"]
