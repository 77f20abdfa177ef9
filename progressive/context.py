"""One factory for OpenGL contexts (headless EGL or a glfw window) and the record of
what the implementation can do, so passes choose their path from facts, not names."""

from __future__ import annotations

import enum
import os
from dataclasses import dataclass, field
from pathlib import Path

import moderngl

from progressive.errors import GLCapabilityError
from progressive.glext import (
    GL_GPU_MEMORY_INFO_CURRENT_AVAILABLE_VIDMEM_NVX,
    GL_GPU_MEMORY_INFO_TOTAL_AVAILABLE_MEMORY_NVX,
    LIBEGL,
    LIBGL,
    GLFunctions,
    ProgramFunctions,
    egl_proc_loader,
)
from progressive.programs import Programs, cache_directory

REQUIRED_VERSION = 450


class Backend(enum.Enum):
    HEADLESS = "egl"
    WINDOW = "glfw"


SOFTWARE_RENDERERS = ("llvmpipe", "softpipe", "swiftshader", "swrast")
"""Renderer names (lower case) of rasterizers that run on the CPU."""


@dataclass(frozen=True)
class Capabilities:
    vendor: str
    renderer: str
    version: str
    atomic_int64: bool          # GL_NV_shader_atomic_int64: one 64-bit atomicMin per point
    shader_int64: bool          # GL_ARB_gpu_shader_int64: exact 64-bit permutation arithmetic
    shader_ballot: bool         # GL_ARB_shader_ballot: a subgroup's invocations meet without a barrier
    query_buffer: bool          # GL_ARB_query_buffer_object: timestamps into buffers
    timer_query: bool
    max_ssbo_bytes: int
    max_compute_groups: tuple[int, int, int]
    max_compute_invocations: int
    max_compute_ssbo_blocks: int
    total_memory_kib: int | None    # NVX memory info, where present
    free_memory_kib: int | None

    @property
    def description(self) -> str:
        return f"{self.renderer} ({self.version})"

    @property
    def software(self) -> bool:
        """A rasterizer running on the CPU (Mesa's llvmpipe or softpipe, SwiftShader)."""
        return any(name in self.renderer.lower() for name in SOFTWARE_RENDERERS)

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def _positive_limit(value: int) -> int:
    """Drivers report 2 GiB and more as a wrapped GLint; anything not positive means 'at least 2^31 - 1'."""
    value = int(value)
    return value if value > 0 else 2**31 - 1


def read_capabilities(ctx: moderngl.Context, gl: GLFunctions) -> Capabilities:
    ext = ctx.extensions
    info = ctx.info
    has_nvx = "GL_NVX_gpu_memory_info" in ext
    return Capabilities(
        vendor=info["GL_VENDOR"],
        renderer=info["GL_RENDERER"],
        version=info["GL_VERSION"],
        atomic_int64="GL_NV_shader_atomic_int64" in ext,
        shader_int64="GL_ARB_gpu_shader_int64" in ext,
        shader_ballot="GL_ARB_shader_ballot" in ext,
        query_buffer="GL_ARB_query_buffer_object" in ext or ctx.version_code >= 440,
        timer_query="GL_ARB_timer_query" in ext or ctx.version_code >= 330,
        max_ssbo_bytes=_positive_limit(info["GL_MAX_SHADER_STORAGE_BLOCK_SIZE"]),
        max_compute_groups=tuple(int(v) for v in info["GL_MAX_COMPUTE_WORK_GROUP_COUNT"]),
        max_compute_invocations=int(info["GL_MAX_COMPUTE_WORK_GROUP_INVOCATIONS"]),
        max_compute_ssbo_blocks=int(info["GL_MAX_COMPUTE_SHADER_STORAGE_BLOCKS"]),
        total_memory_kib=gl.integer(GL_GPU_MEMORY_INFO_TOTAL_AVAILABLE_MEMORY_NVX) if has_nvx else None,
        free_memory_kib=gl.integer(GL_GPU_MEMORY_INFO_CURRENT_AVAILABLE_VIDMEM_NVX) if has_nvx else None,
    )


@dataclass
class GLContext:
    """A current context with its raw entry points and capabilities."""

    ctx: moderngl.Context
    gl: GLFunctions
    caps: Capabilities
    programs: Programs
    window: object | None = None
    _released: bool = field(default=False, repr=False)

    def check(self) -> None:
        """Raise on a pending GL error (tests call this after each pass)."""
        err = self.ctx.error
        if err != "GL_NO_ERROR":
            raise RuntimeError(f"OpenGL error: {err}")

    def release(self) -> None:
        if self._released:
            return
        self._released = True
        self.ctx.release()
        if self.window is not None:
            import glfw

            glfw.destroy_window(self.window)


def create_context(backend: Backend = Backend.HEADLESS, *, size: tuple[int, int] = (1280, 720),
                   title: str = "progressive", visible: bool = True,
                   program_cache: Path | None | bool = True) -> GLContext:
    """A GL 4.5 context; a clear error names what is missing when there is none.
    program_cache: True: the directory the environment gives (progressive/programs.py),
    a Path: that directory, None or False: compile every program."""
    window = None
    if backend is Backend.HEADLESS:
        try:
            ctx = moderngl.create_standalone_context(require=REQUIRED_VERSION, backend="egl", libgl=LIBGL, libegl=LIBEGL)
        except Exception as exc:  # glcontext raises plain Exceptions with driver text
            raise GLCapabilityError(f"no headless OpenGL 4.5 context through EGL: {exc}") from None
        loader = egl_proc_loader()
    else:
        window, ctx, loader = _glfw_context(size, title, visible)
    if ctx.version_code < REQUIRED_VERSION:
        version = ctx.info["GL_VERSION"]
        ctx.release()
        raise GLCapabilityError(f"OpenGL 4.5 is required (compute shaders, direct state access); this driver offers {version}")
    gl = GLFunctions.load(loader)
    caps = read_capabilities(ctx, gl)
    directory = cache_directory(os.environ) if program_cache is True else (program_cache or None)
    programs = Programs(ProgramFunctions.load(loader), program_key(caps), directory)
    ctx.extra = programs     # moderngl's slot for user data: shaderlib.compute reaches it from ctx alone
    return GLContext(ctx=ctx, gl=gl, caps=caps, programs=programs, window=window)


def program_key(caps: Capabilities) -> str:
    """What a program binary is valid for besides its source."""
    return f"{caps.vendor}\n{caps.renderer}\n{caps.version}"


def _glfw_context(size: tuple[int, int], title: str, visible: bool):
    import glfw

    if not glfw.init():
        raise GLCapabilityError("glfw could not initialise a window system (is a display available?)")
    glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 4)
    glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 5)
    glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
    glfw.window_hint(glfw.VISIBLE, glfw.TRUE if visible else glfw.FALSE)
    window = glfw.create_window(size[0], size[1], title, None, None)
    if not window:
        raise GLCapabilityError("could not open an OpenGL 4.5 core window (glfw)")
    glfw.make_context_current(window)
    ctx = moderngl.create_context(require=REQUIRED_VERSION)
    return window, ctx, lambda name: glfw.get_proc_address(name) or 0
