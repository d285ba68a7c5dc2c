"""Security, third pass (issue #43): no code from the working directory runs in a child
interpreter, no path read from a stamp reaches outside its folder, the studio's token is
seen by no other process or user, the studio refuses before it reads, and the low-severity
holes of the audit.  Each test fails on the code before the fix (``docs/threat-model.md``
lists them per boundary)."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from _shared import run_cli

from pysolver.core.child import PACKAGE_ROOT, python_argv
from pysolver.core.staging import staging_dir

# ------------------------------------------------------------------------------ child Pythons

PLANTED = ("pyvista.py", "numpy.py", "runpy.py", "pysolver/__init__.py", "sim/__init__.py",
           "openscad_evaluator.py", "trimesh.py")
"""Modules a hostile working directory could hold: each writes a marker when imported."""


@pytest.fixture
def hostile_cwd(tmp_path, monkeypatch):
    """A working directory full of planted modules; yields the marker file they write."""
    cwd = tmp_path / "cwd"
    marker = tmp_path / "imported-from-cwd.txt"
    for name in PLANTED:
        p = cwd / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(f"open({str(marker)!r}, 'a').write({name!r} + '\\n')\n")
    monkeypatch.chdir(cwd)
    monkeypatch.setenv("PYTHONPATH", str(cwd))      # ignored by an isolated child too
    return marker


def _planted(marker: Path) -> list[str]:
    return marker.read_text().split() if marker.exists() else []


def test_a_child_python_imports_nothing_from_the_working_directory(hostile_cwd):
    code = ("import sys, numpy, pysolver, sim, runpy\n"
            "print(pysolver.__file__); print(repr(sys.path))")
    r = subprocess.run(python_argv(code=code), capture_output=True, text=True, check=True)
    assert _planted(hostile_cwd) == []
    first, path = r.stdout.splitlines()
    assert first == str(Path(PACKAGE_ROOT) / "pysolver" / "__init__.py")
    assert str(Path.cwd()) not in path and "''" not in path
    # the package root comes after the standard library, once: nothing shadows the stdlib
    order = subprocess.run(python_argv(code="import json, os, sys; print(json.dumps("
                                            "[os.path.dirname(os.__file__), *sys.path]))"),
                           capture_output=True, text=True, check=True).stdout
    stdlib, *paths = json.loads(order)
    assert paths.count(PACKAGE_ROOT) == 1
    assert paths.index(stdlib) < paths.index(PACKAGE_ROOT), paths
    with pytest.raises(ValueError):
        python_argv("pysolver.x; import os")
    with pytest.raises(ValueError):
        python_argv()


def test_the_pyvista_probe_runs_no_planted_module(hostile_cwd):
    from sim.report.plots import _pyvista_status

    ok, why = _pyvista_status.__wrapped__()
    assert _planted(hostile_cwd) == []
    assert ok or "pyvista" in why


def test_a_fast_render_worker_runs_no_planted_module(hostile_cwd, tmp_path):
    from pysolver.render.fast import render_files

    scad = tmp_path / "part.scad"
    scad.write_text("cube([1, 2, 3]);\n")
    ans = render_files([(scad, tmp_path / "part.stl")], jobs=1)
    assert _planted(hostile_cwd) == []
    assert ans[0]["ok"], ans[0]["error"]            # the real worker ran
    assert (tmp_path / "part.stl").stat().st_size > 84


def test_a_studio_run_runs_no_planted_module(hostile_cwd, tmp_path):
    from pysolver.studio.server import Build, Job

    job = Job()
    job.state.update(state="running", started=time.time(), log=[])
    folder = tmp_path / "no-such-build"
    req = json.dumps({"folder": str(folder), "landscape": [1.0], "source": {}})
    job._run(Build(folder), req, ["start", "program", "report"], dict(Job.DEFAULT_S))
    assert _planted(hostile_cwd) == []
    state = job.snapshot()
    # the real rerun module answered: a named error about the folder, not an import failure
    assert state["state"] == "error" and f"{folder}/summary.json" in state["error"], state


# ------------------------------------------------------------------------------ stamps

SHAPE = "regular:rows=2,cols=2"


_cli = run_cli


def _tree(folder: Path) -> dict:
    """Every file under ``folder`` with its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and not p.is_symlink()}


