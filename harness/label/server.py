"""The labelling page's HTTP server: the standard library's ``ThreadingHTTPServer`` on 127.0.0.1.

Routes (JSON bodies and answers; an error is ``{"error": "<one line>"}`` with its status code):

===========================  =====================================================================
``GET /``                    the page (``static/index.html``; its script and style from ``/static/``)
``GET /api/state``           frames, counts, suggestions, training status
``GET /api/frame/<i>``       one frame: size, labels (null = not labelled, [] = no ball), proposals
``GET /api/image/<i>``       the frame as JPEG
``POST /api/label``          ``{"frame": i, "boxes": [[x, y, w, h], ...]}`` (COCO pixels; [] = no ball)
``POST /api/undo``           take back the last change of this tab (``{"tab": name, "revision": n}``)
``POST /api/train``          ``{"ball_colour": c}``: start ``rt2 train`` on the labels; ``GET /api/train`` its status
===========================  =====================================================================

Refused: an unknown path or frame (404), a method a path does not take (405), a body that is not
``application/json`` (415), without a length (411), larger than ``MAX_BODY_BYTES`` (413), not JSON or
with a wrong field (400), a ``Host`` other than this server's loopback address (403: a web page
elsewhere cannot reach the server through DNS rebinding), training that cannot start (409), a change
made on an older ``revision`` than the labels' (409 with ``"conflict": true``: another tab changed them;
the page reloads).
Only the three files in ``static/`` are served: no path is ever joined to a request's.
"""

from __future__ import annotations

import json
import re
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from harness.label.session import LabelSession, RevisionConflict, TrainRefused

__all__ = ["MAX_BODY_BYTES", "LabelServer"]

MAX_BODY_BYTES = 64 * 1024
STATIC_DIR = Path(__file__).resolve().parent / "static"
STATIC = {"/": ("index.html", "text/html; charset=utf-8"),
          "/static/app.js": ("app.js", "text/javascript; charset=utf-8"),
          "/static/app.css": ("app.css", "text/css; charset=utf-8")}
_FRAME_ROUTE = re.compile(r"^/api/(frame|image)/([^/]*)$")


class _HttpError(Exception):
    def __init__(self, status: HTTPStatus, message: str):
        super().__init__(message)
        self.status = status


