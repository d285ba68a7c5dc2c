"""``morphshell studio``: landscape requests and maths, the server's guards (token, origin,
bodies, busy builds), the rebuild behind *Run*, the parts' freshness, and end-to-end
browser tests in a real headless chromium (Debian's, driven by Selenium).

The browser tests use one small build (``regular``, one refinement round, no STLs, 20 s
simulated) and check the DOM state, the editor's landscape and the WebGL canvas pixels,
waiting on explicit DOM conditions.
"""

from __future__ import annotations

import hashlib
import http.client
import json
import os
import shutil
import socket
import threading

import igl
import numpy as np
import pytest
from _browser import chrome, have_browser
from _shared import flat_grid

from pysolver.errors import InputError
from pysolver.studio.landscape import (
    Feasibility,
    harmonic_landscape,
    keyframe_values,
    parse_keyframes,
    parse_landscape,
)
from pysolver.studio.shots import drag_on_editor, type_into
from pysolver.tables import read_stencil, read_table, tables_sha256

WAIT_S = 120  # upper bound of an explicit wait (software WebGL and a run on a busy 2-core machine)


# ------------------------------------------------------------------------------ maths


def test_harmonic_landscape_fixes_keyframes_and_is_harmonic_between():
    V, F = flat_grid(9, 40.0)
    b, bc = keyframe_values([(0, 30.0), (80, 90.0)])
    t = harmonic_landscape(V, F, b, bc)
    assert t[0] == pytest.approx(30.0) and t[80] == pytest.approx(90.0)
    L = igl.cotmatrix(V, F)
    free = np.setdiff1d(np.arange(len(V)), b)
    # Laplace's equation at every free vertex (residual relative to the time span)
    assert np.abs((L @ t)[free]).max() < 1e-8 * 60
    # maximum principle: strictly inside the keyframe range away from them, symmetric grid
    assert 30.0 < t[40] < 90.0 and t[40] == pytest.approx(60.0, abs=1e-6)


def test_a_later_keyframe_on_the_same_vertex_wins():
    b, bc = keyframe_values([(3, 10.0), (5, 20.0), (3, 40.0)])
    assert b.tolist() == [3, 5] and bc.tolist() == [40.0, 20.0]


@pytest.mark.parametrize("payload, words", [
    ([], "must be a JSON object"),
    ({"keyframes": [{"vertex": 99, "time": 5}]}, "vertex 99 is outside 0-9"),
    ({"keyframes": [{"vertex": 1, "time": -1}]}, "time -1 s is outside 0-1000 s"),
    ({"keyframes": [{"vertex": 1, "time": 5000}]}, "time 5000 s is outside 0-1000 s"),
    ({"keyframes": [{"vertex": 1.5, "time": 5}]}, "vertex 1.5 is not a whole number"),
    ({"keyframes": [{"vertex": True, "time": 5}]}, "vertex True is not a whole number"),
    ({"keyframes": [{"vertex": 1, "time": float("nan")}]}, "time nan is not a number"),
    ({"keyframes": [{"vertex": 1}]}, "keyframe 0: no time"),
    ({"oops": []}, "unknown key(s) ['oops']"),
    # unknown keys inside a keyframe are refused too, as documented
    ({"keyframes": [{"vertex": 1, "time": 5, "weight": 2}]},
     "keyframe 0: unknown key(s) ['weight']"),
    ({"keyframes": "1,2"}, "'keyframes' must be a list"),
])
def test_bad_keyframes_are_refused_with_the_rule_they_break(payload, words):
    with pytest.raises(InputError) as e:
        parse_keyframes(payload, 10)
    assert words in e.value.problem


@pytest.mark.parametrize("payload, words", [
    ({"landscape": [1.0] * 9}, "9 values, the stencil 10"),
    ({"landscape": [1.0] * 9 + [2000.0]}, "vertex 9: time 2000.0 s is outside"),
    ({"landscape": [1.0] * 9 + [True]}, "list of numbers"),
    ({"landscape": [1.0] * 10, "edits": []}, "unknown key(s) ['edits']"),
])
def test_bad_landscapes_are_refused(payload, words):
    with pytest.raises(InputError) as e:
        parse_landscape(payload, 10)
    assert words in e.value.problem


def test_the_edit_log_is_checked():
    land, log = parse_landscape({"landscape": [5.0] * 10, "edits": [
        {"tool": "brush", "mode": "add", "value": 3, "radius": 8, "falloff": 0.5,
         "vertices": 4}]}, 10, edits=True)
    assert land.tolist() == [5.0] * 10 and log[0]["mode"] == "add"
    for bad in ({"tool": "brush", "mode": "erase"}, {"tool": "script", "mode": "set"},
                {"tool": "brush", "mode": "set", "note": "x"},
                {"tool": "brush", "mode": "set", "radius": 0}):
        with pytest.raises(InputError):
            parse_landscape({"landscape": [5.0] * 10, "edits": [bad]}, 10, edits=True)


# ------------------------------------------------------------------------------ a small build


@pytest.fixture(scope="module")
def small_build(tmp_path_factory):
    from pysolver.build import build

    out = tmp_path_factory.mktemp("studio") / "regular"
    build("regular", out=out, refine=1, render=False, t_end=20.0, progress=False)
    return out


def _copy(build_dir, tmp_path, name="regular"):
    dst = tmp_path / "copy" / name
    shutil.copytree(build_dir, dst, symlinks=True)
    return dst


def _files(folder) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _serve(folders, **kw):
    from pysolver.studio.server import StudioServer, resolve_folders

    srv = StudioServer(resolve_folders(folders), **kw)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    return srv


def _stop(srv):
    srv.shutdown()
    srv.server_close()


@pytest.fixture(scope="module")
def server(small_build):
    srv = _serve([small_build, small_build])
    yield srv
    _stop(srv)


def _request(srv, method, path, body=None, host=None, ctype="application/json", token=True,
             headers=None, raw_body=None):
    from pysolver.studio.server import TOKEN_HEADER

    port = srv.server_address[1]
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    h = {"Host": host or f"127.0.0.1:{port}"}
    if token:
        h[TOKEN_HEADER] = srv.token if token is True else token
    if body is not None or raw_body is not None:
        h["Content-Type"] = ctype
    h.update(headers or {})
    data = raw_body if raw_body is not None else None if body is None else json.dumps(body)
    c.request(method, path, body=data, headers=h)
    r = c.getresponse()
    out = r.read()
    c.close()
    return r.status, out


def _raw(srv, data: bytes) -> bytes:
    """Send raw bytes on one connection; everything the server answers until it closes."""
    s = socket.create_connection(("127.0.0.1", srv.server_address[1]), timeout=10)
    s.sendall(data)
    out = b""
    try:
        while chunk := s.recv(65536):
            out += chunk
    except TimeoutError:
        out += b"<still open>"
    s.close()
    return out


# ------------------------------------------------------------------------------ guards


def test_server_serves_only_its_whitelist(server):
    assert _request(server, "GET", "/")[0] == 200
    assert _request(server, "GET", "/static/three.min.js")[0] == 200
    for path in ("/static/../server.py", "/static/%2e%2e/server.py", "/etc/passwd",
                 "/static/", "/api/build/7/viewer", "/api/build/x/target",
                 "/api/build/0/stl/../cells.csv", "/api/build/0/stl/top.stl"):
        assert _request(server, "GET", path)[0] in (400, 404), path
    # a page on another origin that resolves to 127.0.0.1 (DNS rebinding) is refused
    assert _request(server, "GET", "/api/builds", host="evil.example:80")[0] == 403


def test_every_api_call_needs_the_token(server):
    assert "#token=" + server.token in server.url and len(server.token) >= 32
    assert _request(server, "GET", "/api/builds")[0] == 200
    for token in (False, "wrong", server.token[:-1]):
        st, body = _request(server, "GET", "/api/builds", token=token)
        assert st == 403 and b"token" in body
        assert _request(server, "POST", "/api/build/0/preview", body={"landscape": []},
                        token=token)[0] == 403
    # a token in a URL opens nothing: it would stay in the browser's history
    q = f"?token={server.token}"
    assert _request(server, "GET", "/api/builds" + q, token=False)[0] == 403
    assert _request(server, "GET", "/api/build/0/report" + q, token=False)[0] == 403


def test_a_build_s_report_runs_sandboxed(server):
    """A report comes from a build folder, maybe someone else's: served with a sandbox policy,
    its scripts run in an origin of their own (no session, no reading the studio's pages)."""
    from pysolver.studio.server import TOKEN_HEADER

    c = http.client.HTTPConnection("127.0.0.1", server.server_address[1], timeout=60)
    c.request("GET", "/api/build/0/report", headers={TOKEN_HEADER: server.token})
    r = c.getresponse()
    r.read()
    c.close()
    assert r.status == 200
    policy = [p.strip() for p in (r.getheader("Content-Security-Policy") or "").split(";")]
    assert "sandbox allow-scripts" in policy   # (no allow-same-origin)