@pytest.fixture
def design(tmp_path, monkeypatch, capsys):
    """A design folder made by ``morphshell design`` (``tmp_path/X``)."""
    monkeypatch.chdir(tmp_path)
    assert _cli(["design", SHAPE, "--out", "X"], capsys)[0] == 0
    return tmp_path / "X"


def _edit_stamp(folder: Path, **changes) -> None:
    from pysolver.core.manifest import STAMP_NAME

    p = folder / STAMP_NAME
    p.write_text(json.dumps(dict(json.loads(p.read_text()), **changes)))


DEAD_PID = 2 ** 30   # above any pid_max: a writer that is gone


@pytest.mark.parametrize("how", ["absolute", "dotdot", "link"])
def test_a_stamp_naming_a_path_outside_its_folder_deletes_nothing(design, tmp_path, capsys,
                                                                   how):
    """Hole 3: a ``pending`` entry (a killed writer's temporary file) that points outside the
    folder, by an absolute path, by ``..`` or through a link, made ``morphshell program``
    delete it.  Now the folder is refused as damaged (exit 2), and nothing is deleted."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    victim = elsewhere / ".victim.tmp-0123456789abcdef"
    victim.write_text("the user's")
    entry = {"absolute": str(victim), "dotdot": f"../elsewhere/{victim.name}",
             "link": f"sub/{victim.name}"}[how]
    if how == "link":
        (design / "sub").symlink_to(elsewhere)
    _edit_stamp(design, pending={entry: DEAD_PID})
    before = _tree(design)
    rc, msg = _cli(["program", design], capsys)
    assert victim.read_text() == "the user's"
    assert _tree(design) == before
    assert rc == 2 and "damaged" in msg and "Traceback" not in msg, msg
    assert entry in msg and "Fix:" in msg


@pytest.mark.parametrize("key, value", [
    ("files", {"../../etc/passwd": ["0" * 64, 1]}),
    ("dirs", ["/tmp"]),
    ("prev", {"a/./b": ["0" * 64, 1]}),
    ("pending", {"cells.csv": DEAD_PID}),     # not a temporary file's name
    ("files", {"cells.csv": "sha"}),
])
def test_every_path_a_stamp_names_is_checked(design, capsys, key, value):
    from pysolver.core.manifest import DamagedFolder, read_stamp

    _edit_stamp(design, **{key: value})
    with pytest.raises(DamagedFolder):
        read_stamp(design)
    before = _tree(design)
    rc, msg = _cli(["program", design], capsys)
    assert rc == 2 and "damaged" in msg and _tree(design) == before, msg


@pytest.mark.parametrize("text", ['{"made_by": "morphshell", "vers', "[1, 2]", ""])
def test_a_damaged_stamp_is_reported_as_damaged(design, capsys, text):
    """LOW: a truncated stamp was reported as "no stamp" or "not made by morphshell"."""
    from pysolver.core.manifest import STAMP_NAME

    (design / STAMP_NAME).write_text(text)
    before = _tree(design)
    for argv in (["program", design], ["design", SHAPE, "--out", design]):
        rc, msg = _cli(argv, capsys)
        assert rc == 2 and "is damaged" in msg, msg
        assert "no .morphshell-build stamp" not in msg and "not a morphshell" not in msg
    assert _tree(design) == before


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to give a file to another user")
def test_another_users_lock_file_is_never_deleted(design, tmp_path, capsys):
    """LOW: root removed other users' ``*.morphshell-lock`` files beside ``--out`` (they hold
    ``pid N`` and no live process locks them, which looked stale)."""
    theirs = tmp_path / ".Y.morphshell-lock"
    theirs.write_text("pid 1234")
    os.chown(theirs, 65534, 65534)              # nobody's
    mine = tmp_path / ".Z.morphshell-lock"
    mine.write_text("pid 1234")
    assert _cli(["design", SHAPE, "--out", "X2"], capsys)[0] == 0
    assert theirs.read_text() == "pid 1234" and not mine.exists()


def test_a_long_out_name_is_refused_with_the_right_fix(tmp_path, monkeypatch, capsys):
    """LOW: a 240-character ``--out`` failed on the lock file's name ("remove the lock file
    if it is a link or a folder"); the name itself is the problem, and nothing is made."""
    monkeypatch.chdir(tmp_path)
    rc, msg = _cli(["design", SHAPE, "--out", "a" * 240], capsys)
    assert rc == 2 and "240 bytes long" in msg and "at most 233" in msg, msg
    assert "give a shorter folder name" in msg and "lock" not in msg.split("Fix:")[1]
    assert list(tmp_path.iterdir()) == []
    assert _cli(["design", SHAPE, "--out", "a" * 233], capsys)[0] == 0


