"""The per-pixel visibility buffer: 8 bytes a pixel, word 0 the slot of the nearest
point, word 1 its depth bits, which as a little-endian uint64 is the key the 64-bit
atomicMin sorts by. Row 0 is the top of the image."""

from __future__ import annotations

import numpy as np

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.context import GLContext
from progressive.gpu import fill_uvec4s
from progressive.passes.handles import EMPTY


class VisibilityBuffer:
    """The owner of the buffer; passes read it as handles.Visibility."""

    def __init__(self, glc: GLContext, width: int, height: int, label: str = "visibility"):
        self.glc, self.label = glc, label
        self.buffer = None
        self.width = self.height = 0
        self.clear_program = shaderlib.compute(glc.ctx, "clear.comp", label="clear visibility")
        self.resize(width, height)

    def resize(self, width: int, height: int) -> None:
        """Reallocate when the frame grows or shrinks (no fixed 2048² ceiling)."""
        if (width, height) == (self.width, self.height):
            return
        if self.buffer is not None:
            self.buffer.release()
        self.width, self.height = width, height
        self.buffer = self.glc.ctx.buffer(reserve=-(-width * height // 2) * 16)
        self.buffer.label = self.label

    @property
    def pixels(self) -> int:
        return self.width * self.height

    def clear(self) -> None:
        """Every pixel empty, on the GPU (8 bytes a pixel: one uvec4 clears two)."""
        fill_uvec4s(self.clear_program, self.buffer, 0, -(-self.pixels // 2), EMPTY)
        self.glc.ctx.memory_barrier()

    def bind(self) -> None:
        self.buffer.bind_to_storage_buffer(Binding.VISIBILITY)

    def read(self) -> np.ndarray:
        """(H, W, 2) uint32: slot, depth bits."""
        data = np.frombuffer(self.buffer.read(self.pixels * 8), dtype=np.uint32)
        return data.reshape(self.height, self.width, 2)

    def release(self) -> None:
        self.buffer.release()
        self.clear_program.release()