def test_the_session_cookie_opens_the_api_from_the_studios_origin_only(server):
    """Issue #43 (history): the session cookie ``POST /session`` sets is a token like the
    header; without it, or with a wrong one, 403; a state-changing request with it still
    needs the studio's own origin (CSRF: the cookie alone is not enough)."""
    from pysolver.studio.server import COOKIE

    port = server.server_address[1]
    good = {"Cookie": f"other=1; {COOKIE}={server.token}"}
    assert _request(server, "GET", "/api/builds", token=False, headers=good)[0] == 200
    assert _request(server, "GET", "/api/build/0/report", token=False, headers=good)[0] == 200
    assert _request(server, "GET", "/api/builds", token=False)[0] == 403
    for bad in (f"{COOKIE}=wrong", f"{COOKIE}={server.token[:-1]}", f"x{COOKIE}={server.token}",
                f"{COOKIE}"):
        assert _request(server, "GET", "/api/builds", token=False,
                        headers={"Cookie": bad})[0] == 403, bad
    body = {"landscape": []}
    for origin in (f"http://127.0.0.1:{port + 1}", "null", "http://evil.example"):
        assert _request(server, "POST", "/api/build/0/preview", body=body, token=False,
                        headers={**good, "Origin": origin})[0] == 403, origin
    assert _request(server, "POST", "/api/build/0/preview", body=body, token=False,
                    headers={**good, "Origin": f"http://127.0.0.1:{port}"})[0] == 400


def test_another_origin_is_refused(server):
    port = server.server_address[1]
    for origin in ("http://evil.example", f"http://127.0.0.1:{port + 1}", "null"):
        st, _ = _request(server, "GET", "/api/builds", headers={"Origin": origin})
        assert st == 403, origin
    assert _request(server, "GET", "/api/builds",
                    headers={"Origin": f"http://127.0.0.1:{port}"})[0] == 200
    assert _request(server, "GET", "/api/builds",
                    headers={"Sec-Fetch-Site": "cross-site"})[0] == 403


def test_an_error_reply_never_leaves_a_body_to_be_read_as_a_second_request(server):
    """Request smuggling: a no-cors text/plain fetch (415) or a too-large body (413) used to
    be answered without reading the body, which was then parsed as a second request on the
    kept-alive connection."""
    port = server.server_address[1]
    body = json.dumps({"landscape": [30.0]}).encode()
    inner = (f"POST /api/build/0/preview HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
             f"Content-Type: application/json\r\nX-Morphshell-Token: {server.token}\r\n"
             f"Content-Length: {len(body)}\r\n\r\n").encode() + body
    for ctype, length in (("text/plain", len(inner)), ("application/json", 1 << 40)):
        outer = (f"POST /api/build/0/run HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                 f"X-Morphshell-Token: {server.token}\r\n"
                 f"Content-Type: {ctype}\r\nContent-Length: {length}\r\n\r\n").encode()
        reply = _raw(server, outer + inner)
        assert reply.count(b"HTTP/1.1 ") == 1, reply[:400]      # one request, one answer
        assert reply.split(b" ")[1] in (b"413", b"415")
        assert b"Connection: close" in reply and not reply.endswith(b"<still open>")
    # nor a body on a GET
    get = (f"GET /api/builds HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
           f"X-Morphshell-Token: {server.token}\r\nContent-Length: {len(inner)}\r\n\r\n")
    reply = _raw(server, get.encode() + inner)
    assert reply.count(b"HTTP/1.1 ") == 1 and reply.split(b" ")[1] == b"400"
    assert server.job.snapshot()["state"] == "idle"              # nothing was started


@pytest.mark.parametrize("headers, raw, words", [
    ({"Content-Length": "abc"}, b"{}", b"is not a whole number"),
    ({}, b"{not json", b"is not JSON"),
    ({}, b'{"landscape": NaN}', b"is not JSON"),
    ({}, b"[" * 100000 + b"]" * 100000, b"is not JSON"),
    ({}, b"\xff\xfe", b"is not JSON"),
    ({}, b'["landscape"]', b"must be a JSON object"),
    ({}, b'{"keyframes": [{"vertex": 0, "time": 5, "weight": 1}]}', b"unknown key"),
])
def test_malformed_requests_get_named_messages(server, headers, raw, words):
    path = "/api/build/0/keyframes" if b"keyframes" in raw else "/api/build/0/preview"
    port = server.server_address[1]
    h = {"Host": f"127.0.0.1:{port}", "Content-Type": "application/json",
         "X-Morphshell-Token": server.token, "Content-Length": str(len(raw)), **headers}
    head = f"POST {path} HTTP/1.1\r\n" + "".join(f"{k}: {v}\r\n" for k, v in h.items())
    reply = _raw(server, head.encode() + b"\r\n" + raw)
    status = reply.split(b" ")[1]
    assert status == b"400", reply[:300]
    assert words in reply and b"internal error" not in reply


def test_a_busy_port_is_named(small_build):
    from pysolver.cli import main
    from pysolver.studio.server import StudioServer

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen()
    port = s.getsockname()[1]
    try:
        with pytest.raises(InputError, match=f"port {port} on 127.0.0.1 is in use"):
            StudioServer([small_build], port=port)
        assert main(["studio", str(small_build), "--port", str(port), "--no-browser"]) == 2
    finally:
        s.close()


