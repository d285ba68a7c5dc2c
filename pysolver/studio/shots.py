"""Screenshots of the studio and of the report for the docs (``make studio-shots``).

Runs the studio in this process on a *copy* of a build folder (``build/.studio-shots-*``, so
the build itself is not changed and the part cache is shared), drives Debian's headless
chromium (Selenium with the system chromedriver; nothing is downloaded) through what a user
does, and captures each step:

* ``studio-paint.png``: a stroke that makes a region slower, coloured by reachable band,
  with a cell's details on hover;
* ``studio-error.png``: a bad brush radius and its message (painting refused);
* ``studio-progress.png``: the run into a new build (a variant, ``<name>-2``) and its
  progress bar with its stage and ETA;
* ``studio-results.png``: the variant's verdict, compared with the build before, and the
  parts with a 3D preview;
* ``studio-compare.png``: did the edit work? the variant (A) against the original (B): the
  painted region's requested and simulated times, and every figure of both;
* ``studio-diff.png``: the editor coloured by the completion difference A - B per cell;
* ``studio-ghost.png``: the morph's last frame with the target's translucent ghost, the
  distance to the target on this frame's own colour range;
* ``studio.png``: the whole page; ``report.png``: the top of the build's report.

    python -m pysolver.studio.shots build/petal docs/img
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

from ..errors import InputError
from .server import StudioServer, resolve_folders

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")
FLAGS = ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-default-apps", "--disable-extensions", "--use-angle=swiftshader",
         "--enable-unsafe-swiftshader", "--mute-audio")
MAX_PNG_BYTES = 300_000


def have_browser() -> bool:
    """Debian's chromium and chromium-driver are installed."""
    return CHROMIUM.is_file() and CHROMEDRIVER.is_file()


