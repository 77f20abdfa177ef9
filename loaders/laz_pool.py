"""LAZ decoded in other processes, so that the GIL is not in the way.

lazrs holds the GIL through a whole `decompress_points_with_chunk_table` call: decoding
in the loader's process stops its parser threads and the render loop, and their parsing
stops the decoding. A DecoderPool has decoder processes decode instead, one core each:
fresh interpreters running loaders/laz_worker.py by path (subprocess, `python -P`), so
no process holding a GL context or threads is forked and none imports the package. Each
job is one run of whole chunks read through the chunk table by the worker itself and
decoded into a memfd the loader made and sent with the job; the loader reads the job's
records out of it (one copy, far cheaper than the decode) and closes it. No named
segment: the memory is the kernel's to free once both sides close it, whatever ends a
process, and the records are plain arrays, however long a batch keeps them. Jobs go to
the workers in turn, ROUNDS_AHEAD a worker, and are handed back in file order.

Linux only (memfd, descriptors sent over a Unix socket); elsewhere the loader decodes
in its own process (`available`).
"""

from __future__ import annotations

import contextlib
import enum
import itertools
import os
import pickle
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import laspy
import lazrs
import numpy as np

from progressive.loaders.laz import TABLE_OFFSET_BYTES, Chunk, LazLayout, clipped, decode_chunks
from progressive.loaders.laz_worker import READY
from progressive.loaders.types import available_cores

WORKER = Path(__file__).with_name("laz_worker.py")
JOB_CHUNKS = 4096
"""Most chunks in one job, so that its message stays far below a Unix socket's buffer."""
ROUNDS_PER_WORKER = 8
"""Jobs per worker at least, where the file has that many chunks: all end at about the
same time (a file of few jobs would keep one worker decoding alone at its end)."""
ROUNDS_AHEAD = 2
"""Jobs in flight per worker: the next one waits in its socket while it decodes one."""
MIN_PROCESS_POINTS = 4_000_000
"""Points left to decode below which Decoders.AUTO stays in the loader's process, where
starting the workers costs more than they save (H200, 16 cores: 0.06 s slower for the
1.5 M points a 2 M-point file has left, 0.4 s faster for 20 M: even near 4 M, interpolated)."""
MIN_AUTO_PROCESSES = 4
"""Fewest processes Decoders.AUTO starts: on two cores what they save depends on the
machine (H200, 20 M points, faster than the loader's process by 18 % at two cores, 4 %
at four, 8 % at eight, measured before CORES_PER_PARSER, and 33 % at sixteen with it;
slower by 10-20 % on the llvmpipe machine's two cores, bench/results/llvmpipe/load.md)."""
CORES_PER_PARSER = 4
"""Parser threads that parse a pool's records at once: one per this many of its
processes, at least MIN_PARSERS. Parsing takes about a tenth of the decode's time, and
more threads contending for the GIL slow the thread that feeds the workers (H200, 16
cores, 20 M points: 13.7 M points/s with 16 parsing at once, 14.8 with 8, 16.2 with 4
or 2; lazrs alone 19.7)."""
MIN_PARSERS = 2
READS_PER_PROCESS = 2
"""A streamed local COPC's node reads in flight (reading threads) per decoder process. A
read holds its process only while the node decodes, then parses (under the parse gate)
and encodes on its thread, so with one read a process each process idles meanwhile (H200,
16 cores, the 1 B-point COPC's overview at 0.25 px: 42 ms a node's read, 9.5 of them in
its parse, mostly waiting for the gate or the GIL: bench/results/nvidia-h200/stream_writes_1B/).
With two, the 100 M-point COPC's still overview settled in a median 3.46 s against 5.17
(H100, 16 processes, 3 rounds: bench/results/nvidia-h100/stream_reads_100M/); on 2 cores
with 2 processes, 1 and 2 settle alike."""
WAIT_S = 0.05
"""How long a wait for a worker's answer blocks before it looks at whether the pool closed."""
GRACE_S = 1.0
"""How long closing waits for workers to end by themselves before they are killed."""
START_S = 10.0
"""How long the workers may take to start (import lazrs) before the loader decodes itself."""
ANSWER_BYTES = 1 << 16
NICENESS = 10
"""Added to the workers' nice value: a core the frame loop, the GL driver's threads or the
parser threads want is theirs first, and the decode takes what is left. On the H200's
16 cores, streaming a 1 B-point COPC with 16 workers busy, frames that wrote nothing took
a median 17 ms from the file against 5 ms over HTTP, whose workers wait on the network
(bench/results/nvidia-h200/stream_cf6bc53/frame_loop/): the workers taking the cores is
the likely cause, not yet measured apart."""


