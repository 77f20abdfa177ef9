"""Each pass of a progressive frame timed in isolation: glFinish before and after,
wall-clock on the CPU. Slower than the pipelined frame, but unambiguous about
where GPU time goes (timestamps attribute overlapping work to neighbouring passes).
Also what each screen-space effect adds to resolve, since they run only when asked."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from bench.synthetic import add_cloud_args, setup
from progressive.budget import BudgetParams
from progressive.camera import auto_camera, view_uniforms
from progressive.effects import Effects, EyeDome
from progressive.frame_loop import ProgressiveOptions, ProgressiveRenderer
from progressive.passes.budget import Stamp

EFFECTS = {"point size 3": Effects(point_size=3), "point size 7": Effects(point_size=7),
           "eye-dome lighting": Effects(eye_dome=EyeDome()),
           "point size 3 + eye-dome lighting": Effects(point_size=3, eye_dome=EyeDome())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    add_cloud_args(ap)
    ap.add_argument("--budget", type=int, default=10_000_000)
    args = ap.parse_args(argv)
    s = setup(args)
    glc, cloud, scene, width, height = s.glc, s.cloud, s.scene, s.width, s.height
    r = ProgressiveRenderer(glc, cloud.info, cloud.attribute,
                            ProgressiveOptions(width, height, budget=BudgetParams(fixed=args.budget)), scene=scene)
    cam = auto_camera(cloud.info.bounds_min, cloud.info.bounds_max, width / height)
    style = scene.style()
    for _ in range(5):
        r.frame(cam, style)
    view = view_uniforms(cam, cloud.info.origin, width, height)
    ctx = glc.ctx
    rows: dict[str, list[float]] = {}

    def timed(name, fn):
        ctx.finish()
        t0 = time.perf_counter()
        fn()
        ctx.finish()
        rows.setdefault(name, []).append((time.perf_counter() - t0) * 1e3)

    b, raster = r.budget, r.raster
    for _ in range(7):
        timed("clear", r.vis.clear)
        timed("reproject", lambda: [raster.draw_list(view, r.prepare.reprojection, p) for p in range(raster.passes)])
        timed("budget begin", lambda: b.begin(False))
        timed("fill first", lambda: [raster.draw_piece(view, b.pieces, k, p) for p in range(raster.passes) for k in (0, 1)])
        timed("stamp", lambda: b.stamp(Stamp.FILL))
        timed("budget adapt", b.adapt)
        timed("fill rest", lambda: [raster.draw_piece(view, b.pieces, k, p) for p in range(raster.passes) for k in (2, 3)])
        if raster.winners is not None:
            timed("winners", lambda: [raster.draw_list(view, r.prepare.reprojection, raster.passes)]
                  + [raster.draw_piece(view, b.pieces, k, raster.passes) for k in range(4)])
        timed("prepare", lambda: r.prepare.run(winners=raster.winners))
        timed("resolve", lambda: r.shading.resolve.run(style, r.prepare.pixel_words))
        for name, fx in EFFECTS.items():
            timed(f"resolve with {name}", lambda fx=fx: r.shading.run(style, fx, r.prepare.pixel_words))
        timed("brute force", lambda: (r.vis.clear(), raster.draw(view, 0, r.store.capacity)))
        timed("empty", lambda: None)
    med = {k: float(np.median(v[1:])) for k, v in rows.items()}
    lines = [f"# Passes of a progressive frame, timed in isolation ({args.points:,} points, {width}x{height})", "",
             f"Device: {glc.caps.description}  ", f"Fixed budget: {args.budget:,} points a frame", "",
             "glFinish before and after each pass, wall clock, median of 6 after one warm-up; `resolve with X` is "
             "resolve plus the effect (the effects run only when asked: point size 1 and no eye-dome lighting "
             "run neither).", "", "| pass | ms |", "|---|---:|"]
    lines += [f"| {k} | {v:.3f} |" for k, v in med.items()]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"passes_{args.points}.md").write_text("\n".join(lines) + "\n")
    (out / f"passes_{args.points}.json").write_text(json.dumps({"device": glc.caps.description, "points": args.points,
                                                                  "budget": args.budget, "ms": med}, indent=2))
    print(glc.caps.description, args.points, json.dumps(med))
    r.release()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