def chromium_driver(width: int, height: int, profile, *, extra=()):
    """A headless Debian chromium WebDriver (Selenium with the system chromedriver, so
    selenium-manager never downloads a browser), window ``width`` x ``height`` px, profile
    folder ``profile``.  The flags keep an offline machine quiet and give WebGL a software
    rasteriser (SwiftShader), so canvases really render."""
    try:
        from selenium import webdriver  # optional: a browser only for screenshots and browser tests

        # optional: a browser only for screenshots and browser tests
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        raise InputError("selenium is not installed",
                         fix="pip install -e '.[dev]' (make does it)") from None
    if not have_browser():
        raise InputError("Debian chromium and chromium-driver are needed for screenshots",
                         fix="sudo apt-get install -y chromium chromium-driver (make does it)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = str(CHROMIUM)
    for a in (*FLAGS, *extra):
        opts.add_argument(a)
    opts.add_argument(f"--window-size={width},{height}")
    opts.add_argument(f"--user-data-dir={profile}")
    env = dict(os.environ, SE_OFFLINE="true")
    return webdriver.Chrome(service=Service(str(CHROMEDRIVER), env=env), options=opts)


def _wait(driver, cond, what, timeout=180):
    # optional: a browser only for screenshots and browser tests
    from selenium.webdriver.support.ui import WebDriverWait

    WebDriverWait(driver, timeout, poll_frequency=0.2).until(
        lambda d: cond(d), message=f"timed out waiting for {what}")


def _save_small(png: bytes, path: Path, width: int) -> Path:
    """Save a screenshot at most ``width`` px wide, as a palette PNG if that keeps it small."""
    from PIL import Image  # optional heavy dependency: Pillow only for pictures

    im = Image.open(io.BytesIO(png)).convert("RGB")
    if im.width > width:
        im = im.resize((width, round(im.height * width / im.width)), Image.LANCZOS)
    for colours in (256, 128, 64):
        buf = io.BytesIO()
        im.quantize(colours, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(
            buf, "PNG", optimize=True)
        if buf.tell() <= MAX_PNG_BYTES:
            break
    path.write_bytes(buf.getvalue())
    return path


def _element_png(driver, css: str) -> bytes:
    el = driver.find_element("css selector", css)
    driver.execute_script("arguments[0].scrollIntoView({block: 'start'})", el)
    return el.screenshot_as_png


def type_into(driver, box: str, value: str) -> None:
    """Type ``value`` into the input ``#box`` as a user does (select all, delete, type: the
    page sees real input events); an empty value leaves the box empty."""
    # optional: a browser only for screenshots and browser tests
    from selenium.webdriver.common.keys import Keys

    el = driver.find_element("id", box)
    el.send_keys(Keys.CONTROL, "a")
    el.send_keys(Keys.BACKSPACE)
    if value:
        el.send_keys(value)


def drag_on_editor(driver, vertex: int, dx: int, dy: int) -> None:
    """Drag with the left button on the studio editor's canvas, from the screen point of
    stencil vertex ``vertex`` by (``dx``, ``dy``) px, in two moves."""
    # optional: a browser only for screenshots and browser tests
    from selenium.webdriver.common.action_chains import ActionChains

    canvas = driver.find_element("css selector", "#editor-view canvas")
    x, y = driver.execute_script("return studio.editor.screenOf(arguments[0])", vertex)
    r = driver.execute_script("var r = arguments[0].getBoundingClientRect();"
                              "return [r.left, r.top, r.width, r.height]", canvas)
    ActionChains(driver).move_to_element_with_offset(
        canvas, x - r[0] - r[2] / 2, y - r[1] - r[3] / 2).click_and_hold().move_by_offset(
        dx // 2, dy // 2).move_by_offset(dx - dx // 2, dy - dy // 2).release().perform()


def studio_shots(build_dir, out_dir, *, width: int = 1100, warm: bool = True) -> dict:
    """Write the studio's screenshots (module docstring) of a copy of ``build_dir``.

    ``warm``: the studio makes the first build's data while the browser starts, as
    ``morphshell studio`` does (:meth:`StudioServer.warm`); without it the first page load
    finds nothing made (a cold start, to measure).

    Returns
    -------
    dict
        ``files`` (paths written), ``usable_ms`` (page opened to editor and results shown,
        in the browser), ``ready_ms`` (to the morph viewer loaded too), ``preview_ms``
        (round trip of the live feasibility after a stroke, in the browser), ``run_s``
        (the run, a build of a variant, as the studio timed it) and ``eta_start_s`` (the
        ETA the run started with).
    """
    build_dir = Path(build_dir)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    report = build_dir / "report" / "index.html"
    if not report.is_file():
        raise InputError(f"{report}: no report in this build",
                         fix=f"build it first: morphshell build <shape> --out {build_dir}")
    files, out = [], {}

    def save(png, name):
        files.append(_save_small(png, out_dir / name, width))

    with opened_studio(build_dir, warm=warm) as (d, _):
        out["usable_ms"], out["ready_ms"] = d.execute_script(
            "return [+document.body.getAttribute('data-usable'),"
            " +document.body.getAttribute('data-ready-ms')]")
        _shoot_editor(d, save, out)
        _shoot_run(d, save, out)
        _shoot_report(d, report, save)
    out["files"] = files
    return out


@contextlib.contextmanager
def opened_studio(build_dir, *, warm: bool = True):
    """The studio on a copy of ``build_dir`` (``build/.studio-shots-*``: beside the build, so
    that a run's render stage finds the same part cache), its page opened in a fresh
    headless chromium (a new profile) and loaded (``data-ready``); yields ``(driver,
    server)`` and removes the copy, the profile and the server after.  ``warm``: as
    :func:`studio_shots`."""
    build_dir = Path(build_dir)
    work = Path(tempfile.mkdtemp(prefix=".studio-shots-", dir=build_dir.resolve().parent))
    profile = tempfile.mkdtemp(prefix="morphshell-shots-")
    try:
        copy = work / build_dir.resolve().name
        shutil.copytree(build_dir, copy, symlinks=True)
        srv = StudioServer(resolve_folders([copy]))
        threading.Thread(target=srv.serve_forever, daemon=True).start()
        try:
            if warm:
                srv.warm()
            d = chromium_driver(1400, 1700, profile, extra=("--hide-scrollbars",))
            try:
                d.get(srv.url)
                _wait(d, lambda d: d.find_element("tag name", "body").get_attribute(
                    "data-ready"), "the studio")
                yield d, srv
            finally:
                d.quit()
        finally:
            srv.shutdown()
            srv.server_close()
    finally:
        shutil.rmtree(profile, ignore_errors=True)
        shutil.rmtree(work, ignore_errors=True)


def _shoot_editor(d, save, out: dict) -> None:
    """The editor: a bad brush value refused, then a slower region painted, its reachable
    band and a hover (``studio-error.png``, ``studio-paint.png``, ``studio.png``)."""
    centre = d.execute_script(
        "var e = studio.editor, V = e.V, c = [0, 0, 0], best = 0, bd = Infinity;"
        "for (var i = 0; i < e.nv; i++)"
        "  for (var j = 0; j < 3; j++) c[j] += V[3*i+j] / e.nv;"
        "for (i = 0; i < e.nv; i++) { var dd = Math.hypot(V[3*i]-c[0], V[3*i+1]-c[1],"
        " V[3*i+2]-c[2]); if (dd < bd) { bd = dd; best = i; } } return best;")
    # a bad value first: its message, and painting refused until it is fixed
    d.execute_script("var m = document.getElementById('brush-mode'); m.value = 'add';"
                     "m.dispatchEvent(new Event('change'));")
    type_into(d, "brush-value", "8")
    type_into(d, "brush-radius", "0")
    drag_on_editor(d, centre, 40, 10)
    save(_element_png(d, ".tools"), "studio-error.png")
    # a slower region: +8 s in a 12 mm brush, then the reachable band and a hover
    type_into(d, "brush-radius", "12")
    drag_on_editor(d, centre, 60, 14)
    _wait(d, lambda d: d.find_element("id", "editor-view").get_attribute(
        "data-strokes"), "the stroke")
    _wait(d, lambda d: d.find_element("id", "feas").get_attribute("data-seq") == str(
        d.execute_script("return studio.editor.seq")), "the live feasibility")
    out["preview_ms"] = int(d.find_element("id", "feas").get_attribute("data-ms"))
    d.execute_script("var s = document.getElementById('colour-mode'); s.value = 'band';"
                     "s.dispatchEvent(new Event('change'));"
                     "var p = studio.editor.screenOf(arguments[0]);"
                     "studio.editor.hover(p[0] + 3, p[1] + 3);", centre)
    save(_element_png(d, "#editor-section"), "studio-paint.png")
    save(d.get_screenshot_as_png(), "studio.png")


def _shoot_run(d, save, out: dict) -> None:
    """The run: the progress bar through every stage, then the results, a part's 3D preview
    and the ghost of the target (``studio-progress.png``, ``studio-results.png``,
    ``studio-ghost.png``)."""
    d.find_element("id", "variant").click()       # into a new build beside the original
    d.find_element("id", "run").click()
    # the ETA the run started with (the server's answer to the click)
    _wait(d, lambda d: d.execute_script("return !!(studio.job && studio.job.started)"),
          "the run to start")
    out["eta_start_s"] = d.execute_script("return studio.job.eta_s")
    # the bar with a stage, a percentage and an ETA (whichever stage is running then)
    _wait(d, lambda d: d.execute_script(
        "var j = studio.job; return !!(j && (j.state === 'done' || j.state === 'error' ||"
        " j.state === 'running' && j.stage && j.stage !== 'start' && j.progress > 0.1))"),
        "the run's first stages", timeout=600)
    save(_element_png(d, ".tools"), "studio-progress.png")
    _wait(d, lambda d: d.find_element("id", "progress-text").get_attribute(
        "data-state") in ("done", "error"), "the run", timeout=1800)
    if d.find_element("id", "progress-text").get_attribute("data-state") != "done":
        raise InputError("the studio's run failed: " + d.find_element("id", "error").text)
    out["run_s"] = d.execute_script("return studio.job.seconds")
    _wait(d, lambda d: d.find_element("id", "results").get_attribute("data-state")
          == "shown", "the results")
    d.find_element("css selector", "#parts-table tr[data-name='top.stl'] .part-3d").click()
    _wait(d, lambda d: d.find_element("id", "part-view").get_attribute("data-part"),
          "the part's 3D preview")
    save(_element_png(d, "#results-section"), "studio-results.png")
    _wait(d, lambda d: d.find_element("id", "compare").get_attribute("data-state")
          == "shown", "the comparison")
    save(_element_png(d, "#compare"), "studio-compare.png")
    save(_element_png(d, "#editor-section"), "studio-diff.png")
    d.execute_script("var v = studio.viewers[0]; v.setFrame(v.nf - 1); v.setGhost(true);"
                     "v.setColorMode('distance'); v.setScale('frame');")
    time.sleep(0.5)
    save(_element_png(d, "#viewer-section"), "studio-ghost.png")


def _shoot_report(d, report: Path, save) -> None:
    """The build's report with its viewer at a fifth of the morph (``report.png``)."""
    d.get(report.resolve().as_uri())
    _wait(d, lambda d: d.execute_script(
        "return !!(window.morphViewer && window.morphViewer.renderCount > 0)"),
        "the report's viewer")
    d.execute_script("window.morphViewer.setFrame(Math.round(window.morphViewer.nf*0.2))")
    save(d.get_screenshot_as_png(), "report.png")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pysolver.studio.shots",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("build_dir")
    ap.add_argument("out_dir", nargs="?", default="docs/img")
    ap.add_argument("--cold", action="store_true",
                    help="no warm-up: the page's first requests make the build's data")
    a = ap.parse_args(argv)
    try:
        res = studio_shots(a.build_dir, a.out_dir, warm=not a.cold)
        for p in res["files"]:
            print(f"{p} ({p.stat().st_size // 1000} kB)")
        print(f"page usable (editor, results) after {res['usable_ms']} ms, viewer loaded after "
              f"{res['ready_ms']} ms; live feasibility after a stroke: {res['preview_ms']} ms; "
              f"run into a variant: {res['run_s']} s (ETA at its start: {res['eta_start_s']} s)")
    except InputError as e:
        print(f"studio-shots: error: {e}", file=sys.stderr)
        return 2
    return 0


__all__ = ["studio_shots", "opened_studio", "chromium_driver", "have_browser", "type_into",
           "drag_on_editor"]

if __name__ == "__main__":
    sys.exit(main())
