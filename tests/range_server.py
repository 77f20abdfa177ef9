"""An HTTP server on 127.0.0.1 serving files by range requests, in a thread (or, for the
streaming bench, a process of its own: RangeServerProcess), for the COPC-over-HTTP
tests: the standard library's http.server with a Range handler, and the faults of bad
networks on demand (ranges ignored, connections dropped mid-answer, slow
answers). It counts what it answers, for the status the reader reports. With `tls`
(a certificate and its key, self_signed makes them) it serves HTTPS.
"""

from __future__ import annotations

import multiprocessing
import re
import socket
import ssl
import subprocess
import threading
import time
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

RANGE = re.compile(r"bytes=(\d+)-(\d*)")
HOLD_S = 60.0
"""Longest a held answer waits (a test that fails before it lets them go ends anyway)."""


@dataclass
class Faults:
    """What goes wrong, set by a test before (or while) the server answers."""

    ignore_ranges: bool = False
    drops: dict[int, int] = field(default_factory=dict)
    """Range start -> times an answer for it ends after half its bytes (-1: always)."""
    delays: dict[int, float] = field(default_factory=dict)
    """Range start -> seconds its answers wait before they start."""
    trickle: dict[int, float] = field(default_factory=dict)
    """Range start -> seconds between the bytes of its answers' bodies, sent one by one."""
    close_idle: bool = False
    """Close every connection after its answer, without saying so (as a server that drops
    idle kept-alive connections does)."""
    pause: float = 0.0
    """Seconds every answer waits before it starts (a slow network)."""
    hold: threading.Event | None = None
    """Every answer waits until this is set (HOLD_S at most): the requests a test looks at
    stay in flight for as long as it takes to look, however slow the machine."""


def self_signed(folder: Path) -> tuple[Path, Path]:
    """A certificate for 127.0.0.1 signed by its own key (the openssl command), and the
    key: a client trusts it only where told to (SSL_CERT_FILE)."""
    cert, key = folder / "server.pem", folder / "server.key"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj",
                    "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1", "-keyout", str(key), "-out", str(cert)],
                   check=True, capture_output=True, timeout=60)
    return cert, key


class RangeServer:
    """`with RangeServer({"name": path}) as server: server.url("name")`."""

    def __init__(self, files: dict[str, Path], tls: tuple[Path, Path] | None = None):
        self.files = {name: Path(path).read_bytes() for name, path in files.items()}
        self.faults = Faults()
        self.lock = threading.Lock()
        self.requests = 0           # answered, faults included
        self.bytes = 0              # body bytes sent
        self.ranges: list[tuple[int, int]] = []
        self.active = self.most_active = 0      # requests being answered now, and at most so far
        self.connections = 0                    # accepted
        self._server = _Server(("127.0.0.1", 0), _Handler)
        self.scheme = "https" if tls else "http"
        if tls:
            context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
            context.load_cert_chain(*map(str, tls))
            self._server.socket = context.wrap_socket(self._server.socket, server_side=True)
        self._server.daemon_threads = True
        self._server.block_on_close = False
        self._server.owner = self
        self._thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.05},
                                        daemon=True)

    def url(self, name: str) -> str:
        return f"{self.scheme}://127.0.0.1:{self._server.server_address[1]}/{name}"

    def counts(self, idle_s: float = HOLD_S) -> tuple[int, int]:
        """Requests answered and body bytes sent, once the answers still being sent are
        done (at most idle_s): a client may have read a whole body before the thread
        that sent it has counted its bytes."""
        self._idle(idle_s)
        with self.lock:
            return self.requests, self.bytes

    def reset(self, idle_s: float = HOLD_S) -> None:
        """Counts from zero, once the answers still being sent are done (at most idle_s):
        an earlier test's late answers must not count in the next one's."""
        self._idle(idle_s)
        with self.lock:
            self.requests, self.bytes, self.ranges, self.most_active, self.connections = 0, 0, [], 0, 0

    def _idle(self, idle_s: float) -> None:
        deadline = time.monotonic() + idle_s
        while self.active and time.monotonic() < deadline:
            time.sleep(0.01)

    def __enter__(self) -> RangeServer:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._server.shutdown()
        self._server.server_close()


