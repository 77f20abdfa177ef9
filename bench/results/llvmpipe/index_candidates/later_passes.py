"""The GPU time of a progressive frame's passes after its first on llvmpipe with the
32-bit index pass over the candidates: the index pass over the points dispatched with
the arguments the candidates' count writes (no work group where they were held: this
commit), dispatched with the pieces' and the list's own arguments and returning in the
shader where they were held (12ed18f), or not dispatched at all (a bound: wrong where
they overflow). 1 M points of the tiled sample, 640x360, a fixed budget of 100,000
points, 12 frames a renderer (the first two left out), 6 rounds with the modes in turn.

    PYTHONPATH=. python bench/results/llvmpipe/index_candidates/later_passes.py
"""

import statistics

from bench.synthetic import SAMPLE, load, tiled
from progressive.budget import BudgetParams
from progressive.camera import auto_camera
from progressive.context import create_context
from progressive.frame_loop import ProgressiveOptions, ProgressiveRenderer
from progressive.passes.raster_compute import ComputeRaster, ComputeTuning

SIZE = (640, 360)
DRAWS = ("draw_list", "draw_piece", "draw_batches")


def main() -> None:
    glc = create_context()
    cloud = tiled(str(SAMPLE), 1_000_000)
    scene, _ = load(glc, cloud)
    cam = auto_camera(cloud.info.bounds_min, cloud.info.bounds_max, SIZE[0] / SIZE[1])
    original = {name: getattr(ComputeRaster, name) for name in (*DRAWS, "_falls_back")}

    def skipping(name):
        def draw(self, view, *args):
            if self.candidates and args[-1] == 1:
                return None
            return original[name](self, view, *args)
        return draw

    modes = {"indirect arguments from the count": {},
             "own arguments, returning in the shader": {"_falls_back": lambda self, pass_index: False},
             "not dispatched": {name: skipping(name) for name in DRAWS}}
    frames = {mode: [] for mode in modes}
    for _ in range(6):
        for mode, patches in modes.items():
            for name, fn in original.items():
                setattr(ComputeRaster, name, patches.get(name, fn))
            r = ProgressiveRenderer(glc, cloud.info, cloud.attribute, ProgressiveOptions(
                *SIZE, budget=BudgetParams(fixed=100_000), frames_in_flight=2, tuning=ComputeTuning(candidates=True)),
                scene=scene)
            style = scene.style()
            for _ in range(12):
                r.frame(cam, style)
            frames[mode] += [s.as_dict()["gpu_ms"] for s in r.flush()[2:]]
            r.release()
    for name, fn in original.items():
        setattr(ComputeRaster, name, fn)
    print(f"{glc.ctx.info['GL_RENDERER']}; GPU ms, medians over the {len(frames['not dispatched'])} frames "
          "of each mode that timed each pass")
    print("| index pass over the points | frame | fill | first pass | later passes |")
    print("|---|---:|---:|---:|---:|")
    for mode, rows in frames.items():
        med = {k: statistics.median(r[k] for r in rows if r.get(k) is not None)
               for k in ("frame", "fill", "fill first pass", "fill later passes")}
        print(f"| {mode} | {med['frame']:.2f} | {med['fill']:.2f} | {med['fill first pass']:.2f} | "
              f"{med['fill later passes']:.2f} |")


if __name__ == "__main__":
    main()
