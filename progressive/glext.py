"""OpenGL entry points moderngl does not wrap, reached through ctypes.

moderngl has no glQueryCounter, GL_QUERY_BUFFER or glClearBufferSubData; buffer
clears must stay on the GPU (moderngl's Buffer.clear fills from the CPU)."""

from __future__ import annotations

import ctypes
from collections.abc import Callable
from dataclasses import dataclass

GL_R32UI = 0x8236
GL_RED_INTEGER = 0x8D94
GL_UNSIGNED_INT = 0x1405
GL_TIMESTAMP = 0x8E28
GL_QUERY_RESULT = 0x8866
GL_QUERY_RESULT_AVAILABLE = 0x8867
GL_QUERY_BUFFER = 0x9192
GL_DRAW_INDIRECT_BUFFER = 0x8F3F
GL_POINTS = 0x0000
GL_SYNC_GPU_COMMANDS_COMPLETE = 0x9117
GL_SYNC_FLUSH_COMMANDS_BIT = 0x1
GL_ALREADY_SIGNALED = 0x911A
GL_CONDITION_SATISFIED = 0x911C
GL_GPU_MEMORY_INFO_TOTAL_AVAILABLE_MEMORY_NVX = 0x9048
GL_GPU_MEMORY_INFO_CURRENT_AVAILABLE_VIDMEM_NVX = 0x9049

ProcLoader = Callable[[str], int]

_u = ctypes.c_uint
_i = ctypes.c_int
_iptr = ctypes.c_ssize_t
_vp = ctypes.c_void_p


def egl_proc_loader() -> ProcLoader:
    egl = ctypes.CDLL("libEGL.so.1")
    egl.eglGetProcAddress.restype = ctypes.c_void_p
    egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
    return lambda name: egl.eglGetProcAddress(name.encode()) or 0


@dataclass(frozen=True)
class GLFunctions:
    """Typed function pointers for the few raw calls the renderer needs."""

    clear_named_buffer_sub_data: Callable
    gen_queries: Callable
    delete_queries: Callable
    query_counter: Callable
    get_query_object_ui64v: Callable
    get_query_object_iv: Callable
    get_integerv: Callable
    bind_buffer: Callable
    clear_tex_image: Callable
    fence_sync: Callable
    client_wait_sync: Callable
    delete_sync: Callable
    copy_named_buffer_sub_data: Callable
    use_program: Callable
    bind_vertex_array: Callable
    draw_arrays_indirect: Callable

    @classmethod
    def load(cls, loader: ProcLoader) -> GLFunctions:
        def fn(name: str, *argtypes, restype=None):
            address = loader(name)
            if not address:
                raise RuntimeError(f"OpenGL entry point {name} not found")
            return ctypes.CFUNCTYPE(restype, *argtypes)(address)

        return cls(
            clear_named_buffer_sub_data=fn("glClearNamedBufferSubData", _u, _u, _iptr, _iptr, _u, _u, _vp),
            gen_queries=fn("glGenQueries", _i, ctypes.POINTER(_u)),
            delete_queries=fn("glDeleteQueries", _i, ctypes.POINTER(_u)),
            query_counter=fn("glQueryCounter", _u, _u),
            get_query_object_ui64v=fn("glGetQueryObjectui64v", _u, _u, _vp),
            get_query_object_iv=fn("glGetQueryObjectiv", _u, _u, ctypes.POINTER(_i)),
            get_integerv=fn("glGetIntegerv", _u, ctypes.POINTER(_i)),
            bind_buffer=fn("glBindBuffer", _u, _u),
            clear_tex_image=fn("glClearTexImage", _u, _i, _u, _u, _vp),
            fence_sync=fn("glFenceSync", _u, _u, restype=_vp),
            client_wait_sync=fn("glClientWaitSync", _vp, _u, ctypes.c_uint64, restype=_u),
            delete_sync=fn("glDeleteSync", _vp),
            copy_named_buffer_sub_data=fn("glCopyNamedBufferSubData", _u, _u, _iptr, _iptr, _iptr),
            use_program=fn("glUseProgram", _u),
            bind_vertex_array=fn("glBindVertexArray", _u),
            draw_arrays_indirect=fn("glDrawArraysIndirect", _u, _vp),
        )

    def clear_u32(self, glo: int, value: int, offset: int = 0, size: int | None = None, *, total: int) -> None:
        """Fill [offset, offset+size) of buffer `glo` with a repeated uint32, on the GPU."""
        word = ctypes.c_uint32(value & 0xFFFFFFFF)
        length = total - offset if size is None else size
        self.clear_named_buffer_sub_data(glo, GL_R32UI, offset, length, GL_RED_INTEGER, GL_UNSIGNED_INT, ctypes.byref(word))

    def draw_points_indirect(self, program_glo: int, vao_glo: int, args_glo: int, offset: int) -> None:
        """glDrawArraysIndirect(GL_POINTS) with arguments a compute pass wrote (moderngl's
        render_indirect assumes a 20-byte command stride)."""
        self.use_program(program_glo)
        self.bind_vertex_array(vao_glo)
        self.bind_buffer(GL_DRAW_INDIRECT_BUFFER, args_glo)
        self.draw_arrays_indirect(GL_POINTS, ctypes.c_void_p(offset))
        self.bind_buffer(GL_DRAW_INDIRECT_BUFFER, 0)
        self.bind_vertex_array(0)

    def fence(self) -> int:
        return self.fence_sync(GL_SYNC_GPU_COMMANDS_COMPLETE, 0)

    def signaled(self, sync: int) -> bool:
        """Non-blocking: has the GPU passed this fence? (flushes so it eventually will)"""
        status = self.client_wait_sync(sync, GL_SYNC_FLUSH_COMMANDS_BIT, 0)
        return status in (GL_ALREADY_SIGNALED, GL_CONDITION_SATISFIED)

    def wait(self, sync: int, timeout_ns: int = 10**9) -> None:
        """Block until the GPU passes this fence (frame pacing only)."""
        while self.client_wait_sync(sync, GL_SYNC_FLUSH_COMMANDS_BIT, timeout_ns) not in (GL_ALREADY_SIGNALED, GL_CONDITION_SATISFIED):
            pass

    def clear_texture_u32(self, glo: int, value: int) -> None:
        word = ctypes.c_uint32(value & 0xFFFFFFFF)
        self.clear_tex_image(glo, 0, GL_RED_INTEGER, GL_UNSIGNED_INT, ctypes.byref(word))

    def integer(self, pname: int) -> int:
        value = _i(0)
        self.get_integerv(pname, ctypes.byref(value))
        return int(value.value)
