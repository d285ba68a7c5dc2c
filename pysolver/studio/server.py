"""``morphshell studio``: a local web app to view simulated morphs, paint time landscapes and
build them again.

A small :class:`http.server.ThreadingHTTPServer` bound to 127.0.0.1.  It serves a fixed set
of static files that ship with the package (no CDN, works offline) and JSON endpoints over
the build folders named on the command line; nothing else of the file system is reachable.

Only its user can drive it (``docs/threat-model.md``, "The studio"):

* a random token per start, in the URL it prints (after ``#``, so it is never sent in a
  request line or a Referer).  The browser is started on a private page that POSTs the token
  to ``/session`` in a form body (never in a URL, so never in the browser's history); the
  answer sets it as an ``HttpOnly; SameSite=Strict`` session cookie.  Every ``/api/`` call
  carries it in that cookie or in the ``X-Morphshell-Token`` header (scripts; the page opened
  on the printed URL), compared in constant time;
* the ``Host`` must be ``127.0.0.1:<port>`` or ``localhost:<port>`` (DNS rebinding) and an
  ``Origin``, when sent, that same origin;
* POST bodies are ``application/json`` with a ``Content-Length`` of at most
  ``LIMITS.studio_max_body_bytes``, read whole before anything else; every error reply
  closes the connection, so no unread byte is ever parsed as a second request;
* a build runs one job at a time, and the studio one job at a time: a second request gets
  409 (busy), never a half-done write.

Endpoints (``<i>`` = index of a build folder)::

    GET  /                              the app (index.html)
    GET  /static/<name>                 whitelisted assets (three.js, the viewer, the app)
    GET  /api/builds                    the build folders
    GET  /api/build/<i>/viewer          the simulated morph (sim/viewer.py JSON)
    GET  /api/build/<i>/target          target stencil, landscape, cells, feasibility
    GET  /api/build/<i>/results         the report's verdict and figures, and the run's before
    GET  /api/build/<i>/parts           the STLs (only when made from the current tables)
    GET  /api/build/<i>/stl/<name>      one STL (download)
    GET  /api/build/<i>/report          the report (report/index.html)
    POST /api/build/<i>/preview         {"landscape"} -> feasibility per cell
    POST /api/build/<i>/keyframes       {"keyframes"} -> harmonic landscape + feasibility
    POST /api/build/<i>/import          {"csv"} -> the landscape of a CSV + feasibility
    POST /api/build/<i>/compare         {"other": j, "cells"} -> builds i and j cell by cell
                                         (the painted region, A - B) and their figures
    POST /api/build/<i>/run             {"build", "base_sha256", "landscape", "edits",
                                         "variant"} -> build it again, or into a new
                                         build beside it (a job)
    GET  /api/job                       progress of the running job
    POST /session                       token=<token> (a form) -> 303 to /, the session cookie

The studio writes nothing itself: *Run* is :func:`pysolver.build.rebuild` in a subprocess
(``python -m pysolver.studio.rerun``), the same stages as ``morphshell build`` after the
design stage, which replaces the folder only when every stage has finished.
"""

from __future__ import annotations

import errno
import gzip
import hmac
import json
import os
import re
import secrets
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import webbrowser
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, quote, urlsplit

import numpy as np

from ..build import rebuild_options, report_figures
from ..child import python_argv
from ..errors import InputError, MorphshellError
from ..params import LIMITS, PROGRAMMING
from ..simulator import build_parts, morph_viewer, viewer_assets
from ..stages import STAGES
from ..tables import (
    LANDSCAPE_SOURCE,
    predicted_timing_sd,
    read_record,
    read_stencil,
    read_table,
)
from .compare import compare_cells
from .landscape import (
    Feasibility,
    harmonic_landscape,
    keyframe_values,
    parse_keyframes,
    parse_landscape,
    parse_landscape_csv,
    parse_run,
    run_base_sha256,
)

STATIC_DIR = Path(__file__).resolve().parent / "static"
TOKEN_HEADER = "X-Morphshell-Token"
COOKIE = "morphshell-studio"
SESSION_MAX_BODY = 256
"""Bytes a ``POST /session`` body may have (``token=`` and 43 characters): a longer one is
refused before it is read."""
STL_NAME = re.compile(r"[a-z][a-z0-9_]{0,63}\.stl")
"""STL names the studio serves (and only those listed in ``stl/``)."""


class Busy(MorphshellError):
    """A job is running: the request would change what it is working on (HTTP 409)."""


class Stale(MorphshellError):
    """A Run whose landscape was not edited from the build's current one: another build's,
    or this build's before it was built again (HTTP 409)."""


def _static_files() -> dict:
    files = viewer_assets()
    files.update({name: STATIC_DIR / name for name in ("index.html", "studio.js", "studio.css")})
    return files


_TYPES = {".js": "text/javascript; charset=utf-8", ".css": "text/css; charset=utf-8",
          ".html": "text/html; charset=utf-8"}


def _jsonable(a):
    """A float array as a list with None for non-finite values."""
    return [None if not np.isfinite(x) else round(float(x), 4) for x in np.asarray(a, float)]


def _jsonable_or_none(a):
    """:func:`_jsonable`, or None for None (a record the build does not have)."""
    return None if a is None else _jsonable(a)


