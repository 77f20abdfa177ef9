"""Compute rasterization into the visibility buffer: one 64-bit atomicMin per point
where GL_NV_shader_atomic_int64 exists, else a depth pass and an index pass."""

from __future__ import annotations

from progressive import shaderlib
from progressive.camera import ViewUniforms
from progressive.context import GLContext
from progressive.gpu import grid
from progressive.passes.visibility import VisibilityBuffer
from progressive.pointstore import PointStore


def set_view(program, view: ViewUniforms) -> None:
    """Camera uniforms (camera.glsl); a program may not use all of them."""
    program["u_view_rotation"].write(view.rotation.T.tobytes())
    program["u_view_translation"].write(view.translation.tobytes())
    program["u_projection"].write(view.projection.tobytes())
    if "u_size" in program:
        program["u_size"] = view.size


class ComputeRaster:
    def __init__(self, glc: GLContext, store: PointStore, vis: VisibilityBuffer, *, atomic64: bool):
        if atomic64 and not glc.caps.atomic_int64:
            raise ValueError("64-bit atomics requested but GL_NV_shader_atomic_int64 is missing")
        self.glc, self.store, self.vis = glc, store, vis
        self.atomic64 = atomic64
        if atomic64:
            ext = ("GL_ARB_gpu_shader_int64", "GL_NV_shader_atomic_int64")
            self.programs = [shaderlib.compute(glc.ctx, "raster_compute.comp", dict(store.defines, ATOMIC64=1), ext, "raster64")]
        else:
            self.programs = [
                shaderlib.compute(glc.ctx, "raster_compute.comp", dict(store.defines, ATOMIC64=0, DEPTH_PASS=1), (), "raster32 depth"),
                shaderlib.compute(glc.ctx, "raster_compute.comp", dict(store.defines, ATOMIC64=0, DEPTH_PASS=0), (), "raster32 index"),
            ]

    def draw(self, view: ViewUniforms, first: int, count: int) -> None:
        """Rasterize slots [first, first+count) into the (already cleared) visibility buffer."""
        if count <= 0:
            return
        self.store.bind()
        self.vis.bind()
        for program in self.programs:
            set_view(program, view)
            program["u_first"] = first
            program["u_count"] = count
            program.run(*grid(count))
            self.glc.ctx.memory_barrier()

    def release(self) -> None:
        for p in self.programs:
            p.release()
