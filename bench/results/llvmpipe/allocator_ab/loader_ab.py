"""Probe: the loader alone (bench.load.pipeline) over one file, best and median of 5; this tree."""
import statistics
import sys
import time
from pathlib import Path

from bench.load import pipeline, raw_read

label, path, threads = sys.argv[1], Path(sys.argv[2]), int(sys.argv[3])
raw_read(path)
for attrs in (None, ("rgb",)):
    times = []
    for _ in range(int(sys.argv[4]) if len(sys.argv) > 4 else 5):
        t0 = time.perf_counter()
        pipeline(path, threads, attributes=attrs)
        times.append(time.perf_counter() - t0)
    print(f"{label} {path.name} threads {threads} {'every' if attrs is None else 'rgb'}: median "
          f"{statistics.median(times):.3f} s, best {min(times):.3f} s", flush=True)
