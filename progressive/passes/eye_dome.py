"""Eye-dome lighting on the resolved image, from the depths of the visible points."""

from __future__ import annotations

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.context import GLContext
from progressive.effects import EyeDome
from progressive.gpu import grid_2d
from progressive.passes.handles import Visibility


class EyeDomePass:
    def __init__(self, glc: GLContext):
        self.glc = glc
        self.program = shaderlib.compute(glc.ctx, "eye_dome.comp", label="eye-dome lighting")

    def run(self, vis: Visibility, image, params: EyeDome) -> None:
        p = self.program
        p["u_size"] = (vis.width, vis.height)
        p["u_strength"] = params.strength
        p["u_radius"] = params.radius
        vis.bind()
        image.bind_to_storage_buffer(Binding.IMAGE)
        p.run(*grid_2d(vis.width, vis.height))
        self.glc.ctx.memory_barrier()

    def release(self) -> None:
        self.program.release()
