"""llvmpipe: where the 32-bit depth pass's time goes at HEAD (candidates), variants patched, rounds alternating."""
import statistics, sys
import numpy as np
from bench.kernel import alternating, compiled_raster, patched, word_store_renderer
from progressive import programs
from progressive.context import create_context
from progressive.encoding import Precision
from progressive.passes.raster_compute import ComputeTuning

_set = programs.ComputeProgram.__setitem__
def lenient(self, key, value):
    if key in self._members:
        _set(self, key, value)
programs.ComputeProgram.__setitem__ = lenient

points, rounds = int(sys.argv[1]), int(sys.argv[2])
W, H = 1280, 720
glc = create_context()
cam, scene, r, style = word_store_renderer(glc, points, (W, H))
r.render(cam, W, H, style)
HEAD = "layout(local_size_x = 256) in;"
Z = HEAD + "\nuniform uint u_zero_probe;"
FIRST = "    uint pixel;\n    float depth;\n"
DEPTH = "    uint depth_bits = floatBitsToUint(depth);\n"
LOADS = "            words[j] = held ? point_words(index, levels) : uvec3(HIDDEN_WORD);"
CAND = "    if (depth_bits <= held) add_candidate(i, slot, pixel, depth_bits);"
ATOM = "    if (depth_bits < held) held = atomicMin(visibility[2u * pixel + 1u], depth_bits);"
SINK = "if (record.x == 0x12345u && record.y == u_zero_probe + 7u) visibility[0] = 0u;\n    return;\n"
VARIANTS = {
    "unpatched": [],
    "return before projection": [(HEAD, Z), (FIRST, FIRST + "#if DEPTH_PASS\n    " + SINK + "#endif\n")],
    "return before the pixel's read": [(HEAD, Z), (DEPTH, DEPTH + "#if DEPTH_PASS\n    if (depth_bits == 0x12345u && pixel == u_zero_probe + 7u) visibility[0] = 0u;\n    return;\n#endif\n")],
    "no atomicMin (read only)": [(ATOM, "    if (depth_bits < held && u_zero_probe == 1u) held = atomicMin(visibility[2u * pixel + 1u], depth_bits);"), (HEAD, Z)],
    "no candidate append": [(CAND, "    if (depth_bits <= held && u_zero_probe == 1u) add_candidate(i, slot, pixel, depth_bits);"), (HEAD, Z)],
    "loads doubled": [(HEAD, Z), (LOADS, "            words[j] = held ? (point_words(index, levels) | (point_words(index ^ 1u, levels) & uvec3(u_zero_probe))) : uvec3(HIDDEN_WORD);")],
    "loads from a hot 4096": [(LOADS, "            words[j] = held ? point_words(records + (index & 4095u), levels) : uvec3(HIDDEN_WORD);")],
}
rasters = {name: compiled_raster(glc, scene.store, r.vis, patched({"raster_compute.comp": p}), ComputeTuning(vector_loads=False),
                                 atomic64=False) for name, p in VARIANTS.items()}
r.raster.release()
ms, slots = alternating(r, rasters, cam, (W, H), style, rounds)
print(f"{glc.caps.renderer}; {points:,} points, {W}x{H}, {rounds} rounds; median ms (min-max)")
for name in rasters:
    print(f"{name:36s}", "  ".join(f"{p.value} {statistics.median(ms[name, p]):6.2f} ({min(ms[name, p]):.2f}-{max(ms[name, p]):.2f})" for p in Precision))