# ------------------------------------------------------------------------------ the studio


def _studio_folder(tmp_path: Path, name: str = "b") -> Path:
    """A folder :func:`pysolver.studio.server.resolve_folders` accepts (the guards tested
    here answer before any table is read)."""
    folder = tmp_path / name
    folder.mkdir()
    for n in ("stencil.obj", "cells.csv", "time_landscape.csv"):
        (folder / n).write_text("")
    return folder


@pytest.fixture
def studio(tmp_path):
    from pysolver.studio.server import StudioServer

    srv = StudioServer([_studio_folder(tmp_path)])
    th = threading.Thread(target=srv.serve_forever, daemon=True)
    th.start()
    yield srv
    srv.shutdown()
    srv.server_close()


def _head(srv, method="POST", path="/api/build/0/preview", token=None, **headers) -> bytes:
    port = srv.server_address[1]
    h = {"Host": f"127.0.0.1:{port}", "Content-Type": "application/json", **headers}
    if token:
        h["X-Morphshell-Token"] = token
    return (f"{method} {path} HTTP/1.1\r\n" + "".join(f"{k}: {v}\r\n" for k, v in h.items())
            + "\r\n").encode("utf-8")


def _reply(sock: socket.socket) -> bytes:
    """Everything the server sends until it closes the connection."""
    out = b""
    while chunk := sock.recv(65536):
        out += chunk
    return out


def _connect(srv) -> socket.socket:
    return socket.create_connection(("127.0.0.1", srv.server_address[1]), timeout=30)


@pytest.mark.parametrize("headers", [{}, {"Host": "evil.example"},
                                     {"Origin": "http://evil.example"}])
def test_a_request_without_the_token_is_refused_before_its_body_is_read(studio, headers):
    """Hole 4: the studio read up to 4 MiB of a body before it checked who sent it.  The
    body is never sent here: an answer proves that the studio did not wait for it."""
    s = _connect(studio)
    token = studio.token if headers else None
    s.sendall(_head(studio, token=token, **{"Content-Length": str(4 << 20), **headers}))
    reply = _reply(s)        # (the old studio waited for 4 MiB: a socket timeout)
    s.close()
    assert reply.startswith(b"HTTP/1.1 403") and b"Connection: close" in reply, reply[:300]


def _request_threads() -> int:
    return sum("process_request_thread" in t.name for t in threading.enumerate())


def test_many_tokenless_connections_hold_a_bounded_number_of_threads(studio):
    """Hole 4: 300 tokenless connections made 304 threads.  Each connection here sends half
    a request and stops; the studio serves at most ``studio_max_connections`` at once."""
    from pysolver.params import LIMITS

    base = _request_threads()
    socks = [_connect(studio) for _ in range(4 * LIMITS.studio_max_connections)]
    for s in socks:
        s.sendall(b"POST /api/builds HTTP/1.1\r\nHost: 127.0.0.1\r\n")
    seen = 0
    for _ in range(100):     # let the accept loop take what it will
        seen = max(seen, _request_threads() - base)
        if seen > LIMITS.studio_max_connections:
            break
        time.sleep(0.02)
    for s in socks:
        s.close()
    assert 0 < seen <= LIMITS.studio_max_connections
    # the slots are free again: the studio answers
    s = _connect(studio)
    s.sendall(_head(studio, "GET", "/api/builds", token=studio.token, Connection="close"))
    assert _reply(s).startswith(b"HTTP/1.1 200")
    s.close()


@pytest.mark.parametrize("length", ["\u00b2", "1\u00b9", "5, 5", "-1", "0x10", "1e3",
                                    "99999999999999999999"])
