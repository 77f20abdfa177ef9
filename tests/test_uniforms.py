"""Compute program uniforms (progressive/programs.py Uniform): a value set again as it
was makes no GL call, and the shader sees every value set, scalars, vectors and
matrices alike."""

from __future__ import annotations

import dataclasses

import numpy as np

SOURCE = """#version 430
layout(local_size_x = 1) in;
layout(std430, binding = 0) buffer Out { float values[]; };
uniform uint u_count;
uniform vec3 u_offset;
uniform mat4 u_matrix;
void main() {
    values[0] = float(u_count);
    values[1] = u_offset.x + u_offset.y + u_offset.z;
    values[2] = u_matrix[3][1];
}
"""


class Counted:
    """A GL entry point that counts its calls."""

    def __init__(self, fn):
        self.fn, self.calls = fn, 0

    def __call__(self, *args):
        self.calls += 1
        return self.fn(*args)


def test_repeated_values_make_no_call_and_changes_reach_the_shader(gl):
    calls = gl.programs.calls
    counted = dataclasses.replace(calls, uniforms={k: Counted(f) for k, f in calls.uniforms.items()},
                                  matrices={k: Counted(f) for k, f in calls.matrices.items()})
    gl.programs.calls = counted
    try:
        program = gl.programs.compute(SOURCE, "uniform test")
    finally:
        gl.programs.calls = calls
    out = gl.ctx.buffer(reserve=12)
    out.bind_to_storage_buffer(0)

    def run() -> list[float]:
        program.run(1)
        gl.ctx.memory_barrier()
        return np.frombuffer(out.read(), dtype=np.float32).tolist()

    def made() -> int:
        return sum(f.calls for f in (*counted.uniforms.values(), *counted.matrices.values()))

    matrix = np.eye(4, dtype=np.float32)
    matrix[3, 1] = 5.0          # column 3, row 1 in GLSL (moderngl's column-major bytes)
    program["u_count"], program["u_offset"], program["u_matrix"] = 7, (1.0, 2.0, 3.5), matrix.ravel()
    assert made() == 3 and run() == [7.0, 6.5, 5.0]
    program["u_count"], program["u_offset"], program["u_matrix"] = 7, [1.0, 2.0, 3.5], tuple(matrix.ravel())
    assert made() == 3 and run() == [7.0, 6.5, 5.0]
    matrix[3, 1] = -2.0
    program["u_count"], program["u_matrix"] = 8, matrix.ravel()
    program["u_offset"].write(np.float32([1.0, 2.0, 3.5]).tobytes())
    assert made() == 5 and run() == [8.0, 6.5, -2.0]
    out.release()
    program.release()
    gl.check()