class Decoders(enum.Enum):
    """Where a LAZ with a sound chunk table is decoded."""

    AUTO = "auto"               # PROCESSES for files with MIN_PROCESS_POINTS left, MIN_AUTO_PROCESSES cores
    THREADS = "threads"         # lazrs's threads in the loader's process (the GIL held through each read)
    PROCESSES = "processes"     # decoder processes wherever the platform has them


@dataclass(frozen=True)
class LazOptions:
    """How a loader decodes LAZ files."""

    decoders: Decoders = Decoders.AUTO
    processes: int | None = None
    """Decoder processes; None: the cores available to this process."""


DEFAULTS = LazOptions()


class PoolClosed(Exception):
    """The pool was closed while a decode waited on it (the loader is stopping)."""


class DecodeFailed(Exception):
    """A worker could not decode a job: its message is the worker's exception's."""


def available() -> bool:
    """Whether this platform can run decoder processes."""
    return (hasattr(os, "memfd_create") and hasattr(socket, "send_fds") and hasattr(socket, "AF_UNIX")
            and bool(sys.executable) and WORKER.is_file())


def lazrs_bits(layers: laspy.DecompressionSelection) -> int:
    """`layers` as the integer lazrs.DecompressionSelection takes (laspy's flags are
    numbered otherwise; its to_lazrs() gives an object a worker cannot be sent)."""
    bits = lazrs.SELECTIVE_DECOMPRESS_XY_RETURNS_CHANNEL
    for layer in laspy.DecompressionSelection:
        if layers.is_set(layer):
            bits |= getattr(lazrs, f"SELECTIVE_DECOMPRESS_{layer.name}")
    return bits


def runs(chunks: tuple[Chunk, ...], first_read: int, piece: int) -> list[tuple[int, int]]:
    """(first, end) chunk indices of the jobs: whole chunks up to `first_read` points for
    the first, up to `piece` for the others, at least one chunk and at most JOB_CHUNKS."""
    out, at = [], 0
    while at < len(chunks):
        limit, end, held = (first_read if not out else piece), at, 0
        while end < len(chunks) and end - at < JOB_CHUNKS and (end == at or held + chunks[end][0] <= limit):
            held += chunks[end][0]
            end += 1
        out.append((at, end))
        at = end
    return out


@dataclass
class _Worker:
    process: subprocess.Popen
    sock: socket.socket


@dataclass
class _Job:
    id: int
    worker: _Worker
    fd: int
    points: int
    nbytes: int