def test_concurrent_runs_queue_or_get_409_never_500(small_build):
    """30 concurrent Runs of one build: one starts, the others are told it is busy."""
    srv = _serve([small_build])
    release = threading.Event()
    started = []

    def fake_run(build, req, plan, expect):   # the real job is a rebuild: hold it here
        started.append(json.loads(req)["landscape"][0])
        release.wait(30)
        srv.job._set(state="done", progress=1.0)

    srv.job._run = fake_run
    try:
        land = read_table(small_build, "time_landscape")["time_s"].tolist()
        codes = [None] * 30

        def go(k):
            codes[k] = _request(srv, "POST", "/api/build/0/run", body=_run_body(
                small_build, landscape=[land[0] + k] + land[1:]))[0]

        threads = [threading.Thread(target=go, args=(k,)) for k in range(30)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        assert sorted(codes) == [200] + [409] * 29, codes
        assert len(started) == 1
        assert _request(srv, "GET", "/api/job")[0] == 200
    finally:
        release.set()
        _stop(srv)


# ------------------------------------------------------------------ one landscape, one build


def _other(small_build, tmp_path, name="other", add_s=3.0):
    """A copy of the small build under another name with another landscape (+``add_s``)."""
    from pysolver.design.time_landscape import write_landscape

    f = _copy(small_build, tmp_path, name)
    write_landscape(f, read_table(f, "time_landscape")["time_s"] + add_s)
    return f


def _held_runs(srv, release):
    """Replace the server's rebuild by one that records each request, waits for ``release``
    and then writes the sent landscape into the build (what a rebuild does to it)."""
    from pysolver.design.time_landscape import write_landscape

    sent = []

    def fake_run(build, req, plan, expect):
        r = json.loads(req)
        sent.append(r)
        release.wait(WAIT_S)
        write_landscape(r.get("out") or r["folder"], np.asarray(r["landscape"], float))
        build.forget()
        srv.job._set(state="done", progress=1.0, eta_s=0.0, seconds=0.0)

    srv.job._run = fake_run
    return sent


def _run_body(folder, **kw):
    from pysolver.studio.landscape import run_base_sha256

    land = read_table(folder, "time_landscape")["time_s"]
    body = {"build": folder.name, "base_sha256": run_base_sha256(folder, land),
            "landscape": land.tolist(), "edits": []}
    body.update(kw)
    return body


def test_a_run_is_refused_unless_it_names_its_build_and_the_landscape_it_was_edited_from(
        small_build, tmp_path):
    """Issue #47: a Run with another build's name or landscape hash is refused (409), with a
    message naming the problem, and nothing starts; the right one starts."""
    a, b = _copy(small_build, tmp_path), _other(small_build, tmp_path)
    srv = _serve([a, b])
    release = threading.Event()
    sent = _held_runs(srv, release)
    try:
        for body, code, words in (
                (_run_body(a), 409, "names build 'regular' but was sent to build 'other'"),
                (_run_body(b, base_sha256=_run_body(a)["base_sha256"]), 409,
                 "not made on the current landscape of build 'other'"),
                ({k: v for k, v in _run_body(b).items() if k != "base_sha256"}, 400,
                 "base_sha256"),
                (_run_body(b, variant="../x"), 400, "not a plain folder name"),
                (_run_body(b, variant="regular"), 400, "exists already")):
            st, out = _request(srv, "POST", "/api/build/1/run", body=body)
            assert st == code and words in json.loads(out)["error"], out
        assert sent == [] and srv.job.snapshot()["state"] == "idle"
        st, out = _request(srv, "POST", "/api/build/1/run", body=_run_body(b))
        assert st == 200
        _wait_for(lambda: sent)
        assert sent[0]["folder"] == str(b) and "out" not in sent[0]
        assert sent[0]["landscape"] == _run_body(b)["landscape"]
    finally:
        release.set()
        _stop(srv)


def test_a_run_made_on_one_build_is_refused_by_another_of_the_same_name(small_build,
                                                                         tmp_path):
    """Review of #47: two builds named ``regular`` with one landscape (a studio showing
    ['regular', 'regular', 'regular-2']): a Run edited on the first and sent to the second
    is refused (409, naming the folder) and nothing starts; sent to its own build it runs."""
    a = _copy(small_build, tmp_path)
    b = shutil.copytree(small_build, tmp_path / "elsewhere" / "regular", symlinks=True)
    srv = _serve([a, b])
    release = threading.Event()
    sent = _held_runs(srv, release)
    try:
        assert _run_body(a)["build"] == _run_body(b)["build"] == "regular"
        st, out = _request(srv, "POST", "/api/build/1/run", body=_run_body(a))
        assert st == 409, out
        assert "perhaps one of the same name" in json.loads(out)["error"]
        assert str(b) in json.loads(out)["error"]
        assert sent == [] and srv.job.snapshot()["state"] == "idle"
        # the landscape the editor loads carries the base of its own build
        st, out = _request(srv, "GET", "/api/build/0/target")
        assert st == 200 and json.loads(out)["landscape_sha256"] == _run_body(a)["base_sha256"]
        prog = json.loads(out)["programmed"]  # each cell's predicted timing sd (issue #45)
        assert len(prog["t_sd"]) == len(prog["t_star"]) and min(
            v for v in prog["t_sd"] if v is not None) > 0
        st, out = _request(srv, "POST", "/api/build/0/run", body=_run_body(a))
        assert st == 200, out
        _wait_for(lambda: sent)
        assert sent[0]["folder"] == str(a)
    finally:
        release.set()
        _stop(srv)


def _wait_for(cond, what="the condition"):
    import time

    t_end = time.monotonic() + WAIT_S
    while not cond():
        assert time.monotonic() < t_end, f"timed out waiting for {what}"
        time.sleep(0.02)


def test_a_run_whose_stage_hangs_silently_is_stopped_at_the_timeout(monkeypatch, tmp_path):
    """Issue #46 item 4: the timeout was checked only when a progress line came."""
    import dataclasses
    import time

    from pysolver.core.child import python_argv
    from pysolver.studio import jobs
    from pysolver.studio.builds import Build

    monkeypatch.setattr(jobs, "LIMITS", dataclasses.replace(
        jobs.LIMITS, studio_job_timeout_s=1.0))
    monkeypatch.setattr(jobs, "python_argv", lambda module: python_argv(
        code="import time\ntime.sleep(120)"))   # a stage that never says a word
    job = jobs.Job()
    job.state.update(state="running", started=time.time(), log=[])
    job._run(Build(tmp_path), "{}", ["start", "program", "report"], dict(jobs.Job.DEFAULT_S))
    state = job.snapshot()
    # (not stopped, the silent child would have ended after 120 s as "done")
    assert state["state"] == "error" and "longer than 1 s" in state["error"], state


def test_eta_is_the_rest_of_the_plan_at_this_run_s_pace():
    from pysolver.studio.jobs import PACE_PRIOR_S as P
    from pysolver.studio.jobs import eta_seconds

    plan, expect = ["start", "program", "simulate", "render", "report"], {
        "start": 4.0, "program": 10.0, "simulate": 100.0, "render": 80.0, "report": 10.0}
    # before a stage has finished: the build's own times (a slow start changes nothing)
    assert eta_seconds(plan, expect, {"start": 30.0}, "program", 4.0, 0.0) == 6.0 + 190.0
    # stages that took twice their time: the rest at their pace, pooled with pace 1 over
    # P s (a short stage moves it little, a long one much)
    pace = (20.0 + P) / (10.0 + P)
    assert 1.0 < pace < 1.5
    assert eta_seconds(plan, expect, {"start": 4.0, "program": 20.0}, "simulate", 50.0,
                       0.0) == pytest.approx(100.0 * pace - 50.0 + 90.0 * pace, abs=0.05)
    pace = (220.0 + P) / (110.0 + P)
    assert pace > 1.75
    assert eta_seconds(plan, expect, {"program": 20.0, "simulate": 200.0}, "render", 0.0,
                       0.0) == pytest.approx(90.0 * pace, abs=0.05)
    # a stage's own count: its rest by its rate so far
    assert eta_seconds(plan, expect, {"program": 10.0}, "simulate", 30.0, 0.5) == 30.0 + 90.0
    # late in the last stage: never below 0
    assert eta_seconds(plan, expect, {"program": 10.0}, "report", 50.0, 0.0) == 0.0


@pytest.mark.parametrize("text, words", [
    ("time_s,vertex_id\n0,1\n1,2\n", "not the header"),
    ("vertex_id,time_s\n0,1\n", "1 rows for a target of 2 vertices"),
    ("vertex_id,time_s\n0,1\n0,2\n", "vertex 0 is given twice"),
    ("vertex_id,time_s\n0,1\n2,2\n", "vertex 2 is not one of 0-1"),
    ("vertex_id,time_s\n0,1\n1,nan\n", "line 3: time 'nan'"),
    ("vertex_id,time_s\n0,1\n1,1e9\n", "line 3: time '1e9'"),
    ("vertex_id,time_s\n0,1\n1,=1+1\n", "line 3: time '=1+1'"),
    ("vertex_id,time_s\n0,1,2\n1,2\n", "line 2 '0,1,2' is not"),
    ("vertex_id,time_s\n-1,1\n1,2\n", "line 2 '-1,1' is not"),
    (7, "as text"),
])
def test_a_landscape_csv_is_validated_line_by_line(text, words):
    from pysolver.studio.landscape import parse_landscape_csv

    with pytest.raises(InputError, match=None) as e:
        parse_landscape_csv(text, 2)
    assert words in str(e.value)


def test_a_landscape_csv_round_trips_and_imports_through_the_server(server, small_build):
    from pysolver.studio.landscape import parse_landscape_csv

    land = read_table(small_build, "time_landscape")["time_s"] + 0.1
    text = "vertex_id,time_s\r\n" + "".join(f"{i},{float(t)!r}\r\n" for i, t in
                                              reversed(list(enumerate(land))))
    assert parse_landscape_csv(text, len(land)).tobytes() == land.tobytes()
    st, out = _request(server, "POST", "/api/build/0/import", body={"csv": text})
    assert st == 200 and json.loads(out)["landscape"] == land.tolist()
    st, out = _request(server, "POST", "/api/build/0/import", body={"csv": text, "x": 1})
    assert st == 400


def test_compare_takes_the_cells_whose_request_changed_and_their_figures():
    from pysolver.studio.compare import compare_cells

    a = {"t_star": [10.0, 20.0, 30.0, 40.0], "t_done": [11.0, 26.0, None, 41.0],
         "clamped": [0, 0, 1, 0]}
    b = {"t_star": [10.0, 25.0, 35.0, 40.0], "t_done": [11.0, 24.0, 36.0, 40.0],
         "clamped": [0, 0, 0, 0]}
    r = compare_cells(a, b)
    assert r["region"] == [1, 2]                        # the cells whose t* moved
    assert r["a"] == {"requested_mean_s": 25.0, "simulated_mean_s": 26.0, "timing_rms_s": 6.0,
                      "n_never_complete": 1, "n_out_of_reach": 1}
    assert r["b"]["timing_rms_s"] == pytest.approx(np.sqrt((1 + 1) / 2))
    assert r["diff_done_s"] == [0.0, 2.0, None, 1.0]
    assert compare_cells(a, b, [3])["a"]["timing_rms_s"] == 1.0
    with pytest.raises(InputError, match="4 and 3 unit cells"):
        compare_cells(a, {k: v[:3] for k, v in b.items()})
    with pytest.raises(InputError, match="region cell 9"):
        compare_cells(a, b, [9])


@pytest.mark.parametrize("cells, words", [
    ([2 ** 63], "region cell 9223372036854775808 is not one of 0-3"),
    ([1, 2 ** 64 + 5], "region cell 18446744073709551621 is not one of 0-3"),
    ([10 ** 400], "region cell (a 1329-bit number) is not one of 0-3"),
    ([-1], "region cell -1 is not one of 0-3"),
    ([1, 2.0], "region cell '2.0' is not a whole number"),
    ([True], "region cell 'True' is not a whole number"),
    ("0,1", "must be a list of cell ids"),
])
def test_compare_names_a_region_cell_id_that_is_not_one_of_the_cells(cells, words):
    """Review: an id >= 2^63 overflowed numpy's int64 (a 500 "this is a bug")."""
    from pysolver.studio.compare import compare_cells

    a = {"t_star": [10.0, 20.0, 30.0, 40.0], "t_done": [11.0, 26.0, None, 41.0],
         "clamped": [0, 0, 1, 0]}
    with pytest.raises(InputError) as e:
        compare_cells(a, a, cells)
    assert words in e.value.problem


def test_a_huge_region_cell_id_is_a_400_naming_it(server):
    for cells in ([2 ** 63], [-(2 ** 63) - 1]):
        st, out = _request(server, "POST", "/api/build/0/compare",
                           body={"other": 1, "cells": cells})
        assert st == 400, out
        assert f"region cell {cells[0]} is not one of" in json.loads(out)["error"]


def test_the_viewer_data_is_sent_gzip_compressed_when_the_browser_takes_it(server):
    import gzip

    from pysolver.studio.server import TOKEN_HEADER

    st, plain = _request(server, "GET", "/api/build/0/viewer")
    st2, packed = _request(server, "GET", "/api/build/0/viewer",
                           headers={"Accept-Encoding": "gzip, deflate"})
    assert st == st2 == 200 and gzip.decompress(packed) == plain
    assert len(packed) < 0.9 * len(plain)   # base64 of uint16 positions: ~0.57 on petal
    # the JSON's own size, which the page counts the arriving (decompressed) bytes against
    for accept in ("", "gzip"):
        c = http.client.HTTPConnection("127.0.0.1", server.server_address[1], timeout=60)
        c.request("GET", "/api/build/0/viewer", headers={
            "Host": f"127.0.0.1:{server.server_address[1]}", "Accept-Encoding": accept,
            TOKEN_HEADER: server.token})
        r = c.getresponse()
        r.read()
        assert r.status == 200 and r.getheader("X-Morphshell-Bytes") == str(len(plain))
        c.close()


def test_the_target_is_made_without_the_viewer_and_is_kept_until_its_files_change(
        small_build, tmp_path):
    """Issue #47 item 6: the editor's data no longer makes the morph viewer's (most of the
    first paint's 2 s on petal); its completion times are the viewer's all the same."""
    import os

    from pysolver.studio.builds import Build

    b = Build(_copy(small_build, tmp_path))
    t = b.target()
    assert b._viewer is None and b._viewer_bytes is None          # the viewer was not made
    assert b.target() is t                                         # kept
    v = b.viewer()
    assert t["programmed"]["t_done"] == v["cells"]["t_done"]       # the same rule, rounded alike
    assert len(t["programmed"]["t_done"]) == len(read_table(b.folder, "cells")["cell_id"])
    p = b.folder / "time_landscape.csv"                           # a file it is made from moved
    os.utime(p, ns=(p.stat().st_atime_ns, p.stat().st_mtime_ns + 10 ** 9))
    assert b.target() is not t and b.target() == t


def test_the_target_s_request_has_the_viewer_made_ahead(server):
    """After the editor's data, the studio makes the morph's compressed bytes while the page
    gets usable, so that its next request finds them made."""
    st, _ = _request(server, "GET", "/api/build/0/target")
    assert st == 200
    b = server.builds[0]
    _wait_for(lambda: b._prefetch is not None, "the viewer's thread")   # (after the reply)
    b._prefetch.join(WAIT_S)
    assert not b._prefetch.is_alive() and "gz" in b._viewer_bytes[2]


def test_the_eta_at_a_run_s_start_counts_only_the_parts_the_run_renders():
    """Issue #47: the ETA at a run's start took the build's render with every part rendered
    (4 min said for a 118 s run whose parts were cached)."""
    from pysolver.studio.jobs import RENDER_PART_S, expected_seconds

    defaults = {"start": 4.0, "program": 3.0, "render": 40.0, "report": 10.0}
    summ = {"timings_s": {"program": 2.0, "render": 108.0, "report": 11.0},
            "stages": {"render": {"parts": 700, "rendered": 700, "cached": 0,
                                  "timings_s": {"openscad": 96.0, "total": 108.0}}}}
    # the build's own landscape: every part from the cache, the union and export left
    assert expected_seconds(summ, defaults, 0.0) == {"start": 4.0, "program": 2.0,
                                                     "render": 12.0, "report": 11.0}
    assert expected_seconds(summ, defaults, 1.0)["render"] == pytest.approx(108.0)
    assert expected_seconds(summ, defaults, 0.25)["render"] == pytest.approx(12.0 + 24.0)
    # a build whose own render was all cached: its time, plus the changed parts at the default
    summ["stages"]["render"].update(rendered=0, cached=700)
    summ["timings_s"]["render"] = 12.0
    assert expected_seconds(summ, defaults, 0.5)["render"] == pytest.approx(
        12.0 + 350 * RENDER_PART_S)
    # no render record (an older build): the build's time as it was
    assert expected_seconds({"timings_s": {"render": 50.0}}, defaults, 1.0)["render"] == 50.0


def test_a_run_s_changed_parts_are_none_for_its_own_landscape_and_all_after_refinement(
        small_build):
    from pysolver.studio.builds import Build

    b = Build(small_build)
    land = b.landscape()
    assert b.changed_parts(land, refine=1) == b.changed_parts(land, refine=0) == 0.0
    cells = read_table(small_build, "cells")
    v = int(cells["vertex_a"][0])                        # a vertex of the first cell
    edited = land.copy()
    edited[v] += 5.0
    moved = (cells["vertex_a"] == v) | (cells["vertex_b"] == v)
    bases = set(cells["base_a"][moved]) | set(cells["base_b"][moved])
    n_bases = len(set(cells["base_a"]) | set(cells["base_b"]))
    assert 0 < len(bases) < n_bases
    assert b.changed_parts(edited, refine=0) == pytest.approx(len(bases) / n_bases)
    assert b.changed_parts(edited, refine=1) == 1.0    # the refinement moves every cell


def test_a_run_starts_with_the_eta_of_what_it_will_run(small_build, monkeypatch):
    import dataclasses

    from pysolver.build import rebuild_options
    from pysolver.studio import jobs
    from pysolver.studio.builds import Build

    summ, opts = rebuild_options(small_build)
    summ = dict(summ, timings_s={"program": 2.0, "simulate": 30.0, "refine": 20.0,
                                 "render": 108.0, "report": 11.0},
                stages={"render": {"parts": 700, "rendered": 700,
                                   "timings_s": {"openscad": 96.0}}})
    opts = dataclasses.replace(opts, render=True, refine=1)
    monkeypatch.setattr(jobs, "rebuild_options", lambda folder: (summ, opts))
    monkeypatch.setattr(jobs.Job, "_run", lambda self, *a: None)   # nothing runs
    b = Build(small_build)
    land = b.landscape()
    for landscape, render in ((land, 12.0), (land + 1.0, 108.0)):
        job = jobs.Job()
        job.start(b, 0, landscape, [])
        state = job.snapshot()
        assert "render" in state["plan"]
        assert state["eta_s"] == pytest.approx(jobs.Job.DEFAULT_S["start"] + 2.0 + 30.0 + 20.0
                                               + render + 11.0)


# ------------------------------------------------------------------------------ rebuild


def test_preview_feasibility_is_the_temporal_stage_s(server, small_build):
    V, _, F = read_stencil(small_build / "stencil.obj")
    a, b = int(np.argmin(V[:, 0])), int(np.argmax(V[:, 0]))
    st, data = _request(server, "POST", "/api/build/0/keyframes",
                        body={"keyframes": [{"vertex": a, "time": 15.0},
                                            {"vertex": b, "time": 60.0}]})
    assert st == 200
    r = json.loads(data)
    land = harmonic_landscape(V, F, [a, b], [15.0, 60.0])
    ev = Feasibility(small_build).evaluate(land)
    assert np.allclose(r["landscape"], land, atol=1e-9)
    assert r["feasibility"]["clamped"] == ev["clamped"].astype(int).tolist()
    assert r["feasibility"]["n_clamped"] > 0    # this landscape asks for too early a finish
    st, data = _request(server, "POST", "/api/build/0/preview", body={"landscape": r["landscape"]})
    assert st == 200 and json.loads(data)["feasibility"]["clamped"] == r["feasibility"]["clamped"]


def test_frames_record_the_tables_they_were_simulated_from(small_build):
    # also after the refinement, which keeps its best round's cells.csv and frames
    z = np.load(small_build / "sim" / "frames.npz")
    assert str(z["tables_sha256"]) == tables_sha256(small_build)


def test_an_unedited_rebuild_keeps_the_refinement(small_build, tmp_path):
    """Run on an unchanged landscape is the build again: the same program stage, the same
    refinement rounds, the same thicknesses (the studio used to drop the refinement)."""
    from pysolver.build import rebuild

    f = _copy(small_build, tmp_path)
    land = read_table(f, "time_landscape")["time_s"]
    summary = rebuild(f, land, source={"edits": []}, progress=False)
    before = json.loads((small_build / "sim" / "refine.json").read_text())
    after = json.loads((f / "sim" / "refine.json").read_text())
    assert after["rounds"] == before["rounds"] == 1
    for key in ("thickness_top_mm", "thickness_bottom_mm"):
        assert np.allclose(read_table(f, "cells")[key], read_table(small_build, "cells")[key],
                           atol=1e-6)
    assert after["history"][-1]["rms_incl_never_s"] == pytest.approx(
        before["history"][-1]["rms_incl_never_s"], abs=1e-3)
    assert summary["edited"]["before"]["verdict"] == json.loads(
        (small_build / "report" / "report.json").read_text())["verdict"]
    assert "studio" in json.loads((f / "report" / "report.json").read_text())[
        "provenance"]["landscape"]


def test_a_failed_stage_saves_nothing_of_the_edit(small_build, tmp_path):
    from pysolver.build import rebuild

    f = _copy(small_build, tmp_path)
    before = _files(f)
    n = len(read_stencil(f / "stencil.obj")[0])
    with pytest.raises(InputError, match="mostly infeasible"):
        rebuild(f, np.full(n, 900.0), progress=False)
    assert _files(f) == before
    assert sorted(p.name for p in f.parent.iterdir()) == ["regular"]   # no staging left


# ---------------------------------------------------------------- a variant's source


def test_a_variant_of_a_build_holding_a_users_file_is_refused_and_writes_nothing(
        small_build, tmp_path):
    """Review: a variant copied every top-level file of its source (a user's notes) and
    recorded them as morphshell's; the source was never audited."""
    from pysolver.build import rebuild

    f = _copy(small_build, tmp_path)
    (f / "notes.txt").write_text("mine\n")
    before = _files(f)
    land = read_table(f, "time_landscape")["time_s"]
    with pytest.raises(InputError) as e:
        rebuild(f, land, out=f.parent / "regular-2", progress=False)
    assert "notes.txt: not written by morphshell" in e.value.problem
    assert e.value.exit_code == 2
    assert _files(f) == before
    assert sorted(p.name for p in f.parent.iterdir()) == ["regular"]  # no variant, no staging


def test_a_variant_is_refused_while_its_source_is_being_built(small_build, tmp_path):
    """Review: a variant read its source without its build lock."""
    from pysolver.build import rebuild
    from pysolver.core.locks import build_lock

    f = _copy(small_build, tmp_path)
    land = read_table(f, "time_landscape")["time_s"]
    with build_lock(f):
        with pytest.raises(InputError, match="is being built by pid"):
            rebuild(f, land, out=f.parent / "regular-2", progress=False)
        assert sorted(p.name for p in f.parent.iterdir()) == [
            ".regular.morphshell-lock", "regular"]   # the held lock only
    assert sorted(p.name for p in f.parent.iterdir()) == ["regular"]


def test_a_rebuild_copies_only_the_files_the_stamp_records(small_build, tmp_path):
    """A killed writer's temporary file (a ``pending`` entry of the stamp) is morphshell's,
    so the audit passes it, but it is not part of the design: it is not copied; a recorded
    file that changed is refused."""
    from pysolver.build import REBUILD_DROPPED, _copy_recorded
    from pysolver.core.manifest import read_stamp

    f = _copy(small_build, tmp_path)
    m = read_stamp(f)
    tmp = ".cells.csv.tmp-0123456789abcdef"
    m["pending"][tmp] = 1
    (f / tmp).write_text("half a table")
    (f / ".morphshell-build").write_text(json.dumps(m))
    (tmp_path / "st").mkdir()
    _copy_recorded(f, tmp_path / "st")
    want = {k for k in m["files"] if "/" not in k and k not in REBUILD_DROPPED}
    assert "cells.csv" in want and "stencil.obj" in want
    assert {p.name for p in (tmp_path / "st").iterdir()} == want
    with open(f / "cells.csv", "a") as fh:
        fh.write("\n")
    with pytest.raises(InputError, match="cells.csv changed since morphshell wrote it"):
        _copy_recorded(f, tmp_path / "st")


def _binary_stl(path):
    tri = np.array([[[0, 0, 0], [10, 0, 0], [0, 10, 0]], [[0, 0, 0], [0, 10, 0], [0, 0, 5]]],
                   np.float32)
    rec = np.zeros(len(tri), np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]))
    rec["v"] = tri
    path.write_bytes(b"\0" * 80 + np.uint32(len(tri)).tobytes() + rec.tobytes())


