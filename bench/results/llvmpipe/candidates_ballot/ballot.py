"""The 32-bit depth pass's candidates appended a subgroup at a time (GL_ARB_shader_ballot:
one atomicAdd on the counter for the subgroup's active lanes, each lane's place its rank
among them) against one atomicAdd a candidate, on the renderer's batch walk: the tiled
sample at 1 M points, 1280x720 overview, brute force (clear and draw), the two in turn,
25 rounds after 5 untimed, wall clock between glFinish.

    python ballot.py
"""
import time

import numpy as np

from bench.kernel import compiled_raster, patched, word_store_renderer
from progressive import shaderlib
from progressive.camera import view_uniforms
from progressive.context import create_context
from progressive.passes.raster_compute import ComputeTuning

SIZE = (1280, 720)
ONE = "    uint k = atomicAdd(candidate_meta[CANDIDATE_COUNT], 1u);\n"
SUBGROUP = """    uint64_t lanes = ballotARB(true);
    uvec2 m = unpackUint2x32(lanes);
    uint leader = m.x != 0u ? uint(findLSB(m.x)) : 32u + uint(findLSB(m.y));
    uint k = 0u;
    if (gl_SubGroupInvocationARB == leader) k = atomicAdd(candidate_meta[CANDIDATE_COUNT], uint(bitCount(m.x) + bitCount(m.y)));
    uvec2 below = unpackUint2x32(gl_SubGroupLtMaskARB & lanes);
    k = readInvocationARB(k, leader) + uint(bitCount(below.x) + bitCount(below.y));
"""


def main() -> None:
    glc = create_context()
    cam, scene, r, style = word_store_renderer(glc, 1_000_000, SIZE)
    view = view_uniforms(cam, r.info.origin, *SIZE)
    tuning = ComputeTuning(vector_loads=False, winners=False, candidates=True)
    rasters = {"one atomicAdd a candidate": compiled_raster(glc, r.store, r.vis, patched({}), tuning, atomic64=False)}
    original = shaderlib.source

    def with_ballot(name, defines=None, extensions=()):
        extra = ("GL_ARB_shader_ballot", "GL_ARB_gpu_shader_int64") if name == "raster_compute.comp" else ()
        return original(name, defines, (*extensions, *extra))

    shaderlib.source = with_ballot
    try:
        rasters["a subgroup at a time"] = compiled_raster(glc, r.store, r.vis, patched({"raster_compute.comp": [(ONE, SUBGROUP)]}),
                                                          tuning, atomic64=False)
    finally:
        shaderlib.source = original
    times = {name: [] for name in rasters}
    ids, found = {}, {}
    for round_ in range(30):
        for name, raster in rasters.items():
            r.raster = raster
            glc.ctx.finish()
            t = time.perf_counter()
            r.vis.clear()
            raster.draw(view, 0, r.store.capacity)
            glc.ctx.finish()
            if round_ >= 5:
                times[name].append((time.perf_counter() - t) * 1e3)
            ids[name], found[name] = r.vis.read().copy(), raster.candidates_found()
    print(glc.ctx.info["GL_RENDERER"])
    for name, v in times.items():
        print(f"{name:28s} ms min {min(v):6.2f} median {np.median(v):6.2f}  candidates {found[name]:,}")
    first, second = ids.values()
    print("same ids:", bool(np.array_equal(first, second)))


main()
