"""Point size: a depth-aware dilation of the visibility buffer (nearest point in the
footprint wins) into a second buffer that resolve and eye-dome lighting read."""

from __future__ import annotations

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.context import GLContext
from progressive.effects import footprint
from progressive.gpu import grid_2d
from progressive.passes.visibility import VisibilityBuffer


class DilatePass:
    def __init__(self, glc: GLContext, *, pixel_words: bool):
        """pixel_words: also carry prepare's per-pixel words (progressive frames)."""
        self.glc = glc
        self.pixel_words = pixel_words
        self.program = shaderlib.compute(glc.ctx, "dilate.comp", {"PIXEL_WORDS": int(pixel_words)}, label="dilate")
        self.out: VisibilityBuffer | None = None
        self.words = None

    def run(self, vis: VisibilityBuffer, point_size: int, words=None) -> VisibilityBuffer:
        """The dilated visibility (its words in `self.words` with pixel_words)."""
        if self.out is None:
            self.out = VisibilityBuffer(self.glc, vis.width, vis.height, label="dilated visibility")
        self.out.resize(vis.width, vis.height)
        if self.pixel_words and (self.words is None or self.words.size != vis.pixels * 4):
            if self.words is not None:
                self.words.release()
            self.words = self.glc.ctx.buffer(reserve=vis.pixels * 4)
            self.words.label = "dilated words"
        reach, radius2 = footprint(point_size)
        p = self.program
        p["u_size"] = (vis.width, vis.height)
        p["u_reach"] = reach
        p["u_radius2"] = radius2
        vis.bind()
        self.out.buffer.bind_to_storage_buffer(Binding.DILATED)
        if self.pixel_words:
            words.bind_to_storage_buffer(Binding.PIXEL_WORDS)
            self.words.bind_to_storage_buffer(Binding.DILATED_WORDS)
        p.run(*grid_2d(vis.width, vis.height))
        self.glc.ctx.memory_barrier()
        return self.out

    def release(self) -> None:
        for obj in (self.program, self.out, self.words):
            if obj is not None:
                obj.release()
