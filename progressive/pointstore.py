"""The shuffled point buffer on the GPU: 16 bytes a slot, split into chunks so no GL
buffer exceeds the driver's storage-block limit or 2^31 bytes. The batched layout
keeps each point as four words (progressive/encoding.py: three position words
relative to its batch, then the attribute word) in blocks of BLOCK_RECORDS records
that hold each word plane in turn; the other layouts keep one float32 record a slot
(xyz relative to the origin, the attribute word)."""

from __future__ import annotations

import enum
import functools
from dataclasses import dataclass

import numpy as np

from progressive import batches, encoding, gpu, shaderlib
from progressive.bindings import MAX_POINT_CHUNKS, Binding, UniformBinding
from progressive.context import GLContext
from progressive.errors import ProgressiveError
from progressive.loaders.records import RECORD_BYTES
from progressive.permutation import BATCH_POINTS, BATCH_SLOTS, LAYOUT, SLICE_POINTS, FillOrder, Permutation

EMPTY_WORD = 0xFFFFFFFF
"""Every slot starts as NaN coordinates, which no pass draws: unloaded slots stay dark."""


CLASS_BYTES = 2
"""GPU memory a point's flags take where the store keeps them: class and return flags."""
CLASS_LIMIT = (2**31 - 1) // CLASS_BYTES
"""Points whose flags fit one GL buffer."""


CELL_FRAME_BYTES = encoding.CELL_FRAME_WORDS * 4


class GPUMemoryError(ProgressiveError):
    """An allocation the driver refused (GL_OUT_OF_MEMORY)."""


def chunk_capacity(max_ssbo_bytes: int) -> int:
    """Records of 16 bytes one buffer holds (both stores take 16 bytes a record a buffer)."""
    return min(max_ssbo_bytes, 2**31 - 1) // RECORD_BYTES


def most_records(max_ssbo_bytes: int) -> int:
    """Records a store can hold at all: MAX_POINT_CHUNKS buffers of chunk_capacity, each
    in whole blocks (the word store's)."""
    per = chunk_capacity(max_ssbo_bytes)
    return MAX_POINT_CHUNKS * (per - per % BLOCK_RECORDS)


BLOCK_RECORDS = 4096
"""Records of a word store's block: its four planes in turn, 64 KiB. Planes in buffers
of their own put a point's words gigabytes apart, each an address translation of its
own: on the H200 at 1 B points, prepare took 3.7 times and a fill of 10 M points (a
slice of each batch) 1.8 times as long as on float records, side by side in one run
(bench/results/nvidia-h200/planes/progressive_1000000000.md); in blocks, as long
(stores/progressive_1000000000.md). A multiple of 4, so a batch walk's 16-byte loads of four
words (ComputeTuning.vector_loads) never leave a block."""


class RecordOrder(enum.Enum):
    """Where the batched layout's records live. Slots keep their order either way (slice
    k of every batch before slice k+1 of any: fills and memory limits take the same share
    of every batch); BATCHES stores each batch's records together, so a work group
    walking a batch reads one contiguous block instead of slices spread over the whole
    store: brute force's order. SLOTS keeps the slices of a round together, so a
    progressive fill (the next slice of every batch) reads one contiguous run: the
    progressive renderer's (ProgressiveOptions.records; bench/raster.py and
    bench/progressive.py measure both)."""

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

    def words(self, point_batches: int) -> bytes:
        """The uniform block: the layout, then the permutation's batches (the batch of a
        slot, which the word store's decoding needs whatever the record order)."""
        return np.array([self.batches, self.slices, self.longer, self.rest, point_batches, 0, 0, 0],
                        dtype=np.uint32).tobytes()


