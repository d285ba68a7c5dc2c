"""Screenshots of the studio and of the report for the README (``make studio-shots``).

Runs the studio on a build folder in this process, drives Debian's headless chromium
(Selenium with the system chromedriver; nothing is downloaded), places two keyframes in
the editor without saving them (the build is not changed), and captures the page; then
opens the build's ``report/index.html`` from ``file://`` and captures its top.

    python -m pysolver.studio.shots build/petal docs/img
"""

from __future__ import annotations

import argparse
import io
import os
import shutil
import sys
import tempfile
import threading
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


def _wait(driver, cond, what, timeout=120):
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


def studio_shots(build_dir, out_dir, *, width: int = 1100) -> list[Path]:
    """Write ``studio.png`` and ``report.png`` of ``build_dir`` into ``out_dir``."""
    build_dir = Path(build_dir)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    report = build_dir / "report" / "index.html"
    if not report.is_file():
        raise InputError(f"{report}: no report in this build",
                         fix=f"build it first: morphshell build <shape> --out {build_dir}")
    srv = StudioServer(resolve_folders([build_dir]))
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    profile = tempfile.mkdtemp(prefix="morphshell-shots-")
    out = []
    try:
        d = chromium_driver(1400, 1500, profile, extra=("--hide-scrollbars",))
        try:
            d.get(srv.url)
            _wait(d, lambda d: d.find_element("tag name", "body").get_attribute("data-ready"),
                  "the studio")
            # a frame in the middle of the morph, a picked base, two keyframes (not saved)
            d.execute_script(
                "var v = studio.viewers[0]; if (v) { v.setFrame(Math.round(v.nf * 0.12));"
                " v.selectBase(Math.floor(v.data.n_bases / 2)); }"
                "var e = studio.editor, V = e.V, lo = 0, hi = 0;"
                "for (var i = 0; i < e.nv; i++) { if (V[3*i] < V[3*lo]) lo = i;"
                " if (V[3*i] > V[3*hi]) hi = i; }"
                "e.keyframes = [{kind: 'keyframe', vertex: lo, time: 20},"
                " {kind: 'keyframe', vertex: hi, time: 45}]; e.listKeyframes(); e.update();")
            _wait(d, lambda d: d.find_element("id", "feas").get_attribute("data-seq"),
                  "the live feasibility")
            out.append(_save_small(d.get_screenshot_as_png(), out_dir / "studio.png", width))
            d.get(report.resolve().as_uri())
            _wait(d, lambda d: d.execute_script(
                "return !!(window.morphViewer && window.morphViewer.renderCount > 0)"),
                "the report's viewer")
            d.execute_script("window.morphViewer.setFrame(Math.round(window.morphViewer.nf*0.2))")
            out.append(_save_small(d.get_screenshot_as_png(), out_dir / "report.png", width))
        finally:
            d.quit()
    finally:
        srv.shutdown()
        srv.server_close()
        shutil.rmtree(profile, ignore_errors=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pysolver.studio.shots",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("build_dir")
    ap.add_argument("out_dir", nargs="?", default="docs/img")
    a = ap.parse_args(argv)
    try:
        for p in studio_shots(a.build_dir, a.out_dir):
            print(f"{p} ({p.stat().st_size // 1000} kB)")
    except InputError as e:
        print(f"studio-shots: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
