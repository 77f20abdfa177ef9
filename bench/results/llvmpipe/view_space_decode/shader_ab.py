"""Brute-force raster ms of two shader trees side by side in one process, rounds
alternating: the batched word store of a tiled cloud, compute raster (the 32-bit
two-pass path on llvmpipe), 1280x720, auto camera, exact and adaptive precision;
median GPU ms of the raster pass and the pixels whose slot differs from the first tree's.

    PYTHONPATH=. python bench/results/llvmpipe/view_space_decode/shader_ab.py BEFORE_SHADERS AFTER_SHADERS POINTS ROUNDS
"""
import statistics
import sys
from pathlib import Path

import numpy as np

from bench.synthetic import SAMPLE, load, tiled
from progressive import shaderlib
from progressive.camera import auto_camera
from progressive.context import create_context
from progressive.encoding import Encoding, Precision
from progressive.passes.cull import CullPass
from progressive.passes.raster_compute import ComputeRaster, ComputeTuning
from progressive.permutation import FillOrder
from progressive.pointstore import RecordOrder
from progressive.renderer import Renderer

before, after, points, rounds = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
W, H = 1280, 720
glc = create_context()
cloud = tiled(str(SAMPLE), points)
cam = auto_camera(cloud.info.bounds_min, cloud.info.bounds_max, W / H)
scene, _ = load(glc, cloud, fill=FillOrder.BATCHED, records=RecordOrder.BATCHES, position_encoding=Encoding.WORDS)
r = Renderer(glc, cloud.info, cloud.attribute, width=W, height=H, scene=scene)
style = r.style()
original = shaderlib.shader_text


def raster_of(tree: Path) -> ComputeRaster:
    shaderlib.shader_text = lambda name: (tree / name).read_text()
    try:
        return ComputeRaster(glc, scene.store, r.vis, atomic64=glc.caps.atomic_int64, culling=CullPass(glc, scene.store),
                             tuning=ComputeTuning(vector_loads=False))
    finally:
        shaderlib.shader_text = original


trees = {"before": raster_of(before), "after": raster_of(after)}
r.raster.release()
ms = {(t, p): [] for t in trees for p in Precision}
slots = {}
for k in range(rounds + 1):
    for name, raster in trees.items():
        r.raster = raster
        for p in Precision:
            frame = r.render(cam, W, H, style, precision=p)
            if k:
                ms[name, p].append(frame.gpu_ms["raster"])
            else:
                slots[name, p] = frame.slots.copy()
print(f"{glc.caps.renderer}; {points:,} points, {W}x{H}, {rounds} rounds alternating")
for name in trees:
    for p in Precision:
        t = ms[name, p]
        differ = int(np.count_nonzero(slots[name, p] != slots["before", p]))
        print(f"{name:6s} {p.value:8s} median {statistics.median(t):6.2f} ms  (min {min(t):6.2f}, max {max(t):6.2f})  "
              f"pixels differing from before: {differ}")