def _fake_parts(folder):
    """An STL and its record, as the render stage writes them (made from the tables now)."""
    (folder / "stl").mkdir()
    _binary_stl(folder / "stl" / "top.stl")
    (folder / "stl" / "parts.json").write_text(json.dumps(
        {"tables_sha256": tables_sha256(folder), "files": {"top.stl": hashlib.sha256(
            (folder / "stl" / "top.stl").read_bytes()).hexdigest()}}))


def test_the_report_never_lists_parts_older_than_its_tables(small_build, tmp_path):
    from pysolver.simulator import build_parts
    from sim.report import make_report

    f = _copy(small_build, tmp_path)
    _fake_parts(f)
    assert build_parts(f)["made_from"]["fresh"]
    assert [s["name"] for s in build_parts(f)["stls"]] == ["stl/top.stl"]
    cells = read_table(f, "cells")       # a later program stage: other thicknesses
    cells["thickness_top_mm"] = cells["thickness_top_mm"] + 0.01
    from pysolver.tables import write_table

    write_table(f / "cells.csv", "cells", cells)
    parts = build_parts(f)
    assert not parts["made_from"]["fresh"] and parts["stls"] == []
    assert "other tables" in parts["made_from"]["problem"]
    r = make_report(f, progress=False)
    checks = {x["check"]: x["level"] for x in r["reasons"]}
    assert checks["parts"] == "WARN" and checks["tables"] == "FAIL"
    assert r["stls"] == [] and r["fabrication"]["steps"][0]["title"] == "Render again"
    assert "Do not print" in (f / "report" / "index.html").read_text()


