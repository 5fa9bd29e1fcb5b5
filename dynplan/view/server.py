"""The viewer's HTTP server: the app, the host page, one layout and the given logs, on 127.0.0.1, nothing else.

Every path it answers is in a table built at start (`routes`); anything else is 404, so no request reaches the rest
of the disk. Logs are read by the app with HTTP Range requests (MCAP's summary first, then the chunks it needs).
"""

from __future__ import annotations

import errno
import re
import socket
import sys
import threading
from collections.abc import Sequence
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import quote, urlsplit

from dynplan.cli import InputError
from dynplan.view.app import app_files

PAGE = Path(__file__).parent / "page" / "index.html"
TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript",
    ".css": "text/css",
    ".json": "application/json",
    ".wasm": "application/wasm",
    ".png": "image/png",
    ".svg": "image/svg+xml",
    ".woff": "font/woff",
    ".woff2": "font/woff2",
    ".ttf": "font/ttf",
}
_RANGE = re.compile(r"bytes=(\d*)-(\d*)$")
_BLOCK = 1 << 20


def routes(app: Path, layout: Path, logs: Sequence[Path]) -> tuple[dict[str, Path], list[str]]:
    """URL path → file for everything the viewer serves, and the logs' URL paths in the order given."""
    table = {"/": PAGE, "/index.html": PAGE, "/layout.json": layout}
    table |= {"/app/" + quote(name): path for name, path in app_files(app).items()}
    log_paths = []
    for i, log in enumerate(logs):
        url = f"/logs/{i}/{quote(Path(log).name)}"
        table[url] = Path(log)
        log_paths.append(url)
    return table, log_paths


class ViewServer:
    """Serve `routes` on 127.0.0.1:`port` (0: a free one) in a background thread; a context manager."""

    def __init__(self, table: dict[str, Path], port: int = 0) -> None:
        handler = type("Handler", (_Handler,), {"table": dict(table)})
        try:
            self._server = _Server(("127.0.0.1", port), handler)
        except OSError as error:
            raise InputError(_port_problem(port, error)) from None
        bound = self._server.server_address[1]
        handler.hosts = frozenset({f"127.0.0.1:{bound}", f"localhost:{bound}"})
        self._thread = threading.Thread(target=self._server.serve_forever, name="dynplan-view", daemon=True)

    @property
    def origin(self) -> str:
        return f"http://127.0.0.1:{self._server.server_address[1]}"

    def __enter__(self) -> ViewServer:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._server.shutdown()
        self._server.server_close()


def check_port(port: int) -> None:
    """Refuse a port that cannot be listened on at 127.0.0.1 (0 is always free) before anything slow starts."""
    if port:
        with socket.socket() as probe:
            try:
                probe.bind(("127.0.0.1", port))
            except OSError as error:
                raise InputError(_port_problem(port, error)) from None


def _port_problem(port: int, error: OSError) -> str:
    why = "already in use" if error.errno == errno.EADDRINUSE else f"cannot listen ({error.strerror})"
    return f"--port {port}: {why} on 127.0.0.1; choose another, or 0 for a free one"


class _Server(ThreadingHTTPServer):
    daemon_threads = True

    def handle_error(self, request, client_address) -> None:
        """A browser that drops a connection (a cancelled request, a closed page) is no error of the server's."""
        if not isinstance(sys.exc_info()[1], (ConnectionError, TimeoutError)):
            super().handle_error(request, client_address)


class _Handler(BaseHTTPRequestHandler):
    """GET and HEAD of the table's files, whole or one byte range."""

    table: dict[str, Path] = {}
    hosts: frozenset[str] = frozenset()
    protocol_version = "HTTP/1.1"

    def do_HEAD(self) -> None:  # http.server's naming
        self._answer(body=False)

    def do_GET(self) -> None:
        self._answer(body=True)

    def _answer(self, body: bool) -> None:
        if self.headers.get("Host") not in self.hosts:  # a page of another site, its name rebound to 127.0.0.1
            self.send_error(HTTPStatus.FORBIDDEN)
            return
        path = self.table.get(urlsplit(self.path).path)
        if path is None:
            self.send_error(HTTPStatus.NOT_FOUND)
            return
        try:
            size = path.stat().st_size
            span = _span(self.headers.get("Range"), size)
        except OSError:
            self.send_error(HTTPStatus.NOT_FOUND)
            return
        if span is False:
            self.send_response(HTTPStatus.REQUESTED_RANGE_NOT_SATISFIABLE)
            self.send_header("Content-Range", f"bytes */{size}")
            self.send_header("Content-Length", "0")
            self.end_headers()
            return
        start, end = span or (0, size - 1)
        self.send_response(HTTPStatus.PARTIAL_CONTENT if span else HTTPStatus.OK)
        self.send_header("Content-Type", TYPES.get(path.suffix, "application/octet-stream"))
        self.send_header("Content-Length", str(end - start + 1))
        self.send_header("Accept-Ranges", "bytes")
        self.send_header("Cache-Control", "no-store")
        if span:
            self.send_header("Content-Range", f"bytes {start}-{end}/{size}")
        self.end_headers()
        if body:
            self._copy(path, start, end - start + 1)

    def _copy(self, path: Path, start: int, length: int) -> None:
        with open(path, "rb") as f:
            f.seek(start)
            while length > 0 and (block := f.read(min(_BLOCK, length))):
                self.wfile.write(block)
                length -= len(block)

    def log_message(self, format: str, *args) -> None:  # the base class's names
        pass  # the command prints what matters; a request log would drown it


def _span(header: str | None, size: int) -> tuple[int, int] | bool | None:
    """The inclusive byte span of a `Range: bytes=a-b` header (one range; a suffix `-n` too); None without a header
    (or one this server does not parse: the whole file), False where it is outside the file."""
    match = _RANGE.match(header.strip()) if header else None
    if match is None or match.groups() == ("", "") or max(map(len, match.groups())) > 20:
        return None
    first, last = match.groups()
    if first == "":
        start, end = max(size - int(last), 0), size - 1
    elif last and int(last) < int(first):
        return None  # an invalid range is ignored (RFC 9110 §14.2): the whole file
    else:
        start, end = int(first), min(int(last), size - 1) if last else size - 1
    return (start, end) if start <= end and start < size else False
