"""Distribute: staged batches scattered to their permuted slots (paper 3.1, 3.3).

Batches are staged in a ring of persistently mapped slots (GL_ARB_buffer_storage):
the CPU packs a piece straight into a free slot and flushes what it wrote, the scatter
reads it there, and a fence per slot tells, without waiting, when the GPU is done with
it. So no upload waits for the GPU and no Python copy is made. Where the ring is
missing (no buffer storage) or every slot is still being read, a piece is copied
through an orphaned buffer, which never waits either."""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.context import GLContext
from progressive.glext import GL_CLIENT_MAPPED_BUFFER_BARRIER_BIT, GL_SHADER_STORAGE_BUFFER_OFFSET_ALIGNMENT, BufferStorage
from progressive.gpu import grid
from progressive.loaders.records import RECORD_BYTES
from progressive.loaders.types import BATCH_POINTS
from progressive.pointstore import PointStore
from progressive.stagecopy import StageCopier

RING_SLOTS = 4
"""Pieces the GPU may still be reading while the CPU packs the next: a frame's batches
and the one after (a piece finding its slot busy is copied instead)."""
RECORD_WORDS = RECORD_BYTES // 4
WORD_PIECE_WORDS = 1 << 24
"""Attribute words one piece of a switch stages (64 MiB): handed a slot of records'
worth (2 M words) split over 8 threads, packing threads spent about as long starting
and joining as packing (bench/results/nvidia-h200/packing.md, words a call)."""

Fill = Callable[[np.ndarray, int, int], int]
"""fill(out, lo, hi) writes items [lo, hi) into `out` ((hi - lo, width) uint32, or
(hi - lo, item_bytes) uint8 for items of bytes; maybe mapped memory: written, never
read) and returns a count the caller sums (hidden points)."""


class Staging(enum.Enum):
    RING = "persistently mapped ring"
    COPY = "orphaned buffer, copied"


@dataclass
class StagingStats:
    ring: int = 0       # pieces packed straight into a ring slot
    copied: int = 0     # pieces copied through the orphaned buffer (no ring, or every slot busy)