class Build:
    """One build folder: its tables and caches, loaded lazily and dropped after a run."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.lock = threading.Lock()
        self._viewer = None
        self._viewer_key = None
        self._viewer_bytes = None
        self._feas = None

    def info(self, i: int) -> dict:
        return {"id": i, "name": self.folder.name, "path": str(self.folder),
                "has_frames": (self.folder / "sim" / "frames.npz").is_file()}

    def forget(self) -> None:
        """Drop the caches (the folder was built again)."""
        with self.lock:
            self._feas = None
            self._viewer = self._viewer_key = None

    def viewer(self) -> dict:
        p = self.folder / "sim" / "frames.npz"
        if not p.is_file():
            raise InputError(f"{p}: no simulation in this build",
                             fix=f"run 'morphshell simulate {self.folder}' or press Run")
        key = (p.stat().st_mtime_ns, (self.folder / "cells.csv").stat().st_mtime_ns)
        with self.lock:
            if self._viewer_key != key:
                # positions as uint16 over their box (~2 um on a 150 mm shell, as the
                # report's viewer): petal's morph 6.8 MB instead of 12.5 MB of JSON
                self._viewer = morph_viewer(self.folder, max_frames=241, quantise=True)
                self._viewer_key = key
            return self._viewer

    def viewer_body(self, gzipped: bool) -> bytes:
        """The viewer's JSON as bytes, gzip-compressed when ``gzipped`` (kept with the data:
        petal's morph is 6.8 MB of JSON, 3.9 MB compressed; ``docs/results.md``)."""
        data = self.viewer()
        with self.lock:
            cache = self._viewer_bytes
            if cache is None or cache[0] is not data:
                raw = json.dumps(data, separators=(",", ":")).encode()
                cache = self._viewer_bytes = (data, raw, {})
            if not gzipped:
                return cache[1]
            if "gz" not in cache[2]:
                cache[2]["gz"] = gzip.compress(cache[1], compresslevel=5, mtime=0)
            return cache[2]["gz"]

    def feasibility(self) -> Feasibility:
        with self.lock:
            if self._feas is None:
                self._feas = Feasibility(self.folder)
            return self._feas

    def stencil(self):
        return read_stencil(self.folder / "stencil.obj")

    def landscape(self) -> np.ndarray:
        """(n_vertices,) float, s: the build's own landscape (``time_landscape.csv``)."""
        return read_table(self.folder, "time_landscape")["time_s"]

    def target(self) -> dict:
        V, _, F = self.stencil()
        land = self.landscape()
        cells = read_table(self.folder, "cells")
        ev = self.feasibility().evaluate(land)
        done = None
        if (self.folder / "sim" / "frames.npz").is_file():
            done = self.viewer()["cells"]["t_done"]
        return {"V": np.round(V, 5).reshape(-1).tolist(), "F": F.reshape(-1).tolist(),
                "build": self.folder.name,
                "landscape_sha256": run_base_sha256(self.folder, land),   # a Run's base
                "landscape": [float(x) for x in land],
                "vertex_a": cells["vertex_a"].tolist(), "vertex_b": cells["vertex_b"].tolist(),
                "programmed": {
                    "t_star": _jsonable(cells["t_star_s"]),
                    "clamped": np.asarray(cells["clamped"], int).tolist(),
                    "h_top": _jsonable(cells["thickness_top_mm"]),
                    "h_bottom": _jsonable(cells["thickness_bottom_mm"]),
                    "t_done": done, "t_sd": _jsonable_or_none(
                        predicted_timing_sd(self.folder, len(cells["cell_id"])))},
                "feasibility": self._feas_json(ev),
                "limits": {"max_time_s": LIMITS.max_landscape_s,
                           "max_radius_mm": LIMITS.studio_max_radius_mm},
                "source": read_record(self.folder / LANDSCAPE_SOURCE)}

    @staticmethod
    def _feas_json(ev) -> dict:
        n = len(ev["clamped"])
        n_clamped = int(ev["clamped"].sum())
        return {"t_star": _jsonable(ev["t_star"]), "t_min": _jsonable(ev["t_min"]),
                "t_max": _jsonable(ev["t_max"]), "clamped": ev["clamped"].astype(int).tolist(),
                "side": np.asarray(ev["side"], int).tolist(), "n_clamped": n_clamped,
                "refused": bool(n and n_clamped / n > PROGRAMMING.max_clamped_fraction),
                "max_clamped_fraction": PROGRAMMING.max_clamped_fraction}

    def n_vertices(self) -> int:
        return len(self.stencil()[0])

    def preview(self, payload) -> dict:
        land = parse_landscape(payload, self.n_vertices())
        t0 = time.perf_counter()
        feas = self._feas_json(self.feasibility().evaluate(land))
        feas["seconds"] = round(time.perf_counter() - t0, 4)
        return {"feasibility": feas}

    def import_csv(self, payload) -> dict:
        """``{"csv": text}`` (an upload: validated, :func:`parse_landscape_csv`) -> the
        landscape and its feasibility; nothing is written."""
        if not isinstance(payload, dict) or set(payload) != {"csv"}:
            raise InputError("the import request must be {'csv': text}",
                             fix="send the CSV file's text as 'csv'")
        land = parse_landscape_csv(payload["csv"], self.n_vertices())
        return {"landscape": [float(x) for x in land],
                "feasibility": self._feas_json(self.feasibility().evaluate(land))}

    def check_run(self, req: dict) -> None:
        """Refuse a Run (:func:`parse_run`'s ``req``) that was not edited from this build's
        current landscape: one landscape, one build.  The base hash binds the build's
        resolved folder (:func:`run_base_sha256`), so two builds of one name (``regular``
        beside another ``regular``) and one landscape are still told apart.

        Raises
        ------
        Stale
            It names another build, or its base is not this build's own landscape (another
            build's, of any name, or this one's before it was built again).
        """
        if req["build"] != self.folder.name:
            raise Stale(f"this Run names build {req['build'][:80]!r} but was sent to build "
                        f"{self.folder.name!r}: nothing was built",
                        fix="select the build in the editor, wait for it to load, then Run")
        if req["base_sha256"] != run_base_sha256(self.folder, self.landscape()):
            raise Stale(f"the edit was not made on the current landscape of build "
                        f"{self.folder.name!r} ({self.folder}) "
                        "(another build's, perhaps one of the same name, or this one's "
                        "before it was built again): nothing was built",
                        fix="load the build again in the editor (select it), then Run; "
                            "export the edit as CSV first to keep it")

    def keyframes(self, payload) -> dict:
        V, _, F = self.stencil()
        b, bc = keyframe_values(parse_keyframes(payload, len(V)))
        land = harmonic_landscape(V, F, b, bc)
        return {"landscape": [float(x) for x in land],
                "feasibility": self._feas_json(self.feasibility().evaluate(land))}

    def results(self) -> dict:
        now = report_figures(self.folder)
        edited = (read_record(self.folder / "summary.json") or {}).get("edited") or {}
        has_report = (self.folder / "report" / "index.html").is_file()
        return {"now": now, "before": edited.get("before") if edited else None,
                "edited": bool(edited), "report": has_report}

    def parts(self) -> dict:
        return build_parts(self.folder)

    def stl(self, name: str) -> Path:
        listed = {s["name"] for s in self.parts()["stls"]}
        if not STL_NAME.fullmatch(name) or f"stl/{name}" not in listed:
            raise InputError(f"no printable part {name!r} in this build",
                             fix="pick one of the parts listed (stale parts are not served)")
        return self.folder / "stl" / name