# ------------------------------------------------------------------------------ browser

browser = pytest.mark.skipif(not have_browser(),
                             reason="Debian chromium + chromium-driver not installed "
                                    "(make installs them)")


def _wait(driver, cond, what):
    from selenium.webdriver.support.ui import WebDriverWait

    return WebDriverWait(driver, WAIT_S, poll_frequency=0.2).until(
        lambda d: cond(d), message=f"timed out waiting for {what}")


def _latest_preview(driver) -> bool:
    """The feasibility shown is the answer to the editor's latest edit."""
    return driver.find_element("id", "feas").get_attribute("data-seq") == str(
        driver.execute_script("return studio.editor.seq"))


def _open(driver, server):
    driver.get(server.url)
    _wait(driver, lambda d: d.find_element("tag name", "body").get_attribute("data-ready"),
          "the studio to load")
    assert driver.find_element("tag name", "body").get_attribute("data-ready") == "1", \
        driver.find_element("id", "error").text
    _wait(driver, _latest_preview, "the first preview")


def _keyframes_done(driver) -> bool:
    """The landscape shown is the interpolation of the latest keyframes, and its preview."""
    return driver.execute_script(
        "return document.getElementById('kf-list').getAttribute('data-done')"
        " === String(studio.editor.kfSeq)") and _latest_preview(driver)


def _land(driver) -> np.ndarray:
    return np.asarray(driver.execute_script("return Array.from(studio.editor.st.land)"), float)


def _brush(driver, mode, value, radius, falloff="0.5"):
    driver.execute_script("var m = document.getElementById('brush-mode'); m.value = arguments[0];"
                          "m.dispatchEvent(new Event('change'));", mode)
    for box, v in (("brush-value", value), ("brush-radius", radius), ("brush-falloff", falloff)):
        if not (box == "brush-value" and mode == "smooth"):   # smooth takes no value
            type_into(driver, box, v)


def _stroke(driver, vertex, dx=40, dy=8):
    """Drag on the editor's canvas from the screen point of a stencil vertex."""
    drag_on_editor(driver, vertex, dx, dy)


def _centre(folder) -> tuple[np.ndarray, int]:
    V = read_stencil(folder / "stencil.obj")[0]
    return V, int(np.argmin(np.linalg.norm(V - V.mean(axis=0), axis=1)))


@browser
def test_the_private_page_opens_the_studio_with_no_token_in_any_url(server):
    """Issue #43 (history): the browser, started on the private page, ends on the studio
    with its builds listed, the token in a session cookie and in no address."""
    from pysolver.studio.server import COOKIE, opener_page

    page = opener_page(server.url)
    try:
        with chrome() as d:
            d.get(page.as_uri())
            _wait(d, lambda d: d.current_url.startswith(server.origin) and d.find_element(
                "tag name", "body").get_attribute("data-ready"), "the studio to load")
            assert d.find_element("tag name", "body").get_attribute("data-ready") == "1", \
                d.find_element("id", "error").text
            assert len(d.find_elements("css selector", "#edit-build option")) == 2
            href = d.execute_script("return location.href")
            assert href == server.origin + "/" and "token" not in href
            assert d.execute_script("return studio.token") is None   # the cookie carries it
            [cookie] = [c for c in d.get_cookies() if c["name"] == COOKIE]
            assert cookie["httpOnly"] and cookie["sameSite"] == "Strict" \
                and "expiry" not in cookie
    finally:
        page.unlink()
        page.parent.rmdir()


