"""One owner per file: ``docs/design-folder.md`` names the function that writes each table and
record of the design folder, and the code agrees (read with ``ast``, nothing is imported).

Every call of a writer (``write_table`` with its table kind, ``write_stencil``, ``write_model``,
``atomic_write_text``, ``atomic_file``, ``_write_json``) whose file name is known from the source
(a string, a module-level constant, ``tables.FILENAMES[...]``, a table kind) is attributed to
the function that makes it.  For every file whose row of the docs' Files table names functions
(``pysolver.x.y``), the writers in the code are exactly those (pictures, whose names are built
at run time, only need their named writer to exist); every design-folder file written in the
code is a row of the table.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "design-folder.md"
WRITE_CALLS = {"write_table", "write_stencil", "write_model", "atomic_write_text", "atomic_file",
               "_write_json"}
FIXED_NAMES = {"write_stencil": "stencil.obj", "write_model": "model.npz"}
# the generic writers themselves (they write whatever path they are given)
GENERIC = {"pysolver.tables.write_table", "pysolver.tables.write_stencil",
           "pysolver.tables.write_model", "pysolver.design.pipeline._write_json"}


def _module_strings(tree: ast.Module) -> dict:
    """Module-level ``NAME = "text"`` and ``NAME = {"key": "text", ...}`` constants."""
    out = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 \
                and isinstance(node.targets[0], ast.Name):
            try:
                value = ast.literal_eval(node.value)
            except ValueError:
                continue
            if isinstance(value, (str, dict)):
                out[node.targets[0].id] = value
    return out


TABLES = _module_strings(ast.parse((ROOT / "pysolver" / "tables.py").read_text()))


def _text(node, consts: dict):
    """The string an expression stands for, when the source tells it; else None."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.Name):
        v = consts.get(node.id)
        return v if isinstance(v, str) else None
    if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
            and node.value.id == "tables":
        v = TABLES.get(node.attr)
        return v if isinstance(v, str) else None
    if isinstance(node, ast.Subscript):  # FILENAMES["cells"] or tables.FILENAMES["cells"]
        base = node.value
        name = base.attr if isinstance(base, ast.Attribute) else getattr(base, "id", None)
        key = _text(node.slice, consts)
        table = consts.get(name) if isinstance(consts.get(name), dict) else TABLES.get(name)
        if isinstance(table, dict) and key in table:
            return table[key]
    return None


def _path(node, consts: dict) -> str | None:
    """``folder / "sim" / NAME`` -> ``"sim/<NAME>"``: the parts after the first that the
    source tells (the first is the folder); None when a part is unknown."""
    parts = []
    while isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div):
        t = _text(node.right, consts)
        if t is None:
            return None
        parts.append(t)
        node = node.left
    if not parts:
        return None
    if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "Path":
        node = node.args[0] if node.args else node
    return "/".join(reversed(parts))


def _written_file(call: ast.Call, name: str, consts: dict) -> str | None:
    if name in FIXED_NAMES:
        return FIXED_NAMES[name]
    if name == "write_table" and len(call.args) >= 2:
        kind = _text(call.args[1], consts)
        filenames = TABLES.get("FILENAMES", {})
        if kind in filenames:
            return filenames[kind]
    return _path(call.args[0], consts) if call.args else None


def writers_in(source: str, module: str) -> dict[str, set[str]]:
    """file name -> the functions (``module.func`` or ``module.Class.method``) that write it."""
    tree = ast.parse(source)
    consts = _module_strings(tree)
    out: dict[str, set[str]] = {}

    def visit(node, qual):
        for child in ast.iter_child_nodes(node):
            q = qual
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                q = f"{qual}.{child.name}"
            if isinstance(child, ast.Call):
                f = child.func
                name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", None)
                if name in WRITE_CALLS and q not in GENERIC:
                    file = _written_file(child, name, consts)
                    if file is not None:
                        out.setdefault(file, set()).add(q)
            visit(child, q)

    visit(tree, module)
    return out


