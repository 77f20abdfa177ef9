"""How fast LAS batches parse in processes, against threads, in one run: the headroom of
a loader whose parse does not wait for the GIL. N threads or N processes each parse
every batch of the file (LasSource.parse, reading each span itself), as bench probes of
the parse in threads do (../parse_calls/), so that no worker idles at the end of a
round. The processes are a pool of N fresh interpreters (spawn), each of which opens
the file once; they hand each batch's arrays back

- through a shared-memory block made for the batch (its pages faulted in fresh each
  time; the parent maps it and makes arrays on it, no copy);
- through blocks made once, every one mapped and touched in every worker and in the
  parent at the start, and used again once the parent lets go of a batch's arrays;
- the same, each batch's arrays copied out on N threads of the parent (so that the
  block is free again at once, as a loader would do);
- or not at all (the parse's own rate in processes: the ceiling).

Rounds alternate; ns a point = wall time / (points × N).

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
ALIGN = 64
"""Each array's offset in a block."""
FREE_WAIT_S = 60
"""Longest wait for a free block (a worker that failed never frees its block: the run ends, it does not hang)."""
_source = None
_attached: dict = {}


def _open(path: str, blocks: tuple[str, ...] = ()) -> None:
    """A worker's start: the file opened, every kept block mapped and its pages touched."""
    global _source
    keep_large_blocks()
    _source = L.open_las(path)
    for name in blocks:
        block = shared_memory.SharedMemory(name=name)
        np.ndarray(block.size, np.uint8, buffer=block.buf)[:] = 0
        _attached[name] = block


def _parsed(span: L.Span) -> dict:
    batch = _source.parse(span, span.first, np.zeros(3), tuple(a.name for a in _source.attributes))
    return {"positions": batch.positions, "cells": batch.grid.cells, **batch.attributes}


def _write(buf, arrays: dict) -> list:
    """The arrays copied into `buf` back to back (each at an ALIGN boundary): their layout."""
    layout, at = [], 0
    for key, a in arrays.items():
        np.ndarray(a.shape, a.dtype, buffer=buf, offset=at)[...] = a
        layout.append((key, a.shape, a.dtype.str, at))
        at += -(-a.nbytes // ALIGN) * ALIGN
    return layout


def _arrays(buf, layout: list) -> dict:
    return {n: np.ndarray(shape, np.dtype(dt), buffer=buf, offset=at) for n, shape, dt, at in layout}


def _size(arrays: dict) -> int:
    return sum(-(-a.nbytes // ALIGN) * ALIGN for a in arrays.values())


def _parse_shared(span: L.Span) -> tuple:
    """One batch parsed in this worker, its arrays copied into a block made for it: (name, layout)."""
    arrays = _parsed(span)
    block = shared_memory.SharedMemory(create=True, size=max(1, _size(arrays)))
    layout = _write(block.buf, arrays)
    block.close()
    return block.name, layout


def _parse_into_kept(task: tuple) -> tuple:
    """One batch parsed in this worker and copied into the kept block the parent named: (name, layout)."""
    span, name = task
    return name, _write(_attached[name].buf, _parsed(span))


def _parse_only(span: L.Span) -> int:
    """One batch parsed in this worker, nothing handed back: the parse's own rate."""
    return _parsed(span)["positions"].shape[0]


def _taken(name: str, layout: list) -> int:
    """The parent's side: arrays made on the block (no copy); the block unlinked once mapped."""
    block = shared_memory.SharedMemory(name=name)
    points = _arrays(block.buf, layout)["positions"].shape[0]
    block.close()
    block.unlink()
    return points


def threads(spans, count: int) -> int:
    done = [0] * count

    def work(k):
        for span in spans:
            done[k] += _parsed(span)["positions"].shape[0]

    workers = [threading.Thread(target=work, args=(k,)) for k in range(count)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    return sum(done)


def processes(pool, spans, count: int) -> int:
    return sum(_taken(name, layout) for name, layout in pool.imap_unordered(_parse_shared, spans * count))


def kept(pool, spans, count: int, blocks: dict, copiers: ThreadPoolExecutor | None = None) -> int:
    """Batches handed back in the kept blocks, each used again once the parent has let go of
    its batch's arrays (a free list the task generator waits on); with `copiers`, each
    batch's arrays are copied out of its block on those threads, which then free it."""
    free = queue.Queue()
    for name in blocks:
        free.put(name)

    def tasks():
        for span in spans * count:
            yield span, free.get(timeout=FREE_WAIT_S)

    def take(name: str, layout: list) -> int:
        arrays = _arrays(blocks[name].buf, layout)
        if copiers is not None:
            arrays = {n: a.copy() for n, a in arrays.items()}
        free.put(name)
        return arrays["positions"].shape[0]

    if copiers is None:
        return sum(take(name, layout) for name, layout in pool.imap_unordered(_parse_into_kept, tasks()))
    taken = [copiers.submit(take, name, layout) for name, layout in pool.imap_unordered(_parse_into_kept, tasks())]
    return sum(f.result() for f in taken)


def parse_only(pool, spans, count: int) -> int:
    return sum(pool.imap_unordered(_parse_only, spans * count))


def main() -> None:
    path, counts = sys.argv[1], [int(c) for c in sys.argv[2:]] or [1, 2]
    _open(path)
    spans = list(_source.chunks(BATCH_POINTS))[1:]
    points = sum(len(s) for s in spans)
    print(f"{path}: {len(spans)} batches, {points:,} points, every attribute, {os.cpu_count()} CPUs, rounds {ROUNDS}")
    ctx = mp.get_context("spawn")
    for count in counts:
        blocks = {}
        try:
            for _ in range(2 * count):
                block = shared_memory.SharedMemory(create=True, size=BLOCK_BYTES)
                np.ndarray(BLOCK_BYTES, np.uint8, buffer=block.buf)[:] = 0       # its pages mapped here
                blocks[block.name] = block
            with (ctx.Pool(count, initializer=_open, initargs=(path, tuple(blocks))) as pool,
                  ThreadPoolExecutor(count) as copiers):
                ways = {"threads": partial(threads, spans, count),
                        "processes": partial(processes, pool, spans, count),
                        "processes, kept blocks": partial(kept, pool, spans, count, blocks),
                        "processes, kept blocks, copied out": partial(kept, pool, spans, count, blocks, copiers),
                        "processes, parse only": partial(parse_only, pool, spans, count)}
                for run in ways.values():       # warm: every worker started, every way run once
                    run()
                times = {way: [] for way in ways}
                for _ in range(ROUNDS):
                    for way, run in ways.items():
                        t = time.perf_counter()
                        got = run()
                        times[way].append((time.perf_counter() - t) * 1e9 / (points * count))
                        if got != points * count:
                            raise SystemExit(f"{way}: {got:,} points parsed, not {points * count:,}")
        finally:
            for block in blocks.values():
                block.close()
                block.unlink()
        print(f"{count} worker(s): " + "; ".join(
            f"{way} median {statistics.median(t):.2f} ns/point ({1e3 / statistics.median(t):.0f} M points/s, best {min(t):.2f})"
            for way, t in times.items()), flush=True)


if __name__ == "__main__":
    main()
