"""Reading COPC nodes one at a time in background threads, for streaming: the nodes a
view needs change as the camera moves, so the frame loop asks for nodes and takes what
has arrived without waiting (loaders/copc_residency.py plans which).

Rows are those of `Nodes.of_files` over the files in cloud order, so a plan's rows name
the nodes read here. A node's points are numbered by their cloud index (the file's
offset in the cloud plus the index in the file), as the file read whole numbers them, so
ids and picks of a streamed cloud mean what they mean for the plain file.
"""

from __future__ import annotations

import contextlib
import os
import queue
import threading
import urllib.parse
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from progressive.errors import InputError
from progressive.loaders.allocator import keep_large_blocks
from progressive.loaders.copc import COPC_SUFFIX, CopcSource, hierarchy_nodes, is_copc
from progressive.loaders.http import is_url
from progressive.loaders.laz_pool import DecoderPool
from progressive.loaders.types import Batch, ReadyQueue
from progressive.loaders.validate import one_line


def may_stream(path: str | os.PathLike) -> bool:
    """Worth opening to stream: a local COPC file (its first bytes say so), or a URL
    named as COPC files are (reading it to know would cost a round trip first)."""
    if is_url(str(path)):
        return urllib.parse.urlsplit(str(path)).path.lower().endswith(COPC_SUFFIX)
    return is_copc(path)


def streamable(sources) -> bool:
    """Every source is a COPC file whose hierarchy can be used."""
    return bool(sources) and all(isinstance(s, CopcSource) and s.hierarchy is not None for s in sources)


class NodeReader:
    """Reads nodes of COPC sources (every one usable: `streamable`) on `threads` threads.
    request(row) queues a read; arrivals() gives (row, Batch) or (row, reason) for each
    read finished since, or (row, None) for one cancelled before it began (cancel),
    without waiting. Reads may finish in any order. `decoders`:
    decoder processes for the nodes, one read at a time each (their decoding then leaves
    the GIL to the frame loop; a URL's node goes to its process once fetched); the
    reader closes them. `on_parsed`: what each node's Batch becomes, on its reading
    thread (the core's work that need not wait for the frame loop)."""

    def __init__(self, sources: tuple[CopcSource, ...], origin: np.ndarray, names: tuple[str, ...], threads: int,
                 decoders: DecoderPool | None = None, on_parsed: Callable[[Batch], Batch] | None = None):
        if not streamable(sources):
            raise ValueError("every source must be a COPC file with a usable hierarchy")
        keep_large_blocks()
        h = [s.hierarchy for s in sources]
        self.nodes = hierarchy_nodes(h)
        self.sources = sources
        self.origin = np.asarray(origin, np.float64)
        self.names = names
        self.on_parsed = on_parsed
        offsets = np.cumsum([0] + [s.info.points for s in sources])
        self._file = self.nodes.file
        self._local = np.concatenate([np.arange(x.nodes.size) for x in h])
        self._start = np.concatenate([offsets[i] + x.first for i, x in enumerate(h)])
        self._pool = ThreadPoolExecutor(max(1, threads), thread_name_prefix="copc nodes")
        self.decoders = decoders
        if decoders is not None:
            decoders.start_soon()       # reads wait for them: the session's first reads come at once
        self._lanes: queue.SimpleQueue = queue.SimpleQueue()     # a process's answers are for one read at a time
        for lane in range(decoders.processes if decoders is not None else 0):
            self._lanes.put(lane)
        self._done = ReadyQueue()
        self._futures: dict[int, Future] = {}
        self._lock = threading.Lock()
        self._closed = False

    def first_index(self, row: int) -> int:
        """The cloud index of node `row`'s first point."""
        return int(self._start[row])

    def request(self, row: int) -> None:
        with self._lock:
            if self._closed:
                return
            self._futures[row] = self._pool.submit(self._read, row)

    def cancel(self, rows) -> None:
        """Reads of `rows` not begun yet are dropped: each arrives at once as (row, None)
        (reads under way end as they would)."""
        with self._lock:
            for row in rows:
                future = self._futures.get(row)
                if future is not None and future.cancel():
                    del self._futures[row]
                    self._done.put((row, None))

    @contextlib.contextmanager
    def _lane(self) -> Iterator[int]:
        """A decoder process to this read alone while it decodes (each answers one at a time)."""
        lane = self._lanes.get()
        try:
            yield lane
        finally:
            self._lanes.put(lane)

    def _read(self, row: int) -> None:
        source = self.sources[int(self._file[row])]
        ready = self.decoders is not None and self.decoders.wait_started()
        if self._closed:        # closed while it waited for the processes: nothing to decode here
            return
        try:
            got: Batch | str = source.node_batch(int(self._local[row]), self.first_index(row), self.origin, self.names,
                                                 self.decoders if ready else None, self._lane)
            if self.on_parsed is not None:
                got = self.on_parsed(got)
        except InputError as exc:
            got = one_line(exc)
        except Exception as exc:        # any other failure is one node's too: the viewer goes on
            got = f"{type(exc).__name__}: {one_line(exc)}"
        with self._lock:
            self._futures.pop(row, None)
            if self._closed:
                return
        self._done.put((row, got))

    def wait(self, timeout: float) -> bool:
        """Whether a read has ended (to take with arrivals()), waiting at most `timeout` seconds."""
        return self._done.wait(timeout)

    def arrivals(self) -> list[tuple[int, Batch | str]]:
        out = []
        while True:
            try:
                out.append(self._done.get_nowait())
            except queue.Empty:
                return out

    @property
    def reading(self) -> int:
        """Reads queued or under way."""
        with self._lock:
            return len(self._futures)

    def close(self) -> None:
        """Cancel the queued reads, stop the fetches under way, and wait for the threads."""
        with self._lock:
            self._closed = True
            for f in self._futures.values():
                f.cancel()
        for s in self.sources:
            s.close()
        if self.decoders is not None:
            self.decoders.close()       # a read waiting on a process wakes (and is discarded)
        self._pool.shutdown(wait=True, cancel_futures=True)