class PointStore:
    """`count` points shuffled over slots [0, count); the GPU holds slots [0, capacity).
    A capacity below the count keeps a uniform random subset (progressive/memory.py)."""

    def __init__(self, glc: GLContext, count: int, *, capacity: int | None = None,
                 chunk_points: int | None = None, rotate: bool = True,
                 order: FillOrder = LAYOUT, classes: bool = False, records: RecordOrder = RecordOrder.BATCHES,
                 position_encoding: encoding.Encoding = encoding.Encoding.WORDS, placed: bool = False):
        """classes: keep each point's class and return flags (CLASS_BYTES a slot) for
        filters that apply whatever attribute is shown. records: where the batched
        layout's records live (the slot order is a benchmark baseline).
        position_encoding: words relative to the batch (batched layout only) or float
        records. placed: points are written a run of whole batches at a time with the
        file-order index of its first (place_run), as a streamed cloud's nodes are; the
        indices of slots never written mean nothing."""
        self.count = count
        self.placed = placed
        try:
            self.permutation = Permutation.for_count(count, rotate=rotate, order=order)
        except ValueError as exc:
            raise ProgressiveError(f"{count:,} points do not fit the store's 32-bit slots ({exc})") from None
        slots = self.permutation.slots
        words = position_encoding is encoding.Encoding.WORDS and self.permutation.batches > 0
        self.encoding = encoding.Encoding.WORDS if words else encoding.Encoding.FLOAT
        limit = chunk_capacity(glc.caps.max_ssbo_bytes)
        if words:
            limit -= limit % BLOCK_RECORDS
            chunk_points = chunk_points and chunk_points + (-chunk_points) % BLOCK_RECORDS
        self.chunk_points = min(chunk_points or limit, limit)
        """Records a buffer holds (word store: whole blocks, a chunk_points asked for rounded up)."""
        # A capacity that holds the cloud holds the layout's padding too (under one batch).
        self.capacity = slots if capacity is None or capacity >= count else max(0, capacity)
        self.layout = StoreLayout.of(self.permutation, self.capacity, records)
        chunks = max(1, -(-self.capacity // self.chunk_points))
        if chunks > MAX_POINT_CHUNKS:
            raise ProgressiveError(
                f"{self.capacity:,} points need {chunks} GPU buffers of {self.chunk_points:,} points; "
                f"at most {MAX_POINT_CHUNKS} are supported")
        self.chunks = chunks
        self._glc = glc
        self._fill = shaderlib.compute(glc.ctx, "clear.comp", label="fill store")
        self._clear_batches = None      # shaders/clear_batches.comp, built on the first eviction
        """Fills the new buffers: on the H200's driver glClearNamedBufferSubData blocked
        the CPU while it committed fresh memory, so the renderer's buffers for 100 M
        points took 1.08-1.41 s; with this pass 0.13-0.26 s
        (bench/results/nvidia-h200/startup_fill/)."""
        self.class_buffer = None
        if classes:
            if self.capacity > CLASS_LIMIT:
                raise ProgressiveError(f"class and return filters keep {CLASS_BYTES} bytes a point in one buffer: "
                                       f"at most {CLASS_LIMIT:,} points")
            self.class_buffer = glc.ctx.buffer(reserve=max(16, -(-self.capacity * CLASS_BYTES // 16) * 16))
            self.class_buffer.label = "point flags"
            gpu.fill_uvec4s(self._fill, self.class_buffer, 0, self.class_buffer.size // 16, 0)
        self.boxes = batches.empty_boxes(max(1, self.permutation.batches))
        self.box_buffer = glc.ctx.buffer(self.boxes.tobytes())
        self.box_buffer.label = "batch boxes"
        self.frames = encoding.empty_frames(max(1, self.permutation.batches))
        self._file_order: np.ndarray | None = None
        self._batch_starts = np.zeros(max(1, self.permutation.batches), np.int64) if placed else None
        """A placed store's: the file-order index of each batch's first point, the rest
        following on (place_run)."""
        self.least_cells = np.zeros((max(1, self.permutation.batches), 3), dtype=np.int64)
        self.cell_shifts = np.zeros((max(1, self.permutation.batches), 3), dtype=np.int64)
        self.integer = np.zeros(max(1, self.permutation.batches), dtype=bool)
        """Word store: batches kept as a LAS file's integers, their least integers and the
        bits those are moved up (encoding.integer_frames)."""
        self.frame_buffer = glc.ctx.buffer(self.frames.tobytes()) if words else None
        self.cell_buffer = glc.ctx.buffer(reserve=max(1, self.permutation.batches) * CELL_FRAME_BYTES) if words else None
        """Word store: each LAS batch's cell frame (cell_frames), from which the distribute
        pass encodes the file's integers staged as they are."""
        if words:
            self.frame_buffer.label = "batch frames"
            self.cell_buffer.label = "batch cells"
        self.layout_buffer = glc.ctx.buffer(self.layout.words(self.permutation.batches))
        self.layout_buffer.label = "store layout"
        self.buffers = []
        for c in range(chunks):
            size = self._chunk_records(c) * RECORD_BYTES
            buf = glc.ctx.buffer(reserve=size)
            buf.label = f"{'words' if words else 'points'}[{c}]"
            gpu.fill_uvec4s(self._fill, buf, 0, buf.size // 16, EMPTY_WORD)
            self.buffers.append(buf)
            if glc.ctx.error == "GL_OUT_OF_MEMORY":
                self.release()
                raise GPUMemoryError(f"the GPU could not allocate {size / 2**20:.0f} MiB for points")
        glc.ctx.memory_barrier()

    @property
    def batched(self) -> bool:
        return self.permutation.batches > 0

    @property
    def words(self) -> bool:
        return self.encoding is encoding.Encoding.WORDS

    def set_frames(self, first: int, frames: np.ndarray, boxes: np.ndarray, least: np.ndarray | None = None,
                   shift: np.ndarray | None = None) -> None:
        """Batches first.. are encoded in `frames` and hold `boxes` (word store: set before
        their points are distributed, again for a batch whose points so far are encoded
        anew; progressive/encoding.py BatchAssembler). least, shift: their least
        integers and shifts where they are kept as a LAS file's integers
        (encoding.integer_frames)."""
        k = frames.shape[0]
        self.frames[first: first + k] = frames
        self.integer[first: first + k] = least is not None
        if least is not None:
            self.least_cells[first: first + k], self.cell_shifts[first: first + k] = least, shift
            self.cell_buffer.write(encoding.cell_frames(least, shift).tobytes(), offset=first * CELL_FRAME_BYTES)
        self.frame_buffer.write(frames.tobytes(), offset=first * frames.itemsize * encoding.FRAME_FLOATS)
        batches.merge(self.boxes, first, boxes)
        part = self.boxes[first: first + k]
        self.box_buffer.write(part.tobytes(), offset=first * part.itemsize * batches.BOX_FLOATS)

    def clear_batches(self, batches_cleared) -> None:
        """Empty whole batches of a store that holds every slot (a streamed cloud's
        evicted nodes): their records EMPTY_WORD, their boxes empty (culled), their frames
        unset, so points written there later start from nothing."""
        if not self.batched or self.capacity < self.permutation.slots:
            raise ProgressiveError("only whole batches of a store that keeps every slot can be emptied")
        b = np.asarray(sorted(batches_cleared), dtype=np.int64)
        if b.size == 0:
            return
        if self._clear_batches is None:
            self._clear_batches = shaderlib.compute(self._glc.ctx, "clear_batches.comp", self.defines,
                                                    label="clear batches")
        program = self._clear_batches
        program["u_batches"] = self.permutation.batches
        self.bind()
        for lo, hi in batches.runs(b):
            program["u_first"] = lo
            program["u_count"] = (hi - lo) * BATCH_SLOTS
            program.run(*gpu.grid((hi - lo) * BATCH_SLOTS))
        self._glc.ctx.memory_barrier()
        self.boxes[b] = batches.empty_boxes(b.size)
        self.frames[b] = encoding.empty_frames(b.size)
        self.integer[b] = False
        for lo, hi in batches.runs(b):
            self.box_buffer.write(self.boxes[lo:hi].tobytes(), offset=lo * self.boxes.itemsize * batches.BOX_FLOATS)
            if self.frame_buffer is not None:
                self.frame_buffer.write(self.frames[lo:hi].tobytes(),
                                        offset=lo * self.frames.itemsize * encoding.FRAME_FLOATS)

    def add_boxes(self, first: int, new: np.ndarray) -> None:
        """Grow the boxes of batches first, first + 1, ... by `new` ((k, BOX_FLOATS), as
        batches.boxes_of gives them; batched layout: the rasterizer culls batches outside
        the view with them)."""
        batches.merge(self.boxes, first, new)
        part = self.boxes[first: first + new.shape[0]]
        self.box_buffer.write(part.tobytes(), offset=first * part.itemsize * batches.BOX_FLOATS)

    def bind_boxes(self) -> None:
        self.box_buffer.bind_to_storage_buffer(Binding.BATCH_BOXES)

    def bind_frames(self) -> None:
        self.frame_buffer.bind_to_storage_buffer(Binding.BATCH_FRAMES)

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
        return {"POINT_CHUNKS": self.chunks, "CHUNK_POINTS": self.chunk_points, "CLASS_FILTER": int(self.has_classes),
                "WORD_PLANES": int(self.words), "BLOCK_RECORDS": BLOCK_RECORDS}

    def bind(self) -> None:
        for c, buf in enumerate(self.buffers):
            buf.bind_to_storage_buffer(Binding.points(c))
        self.layout_buffer.bind_to_uniform_block(UniformBinding.STORE_LAYOUT)
        if self.frame_buffer is not None:
            self.bind_frames()
            self.cell_buffer.bind_to_storage_buffer(Binding.BATCH_CELLS)
        if self.class_buffer is not None:
            self.class_buffer.bind_to_storage_buffer(Binding.CLASSES)

    @property
    def file_order(self) -> np.ndarray | None:
        """Where batches were reordered (batches.BatchOrder.MORTON) or placed: the
        file-order index of each cloud index (the permutation's input), uint32; None: the
        same. A placed store's is made from its batches' starts when asked (tests)."""
        if self._batch_starts is not None:
            return self.file_indices(np.arange(self.count)).astype(np.uint32)
        return self._file_order

    def reorder(self, first: int, file_indices: np.ndarray) -> None:
        """Cloud indices first.. hold the points of these file-order indices (a loaded
        batch's rows sorted before upload)."""
        if self.placed:
            raise ValueError("a placed store's points are written in runs of whole batches (place_run)")
        if self._file_order is None:
            self._file_order = np.arange(self.count, dtype=np.uint32)    # the identity for the batches never reordered
        self._file_order[first: first + len(file_indices)] = file_indices

    def place_run(self, first: int, start: int, count: int) -> None:
        """Cloud indices first.. first + count - 1 (first a batch's first) hold the
        file-order indices start.. (a streamed node's points): a few batches' starts, not
        an index a point, so that a node's write spends no numpy call over its points. The
        frame loop lets the GIL go in every numpy call of more than 500 items and then
        waits to take it back from the reading threads: on the H100 machine a node's
        indices written point by point took 0.25 ms of its write's 1.61, 0.06 of them
        running (bench/results/nvidia-h100/stream_writes/write_parts_100M.txt)."""
        if not self.placed or first % BATCH_POINTS:
            raise ValueError("runs are placed from a batch's first point, in a placed store")
        b = first // BATCH_POINTS
        for k in range(-(-count // BATCH_POINTS)):
            self._batch_starts[b + k] = start + k * BATCH_POINTS

    def file_indices(self, cloud: np.ndarray) -> np.ndarray:
        """File-order indices of cloud indices (the permutation's inputs)."""
        if self._batch_starts is not None:
            cloud = np.asarray(cloud, dtype=np.int64)
            return self._batch_starts[cloud // BATCH_POINTS] + cloud % BATCH_POINTS
        return np.asarray(cloud) if self._file_order is None else self._file_order[cloud]

    def slots_of(self, file_indices: np.ndarray) -> np.ndarray:
        """The slot of each file-order index: the GPU's tie key (tests, references)."""
        cloud = np.asarray(file_indices, dtype=np.int64)
        order = self.file_order
        if order is not None:
            back = np.empty(self.count, dtype=np.int64)
            back[order] = np.arange(self.count)
            cloud = back[cloud]
        return self.permutation.forward(cloud)

    def _held(self, c: int) -> int:
        """Records buffer c holds (none past the capacity)."""
        return max(0, min(self.chunk_points, self.capacity - c * self.chunk_points))

    def _chunk_records(self, c: int) -> int:
        """Records buffer c has room for: those it holds (at least one), the word store's
        in whole blocks."""
        n = max(1, self._held(c))
        return n + (-n) % BLOCK_RECORDS if self.words else n

    def raw_words(self) -> np.ndarray:
        """Every record as (capacity, 4) uint32 in record order (StoreLayout): the float
        record, or the word store's three position words and attribute word (tests and
        debugging only)."""
        chunks = []
        for c, buf in enumerate(self.buffers):
            words = np.frombuffer(buf.read(size=self._chunk_records(c) * RECORD_BYTES), dtype=np.uint32)
            if self.words:
                words = words.reshape(-1, encoding.PLANES, BLOCK_RECORDS).transpose(0, 2, 1)
            chunks.append(words.reshape(-1, 4)[: self._held(c)])
        return np.concatenate(chunks)

    def read_words(self) -> np.ndarray:
        """raw_words in slot order."""
        return self.raw_words()[self.layout.record_index(np.arange(self.capacity))]

    def read_records(self) -> np.ndarray:
        """All slots as (capacity, 4) uint32 float records (xyz float32 bits relative to
        the origin, the attribute word), as the GPU decodes them: EMPTY_WORD
        coordinates where nothing is drawn (tests and debugging only)."""
        held = self.read_words()
        if not self.words:
            return held
        out = np.empty_like(held)
        b = self.permutation.slot_batch(np.arange(self.capacity))
        xyz = encoding.decode_frames(held[:, :3], self.frames[b])
        out[:, :3] = xyz.view(np.uint32)
        out[np.isnan(xyz).any(axis=1), :3] = EMPTY_WORD
        out[:, 3] = held[:, 3]
        return out

    def release(self) -> None:
        for buf in self.buffers:
            buf.release()
        self.buffers = []
        for name in ("box_buffer", "layout_buffer", "frame_buffer", "cell_buffer"):
            if getattr(self, name, None) is not None:
                getattr(self, name).release()
                setattr(self, name, None)
        if self.class_buffer is not None:
            self.class_buffer.release()
            self.class_buffer = None
        for name in ("_fill", "_clear_batches"):
            if getattr(self, name, None) is not None:
                getattr(self, name).release()
                setattr(self, name, None)

