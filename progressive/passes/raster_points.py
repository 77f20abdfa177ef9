"""The paper's baseline: GL_POINTS through the fixed pipeline with a depth test,
writing slot and depth bits to integer attachments, then gathered into the
visibility buffer so every later pass is the same for all rasterizers."""

from __future__ import annotations

import moderngl

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.camera import ViewUniforms
from progressive.context import GLContext
from progressive.gpu import grid_2d
from progressive.passes.raster_compute import set_view
from progressive.passes.visibility import EMPTY, VisibilityBuffer
from progressive.pointstore import PointStore


class PointsRaster:
    def __init__(self, glc: GLContext, store: PointStore, vis: VisibilityBuffer):
        self.glc, self.store, self.vis = glc, store, vis
        ctx = glc.ctx
        self.program = ctx.program(
            vertex_shader=shaderlib.source("raster_points.vert"),
            fragment_shader=shaderlib.source("raster_points.frag"),
        )
        self.program.label = "raster points"
        self.vaos = [ctx.vertex_array(self.program, [(buf, "3f4 x4", "a_position")]) for buf in store.buffers]
        self.gather = shaderlib.compute(ctx, "points_gather.comp", label="points gather")
        self.size = (0, 0)
        self.fbo = None
        self._targets = []

    def _ensure_targets(self) -> None:
        size = (self.vis.width, self.vis.height)
        if size == self.size:
            return
        for obj in self._targets:
            obj.release()
        ctx = self.glc.ctx
        slots = ctx.texture(size, 1, dtype="u4")
        depths = ctx.texture(size, 1, dtype="u4")
        depth = ctx.depth_texture(size)
        for t, name in ((slots, "points slots"), (depths, "points depth bits"), (depth, "points depth")):
            t.label = name
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.fbo = ctx.framebuffer(color_attachments=[slots, depths], depth_attachment=depth)
        self._targets = [self.fbo, slots, depths, depth]
        self.size = size

    def draw(self, view: ViewUniforms, first: int, count: int) -> None:
        """Draw slots [first, first+count) into fresh targets and overwrite the
        visibility buffer with the result (the baseline renders whole frames only)."""
        self._ensure_targets()
        ctx = self.glc.ctx
        _, slots, depths, _ = self._targets
        previous = ctx.fbo or ctx.detect_framebuffer()
        self.fbo.use()
        self.fbo.clear(depth=1.0)
        self.glc.gl.clear_texture_u32(slots.glo, EMPTY)
        self.glc.gl.clear_texture_u32(depths.glo, EMPTY)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.depth_func = "<"
        set_view(self.program, view)
        for chunk, local_first, n in self.store.chunk_ranges(first, count):
            self.program["u_chunk_base"] = chunk * self.store.chunk_points
            self.vaos[chunk].render(moderngl.POINTS, vertices=n, first=local_first)
        ctx.disable(moderngl.DEPTH_TEST)
        previous.use()
        ctx.memory_barrier()
        slots.use(0)
        depths.use(1)
        self.gather["u_slots"] = 0
        self.gather["u_depths"] = 1
        self.gather["u_size"] = view.size
        self.vis.buffer.bind_to_storage_buffer(Binding.VISIBILITY)
        self.gather.run(*grid_2d(*view.size))
        ctx.memory_barrier()

    def release(self) -> None:
        for obj in [*self._targets, *self.vaos, self.program, self.gather]:
            obj.release()
