"""Point size: a depth-aware dilation of the visibility buffer (nearest point in the
footprint wins) into a second buffer, of the same size, that resolve and eye-dome
lighting read (its owner, progressive/shading.py, sizes it)."""

from __future__ import annotations

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.context import GLContext
from progressive.effects import footprint
from progressive.gpu import grid_2d
from progressive.passes.handles import Visibility


class DilatePass:
    def __init__(self, glc: GLContext, *, pixel_words: bool):
        """pixel_words: also carry prepare's per-pixel words (progressive frames)."""
        self.glc = glc
        self.pixel_words = pixel_words
        self.program = shaderlib.compute(glc.ctx, "dilate.comp", {"PIXEL_WORDS": int(pixel_words)}, label="dilate")
        self.words = None

    def run(self, vis: Visibility, out: Visibility, point_size: int, words=None) -> None:
        """Dilate `vis` into `out` (its words into `self.words` with pixel_words)."""
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
        out.buffer.bind_to_storage_buffer(Binding.DILATED)
        if self.pixel_words:
            words.bind_to_storage_buffer(Binding.PIXEL_WORDS)
            self.words.bind_to_storage_buffer(Binding.DILATED_WORDS)
        p.run(*grid_2d(vis.width, vis.height))
        self.glc.ctx.memory_barrier()

    def release(self) -> None:
        for obj in (self.program, self.words):
            if obj is not None:
                obj.release()