def test_a_bad_content_length_is_a_400_not_a_traceback(studio, length):
    """LOW: ``Content-Length: ²`` (byte 0xb2: headers are read as Latin-1) passed
    ``str.isdigit`` and then failed ``int``, outside the guard: a traceback and no reply."""
    s = _connect(studio)
    head = _head(studio, token=studio.token).replace(
        b"\r\n\r\n", f"\r\nContent-Length: {length}\r\n\r\n".encode("latin-1"))
    s.sendall(head + b"{}")
    reply = _reply(s)
    s.close()
    assert reply.split(b" ")[1] in (b"400", b"413"), reply[:300]
    assert reply.count(b"HTTP/1.1 ") == 1 and b"internal error" not in reply


def test_an_stl_from_a_folder_named_outside_latin1_downloads(tmp_path, monkeypatch, capsys):
    """LOW: a folder named outside Latin-1 made the STL download send a 200 and then a 500
    on the same connection (the header could not be encoded)."""
    from urllib.parse import quote

    from pysolver.studio.server import StudioServer, attachment
    from pysolver.tables import tables_sha256

    monkeypatch.chdir(tmp_path)
    name = "花-petal"
    assert _cli(["build", SHAPE, "--out", name, "--no-render", "--no-sim"], capsys)[0] == 0
    folder = tmp_path / name
    tri = [0.0] * 3 + [0, 0, 0, 10, 0, 0, 0, 10, 0]     # one triangle (normal, corners)
    stl = b"\0" * 80 + (1).to_bytes(4, "little") + struct.pack("<12fH", *tri, 0)
    (folder / "stl").mkdir()
    (folder / "stl" / "top.stl").write_bytes(stl)
    (folder / "stl" / "parts.json").write_text(json.dumps(
        {"tables_sha256": tables_sha256(folder),
         "files": {"top.stl": hashlib.sha256(stl).hexdigest()}}))
    srv = StudioServer([folder])
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    try:
        s = _connect(srv)
        s.sendall(_head(srv, "GET", "/api/build/0/stl/top.stl", token=srv.token,
                        Connection="close"))
        reply = _reply(s)
        s.close()
    finally:
        srv.shutdown()
        srv.server_close()
    assert reply.count(b"HTTP/1.1 ") == 1 and reply.startswith(b"HTTP/1.1 200"), reply[:300]
    assert f"filename*=UTF-8''{quote(name + '-top.stl')}".encode() in reply
    assert b'filename="_-petal-top.stl"' in reply and reply.endswith(stl)
    assert attachment('a"b\r\nX: y.stl') == ("attachment; filename=\"a_b__X__y.stl\"; "
                                             "filename*=UTF-8''a%22b%0D%0AX%3A%20y.stl")


BROWSER_SCRIPT = """#!/bin/sh
printf '%s\\n' "$@" > {rec}.args
env > {rec}.env
cat "${{1#file://}}" > {rec}.page
stat -c '%a %u' "${{1#file://}}" "$(dirname "${{1#file://}}")" > {rec}.modes
: > {rec}.done
n=0
while [ ! -e {release} ] && [ $n -lt 1200 ]; do sleep 0.1; n=$((n+1)); done
"""
"""A browser that records what it was given and then does not return (until released)."""


