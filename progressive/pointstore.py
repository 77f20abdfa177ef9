"""The shuffled point buffer on the GPU: one 16-byte record per slot, split into
chunks so no GL buffer exceeds the driver's storage-block limit or 2^31 bytes."""

from __future__ import annotations

import enum
import functools
from dataclasses import dataclass

import numpy as np

from progressive import batches
from progressive.bindings import MAX_POINT_CHUNKS, Binding, UniformBinding
from progressive.context import GLContext
from progressive.errors import ProgressiveError
from progressive.loaders.records import RECORD_BYTES
from progressive.permutation import LAYOUT, SLICE_POINTS, FillOrder, Permutation

EMPTY_WORD = 0xFFFFFFFF
"""Every slot starts as NaN coordinates, which no pass draws: unloaded slots stay dark."""


CLASS_BYTES = 2
"""GPU memory a point's flags take where the store keeps them: class and return flags."""
CLASS_LIMIT = (2**31 - 1) // CLASS_BYTES
"""Points whose flags fit one GL buffer."""


class GPUMemoryError(ProgressiveError):
    """An allocation the driver refused (GL_OUT_OF_MEMORY)."""


def chunk_capacity(max_ssbo_bytes: int) -> int:
    return min(max_ssbo_bytes, 2**31 - 1) // RECORD_BYTES


class RecordOrder(enum.Enum):
    """Where the batched layout's records live. Slots keep their order either way (slice
    k of every batch before slice k+1 of any: fills and memory limits take the same share
    of every batch); BATCHES stores each batch's records together, so a work group
    walking a batch reads one contiguous block instead of slices spread over the whole
    store (bench/raster.py measures both)."""

    SLOTS = "slot order"
    BATCHES = "batch after batch"


@dataclass(frozen=True)
class StoreLayout:
    """The record of each slot (shaders/points.glsl record_index, its twin): batches == 0
    is the identity; else batch b holds `slices` slices, one more if b < `longer`, and
    batch `longer` also the first `rest` slots of its next slice, batch after batch. A
    store keeping part of the cloud (a slot prefix) so holds exactly its capacity."""

    batches: int = 0
    slices: int = 0
    longer: int = 0
    rest: int = 0

    @classmethod
    def of(cls, permutation: Permutation, capacity: int, order: RecordOrder) -> StoreLayout:
        if not permutation.batches or order is RecordOrder.SLOTS:
            return cls()
        slices, part = divmod(capacity, permutation.batches * SLICE_POINTS)
        return cls(permutation.batches, slices, *divmod(part, SLICE_POINTS))

    def batch_record(self, b: np.ndarray) -> np.ndarray:
        b = np.asarray(b, dtype=np.int64)
        return ((b * self.slices + np.minimum(b, self.longer)) * SLICE_POINTS
                + np.where(b > self.longer, self.rest, 0))

    def record_index(self, slots) -> np.ndarray:
        s = np.asarray(slots, dtype=np.int64)
        if not self.batches:
            return s
        k, within = np.divmod(s, self.batches * SLICE_POINTS)
        b, j = np.divmod(within, SLICE_POINTS)
        return self.batch_record(b) + k * SLICE_POINTS + j

    def words(self) -> bytes:
        return np.array([self.batches, self.slices, self.longer, self.rest], dtype=np.uint32).tobytes()


