"""The 32-bit raster's index pass over the depth pass's candidates against the index
pass over every point (ComputeTuning.candidates), brute force of the tiled sample in a
batched word store, both rasters timed in one process with rounds alternating.

    PYTHONPATH=. python bench/results/llvmpipe/index_candidates/candidates_ab.py [points] [rounds] [view]

view: overview (the auto camera, the default) or close-up (bench.raster's: one corner
tile from above).
"""

import statistics
import sys

import numpy as np

from bench.kernel import alternating, compiled_raster, patched, word_store_renderer
from bench.raster import close_up
from bench.synthetic import SAMPLE, tiled
from progressive.context import create_context
from progressive.passes.raster_compute import ComputeTuning

SIZE = (1280, 720)


def main() -> None:
    points = int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 9
    view = sys.argv[3] if len(sys.argv) > 3 else "overview"
    glc = create_context()
    cam, scene, r, style = word_store_renderer(glc, points, SIZE)
    if view == "close-up":
        cam = close_up(tiled(str(SAMPLE), points), SIZE[0] / SIZE[1])
    rasters = {name: compiled_raster(glc, scene.store, r.vis, patched({}), ComputeTuning(candidates=on), atomic64=False)
               for name, on in (("every point", False), ("candidates", True))}
    r.raster.release()
    ms, slots = alternating(r, rasters, cam, SIZE, style, rounds)
    print(f"{glc.ctx.info['GL_RENDERER']}; {points:,} points, {SIZE[0]}x{SIZE[1]}, {view}, {rounds} rounds")
    print("| index pass over | precision | median ms | least ms | pixels that differ |")
    print("|---|---|---:|---:|---:|")
    for (name, precision), times in ms.items():
        differ = int(np.count_nonzero(slots[name, precision] != slots["every point", precision]))
        print(f"| {name} | {precision.value} | {statistics.median(times):.2f} | {min(times):.2f} | {differ} |")
    found = rasters["candidates"].candidates_found()
    print(f"candidates of the last frame: {found:,} ({found / points:.1%} of the points)")
    for raster in rasters.values():
        raster.release()
    r.release()
    scene.release()


if __name__ == "__main__":
    main()
