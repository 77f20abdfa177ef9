"""Reading a file over HTTP by range requests: what COPC over http(s):// URLs needs.

Only the bytes asked for are fetched (the standard library's http.client; connections
are kept alive for the next request, one per request in flight), so a COPC file on
object storage is read by its header, hierarchy and kept nodes alone. Every answer is
checked: a server that ignores ranges (200 with the whole file), an error status, a
connection that cannot be made, or a server silent (or trickling) for `timeout_s` is
one line (InputError) at once; a connection dropped before the bytes asked for arrive
is tried again `retries` times, then is a FetchFailed (an InputError a partial load
may skip). Nothing is written anywhere; bytes are handed on only once a request has
all of them.

Node chunks are fetched by `Prefetch`: a few requests in flight on daemon threads,
ahead of the decoder by at most `ahead_bytes`. `Tally` counts what was fetched, for
a session's status. Closing a RemoteFile shuts the sockets of requests in flight, so
a loader that stops never waits for the network.
"""

from __future__ import annotations

import http.client
import re
import socket
import threading
import time
import urllib.parse
from collections.abc import Sequence
from dataclasses import dataclass

from progressive.errors import InputError
from progressive.loaders.streams import PositionedReader
from progressive.loaders.validate import fail

SCHEMES = ("http://", "https://")
TIMEOUT_S = 20.0
"""Seconds a request may wait for the server's next byte (connecting included) before it
fails: object storage answers within a second; a server silent this long is taken as
gone, and the error says so instead of the window waiting on it."""
SLOW_BYTES = 1 << 14
"""Bytes an answer must bring in every timeout_s while it comes (or all it has left): a
server that trickles its bytes (16 KiB in 20 s is 0.8 KB/s) fails as a silent one does,
within about two timeouts, instead of holding the file for hours."""
REQUESTS_IN_FLIGHT = 8
"""Requests at once to one file (laspy's CopcReader takes 8 threads too): a streamed view
waits on round trips, one node a request, so the time to a resident view falls with
this until the server or the decoders are the limit; few enough for a server's limit
per client (--http-requests sets it)."""
MAX_REQUESTS_IN_FLIGHT = 64
"""The most requests at once to one file that --http-requests takes (each is a connection
and a thread)."""
RETRIES = 1
"""Times a request whose connection was dropped is sent again."""
AHEAD_BYTES = 1 << 25
"""Compressed node bytes fetched ahead of the decoder at most (host memory)."""
READ_AHEAD = 1 << 16
"""Bytes fetched at least by a read of the header, the VLRs, the chunk table or the
hierarchy: those small reads come in runs, which one request then answers."""
PIECE = 1 << 16                         # bytes taken from the socket at most at a time
REDIRECTS = 5                           # redirects followed at most (object storage signs URLs by them)
CONTENT_RANGE = re.compile(r"bytes (\d+)-(\d+)/(\d+|\*)")


def is_url(path) -> bool:
    """An http(s):// URL (as a string: a Path would have lost one of its slashes)."""
    return isinstance(path, str) and path[:8].lower().startswith(SCHEMES)


@dataclass(frozen=True)
class HttpOptions:
    """How files are fetched over HTTP."""

    timeout_s: float = TIMEOUT_S
    in_flight: int = REQUESTS_IN_FLIGHT
    retries: int = RETRIES
    ahead_bytes: int = AHEAD_BYTES

    def __post_init__(self):
        if not (self.timeout_s > 0 and self.in_flight >= 1 and self.retries >= 0 and self.ahead_bytes >= 1):
            raise ValueError(f"invalid HTTP options {self}")


DEFAULTS = HttpOptions()


class FetchFailed(InputError):
    """A range whose connection was dropped on every try: the node it holds may be skipped."""


class Dropped(Exception):
    """The connection ended before the bytes asked for (tried again)."""


class _Stale(Exception):
    """A connection kept alive that the server has closed since (sent again at once, on a
    new connection: that is no drop)."""


