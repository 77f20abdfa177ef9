"""Probe, in one process: the loader on the quick bench's 2 M-point tiled LAS (warm) with the
LAS parse as it is (positions left to the grid: `lazy`) against the same parse followed by
computing the float32 positions, as it did before (`eager`), taking turns, 5 rounds, the
best of 7 runs each; `laspy` is bench.load.laspy_user (laspy.read() plus conversion).
Times in ms; `every`: every attribute, `rgb`: RGB alone; 2 parser threads, `1`: one.

    PYTHONPATH=. python bench/results/llvmpipe/las_lazy_positions/lazy_positions.py
"""
import dataclasses
import functools

from bench import data
from bench.compactness import best_of
from bench.load import laspy_user, pipeline, raw_read
from progressive.loaders import las

path = data.scaled(2_000_000).las
raw_read(path)
lazy = las.LasSource.parse


def eager(self, *args, **kwargs):
    batch = lazy(self, *args, **kwargs)
    return dataclasses.replace(batch, xyz=batch.grid.positions())


for _ in range(5):
    row = [f"laspy {best_of(7, lambda: laspy_user(path)) * 1e3:.1f}"]
    for name, parse in (("eager", eager), ("lazy", lazy)):
        las.LasSource.parse = parse
        for label, threads, names in (("every", 2, None), ("rgb", 2, ("rgb",)), ("every1", 1, None), ("rgb1", 1, ("rgb",))):
            row.append(f"{name}-{label} {best_of(7, functools.partial(pipeline, path, threads, attributes=names)) * 1e3:.1f}")
    print(" | ".join(row), flush=True)
