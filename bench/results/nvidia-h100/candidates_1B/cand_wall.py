"""The 32-bit two-pass brute force at N points, 1920x1080 overview, on the batched word
store: each part timed between glFinish (clear, cull and candidates reset, depth pass,
index pass over the candidates or over every point), beside the whole draw's GPU
timestamps and wall clock, one draw between glFinish and REPEATS back to back.

    python cand_wall.py POINTS REPEATS OUT.json
"""
import json
import sys
import time
from collections.abc import Callable

import numpy as np

from bench.kernel import compiled_raster, patched, word_store_renderer
from bench.raster import clear_and_draw, median_gpu_ms
from progressive.camera import view_uniforms
from progressive.context import create_context
from progressive.gpu import grid
from progressive.passes.raster_compute import ComputeRaster, ComputeTuning, Source

SIZE = (1920, 1080)


def wall_ms(glc, fn: Callable[[], None]) -> float:
    glc.ctx.finish()
    t = time.perf_counter()
    fn()
    glc.ctx.finish()
    return (time.perf_counter() - t) * 1e3


def walk(glc, r, raster: ComputeRaster, view, pass_index: int) -> Callable[[], None]:
    """Pass `pass_index` of the batch walk over the whole store."""
    def run() -> None:
        p = raster._prepare(Source.RANGE, pass_index, view)
        p["u_first"] = 0
        p["u_count"] = r.store.capacity
        p.run(*grid(r.store.permutation.batches, local_size=1))
        glc.ctx.memory_barrier()
    return run


def measure(glc, r, view, name: str, candidates: bool, repeats: int) -> dict:
    """One index pass's figures, keyed by `name`."""
    tuning = ComputeTuning(vector_loads=False, winners=False, candidates=candidates)
    raster = compiled_raster(glc, r.store, r.vis, patched({}), tuning, atomic64=False)
    r.raster = raster
    run = clear_and_draw(r, view)
    res = {f"{name}: timestamps ms": median_gpu_ms(glc, run, repeats),
           f"{name}: wall ms": float(np.median([wall_ms(glc, run) for _ in range(repeats)])),
           f"{name}: back to back wall ms": wall_ms(glc, lambda: [run() for _ in range(repeats)]) / repeats}
    index = ((lambda: raster._index_candidates(None, None, mark=False)) if candidates
             else walk(glc, r, raster, view, 1))
    parts = {"clear": r.vis.clear, "cull + reset": lambda: raster.begin_frame(view),
             "depth": walk(glc, r, raster, view, 0), "index": index}
    times = {key: [] for key in parts}
    for _ in range(repeats):
        for key, fn in parts.items():
            times[key].append(wall_ms(glc, fn))
    res.update({f"{name}: {key} wall ms": float(np.median(v)) for key, v in times.items()})
    if candidates:
        res["candidates found"] = raster.candidates_found()
        res["candidate room"] = raster.candidate_capacity(r.vis.pixels)
    raster.release()
    return res


def main() -> None:
    points, repeats, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
    glc = create_context()
    t0 = time.perf_counter()
    cam, scene, r, style = word_store_renderer(glc, points, SIZE)
    print(f"store built in {time.perf_counter() - t0:.1f} s", flush=True)
    view = view_uniforms(cam, r.info.origin, *SIZE)
    res = {"points": points, "renderer": glc.ctx.info["GL_RENDERER"]}
    for name, candidates in (("candidates", True), ("every point", False)):
        res.update(measure(glc, r, view, name, candidates, repeats))
        print(json.dumps(res), flush=True)
    with open(out, "w") as f:
        json.dump(res, f, indent=1)


main()
