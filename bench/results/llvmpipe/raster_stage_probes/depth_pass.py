"""Where the 32-bit depth pass's time goes on llvmpipe with the candidates (the index
pass reads the points that lowered or met their pixel's depth): the raster shader's
text patched per variant, every variant of one set timed in one process, rounds
alternating (bench.kernel.alternating). Brute force of the batched word store of the
tiled sample, 1280x720, auto camera; median GPU ms of the raster pass (min-max).
Timing only: a variant that leaves work out draws wrong ids.

    PYTHONPATH=. python bench/results/llvmpipe/raster_stage_probes/depth_pass.py stages|store POINTS ROUNDS
"""
import statistics
import sys

from bench.kernel import alternating, compiled_raster, patched, word_store_renderer
from progressive import programs
from progressive.context import create_context
from progressive.encoding import Precision
from progressive.passes import raster_compute
from progressive.passes.raster_compute import ComputeTuning

HEAD = "layout(local_size_x = 256) in;"
ZERO = HEAD + "\nuniform uint u_zero_probe;"      # never set: 0, which the compiler cannot know
FIRST = "    uint pixel;\n    float depth;\n"
DEPTH = "    uint depth_bits = floatBitsToUint(depth);\n"
LOADS = "            words[j] = held ? point_words(index, levels) : uvec3(HIDDEN_WORD);"
APPEND = "    if (depth_bits <= held) add_candidate(i, slot, pixel, depth_bits);"
ATOMIC = "    if (depth_bits < held) held = atomicMin(visibility[2u * pixel + 1u], depth_bits);"
STORE = "    if (k < u_candidate_capacity) candidates[k] = uvec4(pixel, depth_bits, slot, listed);"
WORDS64 = ("#if DEPTH_PASS\nlayout(std430, binding = BINDING_CANDIDATES) buffer Candidates64 { uint64_t c64[]; };\n"
           "#endif\nvoid add_candidate(")
