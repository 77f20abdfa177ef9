"""A cloud on the GPU: the shuffled store, the distribute pass that fills it, and the
attribute shown (with the samples its colour range comes from)."""

from __future__ import annotations

import time

import numpy as np

from progressive.colors import ColorStyle, Colormap, robust_range
from progressive.context import GLContext
from progressive.loaders.types import AttributeInfo, AttributeKind, Batch, CloudInfo, nonfinite_records
from progressive.packing import pack_records
from progressive.permutation import FillOrder
from progressive.passes.distribute import DistributePass
from progressive.pointstore import PointStore

RANGE_SAMPLE_PER_BATCH = 20_000


class Scene:
    def __init__(self, glc: GLContext, info: CloudInfo, attribute: AttributeInfo, *, chunk_points: int | None = None,
                 capacity: int | None = None, order: FillOrder = FillOrder.SHUFFLED):
        """capacity: points kept on the GPU (default all; see progressive/memory.py).
        order: FILE stores points in file order (the unshuffled baseline, for benchmarks)."""
        self.glc, self.info, self.attribute = glc, info, attribute
        self.store = PointStore(glc, info.points, capacity=capacity, chunk_points=chunk_points, order=order)
        self.distribute = DistributePass(glc, self.store)
        self.loaded = 0
        self.skipped = 0            # points never drawn: non-finite coordinates or shown value
        self.upload_seconds = 0.0
        self._samples: list[np.ndarray] = []

    @property
    def complete(self) -> bool:
        return self.loaded >= self.info.points

    def add_batch(self, batch: Batch) -> None:
        t0 = time.perf_counter()
        records = pack_records(batch, self.attribute, float(self.info.origin[2]))
        self.skipped += nonfinite_records(records)[0]     # what shaders/common.glsl finite_position skips
        self.distribute.upload(records, batch.start)
        if self.attribute.kind is AttributeKind.SCALAR:
            step = max(1, batch.count // RANGE_SAMPLE_PER_BATCH)
            self._samples.append(records[::step, 3].view(np.float32))
        self.loaded += batch.count
        self.upload_seconds += time.perf_counter() - t0

    def value_range(self) -> tuple[float, float]:
        """Robust (1-99 %) range of the packed scalar values seen so far."""
        if not self._samples:
            return (0.0, 1.0)
        return robust_range(np.concatenate(self._samples))

    def style(self, colormap: Colormap = Colormap.VIRIDIS, background=(0, 0, 0)) -> ColorStyle:
        return ColorStyle.for_attribute(self.attribute, self.value_range(), colormap, background)

    def release(self) -> None:
        self.distribute.release()
        self.store.release()
