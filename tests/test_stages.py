"""The pipeline as data (:mod:`pysolver.stages`): the table declares the stages, the build
runs them in its order, the command line is generated from it, and a new stage is one
entry and one module (``docs/for-contributors.md``)."""

from __future__ import annotations

import dataclasses
import json

import pytest

from pysolver import stages
from pysolver.cli import main
from pysolver.cli.commands import build_options
from pysolver.cli.parser import make_parser, stages_help
from pysolver.cli.table import TOOLS
from pysolver.core.writes import atomic_write_text
from pysolver.stages import OPTIONS, STAGES, BuildOptions, Stage, StageContext
from pysolver.tables import read_table

TINY = "regular:rows=1,cols=2"


def _sub(name):
    ap = make_parser()
    return ap._subparsers._group_actions[0].choices[name]


def test_every_stage_option_is_declared_and_a_build_option_or_converted():
    fields = {f.name for f in dataclasses.fields(BuildOptions)}
    converted = set(stages.PHYSICS_OPTIONS[1:]) | {"min_bumper", "min_gap", "max_cell_length"}
    for s in STAGES:
        for o in s.options:
            assert o in OPTIONS, (s.name, o)
            assert o in fields | converted, (s.name, o)
        assert set(s.needs) <= fields, s.name
        assert {d for d in s.depends if d not in ("scad", "material")} <= fields, s.name
    assert len({s.name for s in STAGES}) == len(STAGES)


def test_the_cli_is_generated_from_the_table():
    text = stages_help()
    for s in STAGES:
        assert f"  {s.name} " in text and ", ".join(s.writes) in text
        if s.command:
            sub = _sub(s.name)
            dests = {a.dest for a in sub._actions}
            assert {OPTIONS[o].dest for o in s.options} <= dests, s.name
    for c in TOOLS:
        assert c.name in text and _sub(c.name)
    assert "refine" not in make_parser()._subparsers._group_actions[0].choices  # build only


def test_cli_defaults_are_the_build_options_defaults():
    from pysolver.design import unit_cell_options

    args = make_parser().parse_args(["build", "petal"])
    opts = build_options(args)
    assert opts == BuildOptions(params=unit_cell_options())
    args = make_parser().parse_args(["--quiet", "build", "petal", "--no-sim", "--no-render",
                                     "--t-end", "30", "--max-cell-length", "8", "--debug"])
    opts = build_options(args)
    assert not (opts.simulate or opts.render or opts.progress) and opts.keep_failed
    assert opts.t_end == 30.0 and opts.params.max_cell_length == 8.0
    sim = build_options(make_parser().parse_args(["simulate", "d", "--no-resume",
                                              "--physics", "gravity"]))
    assert sim.resume is False and sim.physics.switched_on() == ["gravity"]


def test_which_stages_a_build_runs():
    every = [s.name for s in STAGES]
    assert every[:3] == ["design", "program", "simulate"]
    assert every.index("refine") < every.index("render") < every.index("report")

    def skipped(**kw):
        return {s.name for s in STAGES if not s.wanted(BuildOptions(**kw))}

    assert skipped() == set()
    assert skipped(refine=0, render=False) == {"refine", "render"}
    assert skipped(program=False) == {"program", "refine"}
    assert skipped(simulate=False) == {"simulate", "refine", "report"}


def preview(ctx: StageContext) -> dict:
    """The example stage of docs/for-contributors.md, here a test module's function."""
    n = len(read_table(ctx.folder, "bases")["base_id"])
    atomic_write_text(ctx.folder / "preview.txt", f"{ctx.name}: {n} bases\n")
    return {"bases": n}


def test_a_new_stage_is_one_table_entry(tmp_path, monkeypatch):
    """A stage added to the table runs in a build (its output lands in the folder, its
    result in summary.json) and gets its subcommand, with no other change."""
    from pysolver.build import build

    extra = Stage("preview", f"{__name__}:preview", "count the bases",
                  reads=("bases.csv",), writes=("preview.txt",))
    table = (*STAGES[:1], extra, *STAGES[1:])
    monkeypatch.setattr(stages, "STAGES", table)
    monkeypatch.setattr("pysolver.build.STAGES", table)
    monkeypatch.setattr("pysolver.cli.parser.STAGES", table)
    monkeypatch.setattr("pysolver.cli.table.STAGES", table)
    s = build(TINY, out=tmp_path / "b", program=False, simulate=False, render=False,
              progress=False)
    assert list(s["stages"])[:2] == ["design", "preview"]
    assert (tmp_path / "b" / "preview.txt").read_text() == f"{TINY}: 4 bases\n"
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["stages"]["preview"] \
        == {"bases": 4}
    assert "preview.txt" in stages_help()
    (tmp_path / "b" / "preview.txt").unlink()
    assert main(["--quiet", "preview", str(tmp_path / "b")]) == 0     # its subcommand
    assert (tmp_path / "b" / "preview.txt").read_text() == "b: 4 bases\n"


def test_a_failing_stage_is_named_and_leaves_nothing(tmp_path, monkeypatch):
    from pysolver.build import build
    from pysolver.errors import InputError

    def broken(ctx):
        raise InputError(f"{ctx.folder}/bases.csv: no", fix="none")

    monkeypatch.setattr(f"{__name__}.preview", broken)
    extra = Stage("preview", f"{__name__}:preview", "fails")
    monkeypatch.setattr("pysolver.build.STAGES", (*STAGES[:1], extra))
    with pytest.raises(InputError, match=r"preview stage: bases\.csv: no") as e:
        build(TINY, out=tmp_path / "b", progress=False)
    assert "nothing was written" in str(e.value) and not (tmp_path / "b").exists()