def test_the_browser_never_sees_the_token_and_cannot_block_the_studio(tmp_path, monkeypatch):
    """Hole 1 and a LOW: the studio opened ``http://...#token=...`` as the browser's
    command line (``/proc/PID/cmdline`` is readable by every user), and waited for the
    browser command to return before serving."""
    import webbrowser

    from pysolver.studio.server import serve

    rec, release = tmp_path / "rec", tmp_path / "release"
    script = tmp_path / "fake-browser"
    script.write_text(BROWSER_SCRIPT.format(rec=rec, release=release))
    script.chmod(0o755)
    monkeypatch.setenv("BROWSER", str(script))
    monkeypatch.setattr(webbrowser, "_tryorder", None)
    monkeypatch.setattr(webbrowser, "_browsers", {})
    got = []
    th = threading.Thread(target=serve, args=([_studio_folder(tmp_path)],),
                          kwargs={"ready": got.append}, daemon=True)
    th.start()
    try:
        for _ in range(600):        # wait for the browser to have started (not timed)
            if (tmp_path / "rec.done").exists():
                break
            time.sleep(0.05)
        srv = got[0]
        s = _connect(srv)           # served while the browser command has not returned
        s.sendall(_head(srv, "GET", "/api/builds", token=srv.token, Connection="close"))
        assert _reply(s).startswith(b"HTTP/1.1 200")
        s.close()
    finally:
        release.touch()
        if got:
            got[0].shutdown()
        th.join(30)
    args = (tmp_path / "rec.args").read_text()
    assert srv.token not in args and srv.token not in (tmp_path / "rec.env").read_text()
    # the page it was given is private to this user and hands the token to the studio
    page_mode, folder_mode = (tmp_path / "rec.modes").read_text().split("\n")[:2]
    assert page_mode == f"600 {os.geteuid()}" and folder_mode == f"700 {os.geteuid()}"
    assert f'name="token" value="{srv.token}"' in (tmp_path / "rec.page").read_text()
    assert not Path(args.split()[0].removeprefix("file://")).parent.exists()  # removed


def _session(srv, body: str, origin="null", ctype="application/x-www-form-urlencoded"):
    s = _connect(srv)
    s.sendall(_head(srv, "POST", "/session", **{"Content-Type": ctype, "Origin": origin,
                                               "Content-Length": str(len(body)),
                                               "Connection": "close"}) + body.encode())
    reply = _reply(s)
    s.close()
    return reply


def test_the_private_page_hands_the_token_over_in_no_url(studio):
    """Issue #43, LOW (history): the private page did ``location.replace(".../#token=...")``,
    and that URL, token included, stayed in the browser's history.  Now it POSTs a form
    with the token in its body; the studio answers 303 to ``/`` with an HttpOnly,
    SameSite=Strict session cookie; a wrong token gets 403 and no cookie."""
    import html
    import re
    from html.parser import HTMLParser

    from pysolver.studio.server import COOKIE, opener_page

    page = opener_page(studio.url)
    try:
        text = page.read_text()
    finally:
        page.unlink()
        page.parent.rmdir()
    urls = re.findall(r"[a-z]+://[^\s\"'<>]*", html.unescape(text))
    assert urls and not [u for u in urls if studio.token in u], urls
    forms, inputs = [], []

    class Page(HTMLParser):
        def handle_starttag(self, tag, attrs):
            (forms if tag == "form" else inputs if tag == "input" else []).append(dict(attrs))

    Page().feed(text)
    assert forms == [{"method": "post", "action": f"{studio.origin}/session",
                      "enctype": "application/x-www-form-urlencoded"}]
    assert inputs == [{"type": "hidden", "name": "token", "value": studio.token}]
    reply = _session(studio, f"token={studio.token}")
    head = reply.split(b"\r\n\r\n")[0].decode()
    assert head.startswith("HTTP/1.1 303"), reply[:300]
    assert "\r\nLocation: /\r\n" in head and studio.token not in head.split("Set-Cookie")[0]
    cookie = re.search(r"\r\nSet-Cookie: (.*)", head)[1].split("; ")
    assert cookie[0] == f"{COOKIE}={studio.token}"
    assert sorted(cookie[1:]) == ["HttpOnly", "Path=/", "SameSite=Strict"]  # no Max-Age
    for body in ("token=wrong", f"token={studio.token[:-1]}", "",
                 f"token={studio.token}&token={studio.token}"):
        reply = _session(studio, body)
        assert reply.startswith(b"HTTP/1.1 403") and b"Set-Cookie" not in reply, body
    # host and origin, type and size are checked before the body is read
    assert _session(studio, f"token={studio.token}", origin="http://evil.example"
                    ).startswith(b"HTTP/1.1 403")
    assert _session(studio, f"token={studio.token}", ctype="application/json"
                    ).startswith(b"HTTP/1.1 415")
    s = _connect(studio)
    s.sendall(_head(studio, "POST", "/session", **{
        "Content-Type": "application/x-www-form-urlencoded", "Origin": "null",
        "Content-Length": str(4 << 20)}))
    assert _reply(s).startswith(b"HTTP/1.1 413")      # answered with the body unsent
    s.close()