class Job:
    """The one job (a rebuild) running in a subprocess; its progress events (JSON lines on
    its stdout, :func:`pysolver.progress.emit_events`) drive one progress bar over every
    stage, weighted by the stage times of the build being run again; its stderr is kept
    (the last lines) for the error message."""

    DEFAULT_S = {"start": 4.0, "program": 3.0, "simulate": 20.0, "simulate_contact": 20.0,
                 "refine": 25.0, "render": 40.0, "report": 10.0}
    """Expected seconds of a stage the build did not time (its own times come first);
    ``start`` is the subprocess loading the stages."""

    def __init__(self):
        self.lock = threading.Lock()
        self.state = {"state": "idle", "progress": 0.0, "message": "", "build": None,
                      "error": None, "stage": None, "eta_s": None}
        self.on_done = None

    def snapshot(self) -> dict:
        with self.lock:
            return json.loads(json.dumps(self.state))

    def running(self) -> bool:
        with self.lock:
            return self.state["state"] == "running"

    def start(self, build: Build, index: int, land, edits, *, out: Path | None = None,
              on_done=None) -> None:
        """Start a rebuild of ``build`` with landscape ``land`` (validated) and its edit log;
        into the new folder ``out`` (a variant) when given, ``on_done(out)`` called once it
        is complete.

        Raises
        ------
        Busy
            A job is already running (this build's or another's).
        """
        summ, opts = rebuild_options(build.folder)   # InputError: not a build, nothing run
        times = summ.get("timings_s") or {}
        # the stages a rebuild runs, as it decides (pysolver.stages.STAGES after the design)
        plan = ["start"] + [s.name for s in STAGES[1:] if s.wanted(opts)]
        expect = {s: float(times.get(s) or self.DEFAULT_S[s]) for s in self.DEFAULT_S}
        with self.lock:
            if self.state["state"] == "running":
                raise Busy("a run is already going on"
                           + (" (this build)" if self.state["build"] == index else
                              f" (build {self.state['build']})"),
                           fix="wait for it to finish (see the progress bar), then run again")
            self.state = {"state": "running", "progress": 0.0, "message": "starting",
                          "build": index, "error": None, "stage": None, "plan": plan,
                          "eta_s": round(sum(expect[s] for s in plan), 1),
                          "started": time.time(), "log": [],
                          "variant": None if out is None else out.name}
        req = json.dumps({"folder": str(build.folder), "landscape": [float(x) for x in land],
                          "source": {"edits": edits},
                          **({} if out is None else {"out": str(out)})})
        self.on_done = (lambda: on_done(out)) if out is not None and on_done else None
        threading.Thread(target=self._run, args=(build, req, plan, expect),
                         daemon=True).start()

    def _run(self, build: Build, req: str, plan: list, expect: dict):
        cmd = python_argv("pysolver.studio.rerun")
        done_s = 0.0           # expected seconds of the finished stages
        actual: dict = {}      # seconds the finished stages took in this run
        stage, t_stage, frac = "start", time.time(), 0.0
        tail: list[str] = []
        t0 = time.time()
        try:
            proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
            drain = threading.Thread(target=_keep_tail, args=(proc.stderr, tail), daemon=True)
            drain.start()
            ticker, timed_out = threading.Event(), threading.Event()

            def tick():   # the bar moves between progress lines too (time / expected time)
                while not ticker.wait(0.5):
                    if time.time() - t0 > LIMITS.studio_job_timeout_s:   # even when silent
                        timed_out.set()
                        proc.kill()
                        return
                    self._progress(plan, expect, (done_s, actual), stage, t_stage, frac,
                                   None)

            threading.Thread(target=tick, daemon=True).start()
            proc.stdin.write(req)
            proc.stdin.close()
            for raw in proc.stdout:
                ev = progress_event(raw)
                if ev is None:        # not an event (the verdict printed on stdout)
                    continue
                if ev.get("starts") in self.DEFAULT_S:
                    done_s += expect[stage]
                    actual[stage] = time.time() - t_stage
                    stage, t_stage, frac = ev["starts"], time.time(), 0.0
                    if stage not in plan:     # contact switched on: one more simulation
                        plan.insert(plan.index("report") if "report" in plan else len(plan),
                                    stage)
                elif stage != "start" and "k" in ev and (stage != "refine"
                                                         or ev["stage"] == "refine"):
                    frac = max(frac, min(ev["k"] / max(ev["n"], 1), 1.0))
                self._progress(plan, expect, (done_s, actual), stage, t_stage, frac,
                               ev["text"])
            rc = proc.wait()
            ticker.set()
            drain.join(10)
            if timed_out.is_set():
                raise MorphshellError(f"the run took longer than "
                                      f"{LIMITS.studio_job_timeout_s:g} s (stage {stage}) and "
                                      "was stopped; nothing of this edit was saved")
            build.forget()
            if rc in (0, 3) and self.on_done is not None:
                self.on_done()
            if rc not in (0, 3):   # 3 = the report's FAIL verdict: the build is complete
                msg = [t for t in tail if "error:" in t or t.startswith("  Fix:")] or tail[-3:]
                raise MorphshellError(" / ".join(msg).replace("morphshell studio run: ", "")
                                      + "\nNothing of this edit was saved: the build is as "
                                        "it was, and the edit is still in the editor.")
            self._set(state="done", progress=1.0, eta_s=0.0, message="done", stage=None,
                      seconds=round(time.time() - t0, 1))
        except Exception as e:  # noqa: BLE001 - reported to the browser, not raised
            self._set(state="error", error=str(e), message="failed", eta_s=None)

    def _progress(self, plan, expect, done, stage, t_stage, frac, line):
        done_s, actual = done
        total = sum(expect[s] for s in plan)
        now = time.time()
        with self.lock:
            if self.state["state"] != "running":
                return
            if stage is not None:
                spent = now - t_stage
                # within a stage: its own count when it prints one, else the time it has
                # taken of the time it took in the build (never past 95 % on time alone)
                f = max(frac, min(spent / expect[stage], 0.95))
                p = (done_s + f * expect[stage]) / total
                self.state["progress"] = round(max(self.state["progress"], min(p, 0.999)), 4)
                self.state["stage"] = stage
                self.state["eta_s"] = eta_seconds(plan, expect, actual, stage, spent, frac)
            if line is not None:
                self.state["message"] = line[-200:]
                self.state["log"] = (self.state["log"] + [line[-200:]])[-12:]

    def _set(self, **kw):
        with self.lock:
            self.state.update(kw)


