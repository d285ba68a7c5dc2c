"""The studio's HTTP side: the guards every request passes (host, origin, token, bodies,
deadlines), the replies, and the routes to the builds and the job (:class:`Handler`; the
endpoints and the rules are :mod:`pysolver.studio.server`'s docstring)."""

from __future__ import annotations

import hmac
import json
import re
import socket
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qs, quote, urlsplit

from ..build import report_figures
from ..errors import InputError, MorphshellError
from ..params import LIMITS
from .builds import Build, Stale
from .compare import compare_cells
from .jobs import Busy
from .landscape import parse_run

TOKEN_HEADER = "X-Morphshell-Token"
COOKIE = "morphshell-studio"
SESSION_MAX_BODY = 256
"""Bytes a ``POST /session`` body may have (``token=`` and 43 characters): a longer one is
refused before it is read."""

_TYPES = {".js": "text/javascript; charset=utf-8", ".css": "text/css; charset=utf-8",
          ".html": "text/html; charset=utf-8"}


class Handler(BaseHTTPRequestHandler):
    server: ThreadingHTTPServer   # the studio's (pysolver.studio.server.StudioServer)
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
                body = b.viewer_body(gz)
                # the JSON's own bytes (the page counts them as they arrive, decompressed)
                size = ("X-Morphshell-Bytes", str(len(b.viewer_body(False))))
                return self._send(HTTPStatus.OK, body, extra=[
                    ("Content-Encoding", "gzip"), size] if gz else [size])
            if len(parts) == 4 and what in ("target", "results", "parts"):
                self._json(HTTPStatus.OK, getattr(b, what)())
                if what == "target":   # the page asks for the morph next: made meanwhile
                    b.prefetch_viewer()
                return None
            if len(parts) == 4 and what == "report":
                p = b.folder / "report" / "index.html"
                if not p.is_file():
                    raise _NotFound("this build has no report yet")
                # (a report comes from a build folder, maybe someone else's: its scripts run
                # in an origin of their own, which can neither read the studio's pages nor
                # send its session)
                return self._send(HTTPStatus.OK, p.read_bytes(), _TYPES[".html"], extra=[
                    ("Content-Security-Policy", "sandbox allow-scripts")])
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


__all__ = ["Handler", "attachment", "TOKEN_HEADER", "COOKIE"]
