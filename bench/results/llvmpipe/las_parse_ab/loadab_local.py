"""Probe: the loader alone on the 2M tiled LAS, warm, 2 threads, every attribute and RGB, beside laspy_user; this tree."""
import sys
import time

from bench import data
from bench.load import laspy_user, pipeline, raw_read

path = data.scaled(2_000_000).las
raw_read(path)


def best(fn, k=7):
    times = []
    for _ in range(k):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


lp = best(lambda: laspy_user(path))
every = best(lambda: pipeline(path, 2))
rgb = best(lambda: pipeline(path, 2, attributes=("rgb",)))
print(sys.argv[1], f"laspy {lp:.3f} every {every:.3f} ({lp / every:.2f}x) rgb {rgb:.3f} ({lp / rgb:.2f}x)", flush=True)