def progress_event(raw: str) -> dict | None:
    """One line of a Run's stdout as a progress event (:func:`pysolver.progress.say`), or
    None when it is not one: ``event`` ("stage" or "line"), ``stage``, ``text`` (str),
    ``starts`` (str, a stage event), ``k`` and ``n`` (whole numbers, ``n >= 1``) or neither.
    """
    try:
        ev = json.loads(raw)
    except ValueError:
        return None
    if not isinstance(ev, dict) or ev.get("event") not in ("stage", "line") or not all(
            isinstance(ev.get(key), str) for key in ("stage", "text")):
        return None
    if ev["event"] == "stage" and not isinstance(ev.get("starts"), str):
        return None
    if ("k" in ev or "n" in ev) and not (
            isinstance(ev.get("k"), int) and isinstance(ev.get("n"), int) and ev["n"] >= 1):
        return None
    ev["text"] = ev["text"][-200:]
    return ev


def _keep_tail(stream, tail: list, keep: int = 40) -> None:
    """Read ``stream`` to its end, keeping its last ``keep`` lines in ``tail``."""
    for line in stream:
        tail.append(line.rstrip())
        del tail[:-keep]


def eta_seconds(plan, expect, actual, stage, spent, frac) -> float:
    """Seconds a run has left: the rest of the stage running now and the stages after it,
    each at the build's own time scaled by this run's pace.

    Parameters
    ----------
    plan : list of str -- the stages in order
    expect : dict str -> float, s -- each stage's time in the build being run again
    actual : dict str -> float, s -- the finished stages' times in this run
    stage : str -- the stage running now
    spent : float, s -- time in it so far
    frac : float -- its own count (0 when it prints none)

    Returns
    -------
    float, s
        ``pace = sum(actual) / sum(expect)`` over the finished stages but the start (1
        before one has finished; kept within 0.25-4); the stage running now has left
        ``spent (1 - frac) / frac`` once its count is past 5 %, else its paced time less
        ``spent`` (never below 0); each later stage its paced time.
    """
    done = [s for s in actual if s != "start" and s in expect]
    pace = (sum(actual[s] for s in done) / max(sum(expect[s] for s in done), 1e-9)
            if done else 1.0)
    pace = min(max(pace, 0.25), 4.0)
    if frac > 0.05:
        now_left = spent * (1 - frac) / frac
    else:
        now_left = max(expect[stage] * pace - spent, 0.0)
    later = plan[plan.index(stage) + 1:] if stage in plan else []
    return round(now_left + pace * sum(expect[s] for s in later), 1)


