"""Accuracy on the GPU: a brute-force render of the same camera into a second
visibility buffer, and the count of pixels whose visible point is the same."""

from __future__ import annotations

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.camera import ViewUniforms
from progressive.context import GLContext
from progressive.gpu import grid_2d
from progressive.passes.raster_compute import ComputeRaster
from progressive.passes.visibility import VisibilityBuffer
from progressive.pointstore import PointStore


class ComparePass:
    def __init__(self, glc: GLContext, store: PointStore, vis: VisibilityBuffer, *, atomic64: bool):
        self.glc, self.store, self.vis = glc, store, vis
        self.reference = VisibilityBuffer(glc, vis.width, vis.height)
        self.reference.buffer.label = "reference visibility"
        self.raster = ComputeRaster(glc, store, self.reference, atomic64=atomic64)
        self.program = shaderlib.compute(glc.ctx, "compare.comp", label="compare")
        self.counter = glc.ctx.buffer(reserve=4)
        self.counter.label = "equal pixels"

    def run(self, view: ViewUniforms) -> None:
        """Render the reference for `view` and count equal pixels into `counter`."""
        self.reference.resize(self.vis.width, self.vis.height)
        self.reference.clear()
        self.raster.draw(view, 0, self.store.capacity)
        self.glc.gl.clear_u32(self.counter.glo, 0, total=4)
        self.vis.bind()
        self.reference.buffer.bind_to_storage_buffer(Binding.REFERENCE)
        self.counter.bind_to_storage_buffer(Binding.COUNTERS)
        self.program["u_size"] = (self.vis.width, self.vis.height)
        self.program.run(*grid_2d(self.vis.width, self.vis.height))
        self.glc.ctx.memory_barrier()

    def release(self) -> None:
        for obj in (self.raster, self.reference, self.program, self.counter):
            obj.release()
