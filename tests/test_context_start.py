"""The headless context's start: the GL libraries are opened by soname, never looked for
with ctypes.util.find_library, which runs ldconfig and, where they lie outside its cache
(the GPU machine's), gcc and ld: 47 ms of a profiled start there."""

from __future__ import annotations

import ctypes.util

from progressive.context import create_context


def test_the_headless_context_does_not_look_for_its_libraries(monkeypatch):
    def refuse(name):
        raise AssertionError(f"find_library({name!r}) was called")

    monkeypatch.setattr(ctypes.util, "find_library", refuse)
    glc = create_context(program_cache=None)
    try:
        assert glc.ctx.version_code >= 450
    finally:
        glc.release()