class StudioServer(ThreadingHTTPServer):
    daemon_threads = True
    request_queue_size = 128   # a burst of requests waits to be served, never a reset

    def __init__(self, folders, port: int = 0, token: str | None = None):
        self.slots = threading.BoundedSemaphore(LIMITS.studio_max_connections)
        self.builds = [Build(Path(f).resolve()) for f in folders]
        self.builds_lock = threading.Lock()
        self.job = Job()
        self.files = _static_files()
        self.token = token or secrets.token_urlsafe(32)
        try:
            super().__init__(("127.0.0.1", port), Handler)
        except OSError as e:
            if e.errno == errno.EADDRINUSE:
                raise InputError(f"port {port} on 127.0.0.1 is in use (another studio or "
                                 "another program)",
                                 fix="give another --port, or --port 0 for any free one") from None
            if e.errno in (errno.EACCES, errno.EPERM):
                raise InputError(f"port {port}: permission denied (ports below 1024 need "
                                 "root)", fix="use a port from 1024 to 65535, or 0") from None
            raise

    def add_build(self, folder: Path) -> None:
        """List a new build (a variant a Run made) after the others."""
        with self.builds_lock:
            if all(b.folder != folder for b in self.builds):
                self.builds.append(Build(folder))

    def variant_folder(self, build: Build, name: str) -> Path:
        """The new folder of a variant ``name`` of ``build``: beside it, and new.

        Raises
        ------
        InputError
            A file or folder of that name is there already (never replaced).
        """
        out = build.folder.parent / name
        if out.exists() or out.is_symlink() or any(b.folder == out for b in self.builds):
            raise InputError(f"{out} exists already: a variant is always a new build",
                             fix=f"name the variant otherwise (e.g. {build.folder.name}-"
                                 f"{len(self.builds) + 1})")
        return out

    def process_request(self, request, client_address):
        """Serve ``request`` in a thread once one of ``LIMITS.studio_max_connections`` slots
        is free (until then the next connections wait in the listen queue, holding no
        thread and no memory of the studio's)."""
        self.slots.acquire()
        try:
            super().process_request(request, client_address)
        except BaseException:
            self.slots.release()
            raise

    def process_request_thread(self, request, client_address):
        try:
            super().process_request_thread(request, client_address)
        finally:
            self.slots.release()

    def handle_error(self, request, client_address):
        # a browser closing its connection is not worth a traceback on the terminal
        if not isinstance(sys.exc_info()[1], (ConnectionError, TimeoutError)):
            super().handle_error(request, client_address)

    @property
    def origin(self) -> str:
        return f"http://127.0.0.1:{self.server_address[1]}"

    @property
    def url(self) -> str:
        """The URL to open: the origin with the token after ``#`` (never sent to a server)."""
        return f"{self.origin}/#token={self.token}"