class RangeServerProcess:
    """A RangeServer in a process of its own: `with RangeServerProcess({"name": path}) as
    server: server.url("name")`, for a bench whose client must not share its interpreter
    (and the GIL) with the server's threads, as a real server would not. `pause`: seconds
    every answer waits before it starts (Faults.pause: a network's round trip)."""

    def __init__(self, files: dict[str, Path], pause: float = 0.0):
        spawn = multiprocessing.get_context("spawn")
        self._pipe, child = spawn.Pipe()
        self._process = spawn.Process(
            target=_serve_apart, args=({name: str(path) for name, path in files.items()}, pause, child), daemon=True)
        self._base = ""

    def url(self, name: str) -> str:
        return f"{self._base}/{name}"

    def counts(self) -> tuple[int, int]:
        """Requests answered and body bytes sent so far (once the answers under way are done)."""
        self._pipe.send("counts")
        return self._pipe.recv()

    def __enter__(self) -> RangeServerProcess:
        self._process.start()
        self._base = self._pipe.recv()
        return self

    def __exit__(self, *exc) -> None:
        self._pipe.send("stop")
        self._process.join(HOLD_S)


def _serve_apart(files: dict[str, str], pause: float, pipe) -> None:
    """RangeServerProcess's child: serve until told to stop, answering for counts."""
    with RangeServer({name: Path(path) for name, path in files.items()}) as server:
        server.faults.pause = pause
        pipe.send(server.url("").rstrip("/"))
        while (ask := pipe.recv()) != "stop":
            pipe.send(server.counts() if ask == "counts" else None)


class _Server(ThreadingHTTPServer):
    def handle_error(self, request, client_address) -> None:
        """A client that went away (a timeout, a refused answer): nothing to print."""


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"

    def log_message(self, *args) -> None:
        pass

    def setup(self) -> None:
        super().setup()
        with self.server.owner.lock:
            self.server.owner.connections += 1

    def do_GET(self) -> None:
        owner: RangeServer = self.server.owner
        with owner.lock:
            owner.active += 1
            owner.most_active = max(owner.most_active, owner.active)
        try:
            self._get(owner)
        finally:
            with owner.lock:
                owner.active -= 1

    def _get(self, owner: RangeServer) -> None:
        faults = owner.faults
        data = owner.files.get(self.path.lstrip("/"))
        wanted = RANGE.fullmatch(self.headers.get("Range", ""))
        start = int(wanted.group(1)) if wanted else 0
        if faults.delays.get(start) or faults.pause:
            time.sleep(faults.delays.get(start, 0.0) + faults.pause)
        if faults.hold is not None:
            faults.hold.wait(HOLD_S)
        try:
            if data is None:
                self._answer(owner, 404, b"not found\n", {})
            elif faults.ignore_ranges or wanted is None:
                self._answer(owner, 200, data, {})
            elif start >= len(data):
                self._answer(owner, 416, b"", {"Content-Range": f"bytes */{len(data)}"})
            else:
                end = min(int(wanted.group(2)) if wanted.group(2) else len(data) - 1, len(data) - 1)
                with owner.lock:
                    owner.ranges.append((start, end))
                    drops = faults.drops.get(start, 0)
                    if drops > 0:
                        faults.drops[start] = drops - 1
                    drops = drops != 0
                body = data[start:end + 1]
                self._answer(owner, 206, body, {"Content-Range": f"bytes {start}-{end}/{len(data)}"},
                             cut=len(body) // 2 if drops else None, pause=faults.trickle.get(start))
        except (BrokenPipeError, ConnectionResetError):
            self.close_connection = True

    def _answer(self, owner: RangeServer, status: int, body: bytes, headers: dict, cut: int | None = None,
                pause: float | None = None) -> None:
        """Send the answer; `cut`: only that many bytes of the body, then close; `pause`:
        the body's bytes one at a time, this many seconds apart."""
        with owner.lock:
            owner.requests += 1
        self.send_response(status)
        for name, value in {"Content-Length": str(len(body)), "Accept-Ranges": "bytes", **headers}.items():
            self.send_header(name, value)
        self.end_headers()
        sent = body if cut is None else body[:cut]
        step = 1 if pause else 1 << 16
        for at in range(0, len(sent), step):
            self.wfile.write(sent[at:at + step])
            with owner.lock:
                owner.bytes += len(sent[at:at + step])
            if pause:
                self.wfile.flush()
                time.sleep(pause)
        self.wfile.flush()
        if owner.faults.close_idle:
            self.close_connection = True
        if cut is not None:
            self.close_connection = True
            self.connection.shutdown(socket.SHUT_WR)