KEY64 = "c64[CANDIDATE_META / 2u + 2u * k] = (uint64_t(depth_bits) << 32) | uint64_t(slot"
SETS = {
    "stages": {
        "unpatched": [],
        "return before the projection": [(HEAD, ZERO), (FIRST, FIRST + "#if DEPTH_PASS\n    if (record.x == 0x12345u && "
                                                        "record.y == u_zero_probe + 7u) visibility[0] = 0u;\n    return;\n#endif\n")],
        "return before the pixel's read": [(HEAD, ZERO), (DEPTH, DEPTH + "#if DEPTH_PASS\n    if (depth_bits == 0x12345u && "
                                                          "pixel == u_zero_probe + 7u) visibility[0] = 0u;\n    return;\n#endif\n")],
        "no atomicMin (read only)": [(HEAD, ZERO), (ATOMIC, ATOMIC.replace("depth_bits < held)", "depth_bits < held && u_zero_probe == 1u)"))],
        "no candidate appended": [(HEAD, ZERO), (APPEND, APPEND.replace("depth_bits <= held)", "depth_bits <= held && u_zero_probe == 1u)"))],
        "atomicMin without the read before it": [("    uint held = visibility[2u * pixel + 1u];\n" + ATOMIC,
                                                   "    uint held = atomicMin(visibility[2u * pixel + 1u], depth_bits);")],
        "loads doubled": [(HEAD, ZERO), (LOADS, LOADS.replace("point_words(index, levels)", "(point_words(index, levels) | "
                                                              "(point_words(index ^ 1u, levels) & uvec3(u_zero_probe)))"))],
        "loads from a hot 4096": [(LOADS, LOADS.replace("point_words(index, levels)", "point_words(records + (index & 4095u), levels)"))],
    },
    "store": {
        "uvec4 (unpatched)": [],
        "uvec2": [(STORE, "    if (k < u_candidate_capacity) candidates[k].xy = uvec2(pixel, slot);")],
        "one word": [(STORE, "    if (k < u_candidate_capacity) candidates[k].x = pixel ^ slot;")],
        "no store (the counter kept)": [(STORE, "    if (k == 0xFFFFFFF0u) candidates[0].x = pixel ^ slot;")],
        "a 64-bit word and a word": [("void add_candidate(", WORDS64),
                                     (STORE, f"    if (k < u_candidate_capacity) {{ {KEY64}); candidates[k].z = pixel; }}")],
        "a 64-bit word": [("void add_candidate(", WORDS64), (STORE, f"    if (k < u_candidate_capacity) {{ {KEY64} ^ pixel); }}")],
        "a chunk of 4 an invocation": [("void add_candidate(", "uint g_base = 0u, g_used = 4u;\nvoid add_candidate("),
            ("    uint k = atomicAdd(candidate_meta[CANDIDATE_COUNT], 1u);",
             "    if (g_used == 4u) { g_base = atomicAdd(candidate_meta[CANDIDATE_COUNT], 4u); g_used = 0u; }\n    uint k = g_base + g_used++;")],
        "a chunk of 8 an invocation": [("void add_candidate(", "uint g_base = 0u, g_used = 8u;\nvoid add_candidate("),
            ("    uint k = atomicAdd(candidate_meta[CANDIDATE_COUNT], 1u);",
             "    if (g_used == 8u) { g_base = atomicAdd(candidate_meta[CANDIDATE_COUNT], 8u); g_used = 0u; }\n    uint k = g_base + g_used++;")],
        "a chunk of 16 an invocation": [("void add_candidate(", "uint g_base = 0u, g_used = 16u;\nvoid add_candidate("),
            ("    uint k = atomicAdd(candidate_meta[CANDIDATE_COUNT], 1u);",
             "    if (g_used == 16u) { g_base = atomicAdd(candidate_meta[CANDIDATE_COUNT], 16u); g_used = 0u; }\n    uint k = g_base + g_used++;")],
        "skipped where no lane of a group appends": [(APPEND, "    if (anyInvocationARB(depth_bits <= held)) "
                                                               "{ if (depth_bits <= held) add_candidate(i, slot, pixel, depth_bits); }")],
    },
}


def main() -> None:
    variants, points, rounds = SETS[sys.argv[1]], int(sys.argv[2]), int(sys.argv[3])
    size = (1280, 720)
    glc = create_context()
    cam, scene, r, style = word_store_renderer(glc, points, size)
    r.render(cam, *size, style)
    # a variant that leaves a uniform unused loses it: setting it is then skipped
    setitem = programs.ComputeProgram.__setitem__
    programs.ComputeProgram.__setitem__ = lambda self, k, v: setitem(self, k, v) if k in self else None
    compute = raster_compute.shaderlib.compute

    def with_extensions(ctx, name, defines=None, extensions=(), label=None):
        if name == "raster_compute.comp":
            extensions = (*extensions, "GL_ARB_gpu_shader_int64", "GL_ARB_shader_group_vote")
        return compute(ctx, name, defines, extensions, label)

    raster_compute.shaderlib.compute = with_extensions
    rasters = {name: compiled_raster(glc, scene.store, r.vis, patched({"raster_compute.comp": p}),
                                     ComputeTuning(vector_loads=False), atomic64=False) for name, p in variants.items()}
    raster_compute.shaderlib.compute = compute
    r.raster.release()
    ms, _ = alternating(r, rasters, cam, size, style, rounds)
    print(f"{glc.caps.renderer}; {points:,} points, {size[0]}x{size[1]}, {rounds} rounds alternating; median ms (min-max)")
    for name in rasters:
        print(f"{name:42s}", "  ".join(f"{p.value} {statistics.median(ms[name, p]):6.2f} "
                                      f"({min(ms[name, p]):.2f}-{max(ms[name, p]):.2f})" for p in Precision))


main()
