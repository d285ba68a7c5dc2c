"""The studio's first paint, where its time goes (not a test): the page opened in a fresh
headless Debian chromium (software WebGL), on a copy of a build served by the studio, and
the browser's own timings of it.

For each of ``--loads`` fresh browsers (a new profile each: nothing cached), prints and
writes: when the page was usable (``data-usable``: the editor shows the target and its
landscape and accepts a stroke, the results are shown) and when the morph viewer was
loaded (``data-ready-ms``), when ``studio.js`` started to run (three.js parsed before it),
and each request of the page (start, first byte, end; ms from the navigation).  With
``--cold`` the studio makes nothing ahead (no :meth:`StudioServer.warm`).

Writes ``<out>/first_paint.json``.

Usage::

    .venv/bin/python bench/bench_first_paint.py [--build build/petal] [--loads 3] [--cold]
        [--out build/bench]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pysolver.core.records import json_text  # noqa: E402
from pysolver.core.writes import atomic_write_text  # noqa: E402
from pysolver.studio.shots import have_browser, opened_studio  # noqa: E402

TIMINGS = """
var res = {};
performance.getEntriesByType('resource').forEach(function (e) {
  res[e.name.replace(location.origin, '')] = [Math.round(e.startTime),
    Math.round(e.responseStart), Math.round(e.responseEnd)]; });
return {usable_ms: +document.body.getAttribute('data-usable'),
  ready_ms: +document.body.getAttribute('data-ready-ms'),
  studio_js_ms: studio.started, requests: res};
"""


def one_load(build: Path, warm: bool) -> dict:
    """Open the studio on a copy of ``build`` (beside it) in a fresh browser; its timings."""
    with opened_studio(build, warm=warm) as (d, _):
        return d.execute_script(TIMINGS)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build", default="build/petal")
    ap.add_argument("--loads", type=int, default=3)
    ap.add_argument("--cold", action="store_true")
    ap.add_argument("--out", default="build/bench")
    a = ap.parse_args()
    build = Path(a.build)
    if not (build / "summary.json").is_file() or not have_browser():
        print(f"[bench] {build}: no build (make shape=petal first) or no Debian chromium; "
              "skipped", file=sys.stderr)
        return 0
    loads = []
    for k in range(a.loads):
        r = one_load(build, warm=not a.cold)
        loads.append(r)
        q = r["requests"]
        print(f"load {k + 1}/{a.loads}: usable {r['usable_ms']} ms, viewer {r['ready_ms']} ms, "
              f"studio.js ran at {r['studio_js_ms']} ms; target {q.get('/api/build/0/target')}, "
              f"results {q.get('/api/build/0/results')}, parts {q.get('/api/build/0/parts')}, "
              f"viewer {q.get('/api/build/0/viewer')} (start, first byte, end; ms)", flush=True)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "first_paint.json", json_text(
        {"build": str(build), "warm": not a.cold, "loads": loads}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
