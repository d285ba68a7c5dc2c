"""Headless Debian chromium for the browser tests (:func:`pysolver.studio.shots.chromium_driver`:
Selenium with the system chromedriver, so no browser is downloaded)."""

from __future__ import annotations

import contextlib
import shutil
import tempfile

from pysolver.studio.shots import chromium_driver, have_browser

__all__ = ["chrome", "have_browser"]


@contextlib.contextmanager
def chrome(width: int = 1400, height: int = 1600):
    """A headless chromium WebDriver with a fresh profile, closed and removed on exit."""
    profile = tempfile.mkdtemp(prefix="morphshell-chromium-")
    driver = chromium_driver(width, height, profile)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)
