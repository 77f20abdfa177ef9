"""The paper's baseline: GL_POINTS through the fixed pipeline with a depth test,
writing slot and depth bits to integer attachments, then gathered into the
visibility buffer so every later pass is the same for all rasterizers."""

from __future__ import annotations

import moderngl

from progressive import shaderlib
from progressive.camera import ViewUniforms
from progressive.context import GLContext
from progressive.gpu import grid_2d, set_view
from progressive.passes.handles import EMPTY, FillPieces, Meta, Reprojection, Source, StateWord, Visibility
from progressive.pointstore import PointStore

DRAW_POINTS = 2**30
"""Vertices a draw call takes at most (its count is a signed 32-bit integer)."""


class PointsRaster:
    """`passes` is 1. A frame is begin_frame(view), draws, end_frame(); every draw pulls
    its points from the store by gl_VertexID in slot order, so the depth test keeps the
    least slot among equal depths (the render contract's tie rule)."""

    passes = frame_passes = 1
    draws_batches = False
    """Slots in order only: batches written anew start the fill again (frame_loop.py)."""
    winners = None
    """No winners pass: prepare follows the hints and gathers new winners."""

    def __init__(self, glc: GLContext, store: PointStore, vis: Visibility):
        self.glc, self.store, self.vis = glc, store, vis
        ctx = glc.ctx
        defines = dict(store.defines, **StateWord.defines(), **Meta.defines())
        self.pulling = {s: self._program(dict(defines, **Source.defines(s)), f"raster points {s.name.lower()}")
                        for s in Source}
        self.empty_vaos = {s: ctx.vertex_array(p, []) for s, p in self.pulling.items()}
        self.gather = shaderlib.compute(ctx, "points_gather.comp", label="points gather")
        self.size = (0, 0)
        self.fbo = None
        self._targets = []
        self._previous = None

    def _program(self, defines, label):
        program = self.glc.ctx.program(vertex_shader=shaderlib.source("raster_points.vert", defines),
                                       fragment_shader=shaderlib.source("raster_points.frag"))
        program.label = label
        return program

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

    def begin_frame(self, view: ViewUniforms) -> None:
        """Empty targets, bound with a depth test, until end_frame() (the baseline culls nothing)."""
        self._ensure_targets()
        ctx = self.glc.ctx
        _, slots, depths, _ = self._targets
        self._previous = ctx.fbo or ctx.detect_framebuffer()
        self.fbo.use()
        self.fbo.clear(depth=1.0)
        self.glc.gl.clear_texture_u32(slots.glo, EMPTY)
        self.glc.gl.clear_texture_u32(depths.glo, EMPTY)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.depth_func = "<"

    def end_pass(self, view: ViewUniforms, pass_index: int, pieces: FillPieces,
                 reprojection: Reprojection | None) -> None:
        """Nothing between passes: the one pass's depth test decides."""

    def end_frame(self, view: ViewUniforms) -> None:
        """Gather the attachments into the visibility buffer (overwriting it)."""
        ctx = self.glc.ctx
        ctx.disable(moderngl.DEPTH_TEST)
        self._previous.use()
        ctx.memory_barrier()
        _, slots, depths, _ = self._targets
        slots.use(0)
        depths.use(1)
        self.gather["u_slots"] = 0
        self.gather["u_depths"] = 1
        self.gather["u_size"] = view.size
        self.vis.bind()
        self.gather.run(*grid_2d(*view.size))
        ctx.memory_barrier()

    def draw(self, view: ViewUniforms, first: int, count: int) -> None:
        """A whole frame of slots [first, first+count), in draws of at most DRAW_POINTS."""
        self.begin_frame(view)
        program = self.pulling[Source.RANGE]
        set_view(program, view)
        self.store.bind()
        for start in range(first, first + count, DRAW_POINTS):
            program["u_first"] = start
            program["u_count"] = n = min(DRAW_POINTS, first + count - start)
            self.empty_vaos[Source.RANGE].render(moderngl.POINTS, vertices=n)
        self.end_frame(view)

    def _pull(self, source: Source, view: ViewUniforms, args_buffer, offset: int) -> None:
        program = self.pulling[source]
        set_view(program, view)
        self.store.bind()
        self.glc.ctx.memory_barrier()
        self.glc.gl.draw_points_indirect(program.glo, self.empty_vaos[source].glo, args_buffer.glo, offset)

    def draw_piece(self, view: ViewUniforms, pieces: FillPieces, piece: int, pass_index: int) -> None:
        self.pulling[Source.PIECE]["u_piece"] = piece
        pieces.bind()
        self._pull(Source.PIECE, view, pieces.args, pieces.draw_offset(piece))

    def draw_list(self, view: ViewUniforms, reprojection: Reprojection, pass_index: int) -> None:
        self.pulling[Source.LIST]["u_capacity"] = reprojection.capacity
        reprojection.bind()
        self._pull(Source.LIST, view, reprojection.meta, reprojection.draw_offset)

    def release(self) -> None:
        for obj in [*self._targets, *self.empty_vaos.values(), *self.pulling.values(), self.gather]:
            obj.release()
