"""The docs stay true: every project path, ``make`` target, ``morphshell`` subcommand and
option, and dotted ``pysolver``/``sim`` name that ``README.md`` and ``docs/`` mention exists.

A path such as ``sim/frames.npz`` is a file of a build's design folder, not of the source
tree: paths that ``docs/design-folder.md``'s table of files names (and the files under a
folder it names, such as ``report/index.html``) are checked against that table instead."""

from __future__ import annotations

import argparse
import ast
import importlib.util
import re
import shlex
from pathlib import Path

import pytest

from pysolver.cli.parser import make_parser

REPO = Path(__file__).resolve().parent.parent
DOCS = [REPO / "README.md", REPO / "scad" / "README.md",
        *sorted((REPO / "docs").rglob("*.md"))]
TOP = ("pysolver/", "sim/", "scad/", "tests/", "bench/", "docs/", "data/", ".ci/")
_TOPS = "|".join(re.escape(t) for t in TOP)
PATH = re.compile(r"`((?:" + _TOPS + r")[^`\s*<>{}]*)`")
LINK = re.compile(r"\]\(((?!https?:|#|mailto:)[^)\s#]+)")
SOURCE_NAME = re.compile(r"`([A-Za-z_][\w-]*\.(?:py|scad))`")
DOTTED = re.compile(r"`((?:pysolver|sim)(?:\.[A-Za-z_][A-Za-z_0-9]*)+)")
COMMAND = re.compile(r"(?:^|`|\$ |\n)\s*((?:make|morphshell)\b[^`\n#]*)")


def _mentions(pattern) -> list[tuple[str, str]]:
    out = []
    for doc in DOCS:
        for m in pattern.finditer(doc.read_text(encoding="utf-8")):
            out.append((doc.relative_to(REPO).as_posix(), m.group(1)))
    return out


def design_folder_files() -> set[str]:
    """The files and folders of a design folder, as the Files table of
    ``docs/design-folder.md`` names them (``sim/frames.npz``, ``report/``, ...)."""
    text = (REPO / "docs" / "design-folder.md").read_text(encoding="utf-8")
    table = text[text.index("## Files"):]
    table = table[:table.index("\n#", 1)]
    out = set()
    for line in table.splitlines():
        cells = line.strip().strip("|").split("|")
        if len(cells) >= 3:
            out |= set(re.findall(r"`([^`]+)`", cells[0]))
    return out


def _in_design_folder(p: str, names: set[str]) -> bool:
    return p in names or any(n.endswith("/") and p.startswith(n) for n in names)


def test_paths_named_in_the_docs_exist():
    names = design_folder_files()
    assert {"sim/frames.npz", "stencil.obj", "cells.csv"} <= names
    missing = []
    for doc, p in _mentions(PATH):
        p = p.rstrip("/.,:;") if not p.endswith("/") else p
        if not (REPO / p).exists() and not _in_design_folder(p, names):
            missing.append(f"{doc}: {p}")
    for doc, p in _mentions(LINK):
        if not ((REPO / doc).parent / p).exists():
            missing.append(f"{doc}: link {p}")
    assert not missing, "\n".join(missing)


def test_source_files_named_in_the_docs_exist():
    """A bare source file name (``alignment_hole.scad``, ``count_search.py``) is a file of the
    project somewhere."""
    have = {f.name for top in ("pysolver", "sim", "scad", "tests", "bench")
            for f in (REPO / top).rglob("*") if f.is_file()}
    missing = sorted({f"{doc}: {name}" for doc, name in _mentions(SOURCE_NAME)
                      if name not in have})
    assert not missing, "\n".join(missing)


def _resolves(name: str) -> bool:
    """A dotted name is a module, or a module's attribute (read with ast, not imported)."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        mod = ".".join(parts[:k])
        spec = importlib.util.find_spec(mod) if k == 1 or _parent_ok(mod) else None
        if spec is None:
            continue
        rest = parts[k:]
        if not rest:
            return True
        if spec.origin is None or not spec.origin.endswith(".py"):
            return False
        tree = ast.parse(Path(spec.origin).read_text(encoding="utf-8"))
        return _defined(tree, rest)
    return False


def _parent_ok(mod: str) -> bool:
    """``mod``'s parent is a package (only a package has submodules to look for)."""
    try:
        spec = importlib.util.find_spec(mod.rsplit(".", 1)[0])
    except ModuleNotFoundError:
        return False
    return spec is not None and spec.submodule_search_locations is not None


