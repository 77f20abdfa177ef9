"""The per-pixel visibility buffer: 8 bytes a pixel, word 0 the slot of the nearest
point, word 1 its depth bits, which as a little-endian uint64 is the key the 64-bit
atomicMin sorts by. Row 0 is the top of the image."""

from __future__ import annotations

import numpy as np

from progressive.bindings import Binding
from progressive.context import GLContext

EMPTY = 0xFFFFFFFF


class VisibilityBuffer:
    def __init__(self, glc: GLContext, width: int, height: int):
        self.glc = glc
        self.buffer = None
        self.width = self.height = 0
        self.resize(width, height)

    def resize(self, width: int, height: int) -> None:
        """Reallocate when the frame grows or shrinks (no fixed 2048² ceiling)."""
        if (width, height) == (self.width, self.height):
            return
        if self.buffer is not None:
            self.buffer.release()
        self.width, self.height = width, height
        self.buffer = self.glc.ctx.buffer(reserve=width * height * 8)
        self.buffer.label = "visibility"

    @property
    def pixels(self) -> int:
        return self.width * self.height

    def clear(self) -> None:
        self.glc.gl.clear_u32(self.buffer.glo, EMPTY, total=self.buffer.size)

    def bind(self) -> None:
        self.buffer.bind_to_storage_buffer(Binding.VISIBILITY)

    def read(self) -> np.ndarray:
        """(H, W, 2) uint32: slot, depth bits."""
        return np.frombuffer(self.buffer.read(), dtype=np.uint32).reshape(self.height, self.width, 2)

    def release(self) -> None:
        self.buffer.release()