class StagingRing:
    """`slots` slots of `slot_bytes` in one persistently mapped buffer, used in turn; a
    slot is handed out again only once the fence after its scatter has signalled
    (glClientWaitSync with timeout 0: asking never blocks), and what is written to it
    is flushed before the scatter reads it (glext.BufferStorage.mapped says why)."""

    def __init__(self, glc: GLContext, storage: BufferStorage, slot_bytes: int, slots: int = RING_SLOTS):
        align = max(RECORD_BYTES, glc.gl.integer(GL_SHADER_STORAGE_BUFFER_OFFSET_ALIGNMENT))
        self.slot_bytes = -(-slot_bytes // align) * align
        self.glc, self.storage = glc, storage
        self.mapped = storage.mapped(self.slot_bytes * slots)
        self.buffer = glc.ctx.external_buffer(self.mapped.glo, self.mapped.size)
        self.fences: list[int | None] = [None] * slots
        self.next = 0

    @property
    def slots(self) -> int:
        return len(self.fences)

    def acquire(self) -> int | None:
        """The next slot if the GPU has finished reading it, else None (slots are read in
        the order they are handed out, so the others are not free either)."""
        k = self.next
        fence = self.fences[k]
        if fence is not None:
            if not self.glc.gl.signaled(fence):
                return None
            self.glc.gl.delete_sync(fence)
            self.fences[k] = None
        self.next = (k + 1) % self.slots
        return k

    def view(self, slot: int, count: int, width: int) -> np.ndarray:
        """(count, width) uint32 of the mapping at the slot's start."""
        first = slot * self.slot_bytes // 4
        return self.mapped.words[first: first + count * width].reshape(count, width)

    def bind(self, slot: int, size: int) -> None:
        """The first `size` bytes of the slot are written: flush them and make them
        visible to the scatter (glext.BufferStorage.mapped), bind them for it."""
        self.storage.flush(self.mapped, slot * self.slot_bytes, size)
        self.glc.ctx.memory_barrier(GL_CLIENT_MAPPED_BUFFER_BARRIER_BIT)
        self.buffer.bind_to_storage_buffer(Binding.DISTRIBUTE, offset=slot * self.slot_bytes, size=size)

    def read(self, slot: int) -> None:
        """The commands reading the slot are issued: fence them."""
        self.fences[slot] = self.glc.gl.fence()

    def release(self) -> None:
        for fence in self.fences:
            if fence is not None:
                self.glc.gl.delete_sync(fence)
        self.fences = [None] * self.slots
        self.storage.release(self.mapped)     # the GPU keeps deleted storage until its commands finish


class DistributePass:
    def __init__(self, glc: GLContext, store: PointStore, batch_points: int = BATCH_POINTS,
                 ring_slots: int = RING_SLOTS, word_piece: int = WORD_PIECE_WORDS):
        """ring_slots: staging slots of batch_points records each, fewer and smaller for a
        smaller cloud (where the context has buffer storage; GLFunctions.storage None
        stands for a driver without). word_piece: words a slot of the ring of attribute
        switches holds (made at the first switch; the copy path stages a records' slot)."""
        self.glc = glc
        self.store = store
        self.batch_points = batch_points
        storage = glc.gl.storage
        offered = storage is not None and BufferStorage.offered(glc.ctx.version_code, glc.ctx.extensions)
        self.staging = Staging.RING if offered and ring_slots > 0 else Staging.COPY
        self._ring_of = lambda items, piece_bytes: StagingRing(
            glc, storage, piece_bytes, max(1, min(ring_slots, -(-store.count // items))))
        slot_points = max(1, min(batch_points, store.count))    # a small cloud maps no more than it needs
        self.ring = self._ring_of(slot_points, slot_points * RECORD_BYTES) if self.staging is Staging.RING else None
        self.word_ring: StagingRing | None = None
        self.word_piece = max(1, min(word_piece, store.count))
        """Words a piece of a switch stages through the ring (set before the first switch)."""
        self._stage = None      # the copy path's buffer: made when first needed
        self.copy = StageCopier()
        """Copies into the staging memory (the fills of this pass's uploads and the scene's)."""
        self.stats = StagingStats()
        int64 = glc.caps.shader_int64
        defines = dict(store.defines, PERMUTE_INT64=1) if int64 else dict(store.defines)
        ext = ("GL_ARB_gpu_shader_int64",) if int64 else ()
        self._build = lambda only, label, classes=0, cells=0, rgb=0, class_bytes=0: shaderlib.compute(
            glc.ctx, "distribute.comp",
            dict(defines, ATTRIBUTE_ONLY=only, CLASS_WORDS=classes, STAGED_CELLS=cells, RGB_BYTES=rgb,
                 CLASS_BYTES=class_bytes), ext, label)
        self._programs: dict[tuple[bool, bool], object] = {}    # by (cells, rgb): built at the first upload of each kind
        self.words = None       # built at the first attribute switch: no first image waits for it
        self.rgb_words = None   # the same, from staged RGB bytes: built at the first switch to RGB
        self.classes = None         # the flags staged as made (point_flags): built at the first such upload
        self.class_bytes = None     # the flags from staged bytes: built at the first such upload
        self.points_distributed = 0

    @property
    def piece_bytes(self) -> int:
        """Bytes one piece stages: a ring slot (the copy buffer holds as many)."""
        return self.ring.slot_bytes if self.ring is not None else self.batch_points * RECORD_BYTES

    def piece_items(self, width: int) -> int:
        """Items of `width` words one piece stages (a batch of records, or a slot's worth)."""
        return min(self.batch_points * RECORD_WORDS, self.piece_bytes // 4) // width

    def word_piece_items(self) -> int:
        """Attribute words one piece of a switch stages (upload_words)."""
        return self.word_piece if self.staging is Staging.RING else self.piece_items(1)

    @property
    def stage(self):
        """The copy path's buffer: a piece of records (grown for a larger piece)."""
        if self._stage is None:
            self._stage = self.glc.ctx.buffer(reserve=self.piece_bytes)
            self._stage.label = "distribute stage"
        return self._stage

    def upload(self, records: np.ndarray, start: int) -> None:
        """Scatter (n, 4) uint32 records whose first has file-order index `start`."""
        self._scatter(self._program(False), _copy(records, RECORD_WORDS, self.copy), records.shape[0], RECORD_WORDS, start)

    def upload_packed(self, fill: Fill, count: int, start: int, cells: bool = False, rgb: bool = False,
                      hide_nonfinite: bool = False) -> int:
        """Scatter `count` records that `fill` packs piece by piece straight into the
        staging memory; the sum of what it returns. cells: the word store's points
        staged as a LAS file's integers, each piece's X, Y, Z then its attribute words,
        or with `rgb` its R, G, B bytes (encoded in their batches' cell frames); with
        hide_nonfinite a word that is a scalar not finite hides its point (a shown
        scalar)."""
        program = self._program(cells, cells and rgb)
        if cells:
            program["u_hide_nonfinite"] = int(hide_nonfinite)
        return self._scatter(program, fill, count, RECORD_WORDS, start)

    def _program(self, cells: bool, rgb: bool = False):
        """The scatter of float records, or of the word store's cells (a LAS batch's
        integers) with words or RGB bytes, made at its first upload: a cloud uses one
        kind or two."""
        if (cells, rgb) not in self._programs:
            label = "distribute cells" + (" rgb bytes" if rgb else "") if cells else "distribute"
            self._programs[cells, rgb] = self._build(0, label, cells=int(cells), rgb=int(rgb))
        return self._programs[cells, rgb]

    def upload_words(self, words: np.ndarray | Fill, start: int, count: int | None = None) -> None:
        """Replace only the attribute word of points start.. (attribute switching, paper
        3.5): an array of them, or a fill that packs `count` of them straight into the
        staging memory, in pieces of word_piece_items() through the words' own ring."""
        self.words = self.words or self._build(1, "distribute words")
        if isinstance(words, np.ndarray):
            words, count = _copy(words, 1, self.copy), words.shape[0]
        self._scatter(self.words, words, count, 1, start, self._switch_ring(), self.word_piece_items())

    def upload_rgb(self, fill: Fill, start: int, count: int) -> None:
        """Replace the attribute word of points start.. with their RGB: `fill` writes
        each point's R, G, B bytes ((hi - lo, 3) uint8, maybe mapped memory), which the
        scatter makes words (shaders/distribute.comp RGB_BYTES), in pieces of
        word_piece_items() through the words' ring."""
        self.rgb_words = self.rgb_words or self._build(1, "distribute rgb bytes", rgb=1)
        self._scatter(self.rgb_words, fill, count, 1, start, self._switch_ring(), self.word_piece_items(), item_bytes=3)

    def _switch_ring(self) -> StagingRing | None:
        """The ring of a switch's pieces (word_piece words a slot), made at the first switch."""
        if self.staging is Staging.RING and self.word_ring is None:
            self.word_ring = self._ring_of(self.word_piece, self.word_piece * 4)
        return self.word_ring

    def upload_classes(self, codes: np.ndarray, start: int) -> None:
        """Set the flags (class, first and last return) of n points (stores that keep classes)."""
        self.classes = self.classes or self._build(0, "distribute classes", 1)
        self._scatter(self.classes, _copy(codes, 1, self.copy), codes.shape[0], 1, start)

    def upload_class_bytes(self, fill: Fill, count: int, start: int) -> None:
        """Set the flags of points start.. from their class, return number and number of
        returns: `fill` writes a piece's (hi - lo, 3) uint8 as three runs of hi - lo bytes,
        one a field (shaders/distribute.comp CLASS_BYTES), made at the first such upload."""
        self.class_bytes = self.class_bytes or self._build(0, "distribute class bytes", 1, class_bytes=1)
        self._scatter(self.class_bytes, fill, count, 1, start, item_bytes=3)

    def _scatter(self, program, fill: Fill, n: int, width: int, start: int, ring: StagingRing | None = None,
                 step: int | None = None, item_bytes: int | None = None) -> int:
        """Pieces of `step` items (default piece_items) staged in `ring`'s slots (default
        the records' ring) or, where none is free, copied; items of `width` words, or
        with item_bytes of that many bytes back to back (the fill's out then
        (hi - lo, item_bytes) uint8)."""
        ring = ring or self.ring
        step = step or self.piece_items(width)
        if start < 0 or start + n > self.store.count:
            raise ValueError(f"batch [{start}, {start + n}) outside the cloud of {self.store.count} points")
        perm = self.store.permutation
        for name, value in (("u_prime", perm.prime), ("u_rotation", perm.offset), ("u_batches", perm.batches),
                            ("u_capacity", self.store.capacity)):
            if name in program:     # the word store's words program has the prime built in
                program[name] = value
        self.store.bind()
        total = 0
        for lo in range(0, n, step):
            hi = min(n, lo + step)
            words = (hi - lo) * width if item_bytes is None else -(-(hi - lo) * item_bytes // 4)
            slot = ring.acquire() if ring is not None else None
            if slot is not None:
                total += fill(_items(ring.view(slot, words, 1), hi - lo, width, item_bytes), lo, hi)
                ring.bind(slot, words * 4)
                self.stats.ring += 1
            else:
                part = np.empty(words, dtype=np.uint32)
                total += fill(_items(part, hi - lo, width, item_bytes), lo, hi)
                # fresh storage: no wait for the previous scatter to finish reading; as large as
                # a switch's piece of words, which may exceed a slot of records
                self.stage.orphan(max(part.nbytes, self.stage.size))
                self.stage.write(part)
                self.stage.bind_to_storage_buffer(Binding.DISTRIBUTE)
                self.stats.copied += 1
            program["u_start"] = start + lo
            program["u_count"] = hi - lo
            program.run(*grid(hi - lo))
            if slot is not None:
                ring.read(slot)
            self.glc.ctx.memory_barrier()
        self.points_distributed += n
        return total

    def release(self) -> None:
        for ring in (self.ring, self.word_ring):
            if ring is not None:
                ring.release()
        self.ring = self.word_ring = None
        self.copy.close()
        for obj in (self._stage, *self._programs.values(), self.words, self.rgb_words, self.classes,
                    self.class_bytes):
            if obj is not None:
                obj.release()


def without_buffer_storage(glc: GLContext) -> GLContext:
    """The context as a driver without GL_ARB_buffer_storage offers it: uploads copy
    (the fallback, side by side with the ring in tests and benchmarks)."""
    return replace(glc, gl=replace(glc.gl, storage=None))


def _items(staged: np.ndarray, count: int, width: int, item_bytes: int | None) -> np.ndarray:
    """The staged words as a fill writes them: (count, width) uint32, or (count,
    item_bytes) uint8 of items packed back to back."""
    if item_bytes is None:
        return staged.reshape(count, width)
    return staged.reshape(-1).view(np.uint8)[:count * item_bytes].reshape(count, item_bytes)


def _copy(data: np.ndarray, width: int, copy: StageCopier) -> Fill:
    """A fill that copies rows of an array already made."""
    rows = np.asarray(data, dtype=np.uint32).reshape(-1, width)

    def fill(out: np.ndarray, lo: int, hi: int) -> int:
        copy(out, rows[lo:hi])
        return 0

    return fill
