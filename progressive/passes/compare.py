"""Accuracy on the GPU: the count of pixels whose visible point is the same in two
visibility buffers of one size (a frame and the brute-force render of its camera,
which the frame loop composes)."""

from __future__ import annotations

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.context import GLContext
from progressive.gpu import grid_2d
from progressive.passes.handles import Visibility


class ComparePass:
    def __init__(self, glc: GLContext, vis: Visibility):
        self.glc, self.vis = glc, vis
        self.program = shaderlib.compute(glc.ctx, "compare.comp", label="compare")
        self.counter = glc.ctx.buffer(reserve=4)
        self.counter.label = "equal pixels"

    def run(self, reference: Visibility) -> None:
        """Count the pixels of `vis` equal to `reference` into `counter`."""
        self.glc.gl.clear_u32(self.counter.glo, 0, total=4)
        self.vis.bind()
        reference.buffer.bind_to_storage_buffer(Binding.REFERENCE)
        self.counter.bind_to_storage_buffer(Binding.COUNTERS)
        self.program["u_size"] = (self.vis.width, self.vis.height)
        self.program.run(*grid_2d(self.vis.width, self.vis.height))
        self.glc.ctx.memory_barrier()

    def release(self) -> None:
        for obj in (self.program, self.counter):
            obj.release()
