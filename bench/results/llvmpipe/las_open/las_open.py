"""Probe, in one process: opening a LAS (loaders.las.open_las) and the loader over it
(bench.load.pipeline, every attribute) on the quick bench's tiled LAS (bench.data.scaled,
warm), with the open's probe as it is (`now`: the colours' greatest value over one
contiguous copy of R, G, B; the first points' coordinate ends from their integers' ends)
against the ways it had before (`before`: three strided reductions over R, G and B; the
ends of every probed point's float64 coordinates), taking turns, ROUNDS rounds, the best
of REPEATS runs each, beside bench.load.laspy_user. Times in ms.

    PYTHONPATH=. python bench/results/llvmpipe/las_open/las_open.py [POINTS [THREADS]]
"""
import functools
import os
import sys

import numpy as np

from bench import data
from bench.compactness import best_of
from bench.load import laspy_user, pipeline, raw_read
from progressive.loaders import las

points = int(sys.argv[1]) if len(sys.argv) > 1 else 2_000_000
threads = int(sys.argv[2]) if len(sys.argv) > 2 else 2
path = data.scaled(points, fast=False).las
raw_read(path)
repeats = int(os.environ.get("REPEATS", "7"))
now = (las.rgb_max, las.record_ends)


def rgb_max_before(chunk: np.ndarray) -> int:
    return max(int(np.max(chunk[c])) for c in ("red", "green", "blue"))


def ends_before(chunk: np.ndarray, records: las.Records) -> np.ndarray:
    coords = [records.coordinates(chunk, axis) for axis in range(3)]
    return np.array([[c.min() for c in coords], [c.max() for c in coords]])


print(f"{path.name}: {points:,} points, {threads} parser threads, every attribute; best of {repeats}", flush=True)
for _ in range(int(os.environ.get("ROUNDS", "5"))):
    row = [f"laspy {best_of(repeats, lambda: laspy_user(path)) * 1e3:.1f}"]
    for name, (rgb_max, ends) in (("before", (rgb_max_before, ends_before)), ("now", now)):
        las.rgb_max, las.record_ends = rgb_max, ends
        row.append(f"open-{name} {best_of(repeats, lambda: las.open_las(str(path))) * 1e3:.2f}")
        row.append(f"loader-{name} {best_of(repeats, functools.partial(pipeline, path, threads)) * 1e3:.1f}")
    print(" | ".join(row), flush=True)
las.rgb_max, las.record_ends = now
