"""A GPU driver emulated: each raw GL call returns at once (libc's getpid through ctypes),
93 of a frame's 117 holding the GIL (after) or none (before), with Python work between
calls, beside parser threads parsing a real LAS batch of 500,000 points (RGB) again and
again. Frames either in a tight loop or paced to one a 16.6 ms slot.

    PYTHONPATH=. python bench/results/llvmpipe/gil_state_calls/gil_sim.py before|after PARSERS PACE_S WORK

WORK: the Python between two calls (sum(range(WORK)); 3000 is about 5 ms a frame here).
"""

import ctypes
import sys
import threading
import time

import numpy as np

from bench import data
from progressive.loaders.las import open_las

mode, parsers, pace, work = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
address = ctypes.cast(ctypes.CDLL(None).getpid, ctypes.c_void_p).value
releases, holds = ctypes.CFUNCTYPE(ctypes.c_int)(address), ctypes.PYFUNCTYPE(ctypes.c_int)(address)
calls = [holds] * 93 + [releases] * 24 if mode == "after" else [releases] * 117
np.random.default_rng(0).shuffle(calls)

source = open_las(str(data.tiled(2_000_000, False)))
chunks = list(source.chunks(500_000))
origin = np.zeros(3)
stop = False
parsed = [0]


def parse() -> None:
    i = 0
    while not stop:
        parsed[0] += source.parse(chunks[i % len(chunks)], 0, origin, ("rgb",)).count
        i += 1


def frame() -> int:
    x = 0
    for call in calls:
        call()
        x += sum(range(work))
    return x


for _ in range(parsers):
    threading.Thread(target=parse, daemon=True).start()
walls = []
t0 = time.perf_counter()
while time.perf_counter() - t0 < 3.0:
    f0 = time.perf_counter()
    frame()
    walls.append(time.perf_counter() - f0)
    if pace:
        time.sleep(max(0.0, pace - (time.perf_counter() - f0)))
seconds = time.perf_counter() - t0
stop = True
print(f"{mode} parsers {parsers} pace {pace} work {work}: frames/s {len(walls) / seconds:.0f}, frame ms median "
      f"{np.median(walls) * 1e3:.2f} p95 {np.percentile(walls, 95) * 1e3:.2f}, parsed {parsed[0] / seconds / 1e6:.1f} M points/s")
