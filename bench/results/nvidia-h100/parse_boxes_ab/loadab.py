"""Probe: the loader alone on 100M LAS, warm, 8 and 16 parser threads, every attribute and RGB only; this tree."""
import sys
import time

from bench import data
from bench.load import pipeline, raw_read

path = data.scaled(100_000_000).las
raw_read(path)
t0 = time.perf_counter()
raw_read(path)
raw = time.perf_counter() - t0
for threads in (8, 16):
    for attrs in (None, ("rgb",)):
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            pipeline(path, threads, attributes=attrs)
            times.append(time.perf_counter() - t0)
        best = min(times)
        print(sys.argv[1], f"threads {threads} attrs {'every' if attrs is None else 'rgb'} s {sorted(round(t, 3) for t in times)}"
              f" Mpts/s {100 / best:.1f} raw-read share {raw / best:.2f} (raw {raw:.3f} s)", flush=True)
