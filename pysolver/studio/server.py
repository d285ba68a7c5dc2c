"""``morphshell studio``: a local web app to view simulated morphs and edit time landscapes.

A small :class:`http.server.ThreadingHTTPServer` bound to 127.0.0.1.  It serves a fixed
set of static files that ship with the package (no CDN, works offline) and JSON
endpoints over the build folders named on the command line; nothing else of the file
system is reachable.

Endpoints (``<i>`` = index of a build folder)::

    GET  /                          the app (index.html)
    GET  /static/<name>             whitelisted assets (three.js, the viewer, the app)
    GET  /api/builds                the build folders
    GET  /api/build/<i>/viewer      the simulated morph (sim/viewer.py JSON)
    GET  /api/build/<i>/target      target stencil, landscape, cells, feasibility
    POST /api/build/<i>/preview     keyframes/brushes -> landscape + feasibility
    POST /api/build/<i>/save        ... and write time_landscape.csv
    POST /api/build/<i>/run         {"stages": "program" | "program+simulate"}
    GET  /api/job                   progress of the running stage job

Writes: ``time_landscape.csv`` and ``studio_landscape.json`` (the keyframes and brushes
it came from), only in a folder morphshell made, and only over files morphshell made.
Stages run as ``python -m pysolver.cli <stage> <dir>`` subprocesses (the same stage
functions as a build); their progress lines drive the progress bar.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import time
import webbrowser
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np

from .. import tables
from ..atomic import _manifest, atomic_write_text, write_stamp
from ..build import morph_viewer, viewer_assets
from ..errors import InputError, MorphshellError
from ..tables import read_record, read_stencil, read_table
from .landscape import Feasibility, constraint_values, harmonic_landscape, parse_constraints

STATIC_DIR = Path(__file__).resolve().parent / "static"
MAX_BODY_BYTES = 4 << 20
LANDSCAPE_SOURCE = "studio_landscape.json"
"""Keyframes and brushes of the last saved studio landscape (provenance)."""


def _static_files() -> dict:
    files = viewer_assets()
    files.update({name: STATIC_DIR / name for name in ("index.html", "studio.js", "studio.css")})
    return files


_TYPES = {".js": "text/javascript; charset=utf-8", ".css": "text/css; charset=utf-8",
          ".html": "text/html; charset=utf-8"}


def _jsonable(a):
    """A float array as a list with None for non-finite values."""
    return [None if not np.isfinite(x) else round(float(x), 4) for x in np.asarray(a, float)]


class Build:
    """One build folder: its tables and caches, loaded lazily."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.lock = threading.Lock()
        self._viewer = None
        self._viewer_key = None
        self._feas = None

    def info(self, i: int) -> dict:
        return {"id": i, "name": self.folder.name, "path": str(self.folder),
                "has_frames": (self.folder / "sim" / "frames.npz").is_file()}

    def viewer(self) -> dict:
        p = self.folder / "sim" / "frames.npz"
        if not p.is_file():
            raise InputError(f"{p}: no simulation in this build",
                             fix=f"run 'morphshell simulate {self.folder}' or use the "
                                 "'Program and simulate' button")
        key = (p.stat().st_mtime_ns, (self.folder / "cells.csv").stat().st_mtime_ns)
        with self.lock:
            if self._viewer_key != key:
                self._viewer = morph_viewer(self.folder, max_frames=241, quantise=False)
                self._viewer_key = key
            return self._viewer

    def feasibility(self):
        with self.lock:
            if self._feas is None:

                self._feas = Feasibility(self.folder)
            return self._feas

    def stencil(self):

        return read_stencil(self.folder / "stencil.obj")

    def target(self) -> dict:

        V, _, F = self.stencil()
        land = read_table(self.folder, "time_landscape")["time_s"]
        cells = read_table(self.folder, "cells")
        ev = self.feasibility().evaluate(land)
        src = None
        p = self.folder / LANDSCAPE_SOURCE
        if p.is_file():
            try:
                src = json.loads(p.read_text())
            except ValueError:
                src = None
        return {"V": np.round(V, 5).reshape(-1).tolist(), "F": F.reshape(-1).tolist(),
                "landscape": _jsonable(land),
                "vertex_a": cells["vertex_a"].tolist(), "vertex_b": cells["vertex_b"].tolist(),
                "programmed_clamped": np.asarray(cells.get("clamped", np.zeros(len(land))),
                                                 int).tolist(),
                "feasibility": self._feas_json(ev), "source": src}

    @staticmethod
    def _feas_json(ev) -> dict:
        return {"t_star": _jsonable(ev["t_star"]), "t_min": _jsonable(ev["t_min"]),
                "t_max": _jsonable(ev["t_max"]), "clamped": ev["clamped"].astype(int).tolist(),
                "side": np.asarray(ev["side"], int).tolist(),
                "n_clamped": int(ev["clamped"].sum())}

    def landscape(self, payload):

        V, _, F = self.stencil()
        kf, br = parse_constraints(payload, len(V))
        b, bc = constraint_values(V, kf, br)
        land = harmonic_landscape(V, F, b, bc)
        return land, kf, br

    def preview(self, payload) -> dict:
        land, _, _ = self.landscape(payload)
        return {"landscape": _jsonable(land),
                "feasibility": self._feas_json(self.feasibility().evaluate(land))}

    def save(self, payload) -> dict:

        land, kf, br = self.landscape(payload)
        owned = _manifest(self.folder)
        if owned is None:
            raise InputError(f"{self.folder} was not made by morphshell (no .morphshell-build "
                             "stamp): the studio writes only into build folders",
                             fix="build the shape with 'morphshell build' and open that folder")
        for name in (tables.FILENAMES["time_landscape"], LANDSCAPE_SOURCE):
            if (self.folder / name).exists() and name not in owned:
                raise InputError(f"{self.folder / name} is not a morphshell file; it is kept",
                                 fix="move it away, then save again")
        t0 = time.time()
        path = self.folder / tables.FILENAMES["time_landscape"]
        tables.write_table(path, "time_landscape",
                           {"vertex_id": np.arange(len(land)), "time_s": land})
        atomic_write_text(self.folder / LANDSCAPE_SOURCE, json.dumps(
            {"made_by": "morphshell studio", "keyframes": [{"vertex": v, "time": t}
                                                           for v, t in kf],
             "brushes": [{"vertex": v, "radius": r, "time": t} for v, r, t in br],
             "interpolation": "harmonic (igl.harmonic, cotangent Laplacian)"}, indent=1) + "\n")
        write_stamp(self.folder, since=t0 - 1.0)
        return {"written": str(path), "n_vertices": int(len(land)),
                "range_s": [float(land.min()), float(land.max())]}