def test_the_studio_page_drops_the_token_from_its_address():
    """Hole 1 (history): the page keeps the token in memory and its tab's sessionStorage,
    and replaces its address without it at once."""
    from pysolver.studio.server import STATIC_DIR

    js = (STATIC_DIR / "boot.js").read_text()      # the page's network side
    start = js.index("function tokenFromUrl()")
    body = js[start:js.index("\n  }\n", start)]
    assert 'history.replaceState(null, "", location.pathname + location.search)' in body



def test_the_studio_page_puts_no_text_of_a_build_into_its_html():
    """A file name in a build's stl/ is any name the file system allows (``<img src=x
    onerror=...>.stl``: the parts list shows every ``*.stl`` of a fresh build): the page sets
    text with textContent, and innerHTML only to clear an element, so no name, message or
    figure of a build is ever parsed as HTML (script in the page would hold its token)."""
    import re

    from pysolver.studio.server import STATIC_DIR

    for name in ("boot.js", "studio.js"):
        js = (STATIC_DIR / name).read_text()
        sets = re.findall(r"\.(?:innerHTML|outerHTML)\s*=\s*([^;]*);", js)
        assert all(v.strip() == '""' for v in sets), (name, [v for v in sets if v != '""'])
        assert not re.search(r"insertAdjacentHTML|document\.write", js), name


# ------------------------------------------------------------------------------ full disk


def _enospc(*_a, **_k):
    raise OSError(errno.ENOSPC, "No space left on device", "/full/disk/cells.csv")


def test_a_studio_run_on_a_full_disk_names_it(monkeypatch, capsys):
    """LOW: a full disk during a studio Run showed a raw traceback."""
    import io

    from pysolver.studio import rerun

    monkeypatch.setattr(rerun, "rebuild", _enospc)
    monkeypatch.setattr("sys.stdin", io.StringIO(json.dumps(
        {"folder": "x", "landscape": [1.0], "source": {}})))
    assert rerun.main() == 2
    from pysolver.core import progress
    assert progress._EVENTS is None   # (in-process, the run leaves no event stream behind)
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err
    assert "error: no space left on the device (the disk is full) (/full/disk/cells.csv)" in err
    assert "Fix: free some space" in err


def test_a_build_failing_on_a_full_disk_removes_its_staging_folder(tmp_path):
    """LOW: the studio Run's staging folder stayed behind after a full disk."""
    from pysolver.build import BuildOptions, _run_build
    from pysolver.stages import StageContext

    out = tmp_path / "X"
    ctx = StageContext(staging_dir(out), BuildOptions(progress=False), name="X", build={})
    with pytest.raises(OSError):
        _run_build(ctx, out, [], "digest", setup=_enospc)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------ Dask


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to give a folder to another user")
def test_dasks_scratch_folder_is_private_to_the_run(tmp_path, monkeypatch):
    """LOW: Dask's scratch folder was ``<tmp>/dask-scratch-space``, a fixed name in the
    shared temporary folder that another user could make first (and own)."""
    import tempfile

    from pysolver.distributed import dask_client

    shared = tmp_path / "shared-tmp"
    planted = shared / "dask-scratch-space"
    planted.mkdir(parents=True, mode=0o777)
    os.chown(planted, 65534, 65534)              # another user's, made first
    monkeypatch.setenv("TMPDIR", str(shared))
    monkeypatch.setattr(tempfile, "tempdir", str(shared))
    with dask_client(workers=1, progress=False) as client:
        dirs = list(client.run(lambda dask_worker: dask_worker.local_directory).values())
    assert dirs and all(planted not in Path(d).parents for d in dirs), dirs
    assert list(planted.iterdir()) == []
    private = [p for p in shared.iterdir() if p != planted]
    assert private == []                         # the run's own folder is removed after


# ------------------------------------------------------------------------------ memory


def _fake_machine(tmp_path: Path, cgroup: str, files: dict) -> tuple[Path, Path]:
    proc, cg = tmp_path / "proc", tmp_path / "cgroup"
    (proc / "self").mkdir(parents=True)
    (proc / "meminfo").write_text("MemTotal: 67108864 kB\nMemAvailable: 33554432 kB\n")
    (proc / "self" / "cgroup").write_text(cgroup)
    for rel, text in files.items():
        (cg / rel).parent.mkdir(parents=True, exist_ok=True)
        (cg / rel).write_text(text)
    return proc, cg


