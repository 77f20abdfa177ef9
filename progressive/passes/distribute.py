"""Distribute: staged batches scattered to their permuted slots (paper 3.1, 3.3)."""

from __future__ import annotations

import numpy as np

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.context import GLContext
from progressive.gpu import grid
from progressive.loaders.types import BATCH_POINTS
from progressive.packing import RECORD_BYTES
from progressive.pointstore import PointStore


class DistributePass:
    def __init__(self, glc: GLContext, store: PointStore, batch_points: int = BATCH_POINTS):
        self.glc = glc
        self.store = store
        self.batch_points = batch_points
        self.stage = glc.ctx.buffer(reserve=batch_points * RECORD_BYTES)
        self.stage.label = "distribute stage"
        int64 = glc.caps.shader_int64
        defines = dict(store.defines, PERMUTE_INT64=1) if int64 else dict(store.defines)
        ext = ("GL_ARB_gpu_shader_int64",) if int64 else ()
        self._build = lambda only, label, classes=0: shaderlib.compute(
            glc.ctx, "distribute.comp", dict(defines, ATTRIBUTE_ONLY=only, CLASS_WORDS=classes), ext, label)
        self.records = self._build(0, "distribute")
        self.words = None       # built at the first attribute switch: no first image waits for it
        self.classes = self._build(0, "distribute classes", 1) if store.has_classes else None
        self.points_distributed = 0

    def upload(self, records: np.ndarray, start: int) -> None:
        """Scatter (n, 4) uint32 records whose first has file-order index `start`."""
        self._scatter(self.records, np.ascontiguousarray(records, dtype=np.uint32), start)

    def upload_words(self, words: np.ndarray, start: int) -> None:
        """Replace only the attribute word of n points (attribute switching, paper 3.5)."""
        self.words = self.words or self._build(1, "distribute words")
        self._scatter(self.words, np.ascontiguousarray(words, dtype=np.uint32), start)

    def upload_classes(self, codes: np.ndarray, start: int) -> None:
        """Set the class byte of n points (stores that keep classes)."""
        self._scatter(self.classes, np.ascontiguousarray(codes, dtype=np.uint32), start)

    def _scatter(self, program, data: np.ndarray, start: int) -> None:
        n = data.shape[0]
        if start < 0 or start + n > self.store.count:
            raise ValueError(f"batch [{start}, {start + n}) outside the cloud of {self.store.count} points")
        perm = self.store.permutation
        program["u_prime"] = perm.prime
        program["u_rotation"] = perm.offset
        program["u_batches"] = perm.batches
        program["u_capacity"] = self.store.capacity
        self.store.bind()
        self.stage.bind_to_storage_buffer(Binding.DISTRIBUTE)
        for off in range(0, n, self.batch_points):
            part = data[off: off + self.batch_points]
            self.stage.orphan()   # fresh storage: no wait for the previous scatter to finish reading
            self.stage.write(part.tobytes())
            program["u_start"] = start + off
            program["u_count"] = part.shape[0]
            program.run(*grid(part.shape[0]))
            self.glc.ctx.memory_barrier()
        self.points_distributed += n

    def release(self) -> None:
        for obj in (self.stage, self.records, self.words, self.classes):
            if obj is not None:
                obj.release()
