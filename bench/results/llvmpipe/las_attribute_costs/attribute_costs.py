"""Probe: what each attribute adds to the LAS parse of one batch (LasSource.parse, the
records already read), on the quick bench's tiled LAS (bench.data.scaled); the best of
REPEATS runs each, ROUNDS rounds. Times in ms.

    PYTHONPATH=. python bench/results/llvmpipe/las_attribute_costs/attribute_costs.py [POINTS [BATCH]]
"""
import os
import sys
import time

import numpy as np

from bench import data
from progressive.loaders import CloudLoader, las

points = int(sys.argv[1]) if len(sys.argv) > 1 else 2_000_000
batch = int(sys.argv[2]) if len(sys.argv) > 2 else 500_000
repeats, rounds = int(os.environ.get("REPEATS", "7")), int(os.environ.get("ROUNDS", "5"))
loader = CloudLoader([str(data.scaled(points, fast=False).las)])
source, info = loader.sources[0], loader.info
origin = np.asarray(info.origin)
chunk = las.read_span(source.info.path, source.records, las.Span(0, batch), source.info.points)
names = tuple(a.name for a in info.attributes if a.name != "elevation")


def best(parsed: tuple[str, ...]) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        source.parse(chunk, 0, origin, parsed)
        times.append(time.perf_counter() - t0)
    return min(times) * 1e3


print(f"{source.info.path}: point format {source.info.point_format}, {batch:,} records a parse, "
      f"best of {repeats}, {rounds} rounds")
for _ in range(rounds):
    none = best(())
    row = [f"none {none:.2f}"] + [f"{n} +{best((n,)) - none:.2f}" for n in names] + [f"every {best(names):.2f}"]
    print(" | ".join(row), flush=True)
loader.close()
