"""OpenGL entry points moderngl does not wrap, reached through ctypes.

moderngl has no glQueryCounter, GL_QUERY_BUFFER or glClearBufferSubData; buffer
clears must stay on the GPU (moderngl's Buffer.clear fills from the CPU). Nor has it
GL_ARB_get_program_binary: ProgramFunctions builds and loads compute programs itself
(progressive/programs.py). Nor GL_ARB_buffer_storage: BufferStorage makes the
persistently mapped staging buffers uploads are packed into (passes/distribute.py)."""

from __future__ import annotations

import ctypes
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

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
GL_COMPUTE_SHADER = 0x91B9
GL_COMPILE_STATUS = 0x8B81
GL_LINK_STATUS = 0x8B82
GL_INFO_LOG_LENGTH = 0x8B84
GL_ACTIVE_UNIFORMS = 0x8B86
GL_PROGRAM_BINARY_RETRIEVABLE_HINT = 0x8257
GL_PROGRAM_BINARY_LENGTH = 0x8741
GL_NUM_PROGRAM_BINARY_FORMATS = 0x87FE
GL_DISPATCH_INDIRECT_BUFFER = 0x90EE
GL_PROGRAM = 0x82E2
GL_NO_ERROR = 0
GL_MAP_WRITE_BIT = 0x0002
GL_MAP_PERSISTENT_BIT = 0x0040
GL_MAP_FLUSH_EXPLICIT_BIT = 0x0010
GL_CLIENT_MAPPED_BUFFER_BARRIER_BIT = 0x4000
GL_SHADER_STORAGE_BUFFER_OFFSET_ALIGNMENT = 0x90DF
BUFFER_STORAGE_VERSION = 440
"""GL_ARB_buffer_storage is core from OpenGL 4.4."""

ProcLoader = Callable[[str], int]

_u = ctypes.c_uint
_i = ctypes.c_int
_iptr = ctypes.c_ssize_t
_vp = ctypes.c_void_p


LIBEGL = "libEGL.so.1"
LIBGL = "libGL.so.1"
"""The sonames the headless context opens (dlopen finds them as the dynamic linker
would): named here, not found by ctypes.util.find_library, which runs ldconfig and,
where the libraries lie outside its cache, gcc and ld (47 ms of a profiled start on
the H100 machine, bench/results/nvidia-h100/startup_libs/)."""


def egl_proc_loader() -> ProcLoader:
    egl = ctypes.CDLL(LIBEGL)
    egl.eglGetProcAddress.restype = ctypes.c_void_p
    egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
    return lambda name: egl.eglGetProcAddress(name.encode()) or 0


STATE_CALLS = frozenset({
    "glBindBuffer", "glBindVertexArray", "glUseProgram", "glQueryCounter", "glFenceSync", "glDeleteSync",
    "glGenQueries", "glDeleteQueries", "glGetIntegerv",
})
"""The frame's calls that only set or read the context's state, called holding the GIL;
so are the glProgramUniform* ones. The others may do the work they order (llvmpipe runs
a compute dispatch inside glDispatchCompute) or wait for the GPU or a compile (a link
status waits for a parallel link), and release it. Each release hands the GIL to any
thread that wants it, and the frame loop then waits to take it back: a frame makes 93
state calls of its 117 (with GLFunctions.query_into_buffer), and beside a thread busy
in Python the frame loop ran 6.2-7.7 frames a second with them holding it against
2.5-3.1 without (llvmpipe, bench/results/llvmpipe/gil_state_calls/); on the H100
machine a streamed COPC's frames while its overview loaded had a p95 of 22-24 ms against
31-40 ms, loading as fast (bench/results/nvidia-h100/gil_state_calls/). Dispatches
release it: holding it too, frames issued back to back kept it from the parser threads
(the window's load of 100 M points took twice as long there)."""


def _entry(loader: ProcLoader, name: str, *argtypes, restype=None, state: bool | None = None) -> Callable:
    """`name`'s function; `state`: whether the call holds the GIL (default: STATE_CALLS says)."""
    address = loader(name)
    if not address:
        raise RuntimeError(f"OpenGL entry point {name} not found")
    if state is None:
        state = name in STATE_CALLS or name.startswith("glProgramUniform")
    return (ctypes.PYFUNCTYPE if state else ctypes.CFUNCTYPE)(restype, *argtypes)(address)


