"""The settings package (:mod:`pysolver.params`): every field documented, one name per setting.

* every dataclass of the package documents each of its fields, in its ``Attributes`` section
  (numpy style: ``name : type[, unit]`` and a description below) or beside the value (a string
  right after the field: ``type[, unit]: description``), and says where its values come from
  (a ``Source`` sentence);
* every default instance the package exports is an instance of one of its classes;
* no module of the project re-exports a setting under another name at module level
  (``NAME = UNIT_CELL.base_r``): code reads ``UNIT_CELL.base_r`` where it needs it, so a
  setting has one name.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import re
import textwrap
from pathlib import Path

import pytest

import pysolver.params as params

ROOT = Path(__file__).resolve().parents[1]
CLASSES = [v for v in vars(params).values()
           if inspect.isclass(v) and dataclasses.is_dataclass(v)
           and v.__module__.startswith("pysolver.params.")]
INSTANCES = {k: v for k, v in vars(params).items()
             if dataclasses.is_dataclass(v) and not inspect.isclass(v)}


def _beside_values(cls) -> dict[str, str]:
    """field name -> the string right after the field in the class body (its description
    beside its value), read with ``ast``; a class made of topic classes (a dataclass that
    inherits settings dataclasses, as ``StencilSearch``) has its fields beside their values
    in those."""
    out = {}
    for c in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(c):
            continue
        body = ast.parse(textwrap.dedent(inspect.getsource(c))).body[0].body
        out.update({a.target.id: b.value.value for a, b in zip(body, body[1:], strict=False)
                    if isinstance(a, ast.AnnAssign) and isinstance(b, ast.Expr)
                    and isinstance(b.value, ast.Constant) and isinstance(b.value.value, str)})
    return out


def _documented(cls) -> dict[str, str]:
    """field name -> its description, from the ``Attributes`` section of the docstring or
    beside the values (:func:`_beside_values`)."""
    beside = _beside_values(cls)
    if beside:
        return beside
    doc = inspect.getdoc(cls) or ""
    part = doc.split("Attributes\n----------\n", 1)
    assert len(part) == 2, f"{cls.__name__}: no Attributes section"
    out, current = {}, []
    for line in part[1].splitlines():
        m = re.match(r"^([a-z][A-Za-z_0-9]*(?:, [a-z][A-Za-z_0-9]*)*) : \S", line)
        if m:
            current = m.group(1).split(", ")
            for n in current:
                out[n] = ""
        elif line.startswith("    ") and current:
            for n in current:
                out[n] += line.strip() + " "
        elif line and not line.startswith(" "):
            current = []
    return out


def test_the_package_has_its_classes():
    names = {c.__name__ for c in CLASSES}
    assert {"UnitCell", "StencilSearch", "SimConstants", "NewtonSettings", "Tolerances",
            "Limits", "ReportThresholds", "Programming"} <= names
    for name, inst in INSTANCES.items():
        assert type(inst) in CLASSES, f"{name} is not an instance of a settings class"


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_every_field_is_documented(cls):
    doc = _documented(cls)
    fields = [f.name for f in dataclasses.fields(cls)]
    missing = [f for f in fields if f not in doc]
    assert not missing, f"{cls.__name__}: fields without documentation: {missing}"
    empty = [f for f in fields if len(doc[f].split()) < 2]
    assert not empty, f"{cls.__name__}: fields without a description: {empty}"
    stale = sorted(set(doc) - set(fields))
    assert not stale, f"{cls.__name__}: documents fields it does not have: {stale}"
    assert "Source" in (inspect.getdoc(cls) or ""), f"{cls.__name__}: no Source sentence"


def test_thickness_range_is_documented():
    doc = _documented(params.UnitCell)
    assert "printable" in doc["thickness_min"].lower()
    assert params.UNIT_CELL.thickness_min < params.UNIT_CELL.thickness_max


def _instances_and_classes() -> set[str]:
    return set(INSTANCES) | {"tol", "TOL"}


def test_no_module_level_aliases_of_settings():
    """``NAME = SETTINGS.field`` at module level anywhere in the project is an alias."""
    roots = _instances_and_classes()
    bad = []
    for top in ("pysolver", "sim", "bench"):
        for path in sorted((ROOT / top).rglob("*.py")):
            if "params" in path.relative_to(ROOT).parts[:2]:
                continue
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in tree.body:
                if not isinstance(node, (ast.Assign, ast.AnnAssign)) or node.value is None:
                    continue
                v = node.value
                if (isinstance(v, ast.Attribute) and isinstance(v.value, ast.Name)
                        and v.value.id in roots):
                    bad.append(f"{path.relative_to(ROOT)}:{node.lineno}: "
                               f"{ast.unparse(node).splitlines()[0]}")
    assert not bad, "settings re-exported under other names:\n" + "\n".join(bad)


def test_the_alias_check_can_fail(tmp_path):
    tree = ast.parse("from pysolver.params import UNIT_CELL\nBASE_RADIUS = UNIT_CELL.base_r\n")
    node = tree.body[1]
    assert isinstance(node.value, ast.Attribute) and node.value.value.id in \
        _instances_and_classes()