class Job:
    """The one stage job (program, simulate, report) running in subprocesses."""

    STEP = re.compile(r"step (\d+)/(\d+)")

    def __init__(self):
        self.lock = threading.Lock()
        self.state = {"state": "idle", "progress": 0.0, "message": "", "build": None,
                      "error": None, "log": []}

    def snapshot(self) -> dict:
        with self.lock:
            return json.loads(json.dumps(self.state))

    def _set(self, **kw):
        with self.lock:
            self.state.update(kw)

    def start(self, build: Build, index: int, stages: str):
        plan = {"program": [("program", 1.0)],
                "program+simulate": [("program", 0.08), ("simulate", 0.72), ("report", 0.2)]}
        if stages not in plan:
            raise InputError(f"stages = {stages!r}", fix="use 'program' or 'program+simulate'")
        with self.lock:
            if self.state["state"] == "running":
                raise InputError("a stage job is already running",
                                 fix="wait for it to finish (see the progress bar)")
            self.state = {"state": "running", "progress": 0.0, "message": "starting",
                          "build": index, "error": None, "log": [], "stages": stages}
        threading.Thread(target=self._run, args=(build, plan[stages]), daemon=True).start()

    def _run(self, build: Build, plan):
        root = str(Path(__file__).resolve().parents[2])
        env = dict(os.environ, PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))
        done = 0.0
        try:
            for stage, weight in plan:
                cmd = [sys.executable, "-m", "pysolver.cli", stage, str(build.folder)]
                if stage == "simulate":   # the build's own simulated time and step
                    cmd.append("--no-resume")
                    opts = (read_record(build.folder / "summary.json") or {}).get("options", {})
                    for key, flag in (("t_end", "--t-end"), ("dt", "--dt")):
                        if isinstance(opts.get(key), (int, float)):
                            cmd += [flag, repr(float(opts[key]))]
                self._set(message=f"{stage} ...")
                proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.PIPE,
                                        text=True, env=env)
                tail = []
                for line in proc.stderr:
                    line = line.rstrip()
                    tail = (tail + [line])[-20:]
                    m = self.STEP.search(line)
                    frac = int(m.group(1)) / max(int(m.group(2)), 1) if m else None
                    with self.lock:
                        if frac is not None:
                            self.state["progress"] = round(done + weight * frac, 4)
                        self.state["message"] = f"{stage}: {line[-160:]}"
                proc.stdout.read()
                rc = proc.wait()
                if rc not in (0, 3):   # 3 = the report's FAIL verdict: the stage still ran
                    raise MorphshellError(f"{stage} stage failed (exit {rc}): "
                                          + " / ".join(tail[-4:]))
                done += weight
                self._set(progress=round(done, 4), message=f"{stage} done")
            with build.lock:
                build._feas = None          # cells.csv changed
            self._set(state="done", progress=1.0, message="done")
        except Exception as e:  # noqa: BLE001 - reported to the browser, not raised
            self._set(state="error", error=str(e), message=str(e))


class StudioServer(ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self, folders, port: int = 0):
        self.builds = [Build(Path(f).resolve()) for f in folders]
        self.job = Job()
        self.files = _static_files()
        super().__init__(("127.0.0.1", port), Handler)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.server_address[1]}/"


