"""One of each piece of plumbing, read from the source with ``ast`` (nothing is imported):

* atomic writes: only the plumbing, :mod:`pysolver.core`, renames files into place;
* JSON records: only :mod:`pysolver.core.records` encodes what ``json`` cannot
  (``json.dumps(default=...)``), besides the content fingerprint of
  :mod:`pysolver.distributed`, which hashes ``bytes`` by content and hands the rest to it;
* completion: one function called ``completion_times`` (:mod:`sim.model.collisions`);
* provenance: the runtime stages read package versions only through
  :mod:`pysolver.core.provenance`;
* progress: :class:`pysolver.core.progress.Steps` counts and prints ``[stage] subject: k/n ...``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from pysolver.core.progress import Steps, duration, line

ROOT = Path(__file__).resolve().parents[1]
SOURCES = sorted([*ROOT.glob("pysolver/**/*.py"), *ROOT.glob("sim/**/*.py")])


def _rel(p: Path) -> str:
    return p.relative_to(ROOT).as_posix()


def _calls(path: Path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call):
            yield node


def _dotted(node) -> str:
    if isinstance(node, ast.Attribute):
        return f"{_dotted(node.value)}.{node.attr}"
    return node.id if isinstance(node, ast.Name) else "?"


def test_sources_are_found():
    assert len(SOURCES) > 60


def test_only_atomic_moves_files_into_place():
    bad = [f"{_rel(p)}:{c.lineno} {_dotted(c.func)}" for p in SOURCES
           if not _rel(p).startswith("pysolver/core/") for c in _calls(p)
           if _dotted(c.func) in ("os.replace", "os.rename", "shutil.move")
           or (isinstance(c.func, ast.Attribute) and c.func.attr == "rename")]
    assert not bad, "write through pysolver.core.writes.atomic_file:\n" + "\n".join(bad)


def test_one_json_encoder():
    allowed = {"pysolver/core/records.py", "pysolver/distributed.py"}
    bad = [f"{_rel(p)}:{c.lineno}" for p in SOURCES if _rel(p) not in allowed
           for c in _calls(p) if _dotted(c.func) in ("json.dumps", "json.dump")
           and any(k.arg in ("default", "cls") for k in c.keywords)]
    classes = [f"{_rel(p)}:{n.lineno}" for p in SOURCES
               for n in ast.walk(ast.parse(p.read_text())) if isinstance(n, ast.ClassDef)
               and any(_dotted(b).endswith("JSONEncoder") for b in n.bases)]
    assert not bad + classes, "encode through pysolver.core.records:\n" + "\n".join(bad + classes)


def test_one_completion_rule():
    """Completion of the simulated cells from the frames: one function, one name.  (The
    temporal stage's ``completion_time`` predicts one bracket from the material model.)"""
    defs = [f"{_rel(p)}:{n.lineno}" for p in SOURCES
            for n in ast.walk(ast.parse(p.read_text()))
            if isinstance(n, ast.FunctionDef) and "completion" in n.name
            and n.name not in ("read_completion_frames", "completion_time")]
    assert len(defs) == 1 and defs[0].startswith("sim/model/collisions.py:"), defs


def test_versions_come_from_provenance():
    offline = ("pysolver/fitting/",)  # the offline fits record their own tool versions
    bad = []
    for p in SOURCES:
        if _rel(p) == "pysolver/core/provenance.py" or _rel(p).startswith(offline):
            continue
        for n in ast.walk(ast.parse(p.read_text())):
            names = ([a.name for a in n.names] if isinstance(n, ast.Import)
                     else [n.module or ""] if isinstance(n, ast.ImportFrom) else [])
            if any(m.startswith("importlib.metadata") for m in names):
                bad.append(f"{_rel(p)}:{n.lineno}")
    assert not bad, "read versions through pysolver.core.provenance:\n" + "\n".join(bad)


def test_progress_lines_count_and_estimate(capsys):
    steps = Steps("simulate", "petal", 4)
    for k in range(4):
        steps.step(f"t={k}")
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "[simulate] petal: 1/4 t=0  ETA 0 s"
    assert [e.split(" ", 3)[2] for e in err] == ["1/4", "2/4", "3/4", "4/4"]
    assert line("build", "petal", "design ...") == "[build] petal: design ..."
    assert line("render", "", "auto") == "[render] auto"
    quiet = Steps("report", "x", 2, enabled=False)
    quiet.step()
    assert capsys.readouterr().err == ""
    assert quiet.eta_s() == pytest.approx(quiet.durations[0])


@pytest.mark.parametrize("s,text", [(0.4, "0 s"), (48, "48 s"), (125, "2m05s"),
                                    (3725, "1h02m"), (float("nan"), "?")])
def test_duration_words(s, text):
    assert duration(s) == text


def test_the_studio_reads_the_progress_events(capsys):
    """The studio's progress bar reads structured events (issue #46 item 4): the JSON lines
    :func:`pysolver.core.progress.emit_events` writes beside the text lines (the build's stage
    starts and the ``k/n`` counts of the stages), never the text itself
    (:func:`pysolver.studio.jobs.progress_event`); anything else on the stream is not an
    event."""
    import io

    from pysolver.core import progress
    from pysolver.core.progress import say
    from pysolver.studio.server import progress_event

    out = io.StringIO()
    progress.emit_events(out)
    try:
        say("build", "regular:rows=2", "simulate ...", starts="simulate")
        Steps("simulate", "regular:rows=2", 240).step("t=   0.5 s  newton   2")
        Steps("refine", "petal", 2).step("rms 1.20 s")
        Steps("render", "fast parts", 118).step()
        say("build", "petal", "simulate done in 3.0 s")
        say("report", "petal", "quiet", enabled=False)
    finally:
        progress.emit_events(None)
    evs = [progress_event(x) for x in out.getvalue().splitlines()]
    assert [(e["event"], e["stage"], e.get("starts"), e.get("k"), e.get("n")) for e in evs] == [
        ("stage", "build", "simulate", None, None), ("line", "simulate", None, 1, 240),
        ("line", "refine", None, 1, 2), ("line", "render", None, 1, 118),
        ("line", "build", None, None, None)]
    # the text lines are as before, and each event carries its line
    assert [e["text"] for e in evs] == capsys.readouterr().err.splitlines()
    assert [progress_event(x) for x in ("simulation check: PASS", "[1, 2]",
                                        '{"event": "line", "stage": "x", "text": "t", '
                                        '"k": 1, "n": 0}')] == [None, None, None]
