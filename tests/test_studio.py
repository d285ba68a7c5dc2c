"""``morphshell studio``: landscape editing maths, the server's guards, and end-to-end
browser tests in a real headless chromium (Debian's, driven by Selenium).

The browser tests use one small build (``regular``, no STLs, 20 s simulated) and check
the DOM state and the WebGL canvas pixels, waiting on explicit DOM conditions.
"""

from __future__ import annotations

import http.client
import json
import threading

import igl
import numpy as np
import pytest
from _browser import chrome, have_browser
from _shared import flat_grid

from pysolver.errors import InputError
from pysolver.studio.landscape import (
    Feasibility,
    constraint_values,
    harmonic_landscape,
    parse_constraints,
)
from pysolver.tables import read_stencil, read_table

WAIT_S = 90  # upper bound of an explicit wait (software WebGL on a busy 2-core machine)


# ------------------------------------------------------------------------------ maths


def test_harmonic_landscape_fixes_keyframes_and_is_harmonic_between():
    V, F = flat_grid(9, 40.0)
    b, bc = constraint_values(V, [(0, 30.0), (80, 90.0)], [])
    t = harmonic_landscape(V, F, b, bc)
    assert t[0] == pytest.approx(30.0) and t[80] == pytest.approx(90.0)
    L = igl.cotmatrix(V, F)
    free = np.setdiff1d(np.arange(len(V)), b)
    # Laplace's equation at every free vertex (residual relative to the time span)
    assert np.abs((L @ t)[free]).max() < 1e-8 * 60
    # maximum principle: strictly inside the keyframe range away from them, symmetric grid
    assert 30.0 < t[40] < 90.0 and t[40] == pytest.approx(60.0, abs=1e-6)


def test_brush_fixes_every_vertex_within_its_radius_and_keyframes_win():
    V, F = flat_grid(9, 40.0)   # 5 mm spacing
    b, bc = constraint_values(V, [(40, 10.0)], [(40, 5.01, 70.0)])
    # vertex 40 (the centre) and its 4 neighbours at 5 mm
    assert sorted(b.tolist()) == [31, 39, 40, 41, 49]
    assert dict(zip(b.tolist(), bc.tolist(), strict=True))[40] == 10.0
    assert set(bc.tolist()) == {10.0, 70.0}


@pytest.mark.parametrize("payload", [
    [], {"keyframes": [{"vertex": 99, "time": 5}]}, {"keyframes": [{"vertex": 1, "time": -1}]},
    {"keyframes": [{"vertex": 1.5, "time": 5}]}, {"keyframes": [{"vertex": True, "time": 5}]},
    {"keyframes": [{"vertex": 1, "time": float("nan")}]}, {"oops": []},
    {"brushes": [{"vertex": 1, "radius": 0, "time": 5}]}, {"keyframes": "1,2"},
])
def test_bad_constraints_are_refused(payload):
    with pytest.raises(InputError):
        parse_constraints(payload, 10)


def test_no_keyframe_is_refused():
    V, F = flat_grid(4)
    with pytest.raises(InputError):
        harmonic_landscape(V, F, [], [])


# ------------------------------------------------------------------------------ a small build


@pytest.fixture(scope="module")
def small_build(tmp_path_factory):
    from pysolver.build import build

    out = tmp_path_factory.mktemp("studio") / "regular"
    build("regular", out=out, refine=0, render=False, t_end=20.0, progress=False)
    return out


@pytest.fixture(scope="module")
def server(small_build):
    from pysolver.studio.server import StudioServer, resolve_folders

    srv = StudioServer(resolve_folders([small_build, small_build]))
    th = threading.Thread(target=srv.serve_forever, daemon=True)
    th.start()
    yield srv
    srv.shutdown()
    srv.server_close()


