"""Ownership by content (issue 29): a file is morphshell's only if morphshell wrote it, as
recorded (SHA-256 and size) when it was written; everything else in a build folder, put
there at any moment, survives every command.

The design folders are the small ``regular`` patch (design only, about a second).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from _shared import run_cli

from pysolver.cli import main
from pysolver.core import locks, manifest, ownership, staging, writes
from pysolver.errors import EXIT_BAD_INPUT, InputError

SHAPE = "regular:rows=2,cols=2"


_cli = run_cli


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


@pytest.fixture
def design(tmp_path, monkeypatch):
    """A design folder made by ``morphshell design`` (``tmp_path/X``)."""
    monkeypatch.chdir(tmp_path)
    assert main(["--quiet", "design", SHAPE, "--out", "X"]) == 0
    return tmp_path / "X"


def _refused(rc, msg, *patterns):
    assert rc == EXIT_BAD_INPUT, msg
    assert "Traceback" not in msg and "internal error" not in msg, msg
    for p in patterns:
        assert re.search(p, msg), f"{p!r} not in:\n{msg}"


# ---------------------------------------------------------------- adopted, then deleted


def test_a_users_file_is_never_adopted_by_a_failed_stage(design, capsys):
    """The issue's reproduction: compare-scan fails (no simulation) with the user's scan in
    the folder; the former code stamped every file modified since the stage started, and
    the next design deleted the scan."""
    scan = design / "scan.csv"
    scan.write_text("x,y,z\n0,0,0\n1,0,0\n0,1,0\n")
    rc, msg = _cli(["compare-scan", design, scan], capsys)
    assert rc == EXIT_BAD_INPUT, msg
    assert "scan.csv" not in manifest.read_stamp(design)["files"]
    rc, msg = _cli(["design", SHAPE, "--out", design], capsys)
    _refused(rc, msg, r"scan\.csv: not written by morphshell", r"Fix: .*never deletes")
    assert scan.read_text().startswith("x,y,z")


def test_every_file_is_recorded_with_its_hash_and_size(design):
    m = manifest.read_stamp(design)
    assert m["version"] == manifest.STAMP_VERSION
    for rel, (sha, size) in m["files"].items():
        p = design / rel
        assert (_sha(p), p.stat().st_size) == (sha, size), rel
    assert ownership.audit(design) == []


def test_an_edited_file_is_neither_overwritten_nor_deleted(design, capsys):
    cells = design / "cells.csv"
    text = cells.read_text().replace("\n", "\n", 1) + "\n"   # one more blank line
    cells.write_text(text)
    rc, msg = _cli(["program", design], capsys)
    _refused(rc, msg, r"cells\.csv changed since morphshell wrote it: morphshell will not "
                      r"overwrite it", r"Fix: move it out")
    rc, msg = _cli(["design", SHAPE, "--out", design], capsys)
    _refused(rc, msg, r"cells\.csv: changed since morphshell wrote it")
    assert cells.read_text() == text


def test_stage_commands_do_not_ignore_ownership_when_the_stamp_is_gone(design, capsys):
    (design / manifest.STAMP_NAME).unlink()
    before = {p.name: _sha(p) for p in design.iterdir() if p.is_file()}
    for stage in ("program", "simulate", "report", "render"):
        rc, msg = _cli([stage, design], capsys)
        _refused(rc, msg, rf"{design} has no \.morphshell-build stamp: morphshell cannot tell "
                          r"its files from yours")
    assert {p.name: _sha(p) for p in design.iterdir() if p.is_file()} == before


def test_an_older_stamp_without_hashes_is_not_trusted(design, capsys):
    names = sorted(manifest.read_stamp(design)["files"])
    (design / manifest.STAMP_NAME).write_text(json.dumps({"made_by": "morphshell", "files": names}))
    rc, msg = _cli(["design", SHAPE, "--out", design], capsys)
    _refused(rc, msg, r"made by an older morphshell that did not record file contents")
    assert (design / "cells.csv").is_file()


def test_empty_subfolders_are_the_users(tmp_path, design, capsys):
    room = tmp_path / "only-empty"
    (room / "a" / "b").mkdir(parents=True)
    rc, msg = _cli(["design", SHAPE, "--out", room], capsys)
    _refused(rc, msg, r"only-empty is not a morphshell build folder \(a: not made")
    assert (room / "a" / "b").is_dir()
    (design / "plans").mkdir()                        # a user's empty folder in a build
    rc, msg = _cli(["design", SHAPE, "--out", design], capsys)
    _refused(rc, msg, r"plans: a folder morphshell did not make")
    assert (design / "plans").is_dir()


def test_a_copy_of_an_own_subfolder_is_the_users(design, capsys):
    """A copy keeps the stamp inside, but the build folder's manifest does not list it."""
    with staging.atomic_dir(design / "stl") as tmp:
        (tmp / "top.stl").write_text("solid top\nendsolid top\n")
    assert "stl" in manifest.read_stamp(design)["dirs"]
    shutil.copytree(design / "stl", design / "stl-printed")
    rc, msg = _cli(["design", SHAPE, "--out", design], capsys)
    _refused(rc, msg, r"stl-printed: a folder morphshell did not make")
    assert (design / "stl-printed" / "top.stl").is_file()