class Handler(BaseHTTPRequestHandler):
    server: StudioServer
    protocol_version = "HTTP/1.1"
    timeout = 60   # s: a client that stops sending mid-request is dropped
    error_content_type = "text/plain; charset=utf-8"
    error_message_format = "%(code)d %(message)s: %(explain)s\n"

    def log_message(self, fmt, *args):  # quiet: the terminal shows the URL and errors only
        pass

    # ------------------------------------------------------------------ deadline
    def handle_one_request(self):
        """Serve one request, its line and headers read within
        ``LIMITS.studio_header_timeout_s`` of the moment the studio starts waiting for them
        (a kept-alive connection's idle time included): a client that sends slowly, or
        nothing, has its connection closed then, and frees its slot."""
        self._cut = self._headers_in = False
        self._deadline_lock = threading.Lock()
        timer = threading.Timer(LIMITS.studio_header_timeout_s, self._cut_off)
        timer.daemon = True
        timer.start()
        try:
            super().handle_one_request()
        finally:
            timer.cancel()

    def _cut_off(self):
        with self._deadline_lock:
            if self._headers_in:
                return
            self._cut = True
        self.close_connection = True
        try:   # wakes the read waiting for the request line or a header: it sees the end
            self.connection.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass

    def parse_request(self):
        ok = super().parse_request()
        with self._deadline_lock:
            self._headers_in = not self._cut
        if not self._headers_in:   # headers cut short by the deadline: not a request
            self.close_connection = True
            return False
        return ok

    # ------------------------------------------------------------------ replies
    def _send(self, code, body: bytes, ctype="application/json; charset=utf-8", extra=()):
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("Referrer-Policy", "no-referrer")
        self.send_header("X-Frame-Options", "DENY")
        for k, v in extra:
            self.send_header(k, v)
        if code >= 400:   # never keep a connection alive after an error
            self.close_connection = True
            self.send_header("Connection", "close")
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, code, obj):
        self._send(code, json.dumps(obj, separators=(",", ":")).encode())

    def _error(self, code, message, fix=None):
        self._json(code, {"error": message, **({"fix": fix} if fix else {})})

    # ------------------------------------------------------------------ guards
    def _host_ok(self) -> bool:
        # DNS rebinding guard: only requests addressed to this loopback server
        port = self.server.server_address[1]
        return self.headers.get("Host", "") in (f"127.0.0.1:{port}", f"localhost:{port}")

    def _origin_ok(self) -> bool:
        origin = self.headers.get("Origin")
        if origin is None:
            return self.headers.get("Sec-Fetch-Site", "same-origin") in ("same-origin", "none")
        port = self.server.server_address[1]
        return origin in (f"http://127.0.0.1:{port}", f"http://localhost:{port}")

    def _is_token(self, sent: str) -> bool:
        return hmac.compare_digest(sent.encode("utf-8", "surrogateescape"),
                                   self.server.token.encode())

    def _token_ok(self) -> bool:
        """The token in the ``X-Morphshell-Token`` header, else in the session cookie."""
        sent = self.headers.get(TOKEN_HEADER)
        if sent is not None:
            return self._is_token(sent)
        cookies = [part.strip().partition("=") for line in self.headers.get_all("Cookie") or []
                   for part in line.split(";")]
        return any(name == COOKIE and eq and self._is_token(value)
                   for name, eq, value in cookies)

    def _length(self, limit: int = LIMITS.studio_max_body_bytes):
        """The request's ``Content-Length`` (ASCII digits only), or None after an error reply
        (411 without one or with a chunked body, 400 when it is not one whole number, 413
        above ``LIMITS.studio_max_body_bytes``)."""
        if self.headers.get("Transfer-Encoding"):
            return self._error(HTTPStatus.LENGTH_REQUIRED, "chunked request bodies are not "
                                                           "accepted", "send a Content-Length")
        raw = self.headers.get_all("Content-Length") or []
        if not raw:
            return self._error(HTTPStatus.LENGTH_REQUIRED, "no Content-Length",
                               "send the JSON body with its Content-Length")
        if len(raw) > 1 or not re.fullmatch(r"[0-9]{1,18}", raw[0].strip(" \t")):
            return self._error(HTTPStatus.BAD_REQUEST, f"Content-Length {', '.join(raw)[:40]!r} "
                                                       "is not a whole number of bytes")
        n = int(raw[0])
        if n > limit:
            return self._error(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, f"the request body is {n} "
                               f"bytes, more than {limit}")
        return n

    def _read_body(self, limit: int = LIMITS.studio_max_body_bytes):
        """The whole request body, or None after an error reply; the connection is then
        closed, so no unread byte is ever parsed as another request."""
        n = self._length(limit)
        if n is None:
            return None
        body = self.rfile.read(n)
        if len(body) != n:
            self.close_connection = True
            return None
        return body

    def _refusal(self):
        """Why the request is refused before anything of its body is read (host, origin,
        token on ``/api/`` and on every POST, a POST to a path that takes none, a body on a
        GET), as ``(status, message, fix)``; None when it may go on."""
        if not self._host_ok():
            return (HTTPStatus.FORBIDDEN, "bad Host header (the studio answers only to "
                                          "127.0.0.1 and localhost)", None)
        path = urlsplit(self.path).path
        # the app's page itself (public code, no data, never framed) may be reached from
        # another site: the redirect of POST /session that a page opened from a file sent
        app_page = self.command in ("GET", "HEAD") and path == "/" and "Origin" not in self.headers
        if not self._origin_ok() and not app_page:
            return HTTPStatus.FORBIDDEN, "requests from another origin are refused", None
        if path.startswith("/api/") or self.command == "POST":   # every POST, on any path
            if not self._token_ok():
                return (HTTPStatus.FORBIDDEN, "missing or wrong studio token",
                        "open the URL the studio printed when it started (it ends in "
                        "#token=...)")
        if self.command == "POST" and _POST_ROUTE.fullmatch(path) is None:
            return HTTPStatus.NOT_FOUND, f"no POST route {path[:80]!r}", None
        if self.command != "POST" and (self.headers.get("Transfer-Encoding") or self.headers.get(
                "Content-Length", "0").strip() != "0"):
            # a body on a GET would stay on the connection: refused, and the connection closed
            return HTTPStatus.BAD_REQUEST, f"a {self.command} request has no body", None
        return None

    def _payload(self):
        """The POST body parsed as JSON, or ``_NO_BODY`` after an error reply."""
        data = self._read_body()
        if data is None:
            return _NO_BODY
        if self.headers.get_content_type() != "application/json":
            self._error(HTTPStatus.UNSUPPORTED_MEDIA_TYPE,
                        "the request body must be application/json")
            return _NO_BODY
        try:
            return json.loads(data.decode("utf-8") or "{}", parse_constant=_refuse_constant)
        except (UnicodeDecodeError, ValueError, RecursionError) as e:
            self._error(HTTPStatus.BAD_REQUEST, f"the request body is not JSON ({e})",
                        "send a JSON object")
            return _NO_BODY

    def _session(self):
        """``POST /session``: the token in a form body (the private page's) -> ``303 See
        Other`` to ``/`` with the session cookie; a wrong token gets 403 and no cookie.

        The one request whose ``Origin`` may be ``null`` (a page opened from a file has that
        origin): the token in its body is what lets it in.  Host, origin, type and a body of
        at most ``SESSION_MAX_BODY`` bytes are checked before the body is read."""
        origin = self.headers.get("Origin")
        if not self._host_ok() or origin not in (None, "null") and not self._origin_ok():
            return self._error(HTTPStatus.FORBIDDEN, "bad Host or Origin for a session")
        if self.headers.get_content_type() != "application/x-www-form-urlencoded":
            return self._error(HTTPStatus.UNSUPPORTED_MEDIA_TYPE,
                               "a session is opened by a form (token=...)")
        body = self._read_body(SESSION_MAX_BODY)
        if body is None:
            return None
        sent = parse_qs(body.decode("ascii", "replace")).get("token") or [""]
        if len(sent) != 1 or not self._is_token(sent[0]):
            return self._error(HTTPStatus.FORBIDDEN, "wrong studio token",
                               "open the URL the studio printed when it started")
        return self._send(HTTPStatus.SEE_OTHER, b"", "text/plain; charset=utf-8", extra=[
            ("Location", "/"),
            ("Set-Cookie", f"{COOKIE}={self.server.token}; HttpOnly; SameSite=Strict; Path=/")])

    def _guard(self, fn, *, body: bool):
        # who and where from first: nothing of a refused request's body is read (its
        # connection is closed), so a caller without the token holds no memory here
        if self.command == "POST" and urlsplit(self.path).path == "/session":
            return self._session()
        refused = self._refusal()
        if refused is not None:
            return self._error(*refused)
        path = urlsplit(self.path).path
        payload = self._payload() if body else None
        if payload is _NO_BODY:
            return None
        try:
            return fn(path, payload) if body else fn(path)
        except InputError as e:
            return self._error(HTTPStatus.BAD_REQUEST, e.problem, e.fix)
        except (Busy, Stale) as e:
            return self._error(HTTPStatus.CONFLICT, e.problem, e.fix)
        except MorphshellError as e:   # e.g. a model file the build names is broken
            return self._error(HTTPStatus.UNPROCESSABLE_ENTITY, e.problem, e.fix)
        except Exception as e:  # noqa: BLE001 - a bug: tell the browser, keep serving
            return self._error(HTTPStatus.INTERNAL_SERVER_ERROR,
                               f"internal error ({type(e).__name__}: {e}); this is a bug")

    def do_GET(self):  # noqa: N802 - http.server's name
        self._guard(self._get, body=False)

    def do_HEAD(self):  # noqa: N802
        self._guard(self._get, body=False)

    def do_POST(self):  # noqa: N802
        self._guard(self._post, body=True)

    def _other(self):
        # any other method (PUT, DELETE, OPTIONS: a CORS preflight) is refused, its body
        # unread, and the connection closed
        self._error(HTTPStatus.METHOD_NOT_ALLOWED, f"method {self.command} is not allowed")

    do_PUT = do_DELETE = do_OPTIONS = do_PATCH = _other  # noqa: N815

    # ------------------------------------------------------------------ routes
    def _build(self, parts):
        try:
            i = int(parts[2]) if parts[2].isdigit() else -1
        except ValueError:
            i = -1
        with self.server.builds_lock:
            if not 0 <= i < len(self.server.builds):
                raise _NotFound(f"no build number {parts[2][:20]!r}")
            return i, self.server.builds[i]

    def _get(self, path):
        try:
            return self._get_route(path)
        except _NotFound as e:
            return self._error(HTTPStatus.NOT_FOUND, str(e))

    def _get_route(self, path):
        if path == "/favicon.ico":
            return self._send(HTTPStatus.NO_CONTENT, b"", "image/x-icon")
        if path in ("/", "/index.html"):
            path = "/static/index.html"
        if path.startswith("/static/"):
            f = self.server.files.get(path[len("/static/"):])   # a whitelist: no path opened
            if f is None:
                raise _NotFound("not found")
            return self._send(HTTPStatus.OK, f.read_bytes(), _TYPES[f.suffix])
        parts = path.strip("/").split("/")
        if parts == ["api", "builds"]:
            with self.server.builds_lock:
                builds = list(self.server.builds)
            return self._json(HTTPStatus.OK, [b.info(i) for i, b in enumerate(builds)])
        if parts == ["api", "job"]:
            return self._json(HTTPStatus.OK, self.server.job.snapshot())
        if len(parts) >= 4 and parts[:2] == ["api", "build"]:
            i, b = self._build(parts)
            what = parts[3]
            if len(parts) == 4 and what == "viewer":
                gz = "gzip" in self.headers.get("Accept-Encoding", "")
                return self._send(HTTPStatus.OK, b.viewer_body(gz), extra=[
                    ("Content-Encoding", "gzip")] if gz else [])
            if len(parts) == 4 and what in ("target", "results", "parts"):
                return self._json(HTTPStatus.OK, getattr(b, what)())
            if len(parts) == 4 and what == "report":
                p = b.folder / "report" / "index.html"
                if not p.is_file():
                    raise _NotFound("this build has no report yet")
                return self._send(HTTPStatus.OK, p.read_bytes(), _TYPES[".html"])
            if len(parts) == 5 and what == "stl":
                p = b.stl(parts[4])
                return self._send(HTTPStatus.OK, p.read_bytes(), "model/stl", extra=[
                    ("Content-Disposition", attachment(f"{b.folder.name}-{p.name}"))])
        raise _NotFound("not found")

    def _post(self, path, payload):
        parts = path.strip("/").split("/")
        if len(parts) == 4 and parts[:2] == ["api", "build"]:
            try:
                i, b = self._build(parts)
            except _NotFound as e:
                return self._error(HTTPStatus.NOT_FOUND, str(e))
            if parts[3] == "preview":
                return self._json(HTTPStatus.OK, b.preview(payload))
            if parts[3] == "keyframes":
                return self._json(HTTPStatus.OK, b.keyframes(payload))
            if parts[3] == "import":
                return self._json(HTTPStatus.OK, b.import_csv(payload))
            if parts[3] == "compare":
                return self._json(HTTPStatus.OK, self._compare(b, payload))
            if parts[3] == "run":
                return self._run(i, b, payload)
        return self._error(HTTPStatus.NOT_FOUND, "not found")


    def _compare(self, b: Build, payload) -> dict:
        """``{"other": j, "cells": [...] (optional)}`` -> :func:`compare_cells` of this build
        (A) and build j (B), with both builds' report figures."""
        if not isinstance(payload, dict) or not set(payload) <= {"other", "cells"} or \
                "other" not in payload:
            raise InputError("the compare request must be {'other': build number, 'cells': "
                             "[cell ids] (optional)}")
        j = payload["other"]
        if isinstance(j, bool) or not isinstance(j, int):
            raise InputError(f"'other' {str(j)[:20]!r} is not a build number")
        try:
            _, o = self._build(["api", "build", str(j)])
        except _NotFound as e:
            raise InputError(f"compare: {e}", fix="pick one of the builds listed") from None
        cells = payload.get("cells")
        if cells is not None and (not isinstance(cells, list) or len(cells) > 10 ** 6 or any(
                isinstance(c, bool) or not isinstance(c, int) for c in cells)):
            raise InputError("'cells' must be a list of cell ids (whole numbers)")
        out = compare_cells(b.viewer()["cells"], o.viewer()["cells"], cells)
        out["figures"] = {"a": report_figures(b.folder), "b": report_figures(o.folder)}
        out["names"] = {"a": b.folder.name, "b": o.folder.name}
        return out

    def _run(self, i: int, b: Build, payload):
        req = parse_run(payload, b.n_vertices())
        b.check_run(req)
        srv = self.server
        out = None if req["variant"] is None else srv.variant_folder(b, req["variant"])
        srv.job.start(b, i, req["landscape"], req["edits"], out=out, on_done=srv.add_build)
        return self._json(HTTPStatus.OK, srv.job.snapshot())