def _request(srv, method, path, body=None, host=None, ctype="application/json"):
    port = srv.server_address[1]
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    headers = {"Host": host or f"127.0.0.1:{port}"}
    if body is not None:
        headers["Content-Type"] = ctype
    c.request(method, path, body=None if body is None else json.dumps(body), headers=headers)
    r = c.getresponse()
    data = r.read()
    c.close()
    return r.status, data


def test_server_serves_only_its_whitelist(server):
    assert _request(server, "GET", "/")[0] == 200
    assert _request(server, "GET", "/static/three.min.js")[0] == 200
    for path in ("/static/../server.py", "/static/%2e%2e/server.py", "/etc/passwd",
                 "/static/", "/api/build/7/viewer", "/api/build/x/target"):
        assert _request(server, "GET", path)[0] in (400, 404), path
    # a page on another origin that resolves to 127.0.0.1 (DNS rebinding) is refused
    assert _request(server, "GET", "/api/builds", host="evil.example:80")[0] == 403
    # a cross-site form post (not JSON) is refused
    st, _ = _request(server, "POST", "/api/build/0/save", body={}, ctype="text/plain")
    assert st == 415


def test_save_never_overwrites_a_file_morphshell_did_not_make(server, tmp_path):
    from pysolver.studio.server import Build

    folder = tmp_path / "mine"
    folder.mkdir()
    for name in ("stencil.obj", "cells.csv", "time_landscape.csv", "temporal.json"):
        (folder / name).write_bytes((server.builds[0].folder / name).read_bytes())
    before = (folder / "time_landscape.csv").read_bytes()
    with pytest.raises(InputError, match="not made by morphshell"):
        Build(folder).save({"keyframes": [{"vertex": 0, "time": 50.0}]})
    assert (folder / "time_landscape.csv").read_bytes() == before


def test_preview_feasibility_is_the_temporal_stage_s(server, small_build):
    V, _, F = read_stencil(small_build / "stencil.obj")
    a, b = int(np.argmin(V[:, 0])), int(np.argmax(V[:, 0]))
    body = {"keyframes": [{"vertex": a, "time": 35.0}, {"vertex": b, "time": 60.0}]}
    st, data = _request(server, "POST", "/api/build/0/preview", body=body)
    assert st == 200
    r = json.loads(data)
    land = harmonic_landscape(V, F, [a, b], [35.0, 60.0])
    ev = Feasibility(small_build).evaluate(land)
    assert np.allclose(r["landscape"], land, atol=1e-3)
    assert r["feasibility"]["clamped"] == ev["clamped"].astype(int).tolist()
    assert r["feasibility"]["n_clamped"] > 0    # this landscape asks for too early a finish


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
        driver.find_element("id", "status").text


@browser
def test_viewer_loads_and_the_slider_changes_the_frame(server):
    from selenium.webdriver.common.keys import Keys

    with chrome() as d:
        _open(d, server)
        n = d.execute_script("return studio.viewers.length")
        assert n == 2                                          # two builds side by side
        first = d.execute_script("return studio.viewers[0].pixelStats()")
        assert first["ink"] > 0.02, "the canvas is blank: WebGL did not draw the shell"
        slider = d.find_elements("css selector", "#viewer-0 .mv-slider")[0]
        nf = int(slider.get_attribute("max")) + 1
        assert nf > 10
        slider.send_keys(Keys.END)                             # a real key press on the slider
        _wait(d, lambda d: d.find_element("id", "viewer-0").get_attribute("data-frame")
              == str(nf - 1), "the last frame to be drawn")
        last = d.execute_script("return studio.viewers[0].pixelStats()")
        assert last["checksum"] != first["checksum"]           # other pixels on the canvas
        assert abs(last["ink"] - first["ink"]) > 1e-3
        label = d.find_element("css selector", "#viewer-0 .mv-time").text
        t_end = float(np.load(server.builds[0].folder / "sim" / "frames.npz")["t"][-1])
        assert label == f"t = {t_end:.1f} s"
        # the second viewer follows the first one's camera
        d.execute_script("var v = studio.viewers[0]; v.orbit.theta += 0.7; v.orbit.update(true);")
        views = d.execute_script("return studio.viewers.map(function (v) { return v.getView(); })")
        assert views[0]["theta"] == pytest.approx(views[1]["theta"])
        # a click on a base lists its unit cells with their rows
        d.execute_script("studio.viewers[0].selectBase(5)")
        rows = d.find_elements("css selector", "#viewer-0 .mv-cells tr[data-cell]")
        cells = read_table(server.builds[0].folder, "cells")
        mine = np.flatnonzero((cells["base_a"] == 5) | (cells["base_b"] == 5))
        assert sorted(int(r.get_attribute("data-cell")) for r in rows) == mine.tolist()