@browser
def test_a_stroke_changes_only_the_painted_region(server, small_build):
    V, c = _centre(small_build)
    with chrome() as d:
        _open(d, server)
        # issue #47 item 6: the target came with its landscape's feasibility: none asked
        # again at load (the first paint waits for one request less)
        assert not d.execute_script("return studio.editor.previewRequests")
        assert d.find_element("id", "feas").get_attribute("data-n-clamped") is not None
        # the viewers' data came after, counted as they arrived against their JSON's size
        size = sum(len(b.viewer_body(False)) for b in server.builds)
        assert d.find_element("id", "viewers").get_attribute("data-received") == str(size)
        before = _land(d)
        _brush(d, "add", "10", "10", "0.5")
        _stroke(d, c)
        _wait(d, lambda d: d.find_element("id", "editor-view").get_attribute("data-strokes"),
              "the stroke")
        after = _land(d)
        st = d.execute_script("return studio.editor.lastStroke")
        P = np.asarray(st["points"], float)
        # (the page has the stencil as float32, rounded to 1e-5 mm: 1e-3 mm of margin)
        dist = np.linalg.norm(V[:, None, :] - P[None], axis=2).min(axis=1)
        changed = after != before
        assert 3 <= changed.sum() < len(V) / 2
        # bit for bit the same value beyond the brush's radius of every point of the drag
        assert not changed[dist > 10.0 + 1e-3].any()
        assert changed[dist < 10.0 - 1e-3].all()
        inner = dist < 5.0 - 1e-3                          # falloff 0.5: weight 1 inside r/2
        assert inner.sum() >= 1 and np.allclose((after - before)[inner], 10.0, atol=1e-9)
        assert (after - before).min() >= 0 and (after - before).max() <= 10.0 + 1e-9
        _wait(d, _latest_preview, "the painted landscape's feasibility")
        # issue #47: the time scale stays the build's range; times beyond it are counted
        scale = d.execute_script("return [studio.editor.scale.lo, studio.editor.scale.hi]")
        lo, hi = before.min(), before.max()
        assert scale == ([lo, hi] if hi - lo >= 1e-6 else [lo - 1, lo + 1])   # (flat: +-1 s)
        assert d.find_element("id", "editor-view").get_attribute("data-beyond") == str(
            int((after > scale[1]).sum()))
        # issue #47: a tooltip shown during the stroke has the new numbers, not stale ones
        tip = d.find_element("id", "hover")
        k = int(tip.get_attribute("data-cell"))
        t_star = d.execute_script("return studio.editor.feas.t_star[arguments[0]]", k)
        assert tip.is_displayed() and f"requested t* {t_star:.1f} s" in tip.text
        # and one feasibility request per release (a click paints one dab, no drag)
        n0 = d.execute_script("return studio.editor.previewRequests")
        _stroke(d, c, dx=0, dy=0)
        _wait(d, lambda d: d.execute_script("return studio.editor._soon === null") and
              d.find_element("id", "editor-view").get_attribute("data-strokes") == "2" and
              _latest_preview(d), "the click's feasibility")
        assert d.execute_script("return studio.editor.previewRequests") == n0 + 1


@browser
def test_undo_restores_the_landscape_byte_for_byte(server, small_build):
    V, c = _centre(small_build)
    far = int(np.argmax(np.linalg.norm(V - V[c], axis=1)))
    built = read_table(small_build, "time_landscape")["time_s"]
    with chrome() as d:
        _open(d, server)
        assert _land(d).tobytes() == built.tobytes()
        _brush(d, "set", "45", "9")
        _stroke(d, c)
        _brush(d, "smooth", "", "20", "1")
        _stroke(d, far, dx=-30)
        _wait(d, lambda d: d.find_element("id", "editor-view").get_attribute("data-strokes")
              == "2", "two strokes")
        painted = _land(d)
        assert painted.tobytes() != built.tobytes()
        d.find_element("id", "undo").click()
        d.find_element("id", "undo").click()
        assert _land(d).tobytes() == built.tobytes()
        assert d.find_element("id", "undo").get_attribute("disabled") == "true"
        d.find_element("id", "redo").click()
        d.find_element("id", "redo").click()
        assert _land(d).tobytes() == painted.tobytes()


@browser
def test_a_bad_value_shows_its_message_and_clears_after_it_is_fixed(server, small_build):
    from selenium.webdriver.common.keys import Keys

    V, c = _centre(small_build)
    with chrome() as d:
        _open(d, server)
        before = _land(d)
        _brush(d, "add", "5", "0")
        err = d.find_element("id", "brush-error")
        assert "radius must be more than 0 mm" in err.text
        _stroke(d, c)                                    # no silent 5 mm: nothing is painted
        assert _land(d).tobytes() == before.tobytes()
        assert "did not paint" in d.find_element("id", "error").text
        type_into(d, "brush-radius", "")
        assert "radius: give a number" in err.text
        type_into(d, "brush-radius", "5000")
        assert "5000 mm is more than 1000 mm" in err.text
        type_into(d, "brush-radius", "8")
        assert err.text == ""
        _stroke(d, c)
        _wait(d, lambda d: d.find_element("id", "editor-view").get_attribute("data-strokes"),
              "the stroke")
        assert (_land(d) != before).any()
        assert d.find_element("id", "error").text == ""   # the error went with its cause
        # a keyframe row whose time is cleared is marked (not kept at its old value) and
        # does not block the others
        d.find_element("css selector", "input[name=tool][value=keyframe]").click()
        d.execute_script("studio.editor.st.keyframes = [{vertex: 0, time: 30, raw: '30'},"
                         " {vertex: arguments[0], time: 40, raw: '40'}];"
                         " studio.editor.interpolate();", c)
        _wait(d, _keyframes_done, "two keyframes")
        box = d.find_elements("css selector", "#kf-list input")[1]
        box.send_keys(Keys.CONTROL, "a")
        box.send_keys(Keys.BACKSPACE, Keys.TAB)     # the row is drawn again on change
        _wait(d, _keyframes_done, "the keyframes without the cleared one")
        problems = d.execute_script("return Array.from(document.querySelectorAll("
                                    "'#kf-list tr')).map(function (r) {"
                                    " return r.getAttribute('data-problem'); })")
        assert problems == [None, "no time"]
        assert np.allclose(_land(d), 30.0)                # the good row still interpolates
        box = d.find_elements("css selector", "#kf-list input")[1]
        box.send_keys("50\t")
        _wait(d, lambda d: _keyframes_done(d) and not d.find_elements(
            "css selector", "#kf-list tr.bad"), "the row to be fixed")
        assert _land(d)[c] == pytest.approx(50.0)


@browser
def test_a_click_on_the_rim_places_a_keyframe_or_says_why(server, small_build):
    V, _ = _centre(small_build)
    rim = int(np.argmax(V[:, 0]))
    with chrome() as d:
        _open(d, server)
        d.find_element("css selector", "input[name=tool][value=keyframe]").click()
        x, y = d.execute_script("return studio.editor.screenOf(arguments[0])", rim)
        d.execute_script("studio.editor.clickAt(arguments[0], arguments[1])", x, y)
        # (read in one script: the list is drawn again as previews come back)
        _wait(d, lambda d: d.execute_script(
            "var l = document.getElementById('kf-list'), r = l.querySelector('tr');"
            "return l.getAttribute('data-count') === '1' && r && r.dataset.vertex;") == str(rim),
            "a keyframe on the rim vertex")
        d.execute_script("studio.editor.clickAt(arguments[0] + 200, arguments[1] - 300)", x, y)
        err = d.find_element("id", "error")
        assert "click" in err.get_attribute("data-kinds").split()
        assert "no vertex under the pointer" in err.text
        d.execute_script("studio.editor.clickAt(arguments[0], arguments[1])", x, y)
        _wait(d, lambda d: "click" not in (d.find_element("id", "error").get_attribute(
            "data-kinds") or "").split(), "the click error cleared by a click that lands")


