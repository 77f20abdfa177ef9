"""Culling of the batched layout: once a frame, one invocation a batch tests its box
against the view (the test of progressive/batches.py in_view) and writes a flag the
rasterizer reads before each point, so points of batches outside the view cost a
4-byte cached read and no projection. A flag pass instead of a test in every work
group: no barrier in the raster (costly on llvmpipe), one test a batch, not a slice."""

from __future__ import annotations

from progressive import encoding, shaderlib
from progressive.camera import ViewUniforms
from progressive.context import GLContext
from progressive.encoding import Precision
from progressive.gpu import grid, set_view
from progressive.passes.handles import BatchFlags
from progressive.pointstore import PointStore


class CullPass:
    def __init__(self, glc: GLContext, store: PointStore):
        self.glc, self.store = glc, store
        self.program = shaderlib.compute(glc.ctx, "cull.comp", {"ADAPTIVE": 0}, label="cull")
        self._adaptive = None   # built when an adaptive frame first needs it
        self.flags = glc.ctx.buffer(reserve=max(1, store.permutation.batches) * 4)
        self.flags.label = "batch flags"
        self.batch_flags = BatchFlags(self.flags)

    def run(self, view: ViewUniforms, precision: Precision = Precision.EXACT) -> None:
        """Flag each batch 0 (culled) or the words its points are read from: all of them,
        or with ADAPTIVE precision on the word store the fewest that keep the error
        under encoding.ADAPTIVE_ERROR_PX."""
        adaptive = precision is Precision.ADAPTIVE and self.store.words
        if adaptive and self._adaptive is None:
            self._adaptive = shaderlib.compute(self.glc.ctx, "cull.comp", {"ADAPTIVE": 1}, label="cull adaptive")
        program = self._adaptive if adaptive else self.program
        set_view(program, view)
        program["u_batches"] = self.store.permutation.batches
        if adaptive:
            program["u_error_px"] = encoding.ADAPTIVE_ERROR_PX
            program["u_pixel_scale"] = encoding.pixel_scale(view)
            self.store.bind_frames()
        self.store.bind_boxes()
        self.batch_flags.bind()
        program.run(*grid(self.store.permutation.batches))
        self.glc.ctx.memory_barrier()

    def release(self) -> None:
        self.program.release()
        if self._adaptive is not None:
            self._adaptive.release()
        self.flags.release()
