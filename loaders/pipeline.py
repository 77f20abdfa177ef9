"""Several files as one cloud, loaded by background threads while the renderer draws.

One reader thread hands work to parser threads through a one-slot queue, in file order:
the spans of an uncompressed file (each parser reads its own, without the GIL), LAZ
points decoded by lazrs several chunks at a time on every core (a large file's by
decoder processes: laz_pool.py), the chunks of the other formats. Parsed batches wait
in a queue of parser_threads slots. So at most about 2 x parser_threads + 2 batches
(and one LAZ read, or a pool's ROUNDS_AHEAD jobs a worker, and until the first file's
first batches are parsed, the records its probe kept: las.KEPT_BYTES) are in memory at
once, however large the cloud is. Parser threads default to one a core this process may
use, at most types.PARSER_THREADS: more contend for the GIL.
An http(s):// URL is a COPC file read by range requests (`http` says how:
loaders/http.py).
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import queue
import re
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator

import numpy as np

from progressive.errors import InputError
from progressive.loaders.allocator import keep_large_blocks
from progressive.loaders.copc import CopcSource, is_copc, keep_levels, open_copc, open_copc_url
from progressive.loaders.e57 import E57Source, is_e57, open_e57
from progressive.loaders.fastformat import FastSource, is_fast, open_fast
from progressive.loaders.http import DEFAULTS as HTTP_DEFAULTS
from progressive.loaders.http import HttpOptions, is_url
from progressive.loaders.las import LasSource, TruncatedInput, open_las
from progressive.loaders.laz_pool import DEFAULTS as LAZ_DEFAULTS
from progressive.loaders.laz_pool import DecoderPool, LazOptions, PoolClosed
from progressive.loaders.ply import PlySource, is_ply, open_ply
from progressive.loaders.records import ELEVATION
from progressive.loaders.types import BATCH_POINTS, AttributeInfo, Batch, CloudInfo, ReadyQueue, default_parser_threads
from progressive.loaders.validate import fail, shown

Source = LasSource | FastSource | E57Source | PlySource
OPENERS = ((is_fast, open_fast), (is_e57, open_e57), (is_ply, open_ply), (is_copc, open_copc))
"""Formats told apart by their magic; anything else is opened (and checked) as LAS/LAZ."""
Task = tuple[str, Callable[[], Batch]]
WAIT_S = 0.05
"""How long a blocked thread waits before it looks at the stop flag again."""
JOIN_S = 5.0
_END = object()
"""Sentinel: no more tasks (to parsers) or this parser has finished (to the consumer)."""


class _Later:
    """A batch of the later pass (CloudLoader.keep_only's `later`), as the queues carry it."""

    __slots__ = ("batch",)

    def __init__(self, batch: Batch):
        self.batch = batch


def open_cloud(paths: Iterable[str | os.PathLike] | str | os.PathLike, *, partial: bool = False,
               http: HttpOptions = HTTP_DEFAULTS) -> CloudInfo:
    """The cloud's description from the file headers (and each file's first batch)."""
    info, sources = open_sources(paths, partial=partial, http=http)
    close_sources(sources)
    return info


def open_sources(paths, *, partial: bool = False, point_budget: int | None = None,
                 http: HttpOptions = HTTP_DEFAULTS, keep_first: bool = False,
                 view=None, check_count: Callable[[str, int], None] | None = None) -> tuple[CloudInfo, tuple[Source, ...]]:
    """point_budget: the points that fit on the GPU; a larger cloud's COPC files are read
    down to a level of detail (loaders/copc.py keep_levels: the nodes `view` needs most
    where one is given, a copc_choice.View or a function of the cloud's corners). keep_first: the first file, where it is
    a LAZ, keeps what opening it decoded for its first batches (open_las's keep), which
    the first image would otherwise wait for a second decode of. check_count: refuses a
    LAS/LAZ file by its header's point count before its points are read (open_las); the
    whole cloud's count is the caller's to check (COPC files may be cut to the budget)."""
    paths = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    if not paths:
        raise InputError("no input files given")
    opened: list[Source] = []
    try:
        for i, p in enumerate(paths):
            opened.append(_open(p, partial, http, keep_first and i == 0, check_count))
    except BaseException:
        close_sources(opened)
        raise
    sources = keep_levels(tuple(opened), point_budget, view)
    files = tuple(s.info for s in sources)
    lo = np.min([f.bounds_min for f in files], axis=0).astype(np.float64)
    hi = np.max([f.bounds_max for f in files], axis=0).astype(np.float64)
    if all(isinstance(s, FastSource) for s in sources):
        origin, attributes = _fast_cloud(sources)
    elif any(isinstance(s, FastSource) for s in sources):
        first = next(s for s in sources if isinstance(s, FastSource))
        raise fail(first.info.path, "is in the fast format; it cannot be mixed with LAS/LAZ, E57 or PLY files")
    else:
        origin = (lo + hi) / 2
        attributes = _common_attributes(sources, origin)
    check_crs(files)
    info = CloudInfo(files=files, points=sum(f.points for f in files), origin=origin,
                     bounds_min=lo, bounds_max=hi, attributes=attributes)
    return info, sources


EPSG = re.compile(r"EPSG:(\d+)")


def check_crs(files) -> None:
    """Files whose EPSG codes differ cannot be one cloud (their coordinates mean different
    places): one line naming both. Labels without codes are compared by crs_warnings."""
    coded = [(f, EPSG.search(f.crs)) for f in files if f.crs]
    coded = [(f, m.group(1)) for f, m in coded if m]
    for f, code in coded[1:]:
        if code != coded[0][1]:
            first = coded[0][0]
            raise fail(f.path, f"is in {f.crs}, but {shown(first.path)} is in {first.crs}: files in different "
                               f"coordinate systems cannot be one cloud")


def crs_warnings(files) -> list[str]:
    """Different CRS labels where no two EPSG codes disagree (one file may name the same
    CRS differently, or have none): drawn as one cloud, with a warning."""
    labels = {f.crs for f in files if f.crs}
    if len(labels) < 2:
        return []
    return [f"the files name different coordinate systems ({'; '.join(sorted(labels))}); drawn as one cloud as they are"]


def _open(path, partial: bool, http: HttpOptions, keep: bool, check_count: Callable[[str, int], None] | None) -> Source:
    if is_url(path):
        return open_copc_url(path, partial=partial, http=http)
    opener = next((open_ for is_format, open_ in OPENERS if is_format(path)), None)
    if opener is None:
        return open_las(path, partial=partial, keep=keep, check_count=check_count)
    return opener(path, partial=partial)


def close_sources(sources) -> None:
    """Stop what sources fetch in flight (COPC over HTTP); other sources hold nothing open."""
    for source in sources:
        if isinstance(source, CopcSource):
            source.close()


def _fast_cloud(sources: tuple[FastSource, ...]) -> tuple[np.ndarray, tuple[AttributeInfo, ...]]:
    """Fast files are packed already, so they must share the origin and the attribute."""
    first = sources[0]
    for s in sources[1:]:
        if not np.array_equal(s.origin, first.origin) or s.attribute != first.attribute:
            raise fail(s.info.path, f"has a different origin or attribute than {shown(first.info.path)}")
    return first.origin.copy(), (first.attribute,)


def _common_attributes(sources: tuple[LasSource | E57Source | PlySource, ...], origin: np.ndarray) -> tuple[AttributeInfo, ...]:
    """Attributes every file has, in the first file's order (standard ones, then extra
    bytes), with the offsets that keep float32 detail on the GPU."""
    by_file = [{a.name: a for a in s.attributes} for s in sources]
    common = [a for a in sources[0].attributes if all(a.name in f for f in by_file)]
    first_gps = sources[0].first_gps_time
    offsets = {
        "elevation": float(origin[2]),
        "gps_time": float(math.floor(first_gps)) if first_gps is not None and math.isfinite(first_gps) else 0.0,
    }
    return tuple(
        AttributeInfo(a.name, a.kind, np.result_type(*(f[a.name].dtype for f in by_file)),
                      offsets.get(a.name, 0.0))
        for a in common
    )


def _tasks(source: Source, start: int, batch_points: int, origin: np.ndarray,
           names: tuple[str, ...], partial: bool, decoders: DecoderPool | None = None) -> Iterator[Task]:
    """Per batch, the work a parser thread does: parsing LAS chunks (of a LAZ, only the
    layers `names` need were decoded, by `decoders` where they take the file),
    reading fast-format records and checking them for non-finite values."""
    path = source.info.path
    if isinstance(source, FastSource):
        for first, count in source.spans(batch_points):
            yield path, functools.partial(source.read_parsed, first, count, start + first)
        return
    parse = source.parse
    if isinstance(source, CopcSource):      # its nodes are decoded by loaders/copc.py
        chunks = source.chunks(batch_points, salvage=partial, names=names)
    elif isinstance(source, LasSource):
        if pool := source.pool_for(decoders, names):
            parse = functools.partial(_gated, pool.parse_gate, parse)
        chunks = source.chunks(batch_points, salvage=partial, names=names, decoders=decoders)
    else:
        chunks = source.chunks(batch_points, salvage=partial)
    for chunk in chunks:
        yield path, functools.partial(parse, chunk, start, origin, names)
        start += len(chunk)


def _gated(gate: threading.Semaphore, parse: Callable[..., Batch], *args) -> Batch:
    with gate:
        return parse(*args)


def _as_input_error(path: str, exc: BaseException) -> InputError:
    if isinstance(exc, InputError):
        return exc
    if isinstance(exc, OSError):
        return fail(path, f"cannot read: {exc.strerror or exc}")
    return fail(path, f"cannot be loaded: {type(exc).__name__}: {exc}")


class Hold:
    """How many batches a loader's workers may still start (None: any): a caller that
    holds them after the first builds what shows it (context, buffers, programs) with
    the GIL and the cores to itself, then releases them."""

    def __init__(self, first: int | None = None):
        self._left = first
        self._changed = threading.Condition()

    def admit(self, stop: threading.Event) -> bool:
        """Wait until one more batch may start; False once the loader is stopped."""
        with self._changed:
            while self._left == 0 and not stop.is_set():
                self._changed.wait(WAIT_S)
            if self._left:
                self._left -= 1
        return not stop.is_set()

    def release(self) -> None:
        with self._changed:
            self._left = None
            self._changed.notify_all()


class BatchQueue:
    """Polling and iterating the batches worker threads put on `_results`: what every
    loader shares. A subclass sets `_results` and `_stop`, and defines start(first),
    resume(), `done`, _take(item, batches) and _raise_failure(); `_ended` says when
    iterating stops without a failure to raise. Iterating resumes a loader started with
    `first`: it waits for every batch."""

    def poll(self, max_batches: int | None = None) -> list[Batch]:
        """The batches ready now, without waiting. A failure is raised by the first poll
        that finds none: the batches read before it are drawn first (a viewer keeps them
        once it has shown the error)."""
        self.start()
        batches: list[Batch] = []
        while not self.done and (max_batches is None or len(batches) < max_batches):
            try:
                item = self._results.get_nowait()
            except queue.Empty:
                break
            self._take(item, batches)
        if not batches:
            self._raise_failure()
        return batches

    def wait(self, timeout: float) -> bool:
        """Whether a batch (or the end, or a failure) is there to poll, waiting at most
        `timeout` seconds for one."""
        return self._results.wait(timeout)

    def __iter__(self) -> Iterator[Batch]:
        self.start()
        self.resume()
        while not self.done:
            self._raise_failure()
            if self._ended():
                return
            try:
                item = self._results.get(timeout=WAIT_S)
            except queue.Empty:
                continue
            batches: list[Batch] = []
            self._take(item, batches)
            yield from batches

    def _ended(self) -> bool:
        return self._stop.is_set()


class CloudLoader(BatchQueue):
    """Loads a cloud in the background; poll() from a render loop or iterate to block.

    Batches arrive in any order, each with its global file-order `start`. Of the batches
    handed out so far, `nonfinite_positions` counts the points that are never drawn (x,
    y or z NaN/Inf) and `nonfinite_values` the NaN/Inf values per float attribute that
    has any; both are final once `done`.

    `attributes` (names of info.attributes) limits what batches carry, and so what a LAZ
    of point format 6-10 decodes: a caller that shows one attribute and keeps no others
    loads faster. None: every attribute. Fast-format batches carry their one attribute.

    `laz` says where LAZ files are decoded: by default a large one with a sound chunk
    table in decoder processes (laz_pool.py), which the loader ends once it has read
    every file, or at close().

    keep_only(first, later) reads the files twice: batches of `first`, then (poll_later,
    once `done`) batches of the `later` attributes, which a viewer switches to: its
    first image and its every point come as soon as for `first` alone. The two passes'
    batches cover the same points but need not start at the same indices (a LAZ's
    first batches come from its probe's records).
    """

    def __init__(self, paths, *, batch_points: int = BATCH_POINTS,
                 parser_threads: int | None = None, partial: bool = False,
                 attributes: tuple[str, ...] | None = None, point_budget: int | None = None,
                 http: HttpOptions = HTTP_DEFAULTS, view=None, laz: LazOptions = LAZ_DEFAULTS,
                 check_count: Callable[[str, int], None] | None = None,
                 on_parsed: Callable[[Batch], Batch] | None = None):
        """view: the first view, whose nodes a COPC cloud larger than point_budget keeps;
        check_count: refuses a LAS/LAZ file too large by its header alone (open_sources);
        on_parsed: what each batch of the first pass becomes, on the parser thread that
        made it (work its consumer would do on its own thread: the session's framing)."""
        parser_threads = default_parser_threads() if parser_threads is None else parser_threads
        if batch_points < 1 or parser_threads < 1:
            raise ValueError("batch_points and parser_threads must be at least 1")
        keep_large_blocks()
        self.info, self._sources = open_sources(paths, partial=partial, point_budget=point_budget, http=http,
                                                keep_first=True, view=view, check_count=check_count)
        self.attributes = self._chosen(attributes)
        self.later: tuple[str, ...] = ()
        self.batch_points = batch_points
        self.parser_threads = parser_threads
        self.on_parsed = on_parsed
        self.partial = partial
        self.warnings: list[str] = [w for s in self._sources for w in s.warnings] + crs_warnings(self.info.files)
        self.loaded = 0
        self.nonfinite_positions = 0
        self.nonfinite_values: dict[str, int] = {}
        self._finished = 0
        self._first_tasks = 0       # batches of the first pass queued for the parsers
        self._first_queued = False  # ... every one of them
        self._first_taken = 0
        self._later_ready: deque[Batch] = deque()
        self._tasks: queue.Queue = queue.Queue(maxsize=1)
        self._results = ReadyQueue(maxsize=self.parser_threads)
        self._stop = threading.Event()
        """No more reads: set by close() and by a failure."""
        self._closed = threading.Event()
        """Set by close(): the tasks queued and the batches parsed are dropped."""
        self._error: InputError | None = None
        self._threads: list[threading.Thread] = []
        self._hold = Hold()
        self._decoders = DecoderPool.chosen(laz)

    def _chosen(self, attributes: tuple[str, ...] | None) -> tuple[str, ...]:
        known = tuple(a.name for a in self.info.attributes)
        if unknown := sorted(set(attributes or ()) - set(known)):
            raise ValueError(f"the cloud has no attribute {', '.join(unknown)}")
        return known if attributes is None else tuple(n for n in known if n in attributes)

    def keep_only(self, attributes: tuple[str, ...], later: tuple[str, ...] = ()) -> None:
        """Before start(): batches carry only these attributes (as `attributes` at
        construction), once the caller knows from `info` what it will show; `later`: the
        attributes a second pass reads afterwards (poll_later)."""
        if self._threads:
            raise RuntimeError("keep_only() after the loader started")
        self.attributes = self._chosen(attributes)
        # elevation is the positions' own: no batch carries it
        self.later = tuple(n for n in self._chosen(later) if n not in self.attributes and n != ELEVATION)

    @property
    def layered(self) -> bool:
        """Whether a later pass lets the first do less: every file a local LAZ of point
        formats 6-10 (COPC among them), whose layers are decoded apart. Other LAZ files
        decode every field whatever is asked for, a LAS file's first batches reach the
        GPU no sooner for fewer attributes parsed (bench/results/nvidia-h200/viewer_load/),
        and a URL's bytes would be fetched again."""
        return all(type(s) in (LasSource, CopcSource) and not is_url(s.info.path) and s.laz is not None
                   and s.info.point_format >= 6 for s in self._sources)

    @property
    def total(self) -> int:
        return self.info.points

    @property
    def sources(self) -> tuple:
        """The opened files, in cloud order (a streaming reader reads their nodes itself)."""
        return self._sources

    @property
    def done(self) -> bool:
        """Every batch (of the first pass) has been handed to the consumer."""
        return self._finished == self.parser_threads or (self._first_queued and self._first_taken == self._first_tasks)

    @property
    def later_done(self) -> bool:
        """Every batch of the later pass has been handed to the consumer (or there is none)."""
        return self._finished == self.parser_threads and not self._later_ready

    def poll_later(self, max_batches: int | None = None) -> list[Batch]:
        """The later pass's batches ready now (none before `done`), without waiting; a
        failure is raised as by poll()."""
        batches: list[Batch] = []
        while self.done and (max_batches is None or len(batches) < max_batches):
            if not self._later_ready:
                if self._finished == self.parser_threads:
                    break
                try:
                    item = self._results.get_nowait()
                except queue.Empty:
                    break
                self._take(item, batches)
                continue
            batches.append(self._later_ready.popleft())
        if not batches:
            self._raise_failure()
        return batches

    def start(self, first: int | None = None) -> CloudLoader:
        """first: parse that many batches, then wait for resume() (a first start only)."""
        if not self._threads:
            self._hold = Hold(first)
            self._threads = [threading.Thread(target=self._read, name="progressive-reader", daemon=True)]
            self._threads += [threading.Thread(target=self._parse, name=f"progressive-parser-{i}", daemon=True)
                              for i in range(self.parser_threads)]
            for thread in self._threads:
                thread.start()
        return self

    def resume(self) -> None:
        """Parse the rest (after start(first))."""
        self._hold.release()

    def close(self) -> None:
        """Stop the threads; they notice within WAIT_S or after the chunk being decoded
        (fetches in flight fail at once). Only those that started are waited for: a signal
        may interrupt start() before the last (each start waits for its thread to run, and
        lazrs holds the GIL while the reader decodes), and joining one that never started
        raises."""
        self._closed.set()
        self._stop.set()
        close_sources(self._sources)
        if self._decoders is not None:
            self._decoders.close()
        for thread in self._threads:
            if thread.is_alive() and thread is not threading.current_thread():
                thread.join(JOIN_S)

    def __enter__(self) -> CloudLoader:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def _take(self, item, batches: list[Batch]) -> None:
        if item is _END:
            self._finished += 1
        elif isinstance(item, _Later):
            self._count_nonfinite(item.batch)
            self._later_ready.append(item.batch)
        else:
            self._first_taken += 1
            self.loaded += item.count
            self.nonfinite_positions += item.nonfinite_positions
            self._count_nonfinite(item)
            batches.append(item)

    def _count_nonfinite(self, batch: Batch) -> None:
        for name, n in batch.nonfinite_values.items():
            self.nonfinite_values[name] = self.nonfinite_values.get(name, 0) + n

    def _raise_failure(self) -> None:
        """The failure, once the tasks read before it are parsed and handed over (the
        parser threads have ended): a viewer draws them (on many cores a COPC's last node's
        fetch failed while every earlier node was still being parsed)."""
        parsing = any(t.is_alive() for t in self._threads[1:])
        if self._error is not None and not parsing and (self._results.empty() or self.done):
            self.close()
            raise self._error

    def _ended(self) -> bool:
        return self._closed.is_set()

    def _fail(self, path: str, exc: BaseException) -> None:
        """Stop reading; the parser threads parse what is queued, held or not, and end."""
        if self._error is None:
            self._error = _as_input_error(path, exc)
        self._stop.set()
        self._hold.release()

    def _put(self, q: queue.Queue, item, until: threading.Event | None = None) -> bool:
        """Blocking put that gives up once `until` is set (the loader stopped)."""
        until = self._stop if until is None else until
        while not until.is_set():
            try:
                q.put(item, timeout=WAIT_S)
                return True
            except queue.Full:
                pass
        return False

    def _next_task(self):
        """The next task queued, _END once none is left after the reads stopped (or at close())."""
        while not self._closed.is_set():
            try:
                return self._tasks.get(timeout=WAIT_S)
            except queue.Empty:
                if self._stop.is_set():
                    return _END
        return _END

    def _read(self) -> None:
        path = ""
        try:
            for later, names in ((False, self.attributes), (True, self.later)):
                if later and not names:
                    break
                while later and not self.done:      # the first pass's batches have the cores till they are taken
                    if self._stop.wait(WAIT_S):
                        return
                start = 0
                for source in self._sources:
                    path = source.info.path
                    try:
                        tasks = _tasks(source, start, self.batch_points, self.info.origin, names, self.partial,
                                       self._decoders)
                        with contextlib.closing(tasks):
                            for task in tasks:
                                self._first_tasks += not later
                                if not self._put(self._tasks, (*task, later)):
                                    return
                    except TruncatedInput as exc:
                        if not self.partial:
                            raise
                        if str(exc) not in self.warnings:       # the later pass meets it again
                            self.warnings.append(str(exc))
                    start += source.info.points
                self._first_queued = True
        except BaseException as exc:
            if not (isinstance(exc, PoolClosed) and self._stop.is_set()):
                self._fail(path, exc)
        finally:
            if self._decoders is not None:
                self._decoders.close()
            for _ in range(self.parser_threads):
                self._put(self._tasks, _END)

    def _parse(self) -> None:
        try:
            while (task := self._next_task()) is not _END:
                if not self._hold.admit(self._closed):
                    return
                path, make, later = task
                try:
                    batch = make()
                    if self.on_parsed is not None and not later:
                        batch = self.on_parsed(batch)
                except BaseException as exc:
                    self._fail(path, exc)
                    return
                # handed over after another task's failure too, dropped only by close()
                if not self._put(self._results, _Later(batch) if later else batch, self._closed):
                    return
        finally:
            self._put(self._results, _END)