@dataclass(frozen=True)
class GLFunctions:
    """Typed function pointers for the few raw calls the renderer needs."""

    clear_named_buffer_sub_data: Callable
    gen_queries: Callable
    delete_queries: Callable
    query_counter: Callable
    get_query_object_ui64v: Callable
    query_into_buffer: Callable
    """glGetQueryObjectui64v with a GL_QUERY_BUFFER bound: the GPU writes the result
    when it has it, so the call never waits (a state call: holds the GIL)."""
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
    storage: BufferStorage | None
    """Persistently mapped buffers; None: uploads copy (a context built with storage=None
    stands for a driver without GL_ARB_buffer_storage)."""

    @classmethod
    def load(cls, loader: ProcLoader) -> GLFunctions:
        def fn(name: str, *argtypes, restype=None, state=None):
            return _entry(loader, name, *argtypes, restype=restype, state=state)

        return cls(
            clear_named_buffer_sub_data=fn("glClearNamedBufferSubData", _u, _u, _iptr, _iptr, _u, _u, _vp),
            gen_queries=fn("glGenQueries", _i, ctypes.POINTER(_u)),
            delete_queries=fn("glDeleteQueries", _i, ctypes.POINTER(_u)),
            query_counter=fn("glQueryCounter", _u, _u),
            get_query_object_ui64v=fn("glGetQueryObjectui64v", _u, _u, _vp),
            query_into_buffer=fn("glGetQueryObjectui64v", _u, _u, _vp, state=True),
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
            storage=BufferStorage.load(loader),
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


_cp = ctypes.c_char_p
_uptr = ctypes.POINTER(_u)
_ip = ctypes.POINTER(_i)


@dataclass(frozen=True)
class MappedBuffer:
    """A buffer whose storage stays mapped for writing while the GPU reads it:
    `words` is a numpy view on the mapping (valid until release)."""

    glo: int
    size: int
    words: np.ndarray


@dataclass(frozen=True)
class BufferStorage:
    """Immutable buffer storage, persistently mapped (GL_ARB_buffer_storage)."""

    create_buffers: Callable
    named_buffer_storage: Callable
    map_named_buffer_range: Callable
    flush_mapped_named_buffer_range: Callable
    unmap_named_buffer: Callable
    delete_buffers: Callable

    @classmethod
    def load(cls, loader: ProcLoader) -> BufferStorage | None:
        """None where an entry point is missing."""
        try:
            return cls(
                create_buffers=_entry(loader, "glCreateBuffers", _i, _uptr),
                named_buffer_storage=_entry(loader, "glNamedBufferStorage", _u, _iptr, _vp, _u),
                map_named_buffer_range=_entry(loader, "glMapNamedBufferRange", _u, _iptr, _iptr, _u, restype=_vp),
                flush_mapped_named_buffer_range=_entry(loader, "glFlushMappedNamedBufferRange", _u, _iptr, _iptr),
                unmap_named_buffer=_entry(loader, "glUnmapNamedBuffer", _u, restype=ctypes.c_ubyte),
                delete_buffers=_entry(loader, "glDeleteBuffers", _i, _uptr),
            )
        except RuntimeError:
            return None

    @staticmethod
    def offered(version_code: int, extensions: set[str]) -> bool:
        """The context has buffer storage (loaders hand out entry points whatever the
        context offers, so only the version and extensions tell)."""
        return version_code >= BUFFER_STORAGE_VERSION or "GL_ARB_buffer_storage" in extensions

    def mapped(self, size: int) -> MappedBuffer:
        """`size` bytes (a multiple of 4), mapped persistent, not coherent: what the CPU
        writes is seen by the GL commands issued after `flush` names its range and a
        glMemoryBarrier(GL_CLIENT_MAPPED_BUFFER_BARRIER_BIT) follows (the specification
        lets a coherent store's writes reach the server "after an unspecified period of
        time"). On the NVIDIA driver (580, H100), scatters reading a slot rewritten after
        its fence had signalled at times placed words of other points
        (tests/test_switch_words.py), with a coherent mapping
        (bench/results/nvidia-h100/pytest_64de055/) and with this one too
        (pytest_2b32179/); a glFinish before each rewrite prevented it in a short probe.
        bench/results/nvidia-h100/staging_race/ tries other ways."""
        name = _u(0)
        self.create_buffers(1, ctypes.byref(name))
        self.named_buffer_storage(name.value, size, None, GL_MAP_WRITE_BIT | GL_MAP_PERSISTENT_BIT)
        address = self.map_named_buffer_range(name.value, 0, size,
                                              GL_MAP_WRITE_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_FLUSH_EXPLICIT_BIT)
        if not address:
            self.delete_buffers(1, ctypes.byref(name))
            raise RuntimeError(f"could not map a {size}-byte staging buffer")
        words = np.ctypeslib.as_array(ctypes.cast(address, ctypes.POINTER(ctypes.c_uint32)), shape=(size // 4,))
        return MappedBuffer(int(name.value), size, words)

    def flush(self, buffer: MappedBuffer, offset: int, size: int) -> None:
        """The CPU wrote bytes [offset, offset + size) of the mapping (for the commands
        after the next client-mapped buffer barrier)."""
        self.flush_mapped_named_buffer_range(buffer.glo, offset, size)

    def release(self, buffer: MappedBuffer) -> None:
        name = _u(buffer.glo)
        self.unmap_named_buffer(name)
        self.delete_buffers(1, ctypes.byref(name))


@dataclass(frozen=True)
class ProgramFunctions:
    """Compile, link, save and load compute programs, set their uniforms, dispatch."""

    create_shader: Callable
    shader_source: Callable
    compile_shader: Callable
    get_shaderiv: Callable
    get_shader_info_log: Callable
    delete_shader: Callable
    create_program: Callable
    attach_shader: Callable
    detach_shader: Callable
    program_parameteri: Callable
    link_program: Callable
    get_programiv: Callable
    get_program_info_log: Callable
    delete_program: Callable
    get_program_binary: Callable
    program_binary: Callable
    get_active_uniform: Callable
    get_uniform_location: Callable
    use_program: Callable
    dispatch_compute: Callable
    dispatch_compute_indirect: Callable
    bind_buffer: Callable
    get_error: Callable
    get_integerv: Callable
    object_label: Callable
    uniforms: dict          # (base type "f"/"i"/"ui", components) -> glProgramUniform*v
    matrices: dict          # columns -> glProgramUniformMatrix*fv

    @classmethod
    def load(cls, loader: ProcLoader) -> ProgramFunctions:
        def fn(name: str, *argtypes, restype=None):
            return _entry(loader, name, *argtypes, restype=restype)

        return cls(
            create_shader=fn("glCreateShader", _u, restype=_u),
            shader_source=fn("glShaderSource", _u, _i, ctypes.POINTER(_cp), _ip),
            compile_shader=fn("glCompileShader", _u),
            get_shaderiv=fn("glGetShaderiv", _u, _u, _ip),
            get_shader_info_log=fn("glGetShaderInfoLog", _u, _i, _ip, _cp),
            delete_shader=fn("glDeleteShader", _u),
            create_program=fn("glCreateProgram", restype=_u),
            attach_shader=fn("glAttachShader", _u, _u),
            detach_shader=fn("glDetachShader", _u, _u),
            program_parameteri=fn("glProgramParameteri", _u, _u, _i),
            link_program=fn("glLinkProgram", _u),
            get_programiv=fn("glGetProgramiv", _u, _u, _ip),
            get_program_info_log=fn("glGetProgramInfoLog", _u, _i, _ip, _cp),
            delete_program=fn("glDeleteProgram", _u),
            get_program_binary=fn("glGetProgramBinary", _u, _i, _ip, _uptr, _vp),
            program_binary=fn("glProgramBinary", _u, _u, _vp, _i),
            get_active_uniform=fn("glGetActiveUniform", _u, _u, _i, _ip, _ip, _uptr, _cp),
            get_uniform_location=fn("glGetUniformLocation", _u, _cp, restype=_i),
            use_program=fn("glUseProgram", _u),
            dispatch_compute=fn("glDispatchCompute", _u, _u, _u),
            dispatch_compute_indirect=fn("glDispatchComputeIndirect", _iptr),
            bind_buffer=fn("glBindBuffer", _u, _u),
            get_error=fn("glGetError", restype=_u),
            get_integerv=fn("glGetIntegerv", _u, _ip),
            object_label=fn("glObjectLabel", _u, _u, _i, _cp),
            uniforms={(t, n): fn(f"glProgramUniform{n}{t}v", _u, _i, _i, _vp) for t in ("f", "i", "ui") for n in (1, 2, 3, 4)},
            matrices={n: fn(f"glProgramUniformMatrix{n}fv", _u, _i, _i, ctypes.c_ubyte, _vp) for n in (2, 3, 4)},
        )

    def integer(self, pname: int) -> int:
        value = _i(0)
        self.get_integerv(pname, ctypes.byref(value))
        return int(value.value)

    def program_integer(self, program: int, pname: int) -> int:
        value = _i(0)
        self.get_programiv(program, pname, ctypes.byref(value))
        return int(value.value)

    def program_log(self, program: int) -> str:
        size = max(1, self.program_integer(program, GL_INFO_LOG_LENGTH))
        buf = ctypes.create_string_buffer(size)
        self.get_program_info_log(program, size, None, buf)
        return buf.value.decode("utf-8", "replace")

    def shader_log(self, shader: int) -> str:
        size = _i(0)
        self.get_shaderiv(shader, GL_INFO_LOG_LENGTH, ctypes.byref(size))
        buf = ctypes.create_string_buffer(max(1, size.value))
        self.get_shader_info_log(shader, max(1, size.value), None, buf)
        return buf.value.decode("utf-8", "replace")