@pytest.mark.parametrize("cgroup, files, room", [
    ("0::/user.slice/run\n", {"user.slice/memory.max": f"{1 << 30}\n",
                              "user.slice/memory.current": f"{1 << 28}\n",
                              "user.slice/run/memory.max": "max\n"}, 3 << 28),
    ("4:memory:/job\n", {"memory/job/memory.limit_in_bytes": f"{1 << 31}\n",
                         "memory/job/memory.usage_in_bytes": f"{1 << 30}\n"}, 1 << 30),
    ("0::/\n", {"memory.max": "max\n"}, 32 << 30),
])
def test_the_memory_estimate_respects_cgroup_limits(tmp_path, cgroup, files, room):
    """LOW: the pair search's memory budget read only ``MemAvailable`` (32 GiB here), and
    ignored the cgroup's ``memory.max`` (v2) or ``memory.limit_in_bytes`` (v1)."""
    from pysolver.core.machine import available_memory

    proc, cg = _fake_machine(tmp_path, cgroup, files)
    assert available_memory(proc=proc, cgroup_root=cg) == room


def test_the_memory_estimate_respects_ulimit_v():
    """LOW: ``ulimit -v`` (``RLIMIT_AS``) was ignored: measured in a child with 256 MiB of
    address space more than it maps."""
    code = ("import resource\nfrom pysolver.core.machine import available_memory\n"
            "size = int([l for l in open('/proc/self/status') if l.startswith('VmSize')][0]"
            ".split()[1]) * 1024\n"
            "resource.setrlimit(resource.RLIMIT_AS, (size + (256 << 20), resource.RLIM_INFINITY))\n"
            "print(available_memory())\n")
    r = subprocess.run(python_argv(code=code), capture_output=True, text=True, check=True)
    assert 0 < int(r.stdout) <= 256 << 20


# ------------------------------------------------------------------------------ review of #43

PLANTED_MULTIPROCESSING = """import sys
open({marker!r}, "a").write("multiprocessing\\n")
sys.path[:] = [p for p in sys.path if p not in ("", {cwd!r})]
del sys.modules["multiprocessing"]
import multiprocessing  # the real one: the worker still starts
"""
"""A ``multiprocessing`` package that writes a marker, then hands over to the real one."""

CLUSTER_PARENT = """import sys
sys.path[:] = [p for p in sys.path if p != ""]   # the parent itself imports nothing from cwd
sys.path.append({root!r})
from pysolver.distributed import dask_client
with dask_client(workers=1, progress=False) as client:
    print(client.submit(sum, [1, 2]).result())
"""
"""A parent as a ``morphshell`` script is: its own path free of the working directory."""


