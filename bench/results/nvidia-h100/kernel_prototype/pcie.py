"""Where the GPU side of loading is bound. A persistently mapped, coherent buffer (the
staging ring's kind) of MIB MiB: a compute shader reading it in place, glCopyNamedBufferSubData
into a device buffer, the same shader reading a device buffer; and the host writing into
the mapping (numpy copyto) with 1 to 16 threads.

    python pcie.py MIB OUT.json
"""
import json
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from progressive.context import create_context

READ = """#version 450
layout(local_size_x = 256) in;
layout(std430, binding = 0) readonly buffer P { uvec4 p[]; };
layout(std430, binding = 1) writeonly buffer O { uint o[]; };
uniform uint u_n;
void main() {
    uint stride = gl_NumWorkGroups.x * 256u;
    uvec4 a = uvec4(0u);
    for (uint i = gl_GlobalInvocationID.x; i < u_n; i += stride) a ^= p[i];
    if (a.x == 7u && a.y == 9u && a.z == 3u) o[0] = a.w;
}
"""


def median_s(fn: Callable[[], None], finish: Callable[[], None], repeats: int = 5) -> float:
    fn()
    finish()
    t = []
    for _ in range(repeats):
        finish()
        t0 = time.perf_counter()
        fn()
        finish()
        t.append(time.perf_counter() - t0)
    return float(np.median(t))


def main() -> None:
    size, out = int(sys.argv[1]) << 20, sys.argv[2]
    glc = create_context()
    ctx = glc.ctx
    mapped = glc.gl.storage.mapped(size)
    staged = ctx.external_buffer(mapped.glo, mapped.size)
    device = ctx.buffer(reserve=size)
    sink = ctx.buffer(reserve=16)
    prog = ctx.compute_shader(READ)
    prog["u_n"] = size // 16
    src = np.random.default_rng(0).integers(0, 1 << 32, size // 4, dtype=np.uint32)
    mapped.words[:] = src
    glc.gl.storage.flush(mapped, 0, size)
    device.write(src.tobytes())

    def read(buf) -> Callable[[], None]:
        def run() -> None:
            buf.bind_to_storage_buffer(0)
            sink.bind_to_storage_buffer(1)
            prog.run(4096)
        return run

    res = {"renderer": ctx.info["GL_RENDERER"], "bytes": size}
    res["shader reads mapped GB/s"] = size / median_s(read(staged), ctx.finish) / 1e9
    res["copy mapped -> device GB/s"] = size / median_s(lambda: ctx.copy_buffer(device, staged, size=size), ctx.finish) / 1e9
    res["shader reads device GB/s"] = size / median_s(read(device), ctx.finish) / 1e9
    for threads in (1, 2, 4, 8, 16):
        edges = np.linspace(0, src.size, threads + 1).astype(int)
        with ThreadPoolExecutor(threads) as pool:
            def host(pool=pool, edges=edges, threads=threads) -> None:
                list(pool.map(lambda k: np.copyto(mapped.words[edges[k]:edges[k + 1]], src[edges[k]:edges[k + 1]]),
                              range(threads)))
            res[f"host copy into mapping, {threads} threads GB/s"] = size / median_s(host, lambda: None) / 1e9
    print(json.dumps(res, indent=1))
    with open(out, "w") as f:
        json.dump(res, f, indent=1)
    glc.gl.storage.release(mapped)


main()