class Handler(BaseHTTPRequestHandler):
    server: StudioServer
    protocol_version = "HTTP/1.1"

    def log_message(self, fmt, *args):  # quiet: the terminal shows the URL and errors only
        pass

    def _send(self, code, body: bytes, ctype="application/json; charset=utf-8"):
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.end_headers()
        self.wfile.write(body)

    def _json(self, code, obj):
        self._send(code, json.dumps(obj, separators=(",", ":")).encode())

    def _host_ok(self) -> bool:
        # DNS rebinding guard: only requests addressed to this loopback server
        port = self.server.server_address[1]
        return self.headers.get("Host", "") in (f"127.0.0.1:{port}", f"localhost:{port}")

    def _build(self, parts):
        try:
            i = int(parts[2])
        except ValueError:
            i = -1
        if not 0 <= i < len(self.server.builds):
            raise InputError(f"no build number {parts[2]!r}")
        return i, self.server.builds[i]

    def _guard(self, fn):
        if not self._host_ok():
            return self._json(HTTPStatus.FORBIDDEN, {"error": "bad Host header"})
        try:
            return fn()
        except InputError as e:
            return self._json(HTTPStatus.BAD_REQUEST, {"error": str(e)})
        except MorphshellError as e:
            return self._json(HTTPStatus.CONFLICT, {"error": str(e)})
        except Exception as e:  # noqa: BLE001 - a bug: tell the browser, keep serving
            return self._json(HTTPStatus.INTERNAL_SERVER_ERROR,
                              {"error": f"internal error ({type(e).__name__}: {e})"})

    def do_GET(self):  # noqa: N802 - http.server's name
        self._guard(self._get)

    def do_POST(self):  # noqa: N802
        self._guard(self._post)

    def _get(self):
        path = self.path.split("?", 1)[0]
        if path == "/favicon.ico":
            return self._send(HTTPStatus.NO_CONTENT, b"", "image/x-icon")
        if path in ("/", "/index.html"):
            path = "/static/index.html"
        if path.startswith("/static/"):
            name = path[len("/static/"):]
            f = self.server.files.get(name)   # a whitelist: no path from the URL is opened
            if f is None:
                return self._json(HTTPStatus.NOT_FOUND, {"error": "not found"})
            return self._send(HTTPStatus.OK, f.read_bytes(), _TYPES[f.suffix])
        parts = path.strip("/").split("/")
        if parts == ["api", "builds"]:
            return self._json(HTTPStatus.OK, [b.info(i) for i, b in
                                              enumerate(self.server.builds)])
        if parts == ["api", "job"]:
            return self._json(HTTPStatus.OK, self.server.job.snapshot())
        if len(parts) == 4 and parts[:2] == ["api", "build"]:
            _, b = self._build(parts)
            if parts[3] == "viewer":
                return self._json(HTTPStatus.OK, b.viewer())
            if parts[3] == "target":
                return self._json(HTTPStatus.OK, b.target())
        return self._json(HTTPStatus.NOT_FOUND, {"error": "not found"})

    def _post(self):
        if self.headers.get_content_type() != "application/json":
            return self._json(HTTPStatus.UNSUPPORTED_MEDIA_TYPE,
                              {"error": "send application/json"})
        n = int(self.headers.get("Content-Length") or 0)
        if not 0 <= n <= MAX_BODY_BYTES:
            return self._json(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, {"error": "body too large"})
        try:
            payload = json.loads(self.rfile.read(n) or b"{}")
        except ValueError:
            raise InputError("the request body is not JSON") from None
        parts = self.path.split("?", 1)[0].strip("/").split("/")
        if len(parts) == 4 and parts[:2] == ["api", "build"]:
            i, b = self._build(parts)
            if parts[3] == "preview":
                return self._json(HTTPStatus.OK, b.preview(payload))
            if parts[3] == "save":
                if self.server.job.snapshot()["state"] == "running":
                    raise InputError("a stage job is running", fix="save when it has finished")
                return self._json(HTTPStatus.OK, b.save(payload))
            if parts[3] == "run":
                stages = payload.get("stages") if isinstance(payload, dict) else None
                self.server.job.start(b, i, stages)
                return self._json(HTTPStatus.OK, self.server.job.snapshot())
        return self._json(HTTPStatus.NOT_FOUND, {"error": "not found"})


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
        Build folders (side by side in the viewer; the editor works on the first).
    port : int
        TCP port on 127.0.0.1 (0 = any free port).
    open_browser : bool
        Open the default browser on the app.
    ready : callable, optional
        Called with the server once it listens (tests).
    """
    if not 0 <= int(port) <= 65535:
        raise InputError(f"port = {port}", fix="use a port between 1024 and 65535, or 0")
    srv = StudioServer(resolve_folders(dirs), port=int(port))
    print(f"morphshell studio: {srv.url}  ({len(srv.builds)} build(s); Ctrl-C to stop)",
          file=sys.stderr, flush=True)
    if ready is not None:
        ready(srv)
    if open_browser:

        webbrowser.open(srv.url)
    try:
        srv.serve_forever()
    finally:
        srv.server_close()


__all__ = ["StudioServer", "serve", "resolve_folders", "LANDSCAPE_SOURCE"]