def _modules():
    """(dotted module name parts, source text) of every module of pysolver and sim."""
    for top in ("pysolver", "sim"):
        for path in sorted((ROOT / top).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            yield parts, path.read_text(encoding="utf-8")


def code_writers() -> dict[str, set[str]]:
    out: dict[str, set[str]] = {}
    for parts, text in _modules():
        for file, funcs in writers_in(text, ".".join(parts)).items():
            out.setdefault(file, set()).update(funcs)
    return out


def _functions() -> set[str]:
    """Every function and method of the project, as dotted names."""
    out = set()
    for parts, text in _modules():
        for node in ast.parse(text).body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                out.add(".".join(parts + [node.name]))
            elif isinstance(node, ast.ClassDef):
                out |= {".".join(parts + [node.name, m.name]) for m in node.body
                        if isinstance(m, (ast.FunctionDef, ast.AsyncFunctionDef))}
    return out


def _module_names() -> set[str]:
    """Every module-level name of the project (functions, classes, constants), dotted."""
    out = set()
    for parts, text in _modules():
        for node in ast.parse(text).body:
            targets = ([node] if isinstance(node, (ast.FunctionDef, ast.ClassDef)) else
                       node.targets if isinstance(node, ast.Assign) else [])
            for t in targets:
                name = getattr(t, "name", None) or getattr(t, "id", None)
                if name:
                    out.add(".".join(parts + [name]))
    return out


def doc_writers() -> dict[str, set[str]]:
    """file -> the functions that the "written by" column of the docs' Files table names."""
    functions, names = _functions(), _module_names()
    text = DOC.read_text(encoding="utf-8")
    table = text[text.index("## Files"):]
    table = table[:table.index("\n#", 1)]
    out = {}
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 3 or not cells[0].startswith("`"):
            continue
        dotted = set(re.findall(r"`((?:pysolver|sim)\.[\w.]+)`", cells[1]))
        unknown = dotted - functions - names
        assert not unknown, f"docs/design-folder.md, {cells[0]}: no such name {sorted(unknown)}"
        for file in re.findall(r"`([^`]+)`", cells[0]):
            out[file] = dotted & functions
    return out


def test_the_scan_finds_writers():
    src = ('from pysolver import tables\nSTAGE = "x.json"\n'
           'def f(d):\n    tables.write_table(d / "cells.csv", "cells", {})\n'
           'class A:\n    def w(self, d):\n        atomic_write_text(d / "sim" / STAGE, "")\n'
           'def g(d):\n    tables.write_table(d / tables.FILENAMES["bases"], "bases", {})\n')
    assert writers_in(src, "m") == {"cells.csv": {"m.f"}, "sim/x.json": {"m.A.w"},
                                    "bases.csv": {"m.g"}}


def test_every_table_has_its_documented_writers():
    code, doc = code_writers(), doc_writers()
    assert {"stencil.obj", "cells.csv", "time_landscape.csv", "design.json"} <= set(code)
    bad = []
    for file, named in sorted(doc.items()):
        if file.endswith(".png"):
            continue  # pictures: their names are built at run time; the writer is named
        if named and code.get(file, set()) != named:
            bad.append(f"{file}: docs/design-folder.md names {sorted(named)}, the code writes "
                       f"it in {sorted(code.get(file, set()))}")
    assert not bad, "\n".join(bad)


def test_shared_tables_have_one_writer_function():
    """The two tables that later stages update have one writer function each (besides the
    design stage's first write of ``cells.csv``)."""
    code = code_writers()
    assert code["time_landscape.csv"] == {"pysolver.design.time_landscape.write_landscape"}
    assert code["cells.csv"] == {"pysolver.design.pipeline.write_design_tables",
                                 "pysolver.tables.update_cells"}


def test_every_written_design_file_is_documented():
    doc = set(doc_writers())
    names = set(TABLES.get("FILENAMES", {}).values()) | {"stencil.obj", "model.npz",
                                                          "design.json", "temporal.json"}
    missing = sorted(f for f in code_writers() if f in names and f not in doc)
    assert not missing, f"written in the code but not in docs/design-folder.md: {missing}"