@browser
def test_two_keyframes_save_and_program(server, small_build):
    from selenium.webdriver.common.action_chains import ActionChains

    V, _, F = read_stencil(small_build / "stencil.obj")
    a, b = int(np.argmin(V[:, 0])), int(np.argmax(V[:, 0]))
    before = int(read_table(small_build, "cells")["clamped"].sum())
    with chrome() as d:
        _open(d, server)
        d.find_element("id", "clear").click()      # keyframes of an earlier save are listed
        _wait(d, lambda d: d.find_element("id", "kf-list").get_attribute("data-count") == "0",
              "an empty keyframe list")
        canvas = d.find_element("css selector", "#editor-view canvas")
        time_box = d.find_element("id", "kf-time")
        for k, (v, t) in enumerate(((a, 35), (b, 60)), start=1):
            time_box.clear()
            time_box.send_keys(str(t))
            # click a little inside the boundary vertex (towards the centre), so the ray
            # hits a triangle of which it is the nearest corner
            x, y = d.execute_script(
                "var e = studio.editor, V = e.V, v = arguments[0], c = [0, 0, 0];"
                "for (var i = 0; i < e.nv; i++)"
                "  for (var j = 0; j < 3; j++) c[j] += V[3*i+j] / e.nv;"
                "var p = new THREE.Vector3(0.92*V[3*v] + 0.08*c[0], 0.92*V[3*v+1] + 0.08*c[1],"
                " 0.92*V[3*v+2] + 0.08*c[2]).project(e.camera);"
                "var r = e.canvas.getBoundingClientRect();"
                "return [(p.x + 1) / 2 * r.width, (1 - p.y) / 2 * r.height];", v)
            ActionChains(d).move_to_element_with_offset(
                canvas, x - canvas.size["width"] / 2, y - canvas.size["height"] / 2
            ).click().perform()
            _wait(d, lambda d, k=k: d.find_element("id", "kf-list").get_attribute("data-count")
                  == str(k), f"keyframe {k}")
        placed = [(int(r.get_attribute("data-vertex")), float(r.get_attribute("data-time")))
                  for r in d.find_elements("css selector", "#kf-list tr")]
        assert placed == [(a, 35.0), (b, 60.0)]
        _wait(d, _latest_preview, "the live feasibility of both keyframes")
        live = int(d.find_element("id", "feas").get_attribute("data-n-clamped"))
        land = harmonic_landscape(V, F, [a, b], [35.0, 60.0])
        assert live == int(Feasibility(small_build).evaluate(land)["clamped"].sum()) > 0

        d.find_element("id", "save").click()
        _wait(d, lambda d: d.find_element("id", "status").get_attribute("data-state")
              in ("saved", "error"), "the save")
        assert d.find_element("id", "status").get_attribute("data-state") == "saved"
        saved = read_table(small_build, "time_landscape")
        assert saved["vertex_id"].tolist() == list(range(len(V)))
        assert saved["time_s"][a] == pytest.approx(35.0, abs=1e-6)
        assert saved["time_s"][b] == pytest.approx(60.0, abs=1e-6)
        assert np.allclose(saved["time_s"], land, atol=1e-6)

        d.find_element("id", "program").click()
        _wait(d, lambda d: d.find_element("id", "status").get_attribute("data-state")
              in ("done", "error"), "the program stage")
        assert d.find_element("id", "status").get_attribute("data-state") == "done", \
            d.find_element("id", "status").text
        after = read_table(small_build, "cells")["clamped"]
        shown = int(d.find_element("id", "feas").get_attribute("data-programmed-clamped"))
        assert shown == int(after.sum()) == live != before
        assert float(d.find_element("id", "progress").get_attribute("value")) == 1.0
        # the red/blue points on the target are the programmed cells
        n_points = d.execute_script(
            "return studio.editor.marks.geometry.getAttribute('position').count")
        assert n_points == int(after.sum())


