"""Probe: cProfile of a headless view's session open to its first image (100M LAS), after the import."""
import cProfile
import pstats
import time

from bench import data
from bench.startup import frame_until_first_image
from progressive.session import Session, SessionOptions

path = data.scaled(100_000_000).las
for rep in range(2):
    p = cProfile.Profile()
    t = time.perf_counter()
    p.enable()
    with Session([path], SessionOptions(width=1280, height=720)) as s:
        frame_until_first_image(s, s.auto_camera(), path)
        s.glc.ctx.finish()
        p.disable()
        print(rep, "open to first image", round(time.perf_counter() - t, 3), s.startup, flush=True)
pstats.Stats(p).sort_stats("cumulative").print_stats(35)
pstats.Stats(p).sort_stats("tottime").print_stats(20)
