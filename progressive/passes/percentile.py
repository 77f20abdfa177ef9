"""Exact percentiles of the shown scalar over every drawn point in the store: the
GPU counts two levels of a radix histogram of the values' order keys, the host picks
the bins (progressive/quantiles.py). Two passes over the store and two small
readbacks, run when the colour range is taken anew, never per frame."""

from __future__ import annotations

import numpy as np

from progressive import quantiles, shaderlib
from progressive.bindings import Binding
from progressive.context import GLContext
from progressive.gpu import grid
from progressive.pointstore import PointStore


class PercentilePass:
    def __init__(self, glc: GLContext, store: PointStore):
        self.glc, self.store = glc, store
        self.levels = [shaderlib.compute(glc.ctx, "histogram.comp", dict(store.defines, LEVEL=level),
                                         label=f"histogram level {level}") for level in (0, 1)]
        self.counts = glc.ctx.buffer(reserve=quantiles.MAX_TARGETS * quantiles.BINS * 4)
        self.counts.label = "percentile counts"

    def _count(self, level: int, target_list: list[int]) -> np.ndarray:
        program = self.levels[level]
        self.glc.gl.clear_u32(self.counts.glo, 0, total=self.counts.size)
        program["u_count"] = self.store.capacity
        if level == 1:
            program["u_targets"] = tuple(target_list)
        self.store.bind()
        self.counts.bind_to_storage_buffer(Binding.HISTOGRAM)
        program.run(*grid(self.store.capacity))
        self.glc.ctx.memory_barrier()
        rows = 1 if level == 0 else quantiles.MAX_TARGETS
        data = np.frombuffer(self.counts.read(size=rows * quantiles.BINS * 4), dtype=np.uint32)
        return data.reshape(rows, quantiles.BINS).astype(np.int64)

    def run(self, percents=quantiles.PERCENTILES) -> tuple[float, ...] | None:
        """The percentiles (numpy's linear method) of the finite values of drawn points;
        None when there are none."""
        high = self._count(0, [])[0]
        n = int(high.sum())
        if n == 0:
            return None
        wanted = quantiles.ranks(n, percents)
        bins, inside = quantiles.locate(high, wanted)
        target_list = quantiles.targets(bins)
        low = self._count(1, target_list)
        return quantiles.finish(n, bins, inside, wanted, target_list, low, percents)

    def release(self) -> None:
        for obj in (*self.levels, self.counts):
            obj.release()