def _defined(tree, names) -> bool:
    body = tree.body
    for i, n in enumerate(names):
        found = None
        for node in body:
            if isinstance(node, (ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef)) \
                    and node.name == n:
                found = node
            elif isinstance(node, (ast.Assign, ast.AnnAssign)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                if any(isinstance(t, ast.Name) and t.id == n for t in targets):
                    return True  # a value: its attributes are not checked
            elif isinstance(node, (ast.Import, ast.ImportFrom)):
                if any((a.asname or a.name.split(".")[0]) == n for a in node.names):
                    return True
        if found is None:
            return False
        if i == len(names) - 1:
            return True
        body = found.body if isinstance(found, ast.ClassDef) else []
        if isinstance(found, ast.ClassDef) and _dataclass_field(found, names[i + 1]):
            return True
    return False


def _dataclass_field(cls: ast.ClassDef, name: str) -> bool:
    return any(isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name)
               and n.target.id == name for n in cls.body)


def test_dotted_names_in_the_docs_exist():
    missing = sorted({f"{doc}: {name}" for doc, name in _mentions(DOTTED)
                      if not _resolves(name.rstrip("."))})
    assert not missing, "\n".join(missing)


def _make_targets() -> set[str]:
    text = (REPO / "Makefile").read_text()
    return set(re.findall(r"^([A-Za-z][\w-]*):", text, flags=re.M))


def _subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = make_parser()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    raise AssertionError("the command line has no subcommands")


def test_commands_in_the_docs_exist():
    targets, subs = _make_targets(), _subcommands()
    bad = []
    for doc, cmd in _mentions(COMMAND):
        try:
            words = shlex.split(cmd.split("|")[0].split(";")[0].split("&&")[0])
        except ValueError:
            continue
        if not words:
            continue
        if words[0] == "make":
            for w in words[1:]:
                if "=" in w or w.startswith("-"):
                    continue
                if w not in targets:
                    bad.append(f"{doc}: `{cmd.strip()}`: no make target {w!r}")
                break
        elif words[0] == "morphshell" and len(words) > 1 and not words[1].startswith(("-", "<")):
            sub = subs.get(words[1])
            if sub is None:
                bad.append(f"{doc}: `{cmd.strip()}`: no subcommand {words[1]!r}")
                continue
            known = {o for a in sub._actions for o in a.option_strings}
            for w in words[2:]:
                if w.startswith("--") and w.split("=")[0] not in known:
                    bad.append(f"{doc}: `{cmd.strip()}`: {words[1]} has no option {w!r}")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("doc", [d.relative_to(REPO).as_posix() for d in DOCS])
def test_doc_is_readable_text(doc):
    text = (REPO / doc).read_text(encoding="utf-8")
    assert text.strip(), doc


# ---------------------------------------------------------------- the README, the front door

README_LINES = 150
"""The README is a front door: what it is, a picture, the commands, the options, the outputs
and links; the rest is in ``docs/`` by topic."""
MADE_BY_MAKE = {".venv", ".venv/bin/morphshell"}
"""Paths the README names that the first ``make`` creates (not in a checkout)."""
FILE_LIKE = re.compile(r"`([^`\s]*(?:/|\.(?:csv|obj|json|npz|html|png|stl|svg|md|lock|toml)))`")


def test_the_readme_is_short():
    n = len((REPO / "README.md").read_text(encoding="utf-8").splitlines())
    assert n < README_LINES, f"README.md has {n} lines: move the details to a page in docs/"


def test_every_path_the_readme_names_exists():
    """Every file or folder the README names in backticks is in the checkout, in a design
    folder (``docs/design-folder.md``'s table; ``build/<shape>/`` is one; ``*`` globs match
    it), or made by ``make`` (:data:`MADE_BY_MAKE`); every picture and page it links too."""
    import fnmatch

    text = (REPO / "README.md").read_text(encoding="utf-8")
    names = design_folder_files()
    named = set(FILE_LIKE.findall(text))
    assert {"stencil.obj", "sim/frames.npz", "docs/usage.md"} <= named   # the pattern sees them
    missing = []
    for p in sorted(named):
        q = p.removeprefix("build/<shape>/")
        if (REPO / p).exists() or p in MADE_BY_MAKE or q == "" or \
                _in_design_folder(q, names) or any(fnmatch.fnmatch(n, q) for n in names):
            continue
        missing.append(p)
    for link in LINK.findall(text):
        if not (REPO / link).is_file():
            missing.append(f"link {link}")
    assert not missing, "README.md names paths that do not exist: " + ", ".join(missing)
