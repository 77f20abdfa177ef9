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

from bench.kernel import alternating, compiled_raster, word_store_renderer
from progressive.context import create_context
from progressive.encoding import Precision
from progressive.passes.raster_compute import ComputeTuning

before, after, points, rounds = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
W, H = 1280, 720
glc = create_context()
cam, scene, r, style = word_store_renderer(glc, points, (W, H))


def raster_of(tree: Path):
    return compiled_raster(glc, scene.store, r.vis, lambda name, _: (tree / name).read_text(),
                           ComputeTuning(vector_loads=False), atomic64=glc.caps.atomic_int64)


trees = {"before": raster_of(before), "after": raster_of(after)}
r.raster.release()
ms, slots = alternating(r, trees, cam, (W, H), style, rounds)
print(f"{glc.caps.renderer}; {points:,} points, {W}x{H}, {rounds} rounds alternating")
for name in trees:
    for p in Precision:
        t = ms[name, p]
        differ = int(np.count_nonzero(slots[name, p] != slots["before", p]))
        print(f"{name:6s} {p.value:8s} median {statistics.median(t):6.2f} ms  (min {min(t):6.2f}, max {max(t):6.2f})  "
              f"pixels differing from before: {differ}")