@browser
def test_brush_fixes_a_region(server, small_build):
    V, _, _ = read_stencil(small_build / "stencil.obj")
    centre = int(np.argmin(np.linalg.norm(V - V.mean(axis=0), axis=1)))
    with chrome() as d:
        _open(d, server)
        d.find_element("id", "clear").click()      # keyframes of an earlier save are listed
        _wait(d, lambda d: d.find_element("id", "kf-list").get_attribute("data-count") == "0",
              "an empty keyframe list")
        d.find_element("css selector", "input[name=tool][value=brush]").click()
        for box, value in (("brush-radius", "9"), ("kf-time", "44")):
            el = d.find_element("id", box)
            el.clear()
            el.send_keys(value)
        x, y = d.execute_script("return studio.editor.screenOf(arguments[0])", centre)
        canvas = d.find_element("css selector", "#editor-view canvas")
        from selenium.webdriver.common.action_chains import ActionChains

        ActionChains(d).move_to_element_with_offset(
            canvas, x - canvas.location["x"] - canvas.size["width"] / 2,
            y - canvas.location["y"] - canvas.size["height"] / 2).click().perform()
        _wait(d, _latest_preview, "the brushed landscape")
        row = d.find_element("css selector", "#kf-list tr")
        v = int(row.get_attribute("data-vertex"))
        assert row.text.startswith("brush 9 mm")
        land = np.asarray(d.execute_script("return studio.editor.landscape"), float)
        inside = np.linalg.norm(V - V[v], axis=1) <= 9.0
        assert inside.sum() >= 3 and np.allclose(land[inside], 44.0)
        assert np.allclose(land, 44.0)       # one fixed time: the whole landscape is 44 s


def test_program_and_simulate_job_reloads_the_viewer(server, small_build):
    """Last in the file: it re-simulates the shared build."""
    st, data = _request(server, "GET", "/api/build/0/viewer")
    before = json.loads(data)
    frames = small_build / "sim" / "frames.npz"
    mtime = frames.stat().st_mtime_ns
    st, data = _request(server, "POST", "/api/build/0/run", body={"stages": "program+simulate"})
    assert st == 200 and json.loads(data)["state"] == "running"
    st, _ = _request(server, "POST", "/api/build/0/run", body={"stages": "program"})
    assert st == 400                               # one job at a time
    seen = []
    done = threading.Event()

    def poll():
        while True:
            j = json.loads(_request(server, "GET", "/api/job")[1])
            seen.append(j["progress"])
            if j["state"] != "running":
                done.job = j
                done.set()
                return
            done.wait(0.3)

    poll()
    assert done.job["state"] == "done", done.job
    assert seen == sorted(seen) and seen[-1] == 1.0 and len(set(seen)) > 3   # progress moves
    assert frames.stat().st_mtime_ns != mtime
    after = json.loads(_request(server, "GET", "/api/build/0/viewer")[1])
    # the build's own t_end (20 s) and step: the same frame times as before
    assert after["t"] == before["t"] and after["t"][-1] == 20.0
    assert (small_build / "report" / "index.html").stat().st_mtime_ns > mtime
