"""llvmpipe: the 64-bit four-word walk emulated (atomicMin of uint64 as a plain min, racy),
with and without the quad-keys patch, ids compared."""
import subprocess
import sys

import numpy as np

from bench.kernel import compiled_raster, word_store_renderer
from progressive.context import create_context
from progressive.encoding import Precision
from progressive.passes import raster_compute
from progressive.passes.raster_compute import ComputeTuning

glc = create_context()
size = (640, 360)
cam, scene, r, style = word_store_renderer(glc, int(sys.argv[1]), size)
object.__setattr__(glc.caps, "atomic_int64", True)
compute = raster_compute.shaderlib.compute
def no_nv(ctx, name, defines=None, extensions=(), label=None):
    extensions = tuple(e for e in extensions if e != "GL_NV_shader_atomic_int64")
    return compute(ctx, name, defines, extensions, label)
raster_compute.shaderlib.compute = no_nv
FAKE = ("layout(local_size_x = 256) in;", "layout(local_size_x = 256) in;\n#define atomicMin(A, K) fake_min64(A, K)\n")
FAKEFN = ("#include \"visibility.glsl\"\n", "#include \"visibility.glsl\"\n#ifdef VISIBILITY_64\nuint64_t fake_min64(inout uint64_t a, uint64_t k) { uint64_t o = a; if (k < o) a = k; return o; }\n#endif\n")
quad = subprocess.run(["patch", "-o", "/tmp/rc_quad.comp", "shaders/raster_compute.comp", "bench/results/nvidia-h100/quad_keys/quad_keys.patch"], capture_output=True, text=True)
assert quad.returncode == 0, quad.stdout + quad.stderr
quad_text = open("/tmp/rc_quad.comp").read()
def edit_plain(name, text):
    if name == "raster_compute.comp":
        text = text.replace(*FAKE).replace(*FAKEFN)
    return text
def edit_quad(name, text):
    if name == "raster_compute.comp":
        text = quad_text.replace(*FAKE).replace(*FAKEFN)
    return text
t = ComputeTuning(vector_loads=True, winners=False)
rasters = {"plain": compiled_raster(glc, scene.store, r.vis, edit_plain, t, atomic64=True),
           "quad": compiled_raster(glc, scene.store, r.vis, edit_quad, t, atomic64=True),
           "32-bit": compiled_raster(glc, scene.store, r.vis, lambda n, x: x, ComputeTuning(winners=False), atomic64=False)}
r.raster.release()
out = {}
for name, ras in rasters.items():
    r.raster = ras
    for p in Precision:
        out[name, p] = r.render(cam, *size, style, precision=p).slots.copy()
for p in Precision:
    ref = out["32-bit", p]
    for name in ("plain", "quad"):
        print(p.value, name, "equal share", np.mean(out[name, p] == ref), "covered", int((ref != 0xFFFFFFFF).sum()))
