"""A cloud on the GPU: the shuffled store, the distribute pass that fills it, and the
attribute shown (with the samples its colour range comes from). With `keep_batches`
the loaded struct-of-arrays stays in host memory, so the shown attribute can be
switched by streaming one word a point (paper 3.5) instead of reloading the file."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from progressive.colors import Colormap, ColorStyle, robust_range
from progressive.context import GLContext
from progressive.errors import ProgressiveError
from progressive.loaders.types import AttributeInfo, AttributeKind, Batch, CloudInfo, nonfinite_records
from progressive.packing import attribute_word, pack_records
from progressive.passes.distribute import DistributePass
from progressive.permutation import FillOrder
from progressive.pointstore import PointStore

RANGE_SAMPLE_PER_BATCH = 20_000


@dataclass
class AttributeSwitch:
    """Progress of one switch: batches [0, next_batch) of the kept ones carry the new
    attribute on the GPU. `records` counts batches that needed whole records because
    a non-finite value hides (or stops hiding) their points."""

    attribute: AttributeInfo
    previous: tuple[AttributeInfo, ...]   # what the GPU words may still hold
    batches: int                # kept when the switch began; later ones arrive packed with it
    total: int
    next_batch: int = 0
    streamed: int = 0
    records: int = 0
    seconds: float = 0.0

    @property
    def done(self) -> bool:
        return self.next_batch >= self.batches

    @property
    def rate(self) -> float:
        """Points a second, CPU packing and upload included (the GPU scatter is queued)."""
        return self.streamed / self.seconds if self.seconds > 0 else 0.0


class Scene:
    def __init__(self, glc: GLContext, info: CloudInfo, attribute: AttributeInfo, *, chunk_points: int | None = None,
                 capacity: int | None = None, keep_batches: bool = False, order: FillOrder = FillOrder.SHUFFLED):
        """capacity: points kept on the GPU (default all; see progressive/memory.py).
        keep_batches: keep the loaded attributes in host memory to switch attributes.
        order: FILE stores points in file order (the unshuffled baseline, for benchmarks)."""
        self.glc, self.info, self.attribute = glc, info, attribute
        self.store = PointStore(glc, info.points, capacity=capacity, chunk_points=chunk_points, order=order)
        self.distribute = DistributePass(glc, self.store)
        self.loaded = 0
        self.skipped = 0            # points never drawn: non-finite coordinates or shown value
        self.upload_seconds = 0.0
        self.keep_batches = keep_batches
        self.batches: list[Batch] = []
        self.switch: AttributeSwitch | None = None
        self._samples: list[np.ndarray] = []

    @property
    def complete(self) -> bool:
        return self.loaded >= self.info.points

    def add_batch(self, batch: Batch) -> None:
        t0 = time.perf_counter()
        records = pack_records(batch, self.attribute, float(self.info.origin[2]))
        self.skipped += nonfinite_records(records)[0]     # what shaders/common.glsl finite_position skips
        self.distribute.upload(records, batch.start)
        self._sample(records[:, 3])
        if self.keep_batches:
            self.batches.append(batch)
        self.loaded += batch.count
        self.upload_seconds += time.perf_counter() - t0

    def _sample(self, words: np.ndarray) -> None:
        if self.attribute.kind is AttributeKind.SCALAR:
            step = max(1, words.shape[0] // RANGE_SAMPLE_PER_BATCH)
            self._samples.append(words[::step].view(np.float32))

    def begin_switch(self, attribute: AttributeInfo) -> AttributeSwitch:
        """Show `attribute` from now on: batches loaded later are packed with it, and
        stream() rewrites the words of those already on the GPU."""
        if attribute not in self.info.attributes:
            raise ProgressiveError(f"this cloud has no attribute '{attribute.name}'")
        if not self.keep_batches:
            raise ProgressiveError("attribute switching needs the loaded attributes kept (keep_batches)")
        if any(b.records is not None for b in self.batches) and attribute != self.attribute:
            raise ProgressiveError("the fast format stores one attribute; convert again to show another")
        old = self.switch
        previous = (*old.previous, old.attribute) if old and not old.done else (self.attribute,)
        self.switch = AttributeSwitch(attribute, previous, len(self.batches), sum(b.count for b in self.batches))
        self.attribute = attribute
        self._samples = []
        self.skipped = 0
        return self.switch

    def stream(self, seconds: float = 0.008) -> bool:
        """Rewrite kept batches for the switch in progress for about `seconds` (at least
        one batch); True once every loaded point shows the new attribute."""
        sw = self.switch
        if sw is None or sw.done:
            return True
        t0 = time.perf_counter()
        origin_z = float(self.info.origin[2])
        first = sw.next_batch
        while not sw.done and (sw.next_batch == first or time.perf_counter() - t0 < seconds):
            batch = self.batches[sw.next_batch]
            if any(_hides_points(batch, a) for a in (*sw.previous, sw.attribute)):
                records = pack_records(batch, sw.attribute, origin_z)
                self.distribute.upload(records, batch.start)
                words = records[:, 3]
                self.skipped += nonfinite_records(records)[0]
                sw.records += 1
            else:
                words = attribute_word(batch, sw.attribute, origin_z)
                self.distribute.upload_words(words, batch.start)
                self.skipped += batch.nonfinite_positions
            self._sample(words)
            sw.next_batch += 1
            sw.streamed += batch.count
        sw.seconds += time.perf_counter() - t0
        return sw.done

    def drawable(self, hidden: frozenset[int]) -> frozenset[int]:
        """Category codes to leave out: only while a category attribute is shown."""
        return frozenset(hidden) if self.attribute.kind is AttributeKind.CATEGORY else frozenset()

    def categories(self) -> list[int]:
        """Codes present in the kept batches of the shown category attribute."""
        if self.attribute.kind is not AttributeKind.CATEGORY:
            return []
        seen = np.zeros(256, dtype=bool)
        for b in self.batches:
            values = b.attributes.get(self.attribute.name) if b.records is None else b.records[:, 3]
            if values is not None:
                seen[np.unique(np.minimum(values, 255))] = True
        return np.flatnonzero(seen).tolist()

    @property
    def positions_changed(self) -> bool:
        """The switch in progress rewrote whole records: which points are drawn changed."""
        return self.switch is not None and self.switch.records > 0

    def value_range(self) -> tuple[float, float]:
        """Robust (1-99 %) range of the packed scalar values seen so far."""
        if not self._samples:
            return (0.0, 1.0)
        return robust_range(np.concatenate(self._samples))

    def style(self, colormap: Colormap = Colormap.VIRIDIS, background=(0, 0, 0),
              value_range: tuple[float, float] | None = None) -> ColorStyle:
        """`value_range`: scalar values at the colormap's ends (default: the robust range)."""
        return ColorStyle.for_attribute(self.attribute, value_range or self.value_range(), colormap, background)

    def release(self) -> None:
        self.distribute.release()
        self.store.release()
        self.batches.clear()


def _hides_points(batch: Batch, attribute: AttributeInfo) -> bool:
    """pack_records gives NaN coordinates to points whose shown scalar is not finite."""
    return attribute.kind is AttributeKind.SCALAR and bool(batch.nonfinite_values.get(attribute.name))
