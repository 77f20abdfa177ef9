"""Present: the resolved image buffer drawn onto the window's framebuffer."""

from __future__ import annotations

import moderngl

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.context import GLContext


class PresentPass:
    def __init__(self, glc: GLContext):
        self.glc = glc
        self.program = glc.ctx.program(vertex_shader=shaderlib.source("present.vert"),
                                       fragment_shader=shaderlib.source("present.frag"))
        self.program.label = "present"
        self.vao = glc.ctx.vertex_array(self.program, [])

    def run(self, image: moderngl.Buffer, size: tuple[int, int], viewport: tuple[int, int]) -> None:
        """`size`: the image's; `viewport`: the window framebuffer's."""
        ctx = self.glc.ctx
        ctx.screen.use()
        ctx.viewport = (0, 0, *viewport)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        self.program["u_size"] = size
        image.bind_to_storage_buffer(Binding.IMAGE)
        self.vao.render(moderngl.TRIANGLES, vertices=3)

    def release(self) -> None:
        self.vao.release()
        self.program.release()
