"""How fast LAS batches parse in processes, against threads, in one run: the headroom of
a loader whose parse does not wait for the GIL. Threads: each of N threads parses its
share of the file's batches (LasSource.parse, reading each span itself). Processes: a
pool of N fresh interpreters (spawn) each open the file once, parse their share of
batches the same way, and hand each batch's arrays back through one shared-memory block
(copied in once there; the parent maps it and makes arrays on it, no copy), as a
loader's batches would come back; and the same pool parsing without handing anything
back (the parse's own rate in processes); and handed back through blocks made once and
used again (no fresh pages a batch), as they are or copied out on N threads (so that the
block is free again at once, as a loader would do). Rounds alternate; ns a point = wall time / points.

    python parse_processes.py FILE [WORKERS...]
"""

import multiprocessing as mp
import os
import queue
import statistics
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from multiprocessing import shared_memory

import numpy as np

from progressive.loaders import las as L
from progressive.loaders.allocator import keep_large_blocks
from progressive.loaders.types import BATCH_POINTS

ROUNDS = int(os.environ.get("ROUNDS", 3))
BLOCK_BYTES = 64 << 20
"""A kept block's size: a batch of 500,000 points with every attribute of point format 3 takes 27 MB."""
_source = None
_attached: dict = {}


def _open(path: str) -> None:
    global _source
    keep_large_blocks()
    _source = L.open_las(path)


def _parse_shared(span: L.Span) -> tuple:
    """One batch parsed in this worker, its arrays copied into one shared block: (name, layout)."""
    names = tuple(a.name for a in _source.attributes)
    batch = _source.parse(span, span.first, np.zeros(3), names)
    arrays = {"positions": batch.positions, "cells": batch.grid.cells, **batch.attributes}
    size = sum(a.nbytes for a in arrays.values())
    block = shared_memory.SharedMemory(create=True, size=max(1, size))
    layout, at = [], 0
    for name, a in arrays.items():
        np.ndarray(a.shape, a.dtype, buffer=block.buf, offset=at)[...] = a
        layout.append((name, a.shape, a.dtype.str, at))
        at += a.nbytes
    block.close()
    return block.name, layout


def _parse_into_kept(task: tuple) -> tuple:
    """One batch parsed in this worker and copied into the kept block the parent named
    (its pages already mapped on both sides): (name, layout)."""
    span, name = task
    block = _attached.get(name) or _attached.setdefault(name, shared_memory.SharedMemory(name=name))
    names = tuple(a.name for a in _source.attributes)
    batch = _source.parse(span, span.first, np.zeros(3), names)
    layout, at = [], 0
    for key, a in {"positions": batch.positions, "cells": batch.grid.cells, **batch.attributes}.items():
        np.ndarray(a.shape, a.dtype, buffer=block.buf, offset=at)[...] = a
        layout.append((key, a.shape, a.dtype.str, at))
        at += a.nbytes
    return name, layout


def _parse_only(span: L.Span) -> int:
    """One batch parsed in this worker, nothing handed back: the parse's own rate."""
    names = tuple(a.name for a in _source.attributes)
    return _source.parse(span, span.first, np.zeros(3), names).count


def _taken(name: str, layout: list) -> int:
    """The parent's side: arrays made on the block (no copy); the block unlinked once mapped."""
    block = shared_memory.SharedMemory(name=name)
    arrays = {n: np.ndarray(shape, np.dtype(dt), buffer=block.buf, offset=at) for n, shape, dt, at in layout}
    points = arrays["positions"].shape[0]
    del arrays
    block.close()
    block.unlink()
    return points


def threads(spans, names, count: int) -> int:
    shares = [spans[k::count] for k in range(count)]
    done = [0] * count

    def work(k):
        for span in shares[k]:
            done[k] += _source.parse(span, span.first, np.zeros(3), names).count

    workers = [threading.Thread(target=work, args=(k,)) for k in range(count)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    return sum(done)


def processes(pool, spans) -> int:
    return sum(_taken(name, layout) for name, layout in pool.imap_unordered(_parse_shared, spans))


def kept(pool, spans, blocks: dict, copiers: ThreadPoolExecutor | None = None) -> int:
    """Batches handed back in blocks made once and used again once the parent has let go of
    a batch's arrays (a free list the task generator waits on); with `copiers`, each
    batch's arrays are copied out of its block on those threads (as parser threads would),
    which then give the block back at once."""
    free = queue.Queue()
    for name in blocks:
        free.put(name)

    def tasks():
        for span in spans:
            yield span, free.get()

    def take(name: str, layout: list) -> int:
        arrays = {n: np.ndarray(shape, np.dtype(dt), buffer=blocks[name].buf, offset=at) for n, shape, dt, at in layout}
        if copiers is not None:
            arrays = {n: a.copy() for n, a in arrays.items()}
        free.put(name)
        return arrays["positions"].shape[0]

    if copiers is None:
        return sum(take(name, layout) for name, layout in pool.imap_unordered(_parse_into_kept, tasks()))
    taken = [copiers.submit(take, name, layout) for name, layout in pool.imap_unordered(_parse_into_kept, tasks())]
    return sum(f.result() for f in taken)


def parse_only(pool, spans) -> int:
    return sum(pool.imap_unordered(_parse_only, spans))


def main() -> None:
    path, counts = sys.argv[1], [int(c) for c in sys.argv[2:]] or [1, 2]
    _open(path)
    spans = list(_source.chunks(BATCH_POINTS))[1:]
    names = tuple(a.name for a in _source.attributes)
    points = sum(len(s) for s in spans)
    print(f"{path}: {len(spans)} batches, {points:,} points, every attribute, {os.cpu_count()} CPUs, rounds {ROUNDS}")
    ctx = mp.get_context("spawn")
    for count in counts:
        blocks = {}
        for _ in range(2 * count):
            block = shared_memory.SharedMemory(create=True, size=BLOCK_BYTES)
            np.ndarray(BLOCK_BYTES, np.uint8, buffer=block.buf)[:] = 0       # its pages mapped here
            blocks[block.name] = block
        with ctx.Pool(count, initializer=_open, initargs=(path,)) as pool, ThreadPoolExecutor(count) as copiers:
            processes(pool, spans[:count])      # every worker started and warm
            kept(pool, spans, blocks)           # every block mapped in the workers that use it
            ways = {"threads": partial(threads, spans, names, count),
                    "processes": partial(processes, pool, spans),
                    "processes, kept blocks": partial(kept, pool, spans, blocks),
                    "processes, kept blocks, copied out": partial(kept, pool, spans, blocks, copiers),
                    "processes, parse only": partial(parse_only, pool, spans)}
            times = {way: [] for way in ways}
            for _ in range(ROUNDS):
                for way, run in ways.items():
                    t = time.perf_counter()
                    assert run() == points
                    times[way].append((time.perf_counter() - t) * 1e9 / points)
        for block in blocks.values():
            block.close()
            block.unlink()
        print(f"{count} worker(s): " + "; ".join(
            f"{way} median {statistics.median(t):.2f} ns/point ({1e3 / statistics.median(t):.0f} M points/s, best {min(t):.2f})"
            for way, t in times.items()), flush=True)


if __name__ == "__main__":
    main()
