"""The watch server: a fixed set of read-only routes over one `Watcher`.

The standard library's ThreadingHTTPServer is enough for a page polled once a second by a
few browsers and adds no dependency. Routes: `/` (the page), its static files, and
`/data` (JSON); everything else is 404, and only GET and HEAD are served. Every response
carries a Content-Security-Policy of `default-src 'self'` (no inline script), nosniff and
no-referrer; on a loopback address, requests naming another host are refused (DNS
rebinding). At most MAX_CLIENTS connections are served at once (more are closed unread),
each given REQUEST_TIMEOUT_S to send its request.
"""

from __future__ import annotations

import ipaddress
import json
import socket
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from rigtool.errors import RigtoolError
from rigtool.watch.data import Watcher

DEFAULT_PORT = 8765
STATIC_DIR = Path(__file__).parent / "static"  # shipped as package data
STATIC = {  # route -> (file in static/, content type)
    "/": ("index.html", "text/html; charset=utf-8"),
    "/index.html": ("index.html", "text/html; charset=utf-8"),
    "/app.js": ("app.js", "text/javascript; charset=utf-8"),
    "/app.css": ("app.css", "text/css; charset=utf-8"),
    "/uPlot.iife.min.js": ("uPlot.iife.min.js", "text/javascript; charset=utf-8"),
    "/uPlot.min.css": ("uPlot.min.css", "text/css; charset=utf-8"),
    "/uPlot.LICENSE": ("uPlot.LICENSE", "text/plain; charset=utf-8"),
}
HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; object-src 'none'; "
                               "base-uri 'none'; form-action 'none'; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "X-Frame-Options": "DENY",
    "Cross-Origin-Resource-Policy": "same-origin",
}
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "[::1]")
REQUEST_TIMEOUT_S = 10.0
MAX_CLIENTS = 32  # connections served at once; a browser polls /data once a second


def is_loopback(address: str) -> bool:
    """Whether `address` is this host only (127.0.0.0/8, ::1 or localhost)."""
    if address == "localhost":
        return True
    try:
        return ipaddress.ip_address(address).is_loopback
    except ValueError:
        return False


def listening_socket(bind: str, port: int) -> socket.socket:
    """A TCP socket listening on bind:port (0: any free port); a RigtoolError naming the
    address when it is taken or refused."""
    family = socket.AF_INET6 if ":" in bind else socket.AF_INET
    try:
        return socket.create_server((bind, port), family=family, backlog=MAX_CLIENTS)
    except OSError as exc:
        why = exc.strerror or str(exc)
        raise RigtoolError(f"cannot serve the watch page on {bind}:{port} ({why}): choose "
                           "another --port, or 0 for any free one") from exc


def _json_bytes(doc: Any) -> bytes:
    """Strict JSON (no NaN), with <, > and & escaped so it is inert even if sniffed as HTML."""
    text = json.dumps(doc, allow_nan=False, ensure_ascii=False, separators=(",", ":"))
    text = text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")
    return text.encode("utf-8")