def test_hard_links_into_and_out_of_a_build_folder(tmp_path, design, capsys):
    mine = tmp_path / "mine.txt"
    mine.write_text("my notes\n")
    os.link(mine, design / "notes.txt")              # the user's file, linked in
    rc, msg = _cli(["design", SHAPE, "--out", design], capsys)
    _refused(rc, msg, r"notes\.txt: not written by morphshell")
    (design / "notes.txt").unlink()
    keep = tmp_path / "cells-v1.csv"
    os.link(design / "cells.csv", keep)               # a link to morphshell's file, kept out
    old = keep.read_text()
    rc, msg = _cli(["design", SHAPE, "--out", design, "--vertices", "50"], capsys)
    assert rc == EXIT_BAD_INPUT                       # (regular refuses --vertices: no build)
    rc, msg = _cli(["design", SHAPE, "--out", design], capsys)
    assert rc == 0, msg
    assert keep.read_text() == old                    # replaced by rename, never in place


# ---------------------------------------------------------------- symbolic links


def test_a_planted_link_at_a_temporary_name_is_never_followed(tmp_path, design, capsys):
    victim = tmp_path / "victim"
    victim.write_text("precious\n")
    for name in ("cells.csv.tmp", ".cells.csv.tmp", "time_landscape.csv.tmp"):
        os.symlink(victim, design / name)
    rc, msg = _cli(["program", design], capsys)
    # the links are the user's: the stage runs, writes around them and touches neither
    assert victim.read_text() == "precious\n"
    assert not (design / "cells.csv").is_symlink()
    assert rc in (0, EXIT_BAD_INPUT), msg


@pytest.mark.parametrize("where", ["cells.csv", "sim", manifest.STAMP_NAME])
def test_links_in_the_folder_are_refused_not_followed(tmp_path, design, capsys, where):
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "keep.txt").write_text("precious\n")
    target = victim / "keep.txt" if where != "sim" else victim
    if (design / where).exists():
        (design / where).unlink()
    os.symlink(target, design / where)
    stage = "program" if where != "sim" else "simulate"
    rc, msg = _cli([stage, design, *(["--t-end", "1"] if stage == "simulate" else [])],
                   capsys)
    assert rc == EXIT_BAD_INPUT, msg
    assert "Traceback" not in msg
    assert (victim / "keep.txt").read_text() == "precious\n"
    assert sorted(p.name for p in victim.iterdir()) == ["keep.txt"]