def test_a_dask_worker_runs_no_planted_module(tmp_path):
    """HIGH: Dask starts its workers by multiprocessing's "spawn" (``python -B -c 'from
    multiprocessing.spawn import ...'``), which puts the working directory first on the
    worker's path: a ``multiprocessing/`` planted where morphshell ran, ran in every worker."""
    cwd, marker = tmp_path / "cwd", tmp_path / "imported-from-cwd.txt"
    (cwd / "multiprocessing").mkdir(parents=True)
    (cwd / "multiprocessing" / "__init__.py").write_text(
        PLANTED_MULTIPROCESSING.format(marker=str(marker), cwd=str(cwd)))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONSAFEPATH", "PYTHONPATH")}
    r = subprocess.run([sys.executable, "-c", CLUSTER_PARENT.format(root=PACKAGE_ROOT)], cwd=cwd,
                       env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.split() == ["3"], r.stderr[-2000:]
    assert _planted(marker) == []


def test_a_failed_cluster_start_leaves_no_scratch_folder(tmp_path, monkeypatch):
    """LOW: the run's private scratch folder (``mkdtemp``) was left behind when
    ``LocalCluster`` failed to start (a busy port, no memory, a worker that died)."""
    import tempfile

    import distributed

    from pysolver.distributed import dask_client

    def fail(*_a, **_k):
        raise RuntimeError("no cluster today")

    monkeypatch.setattr(distributed, "LocalCluster", fail)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    with pytest.raises(RuntimeError, match="no cluster today"):
        with dask_client(workers=1, progress=False):
            pass
    assert list(tmp_path.iterdir()) == []


def test_no_child_python_is_started_outside_python_argv():
    """LOW: ``bench/bench_build.py`` and ``bench/bench_printed.py`` started ``sys.executable
    -m pysolver.cli`` (the working directory first on the child's path), not through
    :func:`pysolver.core.child.python_argv`."""
    import re

    root = Path(PACKAGE_ROOT)
    files = [*root.glob("pysolver/**/*.py"), *root.glob("sim/**/*.py"), *root.glob("bench/*.py")]
    module_or_code = re.compile(r"sys\.executable\s*,\s*[\"'](-m|-c)[\"']")
    bad = [str(f.relative_to(root)) for f in files if module_or_code.search(f.read_text())]
    assert len(files) > 50 and bad == [], bad


@pytest.mark.parametrize("path, token", [("/", False), ("/x", False), ("/api", False),
                                         ("/api/builds", False), ("/x", True),
                                         ("/api/build/0/nothing", True)])
def test_a_post_anywhere_is_refused_before_its_body_is_read(studio, path, token):
    """MED: only ``/api/`` paths needed the token before the body: a tokenless POST to ``/``
    or ``/x`` with a 4 MiB ``Content-Length`` made the studio wait for the body.  The body is
    never sent: an answer proves that the studio did not wait for it."""
    s = _connect(studio)
    s.sendall(_head(studio, path=path, token=studio.token if token else None,
                    **{"Content-Length": str(4 << 20)}))
    reply = _reply(s)        # (the old studio waited for 4 MiB: a socket timeout)
    s.close()
    assert reply.split(b" ")[1] == (b"404" if token else b"403"), reply[:300]
    assert b"Connection: close" in reply


def test_idle_and_slow_tokenless_connections_do_not_lock_the_studio_out(studio):
    """MED: a slot was taken at accept and the 60 s timeout was per read, so
    ``studio_max_connections`` tokenless connections that send nothing, or half a request,
    held every slot (a slow sender forever).  Now the request line and headers must arrive
    within ``studio_header_timeout_s``: a request with the token is still answered."""
    from pysolver.params import LIMITS

    socks = [_connect(studio) for _ in range(LIMITS.studio_max_connections)]
    for s in socks[::2]:                         # half a request, then nothing more
        s.sendall(b"POST /api/builds HTTP/1.1\r\nHost: 127.0.0.1\r\n")
    try:
        s = _connect(studio)                     # (30 s: the old studio held its slots 60 s)
        s.sendall(_head(studio, "GET", "/api/builds", token=studio.token, Connection="close"))
        reply = _reply(s)
        s.close()
    finally:
        for t in socks:
            t.close()
    assert reply.startswith(b"HTTP/1.1 200"), reply[:300]


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to give a file to another user")
@pytest.mark.parametrize("stamp", ["{damaged", "well-formed"])
def test_another_users_stamp_above_the_output_is_not_ours(tmp_path, monkeypatch, capsys, stamp):
    """MED: the owner search walked up to ``/``: a damaged ``.morphshell-build`` that another
    user left in a shared sticky folder made every build beneath it exit 2 "damaged" (and
    told to delete their file); a well-formed one was honoured (and written to)."""
    from pysolver.core.manifest import STAMP_NAME, STAMP_VERSION

    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o1777)                         # like /tmp: root's, sticky, open to all
    if stamp == "well-formed":
        stamp = json.dumps({"made_by": "morphshell", "version": STAMP_VERSION,
                            "files": {}, "dirs": [], "prev": {}, "pending": {}})
    theirs = shared / STAMP_NAME
    theirs.write_text(stamp)
    os.chown(theirs, 65534, 65534)               # nobody's
    monkeypatch.chdir(tmp_path)
    rc, msg = _cli(["design", SHAPE, "--out", "shared/work/X"], capsys)
    assert rc == 0, msg
    assert theirs.read_text() == stamp and (shared / "work" / "X" / STAMP_NAME).exists()
