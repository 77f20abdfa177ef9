"""The C allocator's large blocks kept for reuse while a cloud loads.

Each parsed batch allocates arrays of a few MB (integers, attributes) and
frees them once the GPU has them. glibc serves blocks over its mmap threshold (128 KiB
at first) with fresh mappings and returns them on free, so every batch pays a page
fault per 4 KiB it touches, and the parser threads' mmap and munmap calls queue on the
process's memory-map lock. Kept in the allocator's heaps instead, the same pages serve
the next batch: on the 2-core CI machine a 500,000-point LAS batch parsed with every
attribute in 16 ms instead of 23-27 ms, with RGB only in 9 ms instead of 13-15 ms
(bench/results/llvmpipe/allocator_ab/).
"""

from __future__ import annotations

import ctypes
import functools

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
"""mallopt's parameters (glibc's malloc.h)."""

MMAP_THRESHOLD = 32 << 20
"""Blocks up to this size come from the heaps (glibc's largest threshold on 64-bit
systems, half its per-thread heap): every array of a loader batch."""

TRIM_THRESHOLD = 256 << 20
"""Free memory a heap keeps before returning its top to the system: a few batches' worth."""


@functools.cache
def keep_large_blocks() -> bool:
    """Set glibc's thresholds once per process (a process-wide setting, as the loaders'
    threads share one allocator); False where the C library has no mallopt (macOS,
    Windows) or refuses them, which only costs speed."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
