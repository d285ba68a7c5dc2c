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

The studio's modules, by concern: this one (the server, its start and its build folders),
:mod:`.handler` (the guards and routes of each request), :mod:`.builds` (one build's data,
assembled for the page), :mod:`.jobs` (a Run in its child process, its progress and ETA),
:mod:`.landscape` (the requests' validation and the feasibility), :mod:`.compare` (A - B).
"""

from __future__ import annotations

import errno
import os
import re
import secrets
import shutil
import sys
import tempfile
import threading
import webbrowser
from http.server import ThreadingHTTPServer
from pathlib import Path

from ..errors import InputError
from ..params import LIMITS
from ..simulator import viewer_assets
from .builds import Build, Stale
from .handler import COOKIE, TOKEN_HEADER, Handler, attachment
from .jobs import Busy, Job, eta_seconds, progress_event

STATIC_DIR = Path(__file__).resolve().parent / "static"


def _static_files() -> dict:
    files = viewer_assets()
    files.update({name: STATIC_DIR / name
                  for name in ("index.html", "boot.js", "studio.js", "studio.css")})
    return files


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

    def warm(self) -> threading.Thread:
        """Make the first build's target, then its viewer's bytes, in a background thread
        (:meth:`Build.warm`): what the page asks for first is ready when the browser has
        started.  Returns the thread."""
        t = threading.Thread(target=self.builds[0].warm, daemon=True, name="studio-warm")
        t.start()
        return t

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
    srv.warm()
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
           "Stale", "Build", "Job", "Handler", "eta_seconds", "progress_event", "TOKEN_HEADER",
           "COOKIE"]