class _NotFound(Exception):
    pass


_POST_ROUTE = re.compile(r"/api/build/[0-9]+/(preview|keyframes|import|compare|run)")
"""The only paths a POST may go to (:meth:`Handler._post`); any other is refused before its
body is read."""

_NO_BODY = object()
"""What :meth:`Handler._payload` returns after an error reply."""


def attachment(name: str) -> str:
    """A ``Content-Disposition`` value that downloads as ``name``, whatever its characters:
    an ASCII fallback (anything but letters, digits, ``.``, ``-`` and ``_`` replaced by
    ``_``) and the name itself in UTF-8 (RFC 6266 and RFC 5987 ``filename*``)."""
    fallback = re.sub(r"[^A-Za-z0-9._-]", "_", name)
    utf8 = quote(name.encode("utf-8", "surrogateescape"), safe="")
    return f"attachment; filename=\"{fallback}\"; filename*=UTF-8''{utf8}"


def _refuse_constant(name):
    raise ValueError(f"{name} is not a JSON number")


def resolve_folders(dirs) -> list[Path]:
    """Build folders to open: those given, else every ``build/<name>/`` with a stencil."""
    if not dirs:
        dirs = sorted(p for p in Path("build").glob("*") if (p / "stencil.obj").is_file())
        if not dirs:
            raise InputError("no build folder given and none in ./build",
                             fix="build a shape first (make shape=petal) or name a folder: "
                                 "morphshell studio build/petal")
    out = []
    for d in dirs:
        p = Path(d)
        need = [n for n in ("stencil.obj", "cells.csv", "time_landscape.csv")
                if not (p / n).is_file()]
        if not p.is_dir() or need:
            raise InputError(f"{p}: not a design folder"
                             + (f" (missing {', '.join(need)})" if p.is_dir() else ""),
                             fix="pass a folder written by 'morphshell build' (build/<shape>)")
        out.append(p.resolve())
    return out