class Tally:
    """Bytes received, requests answered and in flight, of one remote file; written by the
    fetching threads, read by a session at any moment."""

    def __init__(self):
        self._lock = threading.Lock()
        self.bytes = self.requests = self.in_flight = 0

    def begin(self) -> None:
        with self._lock:
            self.in_flight += 1

    def received(self, n: int) -> None:
        with self._lock:
            self.bytes += n

    def end(self) -> None:
        with self._lock:
            self.in_flight -= 1
            self.requests += 1

    def snapshot(self) -> tuple[int, int, int]:
        """(bytes fetched, requests done, requests in flight)."""
        with self._lock:
            return self.bytes, self.requests, self.in_flight


class RemoteFile:
    """A file on an HTTP server, read by range requests. `size` is known once the first
    range has been fetched (open() fetches one). `tally`: another RemoteFile's, where
    this one reads the same file again (a pick), so that the file's status counts both."""

    def __init__(self, url: str, options: HttpOptions = DEFAULTS, tally: Tally | None = None):
        self.url, self.options = url, options
        self.tally = Tally() if tally is None else tally
        self.size: int | None = None
        self._target = url                  # where redirects led
        self._lock = threading.Lock()
        self._open: set = set()             # connections of requests in flight
        self._idle: dict[tuple, list] = {}  # (scheme, host, port) -> connections kept alive
        self._closed = False
        self._cache: list[tuple[int, bytes]] = []
        # requests at once, whichever threads read: a streamed cloud's readers also wait on decoding
        self._slots = threading.BoundedSemaphore(options.in_flight)

    @classmethod
    def open(cls, url: str, options: HttpOptions = DEFAULTS, tally: Tally | None = None) -> RemoteFile:
        """The file, its size learnt from a first range (the file's first READ_AHEAD bytes,
        kept for the header reads that follow)."""
        remote = cls(url, options, tally)
        remote.cached(0, 1)
        return remote

    def close(self) -> None:
        """Fail the requests in flight now (their sockets shut), close the connections kept
        alive and refuse new requests."""
        with self._lock:
            self._closed = True
            connections = list(self._open)
            idle = [conn for kept in self._idle.values() for conn in kept]
            self._idle.clear()
        for conn in connections:
            _shut(conn)
        for conn in idle:
            conn.close()

    def read(self, offset: int, length: int) -> bytes:
        """Bytes [offset, offset + length), all of them, or InputError (FetchFailed where
        the connection was dropped on every try)."""
        problem = None
        for _ in range(1 + self.options.retries):
            try:
                return self._fetch(offset, length)
            except Dropped as exc:
                problem = exc
        raise FetchFailed(f"{self.url}: {problem} (bytes {offset}-{offset + length - 1}, "
                          f"{1 + self.options.retries} tries)")

    def cached(self, offset: int, length: int) -> bytes:
        """Bytes [offset, offset + length) (fewer at the end of the file) through a cache of
        the reads so far, each of at least READ_AHEAD bytes: for the small reads of
        headers and tables, not for node chunks."""
        if self.size is not None:
            length = max(0, min(length, self.size - offset))
            if length == 0:
                return b""
        for start, data in self._cache:
            if start <= offset and offset + length <= start + len(data):
                return data[offset - start:offset - start + length]
        size = max(length, READ_AHEAD)
        if self.size is not None:
            size = min(size, self.size - offset)
        data = self.read(offset, size)
        self._cache.append((offset, data))
        return data[:length]

    def stream(self) -> RemoteStream:
        return RemoteStream(self)

    def _fetch(self, offset: int, length: int) -> bytes:
        with self._slots:
            with self._lock:
                if self._closed:
                    raise InputError(f"{self.url}: reading stopped")
            self.tally.begin()
            try:
                for _ in range(REDIRECTS + 1):
                    answer = self._exchange(urllib.parse.urlsplit(self._target), offset, length)
                    if isinstance(answer, bytes):
                        return answer
                    self._target = urllib.parse.urljoin(self._target, answer)
                raise fail(self.url, f"more than {REDIRECTS} redirects")
            finally:
                self.tally.end()

    def _exchange(self, parts, offset: int, length: int) -> bytes | str:
        """One request, on a connection kept alive from an earlier one where there is one,
        else (or where the server had closed that one) on a new connection."""
        key = (parts.scheme.lower(), parts.hostname, parts.port)
        with self._lock:
            kept = self._idle.get(key)
            conn = kept.pop() if kept else None
        if conn is not None:
            try:
                return self._over(conn, key, parts, offset, length, reused=True)
            except _Stale:
                pass
        kind = http.client.HTTPSConnection if key[0] == "https" else http.client.HTTPConnection
        try:
            conn = kind(parts.hostname or "", parts.port, timeout=self.options.timeout_s)
        except ValueError as exc:           # a port that is not a number
            raise fail(self.url, f"is not a valid URL ({exc})") from None
        return self._over(conn, key, parts, offset, length, reused=False)

    def _over(self, conn, key: tuple, parts, offset: int, length: int, reused: bool) -> bytes | str:
        """The request on `conn`, which is kept alive afterwards where the answer allows."""
        with self._lock:
            self._open.add(conn)
        keep = False
        try:
            answer, keep = self._ask(conn, parts, offset, length, reused)
            return answer
        finally:
            with self._lock:
                self._open.discard(conn)
                keep = keep and not self._closed
                if keep:
                    self._idle.setdefault(key, []).append(conn)
            if not keep:
                conn.close()

    def _ask(self, conn, parts, offset: int, length: int, reused: bool) -> tuple[bytes | str, bool]:
        """The range's bytes, or where a redirect points; and whether the connection may
        serve another request. _Stale where a kept-alive connection turns out closed."""
        where = f"{parts.hostname}:{parts.port or conn.default_port}"
        path = (parts.path or "/") + (f"?{parts.query}" if parts.query else "")
        last = offset + length - 1
        try:
            try:
                conn.request("GET", path, headers={"Range": f"bytes={offset}-{last}", "Accept-Encoding": "identity"})
                response = conn.getresponse()
            except (http.client.RemoteDisconnected, ConnectionResetError, BrokenPipeError, ConnectionAbortedError):
                if reused:
                    raise _Stale() from None
                raise
            if response.status in (301, 302, 303, 307, 308) and response.getheader("Location"):
                return response.getheader("Location"), False
            if response.status == 200:
                raise fail(self.url, "the server ignores range requests (it answered 200 with the whole file, not "
                                     "206 with the bytes asked for); COPC over HTTP needs a server that serves ranges")
            if response.status == 416 and self.size is None:
                raise fail(self.url, "is empty")
            if response.status != 206:
                raise fail(self.url, f"HTTP {response.status} {response.reason}")
            first, end, total = self._content_range(response.getheader("Content-Range") or "")
            if first != offset or end > last or (end < last and end + 1 != total):
                raise fail(self.url, f"the server answered bytes {first}-{end} to a request for {offset}-{last}")
            data = self._body(response, end - first + 1, where)
            return data, response.isclosed() and not response.will_close
        except TimeoutError:
            raise fail(self.url, f"no answer from {where} within {self.options.timeout_s:g} s") from None
        except (http.client.RemoteDisconnected, http.client.IncompleteRead, ConnectionResetError,
                BrokenPipeError) as exc:
            raise Dropped(f"the connection was dropped ({type(exc).__name__})") from None
        except (OSError, http.client.HTTPException) as exc:
            with self._lock:
                if self._closed:
                    raise InputError(f"{self.url}: reading stopped") from None
            text = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
            doing = "cannot connect to" if isinstance(exc, OSError) else "a bad answer from"
            raise fail(self.url, f"{doing} {where}: {text}") from None

    def _content_range(self, header: str) -> tuple[int, int, int]:
        match = CONTENT_RANGE.fullmatch(header.strip())
        if not match or match.group(3) == "*":
            raise fail(self.url, f"the server's answer to a range request has no usable Content-Range ({header!r})")
        first, end, total = int(match.group(1)), int(match.group(2)), int(match.group(3))
        if self.size is None:
            self.size = total
        elif total != self.size:
            raise fail(self.url, f"changed size while being read ({self.size:,} then {total:,} bytes)")
        return first, end, total

    def _body(self, response, n: int, where: str) -> bytes:
        """n bytes of the response, counted as they come; Dropped where it ends first,
        InputError where a timeout_s brings fewer than SLOW_BYTES."""
        data, got = bytearray(n), 0
        view = memoryview(data)
        window, at_window = time.monotonic(), 0
        while got < n:
            piece = response.read1(min(PIECE, n - got))       # what has come, not a full PIECE
            k = len(piece)
            view[got:got + k] = piece
            if not k:
                raise Dropped(f"the connection was dropped after {got:,} of {n:,} bytes")
            got += k
            self.tally.received(k)
            if got < n and time.monotonic() - window >= self.options.timeout_s:
                if got - at_window < min(SLOW_BYTES, n - at_window):
                    raise fail(self.url, f"{where} sent {got - at_window:,} bytes within "
                                         f"{self.options.timeout_s:g} s, too slowly")
                window, at_window = time.monotonic(), got
        response.read()         # nothing left: marks the answer read, so the connection serves the next
        return bytes(data)


