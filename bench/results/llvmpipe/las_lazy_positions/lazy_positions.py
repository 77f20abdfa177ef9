"""Probe, in one process: the loader on a tiled LAS (bench.data.scaled, warm) with the LAS
parse as it is (positions left to the grid: `lazy`) against the same parse followed by
computing the float32 positions, as it did before (`eager`), taking turns, ROUNDS rounds,
the best of REPEATS runs each; `laspy` is bench.load.laspy_user (laspy.read() plus conversion).
Times in ms; `every`: every attribute, `rgb`: RGB alone, at each count of parser threads.

    PYTHONPATH=. python bench/results/llvmpipe/las_lazy_positions/lazy_positions.py [POINTS [THREADS...]]

(defaults: 2,000,000 points, 2 and 1 threads, ROUNDS 5, REPEATS 7: the committed rounds.txt)
"""
import dataclasses
import functools
import os
import sys

from bench import data
from bench.compactness import best_of
from bench.load import laspy_user, pipeline, raw_read
from progressive.loaders import las

points = int(sys.argv[1]) if len(sys.argv) > 1 else 2_000_000
thread_counts = [int(t) for t in sys.argv[2:]] or [2, 1]
path = data.scaled(points, fast=False).las
raw_read(path)
repeats = int(os.environ.get("REPEATS", "7"))
lazy = las.LasSource.parse


def eager(self, *args, **kwargs):
    batch = lazy(self, *args, **kwargs)
    return dataclasses.replace(batch, xyz=batch.grid.positions())


print(f"{path.name}: {points:,} points, parser threads {thread_counts}", flush=True)
for _ in range(int(os.environ.get("ROUNDS", "5"))):
    row = [f"laspy {best_of(repeats, lambda: laspy_user(path)) * 1e3:.1f}"]
    for name, parse in (("eager", eager), ("lazy", lazy)):
        las.LasSource.parse = parse
        for threads in thread_counts:
            for label, names in (("every", None), ("rgb", ("rgb",))):
                seconds = best_of(repeats, functools.partial(pipeline, path, threads, attributes=names))
                row.append(f"{name}-{label}{'' if threads == thread_counts[0] else threads} {seconds * 1e3:.1f}")
    print(" | ".join(row), flush=True)
