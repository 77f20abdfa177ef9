"""Copies into the staging memory (the distribute pass's mapped slots) from the frame
loop's thread, GPU-free. A small copy keeps the GIL, so the thread does not wait to take
it back from the loader's threads. A large copy is split over threads, because one core
writes to mapped memory at about a quarter of the rate eight reach: 9.9 GB/s against
32-38 GB/s on the H100 machine (bench/results/nvidia-h100/kernel_prototype/pcie.json)."""

from __future__ import annotations

import ctypes
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from progressive.loaders.types import available_cores
from progressive.wordpack import PACK_THREADS, threaded

HELD_COPY_BYTES = 4 << 20
"""A copy up to this size keeps the GIL. numpy lets it go for any copy of more than 500
items, and a frame thread that lets it go then waits to take it back from the reading
threads: on the H100 machine a streamed node's copies (about 350 KB) spent 0.10 ms
copying and 0.38 ms waiting (bench/results/nvidia-h100/stream_writes/write_parts_100M.txt).
A larger copy lets it go, so that a loader's pieces of 8 MB do not keep the parser
threads out for a millisecond."""
THREAD_COPY_BYTES = 1 << 20
"""Fewest bytes a copying thread is handed: a part costs its thread about as long to
start and join as copying a few hundred KB."""
COPY_THREADS = min(4, available_cores())
"""Threads a large copy is split over at most. More copy faster but slow the GPU's reads
of the slots it scatters meanwhile, which share the host's memory: on the H100 machine the
GPU side of loading 100 M points ran at 508, 868, 752 and 710 M points/s with the copy on
1, 4, 8 and 16 threads, its scatter dispatches taking 43, 69, 96 and 118 ms
(bench/results/nvidia-h100/distribute_copy/dist_gpu_100M.json)."""

_MEMMOVE_HOLDING_GIL = ctypes.PYFUNCTYPE(ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t)(
    ctypes.cast(ctypes.memmove, ctypes.c_void_p).value)


def _alike(dst: np.ndarray, src: np.ndarray) -> bool:
    return (dst.shape == src.shape and dst.dtype == src.dtype and dst.flags.c_contiguous
            and src.flags.c_contiguous)


class StageCopier:
    """dst[...] = src: one memmove holding the GIL where both are C-contiguous, alike in
    shape and dtype, and of HELD_COPY_BYTES or less; else numpy's assignment, split by
    rows over up to `parts` threads (this one among them, wordpack.threaded) where each
    gets at least THREAD_COPY_BYTES. The pool of `threads` (the caller and threads - 1 more) is made at
    the first use; the scene packs a switch's words on it too (one pool of staging
    threads)."""

    def __init__(self, threads: int = PACK_THREADS, parts: int = COPY_THREADS):
        self.threads = threads
        self.parts = min(parts, threads)
        self._pool: ThreadPoolExecutor | None = None

    @property
    def pool(self) -> ThreadPoolExecutor | None:
        """The staging threads (None where only one may be used)."""
        if self._pool is None and self.threads > 1:
            self._pool = ThreadPoolExecutor(self.threads - 1, thread_name_prefix="progressive-stage")
        return self._pool

    def __call__(self, dst: np.ndarray, src: np.ndarray) -> None:
        if dst.nbytes <= HELD_COPY_BYTES and _alike(dst, src):
            _MEMMOVE_HOLDING_GIL(dst.ctypes.data, src.ctypes.data, dst.nbytes)
            return
        n = dst.shape[0] if dst.ndim else 0
        rows = max(1, THREAD_COPY_BYTES * n // max(1, dst.nbytes))     # rows a thread is handed at least
        if dst.shape != src.shape or self.parts < 2 or n < 2 * rows:
            dst[...] = src
            return
        threaded(lambda out, lo, hi: np.copyto(out, src[lo:hi], "unsafe") or 0, self.pool, self.parts,
                 least=rows)(dst, 0, n)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
