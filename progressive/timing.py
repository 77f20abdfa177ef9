"""GPU timestamps through glQueryCounter (moderngl only has 32-bit TIME_ELAPSED
queries, which cannot nest and wrap after 4.3 s)."""

from __future__ import annotations

import ctypes

from progressive.context import GLContext
from progressive.glext import GL_QUERY_RESULT, GL_TIMESTAMP


class Timestamps:
    """Named GPU timestamps in submission order; pass times are the differences.

    Reading blocks until the GPU has passed the last stamp, so only whole-frame
    renders and benchmarks read them right away."""

    def __init__(self, glc: GLContext, capacity: int = 32):
        self.gl = glc.gl
        self.ids = (ctypes.c_uint * capacity)()
        self.gl.gen_queries(capacity, self.ids)
        self.names: list[str] = []

    def reset(self) -> None:
        self.names = []

    def stamp(self, name: str) -> None:
        """Mark the point after the GPU work of pass `name` (the first stamp is the start)."""
        if len(self.names) >= len(self.ids):
            raise RuntimeError("too many timestamps in one frame")
        self.gl.query_counter(self.ids[len(self.names)], GL_TIMESTAMP)
        self.names.append(name)

    def read_ns(self) -> list[int]:
        out = []
        for i in range(len(self.names)):
            value = ctypes.c_uint64(0)
            self.gl.get_query_object_ui64v(self.ids[i], GL_QUERY_RESULT, ctypes.byref(value))
            out.append(int(value.value))
        return out

    def durations_ms(self) -> dict[str, float]:
        """{pass: ms} from consecutive stamps; the first name marks the start."""
        t = self.read_ns()
        return {self.names[i]: (t[i] - t[i - 1]) / 1e6 for i in range(1, len(t))}

    def release(self) -> None:
        self.gl.delete_queries(len(self.ids), self.ids)
