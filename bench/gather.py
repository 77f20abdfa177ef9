"""Random against sequential reads from the shuffled store: what a visible-set pass
(reproject, resolve) pays per point it looks up."""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.context import create_context
from progressive.gpu import grid
from progressive.pointstore import PointStore

KERNEL = """
layout(local_size_x = 256) in;
#include "common.glsl"
#include "points.glsl"
layout(std430, binding = BINDING_SLOT_LIST) readonly buffer L { uint slots[]; };
layout(std430, binding = BINDING_COUNTERS) buffer O { uint out_words[]; };
uniform uint u_count;
void main() {
    uint i;
    if (!range_index(u_count, i)) return;
    uvec4 r = load_point(slots[i]);
    if (r.x == 12345u && r.y == 678u) out_words[0] = r.z;
}
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, nargs="+", default=[1_000_000])
    ap.add_argument("--lookups", type=int, default=400_000)
    args = ap.parse_args(argv)
    glc = create_context()
    ctx = glc.ctx
    results = []
    for n in args.points:
        store = PointStore(glc, n)
        src = shaderlib.source("common.glsl", store.defines)
        program = ctx.compute_shader(src.replace(shaderlib.shader_text("common.glsl"), "") +
                                     KERNEL.replace('#include "common.glsl"', shaderlib.shader_text("common.glsl"))
                                     .replace('#include "points.glsl"', shaderlib.shader_text("points.glsl")))
        out = ctx.buffer(reserve=16)
        rng = np.random.default_rng(0)
        for name, slots in (("sequential", np.arange(args.lookups, dtype=np.uint32)),
                            ("random", rng.integers(0, n, args.lookups, dtype=np.uint32)),
                            ("random sorted", np.sort(rng.integers(0, n, args.lookups, dtype=np.uint32)))):
            buf = ctx.buffer(slots.tobytes())
            buf.bind_to_storage_buffer(Binding.SLOT_LIST)
            out.bind_to_storage_buffer(Binding.COUNTERS)
            store.bind()
            program["u_count"] = args.lookups
            times = []
            for _ in range(6):
                ctx.finish()
                t0 = time.perf_counter()
                program.run(*grid(args.lookups))
                ctx.finish()
                times.append((time.perf_counter() - t0) * 1e3)
            results.append({"points": n, "order": name, "lookups": args.lookups, "ms": float(np.median(times[1:]))})
            print(json.dumps(results[-1]), flush=True)
            buf.release()
        store.release()
    print(glc.caps.description)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
