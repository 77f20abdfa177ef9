"""What an empty dispatch costs llvmpipe: a compute program of 256 invocations a group
whose every invocation returns at once, dispatched with 98 groups (directly and
indirectly) and indirectly with none, 100 times between glFinish, three rounds.

    PYTHONPATH=. python bench/results/llvmpipe/index_candidates/dispatch_cost.py
"""

import time

import numpy as np

from progressive.context import create_context

SOURCE = """#version 450
layout(local_size_x = 256) in;
layout(std430, binding = 0) buffer B { uint b[]; };
void main() { if (b[0] == 12345u) return; b[gl_GlobalInvocationID.x + 16u] = 1u; }"""


def per_dispatch_ms(ctx, dispatch) -> float:
    best = float("inf")
    for _ in range(3):
        ctx.finish()
        t0 = time.perf_counter()
        for _ in range(100):
            dispatch()
            ctx.memory_barrier()
        ctx.finish()
        best = min(best, (time.perf_counter() - t0) / 100 * 1e3)
    return best


def main() -> None:
    glc = create_context()
    ctx = glc.ctx
    program = ctx.compute_shader(SOURCE)
    ctx.buffer(np.array([12345], np.uint32).tobytes()).bind_to_storage_buffer(0)
    none = ctx.buffer(np.array([0, 1, 1], np.uint32).tobytes())
    groups = ctx.buffer(np.array([98, 1, 1], np.uint32).tobytes())
    print(ctx.info["GL_RENDERER"])
    for name, dispatch in (("98 groups, direct", lambda: program.run(98, 1, 1)),
                           ("98 groups, indirect", lambda: program.run_indirect(groups)),
                           ("no group, indirect", lambda: program.run_indirect(none))):
        print(f"{name}: {per_dispatch_ms(ctx, dispatch):.4f} ms a dispatch (least of 3 rounds of 100)")


if __name__ == "__main__":
    main()