@browser
def test_the_ghost_toggles_and_builds_side_by_side_share_scale_and_time(server):
    from selenium.webdriver.common.keys import Keys

    with chrome() as d:
        _open(d, server)
        assert d.execute_script("return studio.viewers.length") == 2
        v0 = d.find_element("id", "viewer-0")
        assert v0.get_attribute("data-ghost") == "1"
        on = d.execute_script("return studio.viewers[0].pixelStats()")
        assert on["ink"] > 0.02, "the canvas is blank: WebGL did not draw the shell"
        d.find_element("css selector", "#viewer-0 .mv-ghost").click()
        assert v0.get_attribute("data-ghost") == "0"
        off = d.execute_script("return studio.viewers[0].pixelStats()")
        assert off["checksum"] != on["checksum"] and off["ink"] < on["ink"]
        # one time slider: the end of the first is the end of the second
        d.find_elements("css selector", "#viewer-0 .mv-slider")[0].send_keys(Keys.END)
        _wait(d, lambda d: d.execute_script(
            "return studio.viewers.every(function (v) { return v.frame === v.nf - 1; })"),
            "both viewers at the last frame")
        # one colour scale and one mode
        d.execute_script("var s = document.querySelector('#viewer-1 .mv-mode');"
                         "s.value = 'thickness'; s.dispatchEvent(new Event('change'));")
        modes = d.execute_script("return studio.viewers.map(function (v) { return v.mode; })")
        ranges = d.execute_script("return studio.viewers.map(function (v) { return v.range; })")
        assert modes == ["thickness", "thickness"] and ranges[0] == ranges[1]
        # issue #47: robust ranges (2nd-98th percentiles) with the values beyond marked,
        # per-frame ranges, shared by the linked viewers; view presets for both
        d.execute_script("var s = document.querySelector('#viewer-0 .mv-scale');"
                         "s.value = 'robust'; s.dispatchEvent(new Event('change'));")
        vals = np.array([np.nan if v is None else v for v in d.execute_script(
            "return studio.viewers[0].data.base_fields.thickness")], float)
        lo, hi = np.percentile(vals[np.isfinite(vals)], [2, 98])
        beyond = int(((vals < lo - 1e-6) | (vals > hi + 1e-6)).sum())
        for k in (0, 1):
            v = d.find_element("id", f"viewer-{k}")
            assert np.allclose([float(x) for x in v.get_attribute("data-range").split()],
                               [lo, hi], atol=1e-4)
            assert int(v.get_attribute("data-outliers")) == beyond
        if beyond:
            assert f"orange: {beyond} beyond" in v.find_element("class name", "mv-legend").text
        d.execute_script("var s = document.querySelector('#viewer-1 .mv-mode');"
                         "s.value = 'distance'; s.dispatchEvent(new Event('change'));"
                         "s = document.querySelector('#viewer-1 .mv-scale');"
                         "s.value = 'frame'; s.dispatchEvent(new Event('change'));")
        dist = d.execute_script("var v = studio.viewers[0]; return v.fieldValues();")
        assert np.allclose([float(x) for x in v0.get_attribute("data-range").split()],
                           [min(dist), max(dist)], atol=1e-4)
        assert v0.get_attribute("data-outliers") == "0"
        d.find_element("css selector", "#viewer-1 .mv-view-top").click()
        assert d.execute_script("return studio.viewers.map(function (v) { return v.orbit.phi; })"
                                ) == [pytest.approx(0.02)] * 2
        # hover on a base: its cells' t*, completion, thicknesses
        d.execute_script("var v = studio.viewers[0], b = new THREE.Vector3();"
                         "var m = new THREE.Matrix4(); v.bases.getMatrixAt(3, m);"
                         "b.setFromMatrixPosition(m); b.project(v.camera);"
                         "var r = v.canvas.getBoundingClientRect();"
                         "v.hoverAt(r.left + (b.x + 1) / 2 * r.width,"
                         "          r.top + (1 - b.y) / 2 * r.height);")
        tip = d.find_element("css selector", "#viewer-0 .mv-tip")
        assert "t*" in tip.text and "h " in tip.text


@browser
def test_the_parts_are_listed_with_a_3d_preview_and_a_download(small_build, tmp_path):
    f = _copy(small_build, tmp_path, "withparts")
    _fake_parts(f)
    srv = _serve([f])
    try:
        with chrome() as d:
            _open(d, srv)
            _wait(d, lambda d: d.find_element("id", "parts").get_attribute("data-count") == "1",
                  "the parts list")
            d.find_element("css selector", "#parts-table .part-3d").click()
            _wait(d, lambda d: d.find_element("id", "part-view").get_attribute("data-triangles")
                  == "2", "the STL's 3D preview")
            href = d.find_element("css selector", "#parts-table .part-download").get_attribute(
                "href")
            assert "token" not in href      # the session cookie, not the URL, carries it
            cookie = {c["name"]: c["value"] for c in d.get_cookies()}
            st, data = _request(srv, "GET", href.split(str(srv.server_address[1]), 1)[1],
                                token=False, headers={"Cookie": "; ".join(
                                    f"{k}={v}" for k, v in cookie.items())})
            assert st == 200 and data == (f / "stl" / "top.stl").read_bytes()
    finally:
        _stop(srv)


@pytest.fixture
def held(small_build, tmp_path):
    """Two builds (``regular``, and ``other`` with another landscape) in a studio whose
    Runs wait for ``release`` and then only write the sent landscape (no rebuild)."""
    a, b = _copy(small_build, tmp_path), _other(small_build, tmp_path)
    srv = _serve([a, b])
    release = threading.Event()
    sent = _held_runs(srv, release)
    yield srv, a, b, release, sent
    release.set()
    _stop(srv)


def _paint(d, vertex, radius, n, dx=40):
    """Add 10 s with a brush of ``radius`` mm dragged from ``vertex``: the editor's
    landscape once it is the ``n``-th stroke of the page."""
    _brush(d, "add", "10", radius)
    _stroke(d, vertex, dx=dx)
    _wait(d, lambda d: d.find_element("id", "editor-view").get_attribute("data-strokes")
          == str(n), f"stroke {n}")
    return _land(d)


def _select(d, i):
    d.execute_script("var s = document.getElementById('edit-build'); s.value = arguments[0];"
                     "s.dispatchEvent(new Event('change'));", str(i))
    _wait(d, lambda d: d.execute_script("return studio.editor.build.id") == i and
          d.find_element("tag name", "body").get_attribute("data-loading") == "0" and
          _latest_preview(d), f"build {i} to load")


def _run_done(d):
    return d.find_element("id", "progress-text").get_attribute("data-state") in ("done", "error")


@browser
def test_a_run_right_after_switching_builds_builds_only_what_is_on_screen(held):
    """Issue #47, race 1: switching builds and pressing Run before the second has loaded used
    to rebuild the second with the first one's painted landscape."""
    srv, a, b, release, sent = held
    V, c = _centre(a)
    with chrome() as d:
        _open(d, srv)
        painted = _paint(d, c, "10", 1)
        # select the other build and press Run in the same breath (before it has loaded)
        seen = d.execute_script(
            "var s = document.getElementById('edit-build'); s.value = '1';"
            "s.dispatchEvent(new Event('change'));"
            "var r = document.getElementById('run'), was = r.disabled; r.click();"
            "return [was, document.body.getAttribute('data-loading')];")
        assert seen == [True, "1"]                    # Run is disabled while a build loads
        _wait(d, lambda d: d.find_element("tag name", "body").get_attribute("data-loading")
              == "0" and _latest_preview(d), "the other build to load")
        assert sent == [] and srv.job.snapshot()["state"] == "idle"
        other = read_table(b, "time_landscape")["time_s"]
        assert _land(d).tobytes() == other.tobytes()
        d.find_element("id", "run").click()           # now: build 1 with its own landscape
        _wait(d, lambda d: sent, "the run request")
        assert sent[0]["folder"] == str(b) and sent[0]["landscape"] == other.tolist()
        release.set()
        _wait(d, _run_done, "the run")
        # build 0 kept its painted landscape and its undo history
        _select(d, 0)
        assert _land(d).tobytes() == painted.tobytes()
        assert d.find_element("id", "editor-view").get_attribute("data-undo") == "1"


@browser
def test_an_edit_during_a_run_is_kept_as_a_pending_draft(held):
    """Issue #47, race 2: a stroke made during a Run used to be lost when the run ended."""
    srv, a, _, release, sent = held
    V, c = _centre(a)
    far = int(np.argmax(np.linalg.norm(V - V[c], axis=1)))
    with chrome() as d:
        _open(d, srv)
        painted = _paint(d, c, "8", 1)
        d.find_element("id", "run").click()
        _wait(d, lambda d: sent and d.find_element("id", "progress-text").get_attribute(
            "data-state") == "running", "the run to start")
        for box in ("run", "reset", "import", "edit-build"):   # controls that write
            assert d.find_element("id", box).get_attribute("disabled") == "true", box
        during = _paint(d, far, "8", 2, dx=-30)                # paint during the run
        draft = d.find_element("id", "draft")
        n = int(draft.get_attribute("data-vertices"))
        assert draft.is_displayed() and n == int((during != painted).sum()) > 0
        assert "Pending draft" in draft.text
        release.set()
        _wait(d, _run_done, "the run")
        assert d.find_element("id", "progress-text").get_attribute("data-state") == "done"
        _wait(d, _latest_preview, "the draft's feasibility")
        built = read_table(a, "time_landscape")["time_s"]
        assert np.allclose(built, painted, rtol=1e-8)          # what was sent was built
        assert _land(d).tobytes() == during.tobytes()          # and the draft is kept
        assert f"the draft ({n} vertices) is kept" in d.find_element("id", "status").text
        d.find_element("id", "undo").click()                   # one step back: the build
        assert _land(d).tobytes() == built.tobytes()


