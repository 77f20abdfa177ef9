"""Resolve: colour each pixel from the attribute word of its visible point."""

from __future__ import annotations

import numpy as np

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.colors import ColorMode, ColorStyle
from progressive.context import GLContext
from progressive.gpu import grid_2d
from progressive.passes.handles import Visibility
from progressive.pointstore import PointStore


class ResolvePass:
    def __init__(self, glc: GLContext, store: PointStore, vis: Visibility, *, pixel_words: bool = False):
        """pixel_words: read each visible point's word from the buffer prepare writes
        (progressive frames) instead of gathering it from the store."""
        self.glc, self.store, self.vis = glc, store, vis
        defines = dict(store.defines, PIXEL_WORDS=int(pixel_words), **ColorMode.glsl_defines())
        self.program = shaderlib.compute(glc.ctx, "resolve.comp", defines, label="resolve")
        self.palette = glc.ctx.buffer(reserve=256 * 4)
        self.palette.label = "palette"
        self.image = None
        self._palette_key = None

    def run(self, style: ColorStyle, words=None, vis: Visibility | None = None) -> None:
        """`words`: the per-pixel word buffer, with pixel_words. `vis`: another buffer
        of the same size to colour (the point-size pass's output)."""
        vis = vis or self.vis
        if self.image is None or self.image.size != vis.pixels * 4:
            if self.image is not None:
                self.image.release()
            self.image = self.glc.ctx.buffer(reserve=vis.pixels * 4)
            self.image.label = "image"
        if style.palette != self._palette_key:
            self.palette.write(np.asarray(style.palette, dtype=np.uint32).tobytes())
            self._palette_key = style.palette
        p = self.program
        p["u_size"] = (vis.width, vis.height)
        p["u_mode"] = int(style.mode)
        p["u_range"] = style.value_range
        p["u_background"] = style.background
        self.store.bind()
        vis.bind()
        self.image.bind_to_storage_buffer(Binding.IMAGE)
        self.palette.bind_to_storage_buffer(Binding.PALETTE)
        if words is not None:
            words.bind_to_storage_buffer(Binding.PIXEL_WORDS)
        p.run(*grid_2d(vis.width, vis.height))
        self.glc.ctx.memory_barrier()

    def read(self) -> np.ndarray:
        """(H, W, 4) uint8 RGBA, row 0 at the top."""
        data = np.frombuffer(self.image.read(), dtype=np.uint8)
        return data.reshape(self.vis.height, self.vis.width, 4).copy()

    def release(self) -> None:
        for obj in (self.program, self.palette, self.image):
            if obj is not None:
                obj.release()