class PointStore:
    """`count` points shuffled over slots [0, count); the GPU holds slots [0, capacity).
    A capacity below the count keeps a uniform random subset (progressive/memory.py)."""

    def __init__(self, glc: GLContext, count: int, *, capacity: int | None = None,
                 chunk_points: int | None = None, rotate: bool = True,
                 order: FillOrder = LAYOUT, classes: bool = False, records: RecordOrder = RecordOrder.BATCHES):
        """classes: keep each point's class and return flags (CLASS_BYTES a slot) for
        filters that apply whatever attribute is shown. records: where the batched
        layout's records live (the slot order is a benchmark baseline)."""
        limit = chunk_capacity(glc.caps.max_ssbo_bytes)
        self.chunk_points = min(chunk_points or limit, limit)
        self.count = count
        try:
            self.permutation = Permutation.for_count(count, rotate=rotate, order=order)
        except ValueError as exc:
            raise ProgressiveError(f"{count:,} points do not fit the store's 32-bit slots ({exc})") from None
        slots = self.permutation.slots
        # A capacity that holds the cloud holds the layout's padding too (under one batch).
        self.capacity = slots if capacity is None or capacity >= count else max(0, capacity)
        self.layout = StoreLayout.of(self.permutation, self.capacity, records)
        chunks = max(1, -(-self.capacity // self.chunk_points))
        if chunks > MAX_POINT_CHUNKS:
            raise ProgressiveError(
                f"{self.capacity:,} points need {chunks} GPU buffers of {self.chunk_points:,} points; "
                f"at most {MAX_POINT_CHUNKS} are supported")
        self._glc = glc
        self.class_buffer = None
        if classes:
            if self.capacity > CLASS_LIMIT:
                raise ProgressiveError(f"class and return filters keep {CLASS_BYTES} bytes a point in one buffer: "
                                       f"at most {CLASS_LIMIT:,} points")
            self.class_buffer = glc.ctx.buffer(reserve=max(4, -(-self.capacity * CLASS_BYTES // 4) * 4))
            self.class_buffer.label = "point flags"
            glc.gl.clear_u32(self.class_buffer.glo, 0, total=self.class_buffer.size)
        self.boxes = batches.empty_boxes(max(1, self.permutation.batches))
        self.box_buffer = glc.ctx.buffer(self.boxes.tobytes())
        self.box_buffer.label = "batch boxes"
        self.layout_buffer = glc.ctx.buffer(self.layout.words())
        self.layout_buffer.label = "store layout"
        self.buffers = []
        for c in range(chunks):
            n = max(1, min(self.chunk_points, self.capacity - c * self.chunk_points))
            buf = glc.ctx.buffer(reserve=n * RECORD_BYTES)
            buf.label = f"points[{c}]"
            glc.gl.clear_u32(buf.glo, EMPTY_WORD, total=buf.size)
            self.buffers.append(buf)
            if glc.ctx.error == "GL_OUT_OF_MEMORY":
                self.release()
                raise GPUMemoryError(f"the GPU could not allocate {n * RECORD_BYTES / 2**20:.0f} MiB for points")

    @property
    def batched(self) -> bool:
        return self.permutation.batches > 0

    def add_boxes(self, positions, start: int) -> None:
        """Grow the boxes of the batches that file indices [start, start+n) belong to
        (batched layout; the rasterizer culls batches outside the view with them)."""
        if not self.batched:
            return
        first, new = batches.boxes_of(positions, start)
        batches.merge(self.boxes, first, new)
        part = self.boxes[first: first + new.shape[0]]
        self.box_buffer.write(part.tobytes(), offset=first * part.itemsize * batches.BOX_FLOATS)

    def bind_boxes(self) -> None:
        self.box_buffer.bind_to_storage_buffer(Binding.BATCH_BOXES)

    @functools.cached_property
    def kept(self) -> int:
        """File points the GPU holds (the capacity and layout are fixed: counted once; a
        memory-limited batched store counts its last batch's points)."""
        return self.permutation.kept(self.capacity)

    @property
    def has_classes(self) -> bool:
        return self.class_buffer is not None

    @property
    def defines(self) -> dict[str, int]:
        return {"POINT_CHUNKS": len(self.buffers), "CHUNK_POINTS": self.chunk_points, "CLASS_FILTER": int(self.has_classes)}

    def bind(self) -> None:
        for c, buf in enumerate(self.buffers):
            buf.bind_to_storage_buffer(Binding.points(c))
        self.layout_buffer.bind_to_uniform_block(UniformBinding.STORE_LAYOUT)
        if self.class_buffer is not None:
            self.class_buffer.bind_to_storage_buffer(Binding.CLASSES)

    def read_records(self):
        """All slots as (count, 4) uint32, in slot order (tests and debugging only)."""
        parts = [np.frombuffer(b.read(), dtype=np.uint32).reshape(-1, 4) for b in self.buffers]
        return np.concatenate(parts)[self.layout.record_index(np.arange(self.capacity))]

    def release(self) -> None:
        for buf in self.buffers:
            buf.release()
        self.buffers = []
        for name in ("box_buffer", "layout_buffer"):
            if getattr(self, name, None) is not None:
                getattr(self, name).release()
                setattr(self, name, None)
        if self.class_buffer is not None:
            self.class_buffer.release()
            self.class_buffer = None
