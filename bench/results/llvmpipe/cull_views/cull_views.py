"""Probe: is the raster cheaper where batches are culled? bench.raster's 1 M tiled points
(batched word store), 1280x720, compute 32-bit two-pass, one work group a batch, the
index pass over the candidates and over every point: the overview, bench.raster's
close-up, and the overview's camera turned around (every batch culled). GPU ms of a
visibility clear plus the raster (bench.raster.clear_and_draw), and of the clear alone,
medians of 15 after bench.raster's warm-up.

    PYTHONPATH=. python bench/results/llvmpipe/cull_views/cull_views.py
"""
import numpy as np

from bench.raster import clear_and_draw, median_gpu_ms, views
from bench.synthetic import SAMPLE, load, tiled
from progressive import batches
from progressive.camera import Camera, view_uniforms
from progressive.context import create_context
from progressive.passes.raster_compute import ComputeTuning
from progressive.permutation import FillOrder
from progressive.renderer import Raster, Renderer

W, H = 1280, 720
glc = create_context()
cloud = tiled(str(SAMPLE), 1_000_000)
scene, _ = load(glc, cloud, fill=FillOrder.BATCHED)
cams = views(cloud, W / H)
c = cams["overview"]
cams["away"] = Camera(position=c.position, target=tuple(2 * np.asarray(c.position) - np.asarray(c.target)), near=c.near, far=c.far)
for cand in (True, False):
    r = Renderer(glc, cloud.info, cloud.attribute, raster=Raster.COMPUTE32, width=W, height=H, scene=scene,
                 tuning=ComputeTuning(batch_groups=True, vector_loads=False, candidates=cand))
    r.render(cams["overview"], W, H, r.style())
    for name, cam in cams.items():
        u = view_uniforms(cam, cloud.info.origin, W, H)
        culled = 1 - float(np.mean(batches.in_view(scene.store.boxes, u)))
        full = median_gpu_ms(glc, clear_and_draw(r, u), 15)
        clear = median_gpu_ms(glc, r.vis.clear, 15)
        print(f"candidates={cand} {name:9s} culled {culled:.2f} clear+raster {full:.2f} ms clear {clear:.2f} ms", flush=True)
    r.release()
