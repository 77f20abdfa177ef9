"""llvmpipe: the candidate append's cost by its store's width (timing only; ids not kept)."""
import statistics, sys
from bench.kernel import alternating, compiled_raster, patched, word_store_renderer
from progressive import programs
from progressive.context import create_context
from progressive.encoding import Precision
from progressive.passes.raster_compute import ComputeTuning
from progressive.passes import raster_compute as rc
import numpy as np
_set = programs.ComputeProgram.__setitem__
programs.ComputeProgram.__setitem__ = lambda self, k, v: _set(self, k, v) if k in self._members else None

points, rounds = int(sys.argv[1]), int(sys.argv[2])
W, H = 1280, 720
glc = create_context()
cam, scene, r, style = word_store_renderer(glc, points, (W, H))
r.render(cam, W, H, style)
STORE = "    if (k < u_candidate_capacity) candidates[k] = uvec4(pixel, depth_bits, slot, listed);"
U64 = """#if DEPTH_PASS
layout(std430, binding = BINDING_CANDIDATES) buffer Candidates64 { uint64_t c64[]; };
#endif
void add_candidate("""
VARIANTS = {
    "uvec4 (HEAD)": [],
    "uvec2 .xy only": [(STORE, "    if (k < u_candidate_capacity) candidates[k].xy = uvec2(pixel, slot);")],
    "one uint": [(STORE, "    if (k < u_candidate_capacity) candidates[k].x = pixel ^ slot;")],
    "no store": [(STORE, "    if (k == 0xFFFFFFF0u) candidates[0].x = pixel ^ slot;")],
    "uint64 + uint (key, pixel)": [("void add_candidate(", U64),
        (STORE, "    if (k < u_candidate_capacity) { c64[CANDIDATE_META / 2u + 2u * k] = (uint64_t(depth_bits) << 32) | uint64_t(slot); candidates[k].z = pixel; }")],
    "uint64 alone": [("void add_candidate(", U64),
        (STORE, "    if (k < u_candidate_capacity) { c64[CANDIDATE_META / 2u + 2u * k] = (uint64_t(depth_bits) << 32) | uint64_t(slot ^ pixel); }")],
}
orig = rc.shaderlib.compute
def comp(ctx, name, defines=None, extensions=(), label=None):
    if name == "raster_compute.comp":
        extensions = tuple(extensions) + ("GL_ARB_gpu_shader_int64",)
    return orig(ctx, name, defines, extensions, label)
rc.shaderlib.compute = comp
rasters = {name: compiled_raster(glc, scene.store, r.vis, patched({"raster_compute.comp": p}), ComputeTuning(vector_loads=False),
                                 atomic64=False) for name, p in VARIANTS.items()}
rc.shaderlib.compute = orig
r.raster.release()
ms, slots = alternating(r, rasters, cam, (W, H), style, rounds)
print(f"{glc.caps.renderer}; {points:,} points, {W}x{H}, {rounds} rounds; median ms (min-max)")
for name in rasters:
    print(f"{name:30s}", "  ".join(f"{p.value} {statistics.median(ms[name, p]):6.2f} ({min(ms[name, p]):.2f}-{max(ms[name, p]):.2f})" for p in Precision))
