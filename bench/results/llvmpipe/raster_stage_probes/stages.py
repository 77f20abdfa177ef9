"""Where the 32-bit two-pass raster's time goes on llvmpipe, and three ideas tried: the
raster shader's text patched per variant (as bench/kernel.py patches the 64-bit walk),
every variant timed in one process with rounds alternating. Brute force of the batched
word store of the tiled sample, 1280x720, auto camera, one word a load; median GPU ms
of the raster pass, pixels whose slot differs from the unpatched shader's.

    PYTHONPATH=. python bench/results/llvmpipe/raster_stage_probes/stages.py POINTS ROUNDS
"""
import ctypes
import statistics
import sys

import numpy as np

from bench.kernel import alternating, compiled_raster, patched, word_store_renderer
from progressive.context import create_context
from progressive.encoding import Precision
from progressive.glext import _entry, egl_proc_loader
from progressive.passes.raster_compute import ComputeTuning

points, rounds = int(sys.argv[1]), int(sys.argv[2])
W, H = 1280, 720
glc = create_context()
cam, scene, r, style = word_store_renderer(glc, points, (W, H))
r.render(cam, W, H, style)

# The visibility buffer also bound as a buffer texture (r32ui) on unit 7, for the texelFetch variant.
UNIT = 7
loader = egl_proc_loader()
gen = _entry(loader, "glGenTextures", ctypes.c_int, ctypes.POINTER(ctypes.c_uint))
bind = _entry(loader, "glBindTexture", ctypes.c_uint, ctypes.c_uint)
tex_buffer = _entry(loader, "glTexBuffer", ctypes.c_uint, ctypes.c_uint, ctypes.c_uint)
active = _entry(loader, "glActiveTexture", ctypes.c_uint)
texture = ctypes.c_uint()
gen(1, ctypes.byref(texture))
active(0x84C0 + UNIT)
bind(0x8C2A, texture.value)
tex_buffer(0x8C2A, 0x8236, r.vis.buffer.glo)
active(0x84C0)

HEAD = "layout(local_size_x = 256) in;"
FIRST = "    uint pixel;\n    float depth;\n"
DEPTH = "    uint depth_bits = floatBitsToUint(depth);\n"
DEPTH_TEST = "    if (depth_bits < visibility[2u * pixel + 1u]) atomicMin(visibility[2u * pixel + 1u], depth_bits);"
INDEX_TEST = ("    if (depth_bits == visibility[2u * pixel + 1u] && slot < visibility[2u * pixel]\n"
              "        && slot < atomicMin(visibility[2u * pixel], slot)) {")
READS_ONLY = [(DEPTH_TEST, "    if (depth_bits < visibility[2u * pixel + 1u] && pixel == 0xFFFFFFF0u) visibility[0] = 0u;"),
              (INDEX_TEST, "    if (depth_bits == visibility[2u * pixel + 1u] && slot < visibility[2u * pixel]\n"
                           "        && pixel == 0xFFFFFFF0u) { visibility[1] = 0u;")]
VARIANTS = {
    "unpatched": [],
    "loads and decode only (return before the projection)":
        [(FIRST, FIRST + "#ifndef WINNERS\n    if (record.x == 0x12345u && record.y == 7u) visibility[0] = 0u;\n    return;\n#endif\n")],
    "+ projection (return before the pixel's read)":
        [(DEPTH, DEPTH + "    if (depth_bits == 0x12345u && pixel == 7u) visibility[0] = 0u;\n    return;\n")],
    "+ reads (no atomics)": READS_ONLY,
    "+ reads through a buffer texture (no atomics)":
        [(HEAD, HEAD + "\nuniform usamplerBuffer u_vis_tex;\n#define VIS(k) texelFetch(u_vis_tex, int(k)).x")]
        + [(old, new.replace("visibility[2u * pixel + 1u]", "VIS(2u * pixel + 1u)").replace("slot < visibility[2u * pixel]", "slot < VIS(2u * pixel)"))
           for old, new in READS_ONLY],
    "atomics made plain stores": [(DEPTH_TEST, DEPTH_TEST.replace("atomicMin(visibility[2u * pixel + 1u], depth_bits)",
                                                                   "visibility[2u * pixel + 1u] = depth_bits")),
                                  (INDEX_TEST, INDEX_TEST.replace("\n        && slot < atomicMin(visibility[2u * pixel], slot)) {",
                                                                  ") { visibility[2u * pixel] = slot;"))],
    "index pass reads slot and depth as one uvec2":
        [(HEAD, HEAD + "\nlayout(std430, binding = BINDING_VISIBILITY) buffer VisibilityPairs { uvec2 visibility_pairs[]; };"),
         (INDEX_TEST, INDEX_TEST.replace("    if (depth_bits == visibility[2u * pixel + 1u] && slot < visibility[2u * pixel]",
                                         "    uvec2 held = visibility_pairs[pixel];\n    if (depth_bits == held.y && slot < held.x"))],
}
rasters = {name: compiled_raster(glc, scene.store, r.vis, patched({"raster_compute.comp": patches}),
                                 ComputeTuning(vector_loads=False), atomic64=False) for name, patches in VARIANTS.items()}
for raster in rasters.values():
    for program in raster._programs.values():
        if "u_vis_tex" in program:
            program["u_vis_tex"] = UNIT
r.raster.release()
ms, slots = alternating(r, rasters, cam, (W, H), style, rounds)
print(f"{glc.caps.renderer}; {points:,} points, {W}x{H}, {rounds} rounds alternating; ms median (min-max), pixels differing")
for name in rasters:
    cells = [f"{p.value} {statistics.median(ms[name, p]):6.2f} ({min(ms[name, p]):.2f}-{max(ms[name, p]):.2f}) "
             f"{int(np.count_nonzero(slots[name, p] != slots['unpatched', p])):>6}" for p in Precision]
    print(f"{name:55s} " + "  ".join(cells))
