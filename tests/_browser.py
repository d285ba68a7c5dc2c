"""Headless Debian chromium for the browser tests (Selenium, the system chromedriver).

No browser is downloaded: the driver path is given explicitly, so selenium-manager never
runs.  The flags keep an offline machine quiet (no background networking, no component
updates) and give WebGL a software rasteriser (SwiftShader), so canvases really render.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")
FLAGS = ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-default-apps", "--disable-extensions", "--use-angle=swiftshader",
         "--enable-unsafe-swiftshader", "--mute-audio")


def have_browser() -> bool:
    return CHROMIUM.is_file() and CHROMEDRIVER.is_file()


@contextlib.contextmanager
def chrome(width: int = 1400, height: int = 1600):
    """A headless chromium WebDriver with a fresh profile, closed and removed on exit."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    profile = tempfile.mkdtemp(prefix="morphshell-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = str(CHROMIUM)
    for a in FLAGS:
        opts.add_argument(a)
    opts.add_argument(f"--window-size={width},{height}")
    opts.add_argument(f"--user-data-dir={profile}")
    env = dict(os.environ, SE_OFFLINE="true")
    driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER), env=env), options=opts)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)