class _Handler(BaseHTTPRequestHandler):
    server_version = "rt2-label"
    protocol_version = "HTTP/1.1"

    @property
    def session(self) -> LabelSession:
        return self.server.session  # type: ignore[attr-defined]

    def log_message(self, format, *args):  # noqa: A002 - the base class's name
        if self.server.verbose:  # type: ignore[attr-defined]
            super().log_message(format, *args)

    # -- plumbing -------------------------------------------------------------------------------
    def _send(self, status: HTTPStatus, body: bytes, content_type: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, obj, status: HTTPStatus = HTTPStatus.OK) -> None:
        self._send(status, json.dumps(obj, allow_nan=False).encode(), "application/json")

    def _check_host(self) -> None:
        host = self.headers.get("Host", "")
        if host not in self.server.allowed_hosts:  # type: ignore[attr-defined]
            raise _HttpError(HTTPStatus.FORBIDDEN, f"Host {host!r} is not this server's address ({self.server.url})")  # type: ignore[attr-defined]

    def _body(self):
        ctype = self.headers.get("Content-Type", "").split(";")[0].strip().lower()
        if ctype != "application/json":
            raise _HttpError(HTTPStatus.UNSUPPORTED_MEDIA_TYPE, f"send the body as application/json, got Content-Type {ctype or 'none'!r}")
        length = self.headers.get("Content-Length")
        if length is None or not length.isdigit():
            raise _HttpError(HTTPStatus.LENGTH_REQUIRED, f"a Content-Length header (bytes) is required, got {length!r}")
        if int(length) > MAX_BODY_BYTES:
            self.close_connection = True  # the body is not read
            raise _HttpError(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, f"body of {int(length)} bytes; at most {MAX_BODY_BYTES} are taken")
        raw = self.rfile.read(int(length))
        try:
            return json.loads(raw.decode("utf-8")) if raw else {}
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise _HttpError(HTTPStatus.BAD_REQUEST, f"the body is not valid JSON: {exc}") from None

    def _handle(self, method: str) -> None:
        try:
            self._check_host()
            path = self.path.split("?", 1)[0]
            if method == "GET":
                self._get(path)
            else:
                self._post(path)
        except _HttpError as exc:
            self.close_connection = True  # a body may be left unread: never parse it as the next request
            self._json({"error": str(exc)}, exc.status)
        except RevisionConflict as exc:
            self._json({"error": str(exc), "conflict": True, "revision": self.session.store.revision}, HTTPStatus.CONFLICT)
        except LookupError as exc:
            self._json({"error": str(exc.args[0]) if exc.args else "not found"}, HTTPStatus.NOT_FOUND)
        except ValueError as exc:
            self._json({"error": str(exc)}, HTTPStatus.BAD_REQUEST)
        except OSError as exc:  # a write failed (disk full, permissions): the label is not saved
            self._json({"error": f"cannot save: {exc}"}, HTTPStatus.INTERNAL_SERVER_ERROR)

    def do_GET(self):  # noqa: N802 - http.server's name
        self._handle("GET")

    def do_HEAD(self):  # noqa: N802
        self._handle("GET")

    def do_POST(self):  # noqa: N802
        self._handle("POST")

    def do_PUT(self):  # noqa: N802
        self._refuse()

    do_DELETE = do_PATCH = do_PUT

    def _refuse(self) -> None:
        self.close_connection = True
        self._json({"error": f"method {self.command} is not used here (GET pages and state, POST changes)"}, HTTPStatus.METHOD_NOT_ALLOWED)

    # -- routes ---------------------------------------------------------------------------------
    def _get(self, path: str) -> None:
        if path in STATIC:
            name, ctype = STATIC[path]
            self._send(HTTPStatus.OK, (STATIC_DIR / name).read_bytes(), ctype)
        elif path == "/favicon.ico":
            self._send(HTTPStatus.NO_CONTENT, b"", "image/x-icon")
        elif path == "/api/state":
            self._json(self.session.state())
        elif path == "/api/train":
            self._json(self.session.training.status())
        elif m := _FRAME_ROUTE.match(path):
            i = self.session.frame_index(m.group(2))
            if m.group(1) == "frame":
                self._json(self.session.frame(i))
            else:
                self._send(HTTPStatus.OK, self.session.jpeg(i), "image/jpeg")
        elif path in ("/api/label", "/api/undo"):
            raise _HttpError(HTTPStatus.METHOD_NOT_ALLOWED, f"{path} takes POST")
        else:
            raise _HttpError(HTTPStatus.NOT_FOUND, f"no page {path[:200]!r}")

    def _post(self, path: str) -> None:
        routes = {"/api/label": self.session.label, "/api/undo": self.session.undo, "/api/train": self._train}
        if path not in routes:
            if path in STATIC or path == "/api/state" or _FRAME_ROUTE.match(path):
                raise _HttpError(HTTPStatus.METHOD_NOT_ALLOWED, f"{path} takes GET")
            raise _HttpError(HTTPStatus.NOT_FOUND, f"no page {path[:200]!r}")
        self._json(routes[path](self._body()))

    def _train(self, body):
        try:
            return self.session.train(body)
        except TrainRefused as exc:
            raise _HttpError(HTTPStatus.CONFLICT, str(exc)) from None


class LabelServer:
    """The page's server on ``127.0.0.1:port`` (0 = a free port), answering in threads.

    ``serve_forever()`` blocks; ``url`` is where the page is. Loopback only: the labels and the
    images are the user's, and the page has no login.
    """

    def __init__(self, session: LabelSession, port: int = 0, *, verbose: bool = False):
        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
            raise ValueError(f"--port must be an integer in [0, 65535], got {port!r}")
        try:
            self.httpd = ThreadingHTTPServer(("127.0.0.1", port), _Handler)
        except OSError as exc:
            raise ValueError(f"--port {port}: cannot listen on 127.0.0.1:{port}: {exc.strerror or exc}") from None
        self.httpd.daemon_threads = True
        self.port = self.httpd.server_address[1]
        self.url = f"http://127.0.0.1:{self.port}/"
        self.httpd.session = session
        self.httpd.verbose = verbose
        self.httpd.url = self.url
        self.httpd.allowed_hosts = {f"127.0.0.1:{self.port}", f"localhost:{self.port}"}
        self._thread: threading.Thread | None = None

    def serve_forever(self) -> None:
        self.httpd.serve_forever(poll_interval=0.2)

    def start(self) -> "LabelServer":
        """Serve in a background thread (tests, notebooks)."""
        self._thread = threading.Thread(target=self.serve_forever, daemon=True, name="rt2 label server")
        self._thread.start()
        return self

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
        if self._thread is not None:
            self._thread.join(timeout=5)
