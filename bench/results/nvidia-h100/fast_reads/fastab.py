"""Probe: the fast-format loader alone at 100M, this process's tree (old or new, swapped by the caller)."""
import sys
import time

from bench import data
from bench.load import pipeline, raw_read

files = data.scaled(100_000_000)
path = dict(files.formats())["fast"]
raw_read(path)
for threads in (8, 16):
    t = time.perf_counter()
    raw_read(path)
    r = time.perf_counter() - t
    t = time.perf_counter()
    pipeline(path, threads)
    p = time.perf_counter() - t
    print(f"{sys.argv[1]} threads {threads}: raw {r:.3f} s, loader {p:.3f} s, share of raw {r / p:.2f}", flush=True)