@browser
def test_a_run_into_a_variant_shows_its_verdict_and_keeps_the_original(server, small_build):
    """Last in the file: it builds a variant (``regular-2``) beside the shared build, which
    must stay as it was, with its editing state and undo history."""
    V, c = _centre(small_build)
    before = _files(small_build)
    old = json.loads((small_build / "report" / "report.json").read_text())
    with chrome() as d:
        _open(d, server)
        d.execute_script("var v = studio.viewers[0]; v.orbit.theta += 0.9; v.orbit.update(true);"
                         "v.setFrame(7); v.selectBase(4);")
        view = d.execute_script("return studio.viewers[0].getView()")
        # a landscape imported from CSV (checked by the server), then a stroke on it
        d.execute_script("var t = studio.editor.csv().replace(/\\n0,([^\\n]*)/, '\\n0,77');"
                         "studio.importCsv(new File([t], 'mine.csv'));")
        _wait(d, lambda d: _land(d)[0] == 77.0 and _latest_preview(d), "the imported CSV")
        painted = _paint(d, c, "8", 1)
        assert d.find_element("id", "editor-view").get_attribute("data-undo") == "2"
        d.execute_script("studio.editor.clickAt(-5000, -5000)")   # an error to be cleared
        assert d.find_element("id", "error").text
        d.find_element("id", "variant").click()
        assert d.find_element("id", "variant-name").get_attribute("value") == "regular-2"
        d.find_element("id", "run").click()
        _wait(d, lambda d: d.find_element("id", "progress-text").get_attribute("data-state")
              == "running", "the run to start")
        assert d.find_element("id", "run").get_attribute("disabled") == "true"
        seen = []

        def finished(d):
            seen.append(float(d.find_element("id", "progress").get_attribute("value")))
            return _run_done(d)

        _wait(d, finished, "the run")
        assert d.find_element("id", "progress-text").get_attribute("data-state") == "done", \
            d.find_element("id", "error").text
        assert float(d.find_element("id", "progress").get_attribute("value")) == 1.0
        assert seen == sorted(seen) and len({x for x in seen if 0 < x < 1}) >= 3  # it moved
        assert d.find_element("id", "run").get_attribute("disabled") is None
        assert d.find_element("id", "error").text == ""       # a run that worked clears it
        _wait(d, lambda d: d.find_element("id", "results").get_attribute("data-state")
              == "shown", "the results")
        # the variant is listed, selected, and holds the edited landscape and its log
        var = small_build.parent / "regular-2"
        names = [o.text for o in d.find_elements("css selector", "#edit-build option")]
        assert names == ["regular", "regular", "regular-2"]
        assert d.execute_script("return studio.editor.build.name") == "regular-2"
        assert _files(small_build) == before                  # the original is untouched
        # issue #47: the same landscape run again would find the variant's parts cached
        from pysolver.studio.builds import Build
        assert Build(small_build).built_before(painted) == var
        assert Build(small_build).changed_parts(painted, refine=1) == 0.0
        assert np.allclose(read_table(var, "time_landscape")["time_s"], painted, rtol=1e-8)
        assert _land(d).tobytes() == read_table(var, "time_landscape")["time_s"].tobytes()
        rec = json.loads((var / "studio_landscape.json").read_text())
        assert [(e["tool"], e["mode"]) for e in rec["edits"]] == [("import", "csv"),
                                                                  ("brush", "add")]
        assert rec["variant_of"] == "regular"
        new = json.loads((var / "report" / "report.json").read_text())
        assert d.find_element("id", "verdict").get_attribute("data-verdict") == new["verdict"]
        rows = {r.get_attribute("data-key"): [td.text for td in
                                              r.find_elements("tag name", "td")]
                for r in d.find_elements("css selector", "#figures tr[data-key]")}
        assert rows["shape_rms_mm"][1] == f"{new['metrics']['shape']['rms_mm']:.2f}"
        assert rows["shape_rms_mm"][2] == f"{old['metrics']['shape']['rms_mm']:.2f}"  # before
        assert rows["n_clamped"][1] == str(new["metrics"]["timing"]["n_clamped"])
        assert rows["timing_rms_s"][0] == "timing RMS error, programmable cells (s)"
        assert rows["timing_rms_all_s"][0] == "timing RMS error, all cells (s)"
        assert d.find_element("id", "report-link").get_attribute("hidden") is None
        # the viewers: one more, and the first kept its camera and frame
        assert d.execute_script("return studio.viewers.length") == 3
        got = d.execute_script("return studio.viewers[0].getView()")
        assert got["theta"] == pytest.approx(view["theta"])
        assert d.execute_script("return [studio.viewers[0].frame, studio.viewers[0].picked]") \
            == [7, 4]
        # did the edit work? the variant (A) against the original (B), opened by the run
        _wait(d, lambda d: d.find_element("id", "compare").get_attribute("data-state")
              == "shown", "the comparison")
        ta = read_table(var, "cells")["t_star_s"]
        tb = read_table(small_build, "cells")["t_star_s"]
        region = np.abs(ta - tb) > 1e-6
        assert int(d.find_element("id", "compare").get_attribute("data-region")) == \
            region.sum() > 0
        cl = np.asarray(read_table(var, "cells")["clamped"], bool)
        row = [td.text for td in d.find_elements("css selector",
                                                 "#cmp-region tr[data-key=n_out_of_reach] td")]
        assert row[1] == str(int(cl[region].sum()))
        row = [td.text for td in d.find_elements("css selector",
                                                 "#cmp-figures tr[data-key=shape_rms_mm] td")]
        assert row[1:3] == [f"{new['metrics']['shape']['rms_mm']:.2f}",
                            f"{old['metrics']['shape']['rms_mm']:.2f}"]
        assert d.find_element("id", "editor-view").get_attribute("data-colour") == "diff"
        # back on the original: its edited landscape and its undo history are still there
        _select(d, 0)
        assert _land(d).tobytes() == painted.tobytes()
        assert d.find_element("id", "editor-view").get_attribute("data-undo") == "2"
        # the region painted in the editor there, compared in the same two builds
        d.find_element("id", "cmp-painted").click()
        d.find_element("id", "cmp-go").click()
        built = read_table(small_build, "time_landscape")["time_s"]
        cells = read_table(small_build, "cells")
        moved = np.flatnonzero(painted != built)
        mine = np.isin(cells["vertex_a"], moved) | np.isin(cells["vertex_b"], moved)
        _wait(d, lambda d: d.find_element("id", "compare").get_attribute("data-state")
              == "shown" and "painted in the editor" in d.find_element(
                  "css selector", "#compare h4").text, "the painted region's comparison")
        assert d.find_element("id", "compare").get_attribute("data-region") == str(mine.sum())


def test_the_target_is_made_again_when_the_refinement_record_changes(small_build, tmp_path):
    """The target's per-cell sd comes from sim/refine.json (the refinement writes it after
    cells.csv): a target kept from before it was written would show the old sds."""
    from pysolver.studio.builds import Build
    from pysolver.tables import PREDICTED_SD

    b = Build(_copy(small_build, tmp_path))
    t = b.target()
    rec_path = b.folder / "sim" / "refine.json"
    rec = json.loads(rec_path.read_text())
    n = len(rec[PREDICTED_SD])
    rec[PREDICTED_SD] = [7.25] * n
    rec_path.write_text(json.dumps(rec))
    tmp = b.folder / "temporal.json"   # the refinement's record is the later one
    os.utime(rec_path, ns=(tmp.stat().st_atime_ns, tmp.stat().st_mtime_ns + 10 ** 9))
    assert t["programmed"]["t_sd"] != [7.25] * n
    assert b.target()["programmed"]["t_sd"] == [7.25] * n


def test_a_stage_expected_to_take_no_time_moves_the_bar_without_dividing_by_zero():
    """expected_seconds can expect 0 s of render (every part from the cache, and the build's
    render time all of it OpenSCAD's): the progress update divided by it, and the
    ZeroDivisionError in the reading loop marked the job failed while its child ran on."""
    from pysolver.studio.jobs import Job, expected_seconds

    defaults = {"start": 4.0, "program": 3.0, "render": 40.0, "report": 10.0}
    summ = {"timings_s": {"program": 2.0, "render": 96.0, "report": 11.0},
            "stages": {"render": {"parts": 700, "rendered": 700, "cached": 0,
                                  "timings_s": {"openscad": 96.0, "total": 96.0}}}}
    expect = expected_seconds(summ, defaults, 0.0)
    assert expect["render"] == 0.0
    job = Job()
    plan = ["start", "program", "render", "report"]
    job.state.update(state="running", progress=0.0, log=[])
    job._progress(plan, expect, (9.0, {"start": 4.0, "program": 2.0}), "render", 0.0, 0.5,
                  "[render] regular: 350/700")
    s = job.snapshot()
    assert s["state"] == "running" and s["stage"] == "render"
    assert s["progress"] == pytest.approx(9.0 / sum(expect[k] for k in plan), abs=1e-3)


def test_a_job_that_fails_while_its_child_runs_stops_the_child(monkeypatch):
    """An unforeseen error in the loop reading a Run's progress (a bug) marks the job failed:
    its child, which would go on building behind a job that says it stopped (and a second
    Run could start beside it), is stopped too."""
    import subprocess

    from pysolver.core.child import python_argv
    from pysolver.studio import jobs

    started = []

    class Recorded(subprocess.Popen):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            started.append(self)

    def broken(raw):
        raise RuntimeError("a bug in the progress reader")

    monkeypatch.setattr(jobs, "python_argv", lambda module: python_argv(
        code="import sys, time\nsys.stdin.read()\nprint('{}', flush=True)\ntime.sleep(600)\n"))
    monkeypatch.setattr(jobs, "progress_event", broken)
    monkeypatch.setattr(jobs.subprocess, "Popen", Recorded)
    job = jobs.Job()
    job.state.update(state="running", log=[])
    job._run(None, "{}", ["start"], {"start": 4.0})
    s = job.snapshot()
    assert s["state"] == "error" and "a bug in the progress reader" in s["error"]
    assert len(started) == 1 and started[0].poll() is not None   # stopped, not left running