class DecoderPool:
    """Decoder processes, started at the first decode, ended by close(). One decode at a
    time (the loader's reader thread); close() may come from any thread: it wakes a
    decode waiting on a worker, which then raises PoolClosed."""

    def __init__(self, processes: int | None = None, min_points: int = 0):
        """min_points: the fewest points left to decode that the pool takes (`takes`)."""
        self.processes = available_cores() if processes is None else processes
        if self.processes < 1:
            raise ValueError("a decoder pool needs at least one process")
        self.min_points = min_points
        self.parse_gate = threading.BoundedSemaphore(max(MIN_PARSERS, self.processes // CORES_PER_PARSER))
        """Held by a parser thread while it parses records of this pool's (pipeline.py)."""
        self._workers: list[_Worker] = []
        self._lock = threading.Lock()
        self._start_lock = threading.Lock()        # decode_run's callers start the workers once
        self._closed = False
        self._active = False
        self._failed = False
        self._ids = itertools.count()
        self._start_ended = threading.Event()       # start_soon's start has ended (or the pool closed)

    @classmethod
    def chosen(cls, options: LazOptions) -> DecoderPool | None:
        """The pool `options` ask for; None where they ask for threads or the platform has no processes."""
        processes = available_cores() if options.processes is None else options.processes
        auto = options.decoders is Decoders.AUTO
        if options.decoders is Decoders.THREADS or not available() or (auto and processes < MIN_AUTO_PROCESSES):
            return None
        return cls(processes, MIN_PROCESS_POINTS if auto else 0)

    def takes(self, points: int) -> bool:
        return points >= self.min_points

    def pids(self) -> list[int]:
        return [w.process.pid for w in self._workers]

    def _start(self) -> list[_Worker]:
        """The workers, each ready (lazrs imported) within START_S; none where one is not
        (a Python without lazrs, say): then the loader's process decodes."""
        env = {**os.environ, "RAYON_NUM_THREADS": "1"}
        workers: list[_Worker] = []
        try:
            for _ in range(self.processes):
                ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
                try:
                    process = subprocess.Popen([sys.executable, "-P", str(WORKER), str(theirs.fileno())],
                                               pass_fds=(theirs.fileno(),), env=env, stdin=subprocess.DEVNULL,
                                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                except BaseException:
                    ours.close()
                    raise
                finally:
                    theirs.close()
                ours.settimeout(WAIT_S)
                workers.append(_Worker(process, ours))
                os.setpriority(os.PRIO_PROCESS, process.pid, os.getpriority(os.PRIO_PROCESS, 0) + NICENESS)
            deadline = time.monotonic() + START_S
            for w in workers:
                while (ready := _ready(w)) is None and time.monotonic() < deadline and not self._closed:
                    pass
                if not ready:
                    raise OSError("a LAZ decoder process did not start")
        except OSError:
            _end(workers)
            return []
        except BaseException:
            _end(workers)
            raise
        return workers

    def decode(self, path: str, laz: LazLayout, points: int, first_read: int, dtype: np.dtype, piece: int,
               layers: laspy.DecompressionSelection | None = None, skip: int = 0) -> Iterator[np.ndarray]:
        """What laz.decode_chunks yields (the first `points` points of laz.chunks but
        for the first `skip`; only the LAZ layers `layers` decoded, None: all), decoded
        by the workers in jobs of whole chunks (the first of about `first_read` points,
        then of at most `piece`, ROUNDS_PER_WORKER a worker where there are chunks enough),
        as record arrays in file order, one per job; where the workers cannot start, by
        decode_chunks in this process."""
        bits = None if layers is None else lazrs_bits(layers)
        chunks = clipped(list(laz.chunks), points, None)
        offset = laz.point_data + TABLE_OFFSET_BYTES + sum(n for _, n in chunks[:skip])
        chunks = chunks[skip:]
        left = sum(n for n, _ in chunks)
        jobs = runs(chunks, first_read, min(piece, max(1, left // (self.processes * ROUNDS_PER_WORKER))))
        starts = list(itertools.accumulate((sum(n for _, n in chunks[a:b]) for a, b in jobs), initial=offset))
        if not jobs:
            return
        with self._lock:
            self._check_open()
            if self._active:
                raise RuntimeError("one decode at a time")
            self._active = True
        workers: list[_Worker] = []
        pending: deque[_Job] = deque()
        try:
            workers = self._current()
            if not workers:
                yield from decode_chunks(path, laz, points, first_read, dtype, available_cores(),
                                         None if layers is None else layers.to_lazrs(), skip)
                return
            for i, (first, end) in enumerate(jobs):
                while len(pending) >= ROUNDS_AHEAD * len(workers):
                    yield self._take(pending.popleft(), dtype)
                pending.append(self._send(workers[i % len(workers)], path, starts[i], chunks[first:end],
                                          laz.vlr_data, bits, dtype.itemsize))
            while pending:
                yield self._take(pending.popleft(), dtype)
        finally:
            for job in pending:
                os.close(job.fd)
            with self._lock:
                self._active = False
                if self._closed:
                    _close_sockets(workers)

    def start_soon(self) -> None:
        """Start the workers on a thread of their own, while the caller goes on
        (`wait_started` waits for them, `ready` says whether they are there)."""
        def start() -> None:
            try:
                with self._start_lock:
                    if not self._workers and not self._failed and not self._closed:
                        with contextlib.suppress(PoolClosed):
                            self._started()
            finally:
                self._start_ended.set()

        threading.Thread(target=start, name="start LAZ decoders", daemon=True).start()

    def wait_started(self, timeout: float = START_S) -> bool:
        """After start_soon: wait at most `timeout` seconds for its start to end; whether
        the workers are ready. Waiting is cheap (they are ready within about 0.13 s for 8
        on 2 cores) beside decoding in the caller's process meanwhile, where lazrs holds
        the GIL through each decode."""
        self._start_ended.wait(timeout)
        return self.ready

    @property
    def ready(self) -> bool:
        """The workers are started and none was lost."""
        return bool(self._workers) and not self._failed and not self._closed

    def decode_run(self, lane: int, path: str, offset: int, table: tuple[Chunk, ...], vlr: bytes,
                   layers: laspy.DecompressionSelection | None, dtype: np.dtype) -> np.ndarray:
        """One run of whole chunks (`table`'s (points, bytes), from byte `offset` of the
        file) decoded by worker `lane` (mod the processes), waiting for it: for callers
        that decode on several threads at once, each on a lane of its own (a streaming
        reader's nodes). DecodeFailed where the workers cannot start or one is lost (the
        caller decodes in its own process then), PoolClosed once closed."""
        return self._run(lane, (path, offset), table, vlr, layers, np.empty(sum(n for n, _ in table), dtype))

    def decode_bytes(self, lane: int, compressed: bytes, table: tuple[Chunk, ...], vlr: bytes,
                     layers: laspy.DecompressionSelection | None, out: np.ndarray) -> None:
        """decode_run of chunks held in memory (a node fetched over HTTP: the worker reads
        them from a memfd sent with the job), into the records `out`."""
        self._run(lane, compressed, table, vlr, layers, out)

    def _run(self, lane: int, source: tuple[str, int] | bytes, table: tuple[Chunk, ...], vlr: bytes,
             layers: laspy.DecompressionSelection | None, out: np.ndarray) -> np.ndarray:
        with self._start_lock:
            workers = self._current()
        if not workers:
            raise DecodeFailed("the LAZ decoder processes could not start")
        bits = None if layers is None else lazrs_bits(layers)
        worker = workers[lane % len(workers)]
        try:
            if isinstance(source, bytes):
                job = self._send(worker, None, 0, table, vlr, bits, out.dtype.itemsize, source)
            else:
                job = self._send(worker, *source, table, vlr, bits, out.dtype.itemsize)
            return self._take(job, out.dtype, out)
        except OSError as exc:        # its socket reset: the worker is gone
            self._check_open()
            raise self._lost(worker) from exc

    def _current(self) -> list[_Worker]:
        """The workers there are, or those started now where there are none or one was lost."""
        return self._started() if self._failed or not self._workers else self._workers

    def _started(self) -> list[_Worker]:
        """The workers, started now; none where they cannot start or one was lost (a
        worker that failed to start or died is not tried again: the loader's process
        decodes the files that follow)."""
        if self._failed:
            with self._lock:
                lost, self._workers = self._workers, []
            _end(lost)
            return []
        started = self._start()
        with self._lock:
            closed = self._closed
            if not closed:
                self._workers, self._failed = started, not started
        if closed:
            _end(started)
            self._check_open()
        return started

    def _send(self, worker: _Worker, path: str | None, offset: int, table: tuple[Chunk, ...], vlr: bytes,
              layers: int | None, itemsize: int, compressed: bytes | None = None) -> _Job:
        """The job to `worker`; with `compressed` (path None) its chunks go along in a
        second memfd, which the worker reads instead of a file."""
        points = sum(n for n, _ in table)
        job = _Job(next(self._ids), worker, os.memfd_create("progressive-laz", os.MFD_CLOEXEC), points,
                   points * itemsize)
        given = -1
        try:
            os.ftruncate(job.fd, job.nbytes)
            fds = [job.fd]
            if compressed is not None:
                given = os.memfd_create("progressive-laz-in", os.MFD_CLOEXEC)
                view, put = memoryview(compressed), 0
                while put < len(view):
                    put += os.write(given, view[put:])
                fds.append(given)
            message = pickle.dumps((job.id, path, offset, list(table), vlr, layers, job.nbytes))
            try:
                socket.send_fds(worker.sock, [message], fds)
            except OSError as exc:
                self._check_open()
                raise self._lost(worker) from exc
        except BaseException:
            os.close(job.fd)
            raise
        finally:
            if given >= 0:
                os.close(given)         # the worker holds its own descriptor of it now
        return job

    def _take(self, job: _Job, dtype: np.dtype, out: np.ndarray | None = None) -> np.ndarray:
        """The job's records once its worker answers (into `out` where given); its
        error, raised, if it failed."""
        try:
            _, error, text = self._answer(job)
            if error is not None:
                raise DecodeFailed(text or error)
            records = np.empty(job.points, dtype) if out is None else out
            view, got = memoryview(records).cast("B"), 0
            while got < job.nbytes:
                n = os.preadv(job.fd, [view[got:]], got)
                if n <= 0:
                    raise DecodeFailed("the LAZ decoder process left its job unfinished")
                got += n
            return records
        finally:
            os.close(job.fd)

    def _answer(self, job: _Job) -> tuple:
        """The worker's answer to `job` (it answers in the order it was sent jobs; the
        answers to jobs of a decode given up are passed over)."""
        while True:
            self._check_open()
            try:
                raw = job.worker.sock.recv(ANSWER_BYTES)
            except TimeoutError:
                continue
            except OSError:
                self._check_open()
                raise
            if not raw:
                self._check_open()
                raise self._lost(job.worker)
            answer = pickle.loads(raw)
            if answer[0] == job.id:
                return answer

    def _lost(self, worker: _Worker) -> DecodeFailed:
        """A worker gone (killed, or lazrs aborted it): its job's decode error."""
        self._failed = True
        with contextlib.suppress(subprocess.TimeoutExpired):
            worker.process.wait(GRACE_S)
        return DecodeFailed(f"the LAZ decoder process ended (exit status {worker.process.returncode})")

    def _check_open(self) -> None:
        if self._closed:
            raise PoolClosed("the decoder pool is closed")

    def close(self) -> None:
        """End the workers: their sockets are shut, so that they end (and a decode
        waiting on them wakes); one that has not within GRACE_S is killed. Safe to call
        again."""
        self._start_ended.set()
        with self._lock:
            self._closed = True
            workers, self._workers = self._workers, []
            active = self._active
            for w in workers:
                with contextlib.suppress(OSError):
                    w.sock.shutdown(socket.SHUT_RDWR)
            if not active:
                _close_sockets(workers)
        _reap(workers)

    def __enter__(self) -> DecoderPool:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


def _ready(worker: _Worker) -> bool | None:
    """Whether the worker said it is ready; None: not yet (WAIT_S passed)."""
    try:
        return worker.sock.recv(len(READY)) == READY
    except TimeoutError:
        return None
    except OSError:
        return False


def _reap(workers: list[_Worker]) -> None:
    """Wait for workers whose sockets are shut to end; kill those that have not within GRACE_S."""
    deadline = time.monotonic() + GRACE_S
    for w in workers:
        with contextlib.suppress(subprocess.TimeoutExpired):
            w.process.wait(max(0.0, deadline - time.monotonic()))
        if w.process.poll() is None:
            w.process.kill()
            w.process.wait()


def _end(workers: list[_Worker]) -> None:
    _close_sockets(workers)
    _reap(workers)


def _close_sockets(workers: list[_Worker]) -> None:
    for w in workers:
        w.sock.close()