def test_a_planted_lock_link_does_not_truncate_its_target(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    victim = tmp_path / "victim"
    victim.write_text("precious\n")
    (tmp_path / "build").mkdir()
    os.symlink(victim, tmp_path / "build" / f".{SHAPE}.morphshell-lock")
    rc, msg = _cli(["design", SHAPE], capsys)
    _refused(rc, msg, r"cannot open the lock file")
    assert victim.read_text() == "precious\n"


# ---------------------------------------------------------------- kills and full disks


def test_a_killed_write_leaves_the_old_file_and_a_rebuild_works(design, capsys):
    """A stage killed while writing (after its temporary file was made, before the rename)
    and one killed after the rename but before its stamp update is read back: the folder
    holds the old file or the new one, and both are morphshell's."""
    cells = design / "cells.csv"
    old = _sha(cells)
    cm = writes.atomic_file(cells)
    tmp = cm.__enter__()                              # a kill: no __exit__, no clean-up
    tmp.write_text("half")
    assert _sha(cells) == old
    cm2 = writes.atomic_file(design / "sim" / "checkpoint.npz")
    np.savez(cm2.__enter__(), k=np.arange(3))         # a killed simulate's checkpoint
    assert ownership.audit(design) == []
    rc, msg = _cli(["design", SHAPE, "--out", design], capsys)
    assert rc == 0, msg
    assert not list(design.glob(".*tmp*")) and ownership.audit(design) == []


def test_a_full_disk_leaves_the_old_file_and_no_temporary(design):
    cells = design / "cells.csv"
    old = cells.read_bytes()
    with pytest.raises(OSError, match="No space left"):
        with writes.atomic_file(cells) as tmp:
            tmp.write_text("partial")
            raise OSError(28, "No space left on device")
    assert cells.read_bytes() == old
    hidden = sorted(p.name for p in design.iterdir() if p.name.startswith("."))
    assert hidden == [manifest.STAMP_NAME]
    assert ownership.audit(design) == []


def test_a_rename_killed_after_the_record_is_still_recognised(design):
    """The new hash is recorded before the rename, the old one kept as ``prev``."""
    cells = design / "cells.csv"
    m = manifest.read_stamp(design)
    new = b"cell_id\n"
    rec = [hashlib.sha256(new).hexdigest(), len(new)]
    with manifest.folder_lock(design):
        manifest.store_stamp(design, dict(m, files={**m["files"], "cells.csv": rec},
                                   prev={"cells.csv": m["files"]["cells.csv"]}), m)
    assert ownership.audit(design) == []                        # still the old file: ours
    cells.write_bytes(new)
    assert ownership.audit(design) == []                        # the new one: ours too


# ---------------------------------------------------------------- stale runs


def test_stale_run_folders_are_recognised_by_their_stamp_not_their_name(tmp_path):
    parent = tmp_path / "build"
    dst = parent / "petal"
    with staging.atomic_dir(dst) as tmp:
        (tmp / "summary.json").write_text("old complete\n")
    # the state after replace_dir's first rename: the old folder moved aside, dst absent
    tok = manifest.new_token()
    aside = manifest.make_private(parent, f".petal.old-{tok}", role="old", token=tok,
                                 **{"for": "petal"})
    os.replace(dst, aside / "petal")
    tok2 = manifest.new_token()
    killed = manifest.make_private(parent, f".petal.tmp-{tok2}", role="tmp", token=tok2,
                                  **{"for": "petal"})
    (killed / "cells.csv").write_text("half\n")
    for name in (".petal.tmp-notes", ".petal.old-2023", f".petal.tmp-{manifest.new_token()}"):
        (parent / name).mkdir()
        (parent / name / "mine.txt").write_text("keep me\n")
    forged = parent / f".petal.tmp-{manifest.new_token()}"   # a copy of a build, renamed
    shutil.copytree(aside / "petal", forged)
    with locks.build_lock(dst):
        done = staging.recover_stale(dst)
    assert (dst / "summary.json").read_text() == "old complete\n"
    assert not aside.exists() and not killed.exists() and len(done) == 3
    names = sorted(p.name for p in parent.iterdir())
    assert names == sorted([".petal.tmp-notes", ".petal.old-2023", forged.name, "petal"]
                           + [n for n in names if n.startswith(".petal.tmp-")
                              and n not in (".petal.tmp-notes", forged.name)])
    assert (parent / ".petal.old-2023" / "mine.txt").read_text() == "keep me\n"


def test_staging_is_recognised_by_stamp_and_kept_for_a_week(tmp_path, monkeypatch):
    parent = tmp_path / "build"
    parent.mkdir()
    now = time.time()
    monkeypatch.setattr(staging.time, "time", lambda: now - 8 * 24 * 3600)
    staging.open_staging(staging.staging_dir(parent / "old"), inputs_sha256="a")       # 8 days old
    monkeypatch.setattr(staging.time, "time", lambda: now - 2 * 24 * 3600)
    staging.open_staging(staging.staging_dir(parent / "recent"), inputs_sha256="b")    # 2 days old
    monkeypatch.setattr(staging.time, "time", lambda: now)
    mine = parent / ".notes.morphshell-staging"                          # the user's
    mine.mkdir()
    (mine / "n.txt").write_text("keep\n")
    os.utime(mine, (now - 1e8, now - 1e8))
    done = staging.clean_stale_siblings(parent / "petal")
    assert [p.name for p in done] == [".old.morphshell-staging"]
    assert sorted(p.name for p in parent.iterdir()) == [".notes.morphshell-staging",
                                                        ".recent.morphshell-staging"]
    assert staging.STALE_STAGING_S == 7 * 24 * 3600
    with pytest.raises(InputError, match="not a staging folder of morphshell's"):
        staging.open_staging(staging.staging_dir(parent / "notes"), inputs_sha256="c")
    assert (mine / "n.txt").is_file()


def test_a_users_file_in_a_replaced_folder_is_kept(tmp_path):
    dst = tmp_path / "out"
    with staging.atomic_dir(dst) as tmp:
        (tmp / "a.txt").write_text("a\n")
    new = tmp_path / "new"
    new.mkdir()
    manifest.start_stamp(new)
    staging.seal(new)
    real_claim = staging.claim_output               # (the name replace_dir calls)

    def late(d, **kw):                                # the user writes right after the check
        out = real_claim(d, **kw)
        (dst / "late.txt").write_text("mine\n")
        return out

    staging.claim_output = late
    try:
        with pytest.warns(UserWarning, match="kept 1 file"):
            staging.replace_dir(new, dst)
    finally:
        staging.claim_output = real_claim
    kept = list(tmp_path.glob(".out.old-*/out/late.txt"))
    assert len(kept) == 1 and kept[0].read_text() == "mine\n"


def test_nested_and_result_folders(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    (out / "a.csv").write_text("x\n")
    with pytest.raises(InputError, match="not a morphshell build folder"):
        ownership.claim_output(out)
    (out / "a.csv").unlink()
    manifest.start_stamp(out)
    writes.atomic_write_text(out / "a.csv", "x\n")
    writes.atomic_write_text(out / "sub" / "b.csv", "y\n")   # a folder made in place is recorded
    assert manifest.read_stamp(out)["dirs"] == ["sub"] and ownership.foreign_files(out) == []
    (out / "sub" / "c.csv").write_text("user\n")
    assert ownership.foreign_files(out) == [out / "sub" / "c.csv"]
    assert ownership.claim_output(out / "sub2") == out / "sub2"
