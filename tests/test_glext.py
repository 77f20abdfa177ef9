"""The raw GL entry points: those that only set or read state are called holding the
GIL (no hand-over to another thread for a bind or a uniform), the others release it
while the driver may work or wait. GPU-free: the entry point's address is CPython's
PyGILState_Check, which says whether the calling thread holds the GIL."""

from __future__ import annotations

import ctypes

import pytest

from progressive import glext
from progressive.glext import STATE_CALLS, GLFunctions, ProgramFunctions

GIL_CHECK = ctypes.cast(ctypes.pythonapi.PyGILState_Check, ctypes.c_void_p).value


def holds_gil_in(name: str) -> bool:
    """Whether a call through the entry point made for `name` runs holding the GIL."""
    call = glext._entry(lambda _: GIL_CHECK, name, restype=ctypes.c_int)
    return bool(call())


@pytest.mark.parametrize("name", ["glBindBuffer", "glUseProgram", "glQueryCounter", "glFenceSync", "glDeleteSync",
                                  "glProgramUniform1uiv", "glProgramUniformMatrix4fv"])
def test_state_calls_hold_the_gil(name):
    assert holds_gil_in(name)


@pytest.mark.parametrize("name", ["glDispatchCompute", "glDispatchComputeIndirect", "glDrawArraysIndirect",
                                  "glClientWaitSync", "glCopyNamedBufferSubData", "glClearNamedBufferSubData",
                                  "glLinkProgram", "glGetProgramiv", "glGetError", "glGetQueryObjectui64v"])
def test_calls_that_may_work_or_wait_release_it(name):
    assert not holds_gil_in(name)


def test_state_calls_name_entry_points_the_renderer_loads():
    """A misspelt name would silently release the GIL: each is one the loaders ask for."""
    asked: list[str] = []

    def loader(name: str) -> int:
        asked.append(name)
        return GIL_CHECK        # not called: any address makes the function pointer

    GLFunctions.load(loader)
    ProgramFunctions.load(loader)
    assert STATE_CALLS <= set(asked)


def test_a_query_written_into_a_buffer_holds_it_a_query_read_releases_it():
    """The budget pass's timestamps go into a buffer (the call never waits); timing.py
    reads results back, which waits for the GPU."""
    gl = GLFunctions.load(lambda _: GIL_CHECK)
    holds = ctypes._FUNCFLAG_PYTHONAPI
    assert type(gl.query_into_buffer)._flags_ & holds
    assert not type(gl.get_query_object_ui64v)._flags_ & holds
    assert glext._entry(lambda _: GIL_CHECK, "glGetQueryObjectui64v", restype=ctypes.c_int, state=True)()