def _shut(conn) -> None:
    sock = conn.sock
    if sock is not None:
        try:
            sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass


class RemoteStream(PositionedReader):
    """A RemoteFile as a seekable binary stream, read through its cache: for laspy and
    lazrs, which read headers and chunk tables from file objects."""

    def __init__(self, remote: RemoteFile):
        super().__init__()
        self._remote = remote

    def end(self) -> int:
        return self._remote.size or 0

    def readinto(self, buffer) -> int:
        data = self._remote.cached(self._pos, len(buffer)) if self._pos < (self._remote.size or 0) else b""
        buffer[:len(data)] = data
        self._pos += len(data)
        return len(data)


class Prefetch:
    """The byte ranges `spans` fetched in order with up to options.in_flight requests at
    once, on daemon threads, at most options.ahead_bytes ahead of take(); take(i), in
    order, gives span i's bytes or raises its InputError."""

    def __init__(self, remote: RemoteFile, spans: Sequence[tuple[int, int]]):
        self._remote, self._spans = remote, list(spans)
        self._cond = threading.Condition()
        self._results: dict[int, bytes | InputError] = {}
        self._next = self._taken = self._ahead = 0
        self._stopped = False
        self._threads = [threading.Thread(target=self._work, name=f"progressive-fetch-{i}", daemon=True)
                         for i in range(min(remote.options.in_flight, len(self._spans)))]
        for thread in self._threads:
            thread.start()

    def take(self, i: int) -> bytes:
        with self._cond:
            while i not in self._results:
                self._cond.wait()
            result = self._results.pop(i)
            self._taken = i + 1
            self._ahead -= self._spans[i][1]
            self._cond.notify_all()
        if isinstance(result, InputError):
            raise result
        return result

    def close(self) -> None:
        with self._cond:
            self._stopped = True
            self._cond.notify_all()

    def __enter__(self) -> Prefetch:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _work(self) -> None:
        while True:
            with self._cond:
                while not self._stopped and self._next < len(self._spans) and self._next > self._taken \
                        and self._ahead + self._spans[self._next][1] > self._remote.options.ahead_bytes:
                    self._cond.wait()
                if self._stopped or self._next >= len(self._spans):
                    return
                i, self._next = self._next, self._next + 1
                self._ahead += self._spans[i][1]
            try:
                result: bytes | InputError = self._remote.read(*self._spans[i])
            except InputError as exc:
                result = exc
            except BaseException as exc:        # a bug: handed to the reader, which fails with it
                result = InputError(f"{self._remote.url}: {type(exc).__name__}: {exc}")
            with self._cond:
                self._results[i] = result
                self._cond.notify_all()
            if isinstance(result, InputError) and not isinstance(result, FetchFailed):
                return                          # the reader fails at this span: fetch no more
