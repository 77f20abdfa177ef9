"""Slots of arbitrary file-order indices computed on the GPU (the same GLSL the
distribute pass uses), so tests can compare GPU and numpy for any N < 2^32."""

from __future__ import annotations

import numpy as np

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.context import GLContext
from progressive.gpu import grid
from progressive.permutation import Permutation


def gpu_permute(glc: GLContext, perm: Permutation, indices: np.ndarray, *, int64: bool) -> np.ndarray:
    if int64 and not glc.caps.shader_int64:
        raise ValueError("GL_ARB_gpu_shader_int64 is not available")
    defines = {"PERMUTE_INT64": 1} if int64 else {}
    ext = ("GL_ARB_gpu_shader_int64",) if int64 else ()
    program = shaderlib.compute(glc.ctx, "permute.comp", defines, ext, "permute")
    data = np.ascontiguousarray(indices, dtype=np.uint32)
    buf = glc.ctx.buffer(data.tobytes())
    buf.bind_to_storage_buffer(Binding.DISTRIBUTE)
    program["u_count"] = data.size
    program["u_prime"] = perm.prime
    program["u_rotation"] = perm.offset
    program["u_batches"] = perm.batches
    program.run(*grid(data.size))
    glc.ctx.memory_barrier()
    out = np.frombuffer(buf.read(), dtype=np.uint32).copy()
    buf.release()
    program.release()
    return out
