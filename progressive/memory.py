"""How many points fit on the GPU: the cloud's 16 bytes a point plus the per-pixel
and staging buffers, against what the driver reports free (NVX memory info) or a
configured limit. When the cloud does not fit, the store keeps the points whose
shuffled slot falls below its capacity: a uniform random subset, by the shuffle. COPC
files are cut first, by level of detail, to what fits in a configured limit
(points_within; loaders/copc.py): every point of the octree's upper levels."""

from __future__ import annotations

from dataclasses import dataclass

from progressive.bindings import MAX_POINT_CHUNKS
from progressive.context import Capabilities
from progressive.loaders.records import RECORD_BYTES
from progressive.loaders.types import BATCH_POINTS
from progressive.passes.prepare import GATHER_BYTES
from progressive.passes.raster_compute import CANDIDATE_BYTES, CANDIDATES_PER_PIXEL
from progressive.permutation import BATCH_SLOTS
from progressive.pointstore import BLOCK_RECORDS, most_records

# visibility, reference, two lists, hint, words, image, winners, prepare's gathers, the
# 32-bit raster's candidates (counted on every path: the loader plans before the context)
PIXEL_BYTES = 8 + 8 + 2 * (4 + 16) + 4 + 4 + 4 + 16 + 4 + GATHER_BYTES + CANDIDATES_PER_PIXEL * CANDIDATE_BYTES
HEADROOM = 0.9                                     # of the free memory the driver reports
STREAM_BYTES = 2 << 30
"""GPU memory a streamed cloud keeps unless a limit is configured (less where the driver
reports less free): as a tiled-scene viewer's memory budget, for the nodes a view needs
rather than a store for every node, allocated at once and filled before the first image
(a 1 B-point COPC: about 19 GiB; on the H100 machine, with a 4 GiB limit, making the
passes and their buffers took 0.48 s of a 1.02 s first image,
bench/results/nvidia-h100/stream_0a0bbe1/; llvmpipe's memory is the host's: at 1280x720
the passes took 0.14-0.19, 0.30-0.32 and 0.63 s with 256 MiB, 512 MiB and 1 GiB on the
2-core machine, bench/results/llvmpipe/stream_store_probes/). 2 GiB holds 125 M points, 60 a pixel at 1920x1080."""
SOFTWARE_STREAM_BYTES = 256 << 20
"""The same default for a software rasterizer (llvmpipe), whose buffers are host memory
it zeroes when they are made: a 100 M-point COPC opened with its 1 GiB spent 0.72-1.27 s
of the open making them, with 256 MiB 0.11-0.18 s (the 2-core machine,
bench/results/llvmpipe/stream_store_probes/default_open.txt), and 256 MiB already holds
more points than it draws in a frame (8.9 M at 1280x720; llvmpipe draws about 60 M
points/s)."""


def stream_bytes(caps: Capabilities) -> int:
    """The memory a streamed cloud keeps where no limit is configured."""
    return SOFTWARE_STREAM_BYTES if caps.software else STREAM_BYTES


@dataclass(frozen=True)
class MemoryPlan:
    points: int
    capacity: int                 # points kept on the GPU
    available_bytes: int | None   # what the plan was made against; None: no information
    source: str                   # where that figure came from, for the message

    @property
    def subset(self) -> bool:
        return self.capacity < self.points

    def message(self, shown: int | None = None) -> str:
        """`shown`: the points the store's slots hold (the layout's padding is no point)."""
        need = self.points * RECORD_BYTES / 2**30
        have = (self.available_bytes or 0) / 2**30
        return (f"the cloud needs {need:.2f} GiB of GPU memory but {have:.2f} GiB is available ({self.source}): "
                f"showing a uniform random subset of {shown if shown is not None else self.capacity:,} "
                f"of {self.points:,} points")


def plan(points: int, caps: Capabilities, pixels: int, limit_bytes: int | None = None,
         extra_bytes_per_point: int = 0, default_bytes: int | None = None) -> MemoryPlan:
    """extra_bytes_per_point: what a point costs beside its record (its class byte).
    default_bytes: the limit where none is configured (a streamed cloud's stream_bytes);
    None: what the driver reports free, else every point."""
    available, source = None, "no limit known"
    if caps.free_memory_kib is not None:
        available, source = int(caps.free_memory_kib * 1024 * HEADROOM), "free GPU memory"
    limited = "configured limit"
    if limit_bytes is None and default_bytes is not None:
        limit_bytes, limited = default_bytes, f"{default_bytes / 2**30:g} GiB by default; --gpu-memory-limit sets it"
    if limit_bytes is not None and (available is None or limit_bytes < available):
        available, source = limit_bytes, limited
    capacity = points if available is None else min(points, points_within(available, pixels, extra_bytes_per_point))
    most = most_records(caps.max_ssbo_bytes) - BATCH_SLOTS      # a batch's padding spare
    if capacity > most:
        return MemoryPlan(points, most, most * RECORD_BYTES, f"a store holds at most {MAX_POINT_CHUNKS} buffers "
                                                             f"of {caps.max_ssbo_bytes / 2**20:g} MiB on this driver")
    return MemoryPlan(points, capacity, available, source)


def points_within(available_bytes: int, pixels: int, extra_bytes_per_point: int = 0) -> int:
    """Points that fit in `available_bytes` beside the per-pixel and staging buffers and
    the word store's padding (its last block's unused records). The loader asks it of
    the configured limit before the GL context (and the driver's figure) exists, to
    choose a COPC file's levels."""
    return max(0, (available_bytes - _overhead(pixels)) // (RECORD_BYTES + extra_bytes_per_point))


def bytes_for(points: int, pixels: int, extra_bytes_per_point: int = 0) -> int:
    """The least memory limit under which `points` points fit (points_within's inverse)."""
    return _overhead(pixels) + points * (RECORD_BYTES + extra_bytes_per_point)


def _overhead(pixels: int) -> int:
    return pixels * PIXEL_BYTES + (BATCH_POINTS + BLOCK_RECORDS) * RECORD_BYTES


def peak_rss_bytes() -> int:
    """The process's peak resident memory so far (Linux reports KiB)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