def serve(dirs, *, port: int = 0, open_browser: bool = True, ready=None) -> None:
    """Run the studio until interrupted.

    Parameters
    ----------
    dirs : list of path-like
        Build folders (side by side in the viewer; the editor works on one at a time).
    port : int
        TCP port on 127.0.0.1 (0 = any free port).
    open_browser : bool
        Open the default browser on the app (with its token).
    ready : callable, optional
        Called with the server once it listens (tests).

    Raises
    ------
    InputError
        A port outside 0-65535 or in use, or a folder that is not a build.
    """
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise InputError(f"port {port!r} is not a TCP port",
                         fix="use a port from 1024 to 65535, or 0 for any free one")
    srv = StudioServer(resolve_folders(dirs), port=port)
    print(f"morphshell studio: {srv.url}\n  ({len(srv.builds)} build(s); only this URL, with "
          "its token, can drive the studio; Ctrl-C to stop)", file=sys.stderr, flush=True)
    if ready is not None:
        ready(srv)
    page = opener_page(srv.url) if open_browser else None
    if page is not None:   # in a thread: a browser command that never returns blocks nothing
        threading.Thread(target=webbrowser.open, args=(page.as_uri(),), daemon=True,
                         name="studio-browser").start()
    try:
        srv.serve_forever()
    finally:
        srv.server_close()
        if page is not None:
            shutil.rmtree(page.parent, ignore_errors=True)


def opener_page(url: str) -> Path:
    """A private page that hands the token of ``url`` (the studio's) to the studio.

    The browser is started on this file, never on ``url``: a command line can be read by
    every local user (``/proc/PID/cmdline``), a file of mode 0600 in a folder of mode 0700
    only by this one.  The page submits a form, ``POST /session`` with ``token=...`` in its
    body, and the studio answers with its session cookie and a redirect to ``/``: the token is
    in no URL, so in no history entry.

    Parameters
    ----------
    url : str
        ``http://127.0.0.1:<port>/#token=...`` (:attr:`StudioServer.url`).

    Returns
    -------
    pathlib.Path
        ``<private temporary folder>/open.html``; remove its folder when the studio stops.
    """
    m = re.fullmatch(r"(http://127\.0\.0\.1:\d+)/#token=([A-Za-z0-9_-]+)", url)
    if m is None:
        raise ValueError(f"not a studio URL: {url[:80]!r}")
    folder = Path(tempfile.mkdtemp(prefix="morphshell-studio-"))   # mode 0700, this user's
    page = folder / "open.html"
    html = ('<!doctype html><meta charset="utf-8"><meta name="referrer" content="no-referrer">'
            f'<title>morphshell studio</title><form method="post" action="{m[1]}/session" '
            'enctype="application/x-www-form-urlencoded">'
            f'<input type="hidden" name="token" value="{m[2]}">'
            "<p>Opening the studio... <button>Open</button></p></form>"
            "<script>document.forms[0].submit()</script>\n")
    fd = os.open(page, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(html)
    return page


__all__ = ["StudioServer", "serve", "resolve_folders", "opener_page", "attachment", "Busy",
           "TOKEN_HEADER", "COOKIE"]
