"""Probe, in one process: the loader on a tiled LAS (bench.data.scaled, warm) with every
attribute, each plain field (no bit field, not RGB or scan angle) handed over as a copy
(`copies`, as committed) or as a strided view of the records read (`views`), taking turns,
ROUNDS rounds, the best of REPEATS runs each, beside bench.load.laspy_user (laspy.read()
plus conversion); then the host memory a kept batch holds a point with each (every
buffer its arrays keep alive, counted once). Times in ms.

    PYTHONPATH=. python bench/results/llvmpipe/las_field_views/field_views.py [POINTS [THREADS]]
"""
import functools
import os
import sys

import numpy as np

from bench import data
from bench.compactness import best_of
from bench.load import laspy_user, pipeline, raw_read
from progressive.loaders import CloudLoader, las

points = int(sys.argv[1]) if len(sys.argv) > 1 else 2_000_000
threads = int(sys.argv[2]) if len(sys.argv) > 2 else 2
path = data.scaled(points, fast=False).las
raw_read(path)
repeats = int(os.environ.get("REPEATS", "5"))
copies = las.LasSource._values


def views(self, chunk, raw, name):
    column = self.columns.get(name)
    plain = (column is not None and column.index is None and column.dimension in chunk.array.dtype.names
             and chunk.sub_fields_dict.get(column.dimension) is None
             and column.dimension not in {d.name for d in chunk.point_format.extra_dimensions})
    return chunk.array[column.dimension] if plain else copies(self, chunk, raw, name)


def owner(a: np.ndarray) -> np.ndarray:
    while isinstance(a.base, np.ndarray):
        a = a.base
    return a


def held_bytes() -> float:
    with CloudLoader([path], parser_threads=threads) as loader:
        batches = list(loader)
    owners = {}
    for b in batches:
        for a in (b.grid.cells, *b.attributes.values()):
            o = owner(a)
            owners[id(o)] = o.nbytes if o.base is None else a.nbytes
    return sum(owners.values()) / sum(b.count for b in batches)


print(f"{path.name}: {points:,} points, {threads} parser threads, every attribute", flush=True)
for _ in range(int(os.environ.get("ROUNDS", "5"))):
    row = [f"laspy {best_of(repeats, lambda: laspy_user(path)) * 1e3:.1f}"]
    for name, values in (("copies", copies), ("views", views)):
        las.LasSource._values = values
        row.append(f"{name} {best_of(repeats, functools.partial(pipeline, path, threads)) * 1e3:.1f}")
    print(" | ".join(row), flush=True)
for name, values in (("copies", copies), ("views", views)):
    las.LasSource._values = values
    print(f"{name}: {held_bytes():.1f} bytes a point held by the batches", flush=True)