class _Handler(BaseHTTPRequestHandler):
    server: WatchServer
    server_version = "rigtool-watch"
    sys_version = ""
    timeout = REQUEST_TIMEOUT_S  # a client that stops sending mid-request frees its thread
    # The base answers a request line without a version it can read as HTTP/0.9: the body
    # alone, with no status line and no headers. Answered as HTTP/1.0, even the error page
    # for an unparsable version carries HEADERS.
    default_request_version = "HTTP/1.0"

    def end_headers(self) -> None:
        """Every response, the server's own error pages included, carries HEADERS."""
        for key, value in HEADERS.items():
            self.send_header(key, value)
        super().end_headers()

    def do_GET(self) -> None:
        self._serve(body=True)

    def do_HEAD(self) -> None:
        self._serve(body=False)

    def _refuse(self) -> None:
        self._send(404, b"not found\n", "text/plain; charset=utf-8", True)

    do_POST = do_PUT = do_DELETE = do_PATCH = do_OPTIONS = do_TRACE = do_CONNECT = _refuse

    def _serve(self, body: bool) -> None:
        path = self.path.split("?", 1)[0]
        if not self._host_ok():
            self._send(404, b"not found\n", "text/plain; charset=utf-8", body)
        elif path == "/data":
            try:
                payload = _json_bytes(self.server.watcher.data())
                self._send(200, payload, "application/json; charset=utf-8", body)
            except RigtoolError as exc:
                self._send(503, _json_bytes({"error": str(exc)}),
                           "application/json; charset=utf-8", body)
            except Exception as exc:  # noqa: BLE001 - a bad read must not end the server
                self._send(503, _json_bytes({"error": f"{type(exc).__name__}: {exc}"}),
                           "application/json; charset=utf-8", body)
        elif path in STATIC:
            name, kind = STATIC[path]
            self._send(200, self.server.static(name), kind, body)
        else:
            self._send(404, b"not found\n", "text/plain; charset=utf-8", body)

    def _host_ok(self) -> bool:
        """On loopback, only requests addressed to loopback names (no DNS rebinding)."""
        if not self.server.loopback:
            return True
        host = (self.headers.get("Host") or "").strip().lower()
        name = host.rsplit(":", 1)[0] if not host.endswith("]") else host
        return name in LOOPBACK_NAMES or is_loopback(name)

    def _send(self, code: int, payload: bytes, kind: str, body: bool) -> None:
        self.send_response(code)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(payload)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        if body:
            self.wfile.write(payload)

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - the base's name
        return None


class WatchServer(ThreadingHTTPServer):
    """Serves one Watcher's page and data; `serve_in_thread` or `serve_forever`."""

    daemon_threads = True

    def __init__(self, watcher: Watcher, port: int = DEFAULT_PORT,
                 bind: str = "127.0.0.1", listener: socket.socket | None = None) -> None:
        """Serve on `listener` (one handed over by another process) or bind now
        (RigtoolError naming the address when it is taken or refused); nothing is read until
        a request."""
        self.watcher = watcher
        self.loopback = is_loopback(bind)
        listener = listener if listener is not None else listening_socket(bind, port)
        super().__init__(listener.getsockname()[:2], _Handler, bind_and_activate=False)
        self.socket.close()  # the unbound socket the base made; `listener` serves instead
        self.socket = listener
        self._slots = threading.BoundedSemaphore(MAX_CLIENTS)
        self._static: dict[str, bytes] = {}
        self._thread: threading.Thread | None = None

    def process_request(self, request: Any, client_address: Any) -> None:
        """Serve a connection in its own thread, or close it unread when MAX_CLIENTS are
        being served: a flood of clients costs the server no more than MAX_CLIENTS threads."""
        if not self._slots.acquire(blocking=False):
            self.shutdown_request(request)
            return
        try:
            super().process_request(request, client_address)
        except BaseException:
            self._slots.release()
            raise

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        """One connection's thread; its slot is freed when it ends."""
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._slots.release()

    @property
    def url(self) -> str:
        """The page's address."""
        host, port = self.server_address[:2]
        host = f"[{host}]" if ":" in str(host) else host
        return f"http://{host}:{port}/"

    def static(self, name: str) -> bytes:
        """A bundled static file, read once."""
        if name not in self._static:
            self._static[name] = (STATIC_DIR / name).read_bytes()
        return self._static[name]

    def serve_in_thread(self) -> threading.Thread:
        """Serve from a daemon thread (beside a sweep); `stop` ends it."""
        self._thread = threading.Thread(target=self.serve_forever, kwargs={"poll_interval": 0.5},
                                        name="rigtool-watch", daemon=True)
        self._thread.start()
        return self._thread

    def stop(self) -> None:
        """Stop serving and close the socket and the read-only connection."""
        if self._thread is not None:
            self.shutdown()
            self._thread.join(timeout=5)
        self.server_close()
        self.watcher.close()
