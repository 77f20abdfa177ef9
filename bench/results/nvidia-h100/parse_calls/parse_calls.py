"""A/B in one process: a LAS batch's parse with fewer numpy calls (this tree:
loaders/las.py's bit fields in one call, 8-bit RGB clipped into its array in one,
no non-finite check of the scan angle, loaders/types.nonfinite_count's sum first)
against the parse before (its _values and count, restored here). Each thread parses
every batch of the file (spans, read by the parse); rounds alternate. Prints ns a point
(wall time / points parsed by all threads), every attribute.

    python parse_calls.py FILE [THREADS...]
"""

import os
import statistics
import sys
import threading
import time

import laspy
import numpy as np

from progressive.loaders import las as L
from progressive.loaders.allocator import keep_large_blocks
from progressive.loaders.types import BATCH_POINTS

ROUNDS = int(os.environ.get("ROUNDS", 5))


def values_before(self, chunk: laspy.PackedPointRecord, raw: np.ndarray, name: str) -> np.ndarray:
    """LasSource._values before this change."""
    if name == "rgb":
        red = chunk.array.dtype.fields["red"][1]
        if self.info.rgb_16bit:
            out = np.empty((raw.shape[0], 3), np.uint8)
            for channel in range(3):
                out[:, channel] = raw[:, red + 2 * channel + 1]
            return out
        return np.minimum(L._rows_of(raw, red, 6).view("<u2").reshape(-1, 3), L.RGB8_MAX).astype(np.uint8)
    if name == "scan_angle":
        if self.info.point_format < 6:
            return np.asarray(chunk["scan_angle_rank"], dtype=np.float32)
        return (np.asarray(chunk["scan_angle"], dtype=np.float64) * L.SCAN_ANGLE_STEP).astype(np.float32)
    column = self.columns[name]
    values = np.asarray(chunk[column.dimension])
    return np.ascontiguousarray(values if column.index is None else values[:, column.index])


def count_before(values: np.ndarray) -> int:
    """loaders/types.nonfinite_count before this change."""
    if values.dtype.kind != "f":
        return 0
    return int(values.size - np.count_nonzero(np.isfinite(values)))


NOW = (L.LasSource._values, L.nonfinite_count, L.FROM_INTEGERS)
BEFORE = (values_before, count_before, frozenset())


def use(way) -> None:
    L.LasSource._values, L.nonfinite_count, L.FROM_INTEGERS = way


def once(src, spans, names, points, count: int) -> float:
    def work():
        for span in spans:
            src.parse(span, span.first, np.zeros(3), names)

    workers = [threading.Thread(target=work) for _ in range(count)]
    t = time.perf_counter()
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    return (time.perf_counter() - t) * 1e9 / (points * count)


def alternate(ways: dict, use, src, spans, names, points, threads: list[int]) -> None:
    """For each count of threads, ROUNDS rounds of every way in turn (`use(way)` puts it in
    place), each timed by once(); prints a line of medians a count."""
    for count in threads:
        times = {label: [] for label in ways}
        for _ in range(ROUNDS):
            for label, way in ways.items():
                use(way)
                times[label].append(once(src, spans, names, points, count))
        print(f"{count} thread(s): " + "; ".join(
            f"{label} median {statistics.median(t):.2f} ns/point (best {min(t):.2f})" for label, t in times.items()),
            flush=True)


def opened(path: str):
    """The file opened, its spans but the first (small) one, every attribute's name and
    the spans' points: what alternate() parses."""
    keep_large_blocks()
    src = L.open_las(path)
    spans = list(src.chunks(BATCH_POINTS))[1:]
    return src, spans, tuple(a.name for a in src.attributes), sum(len(s) for s in spans)


def main() -> None:
    path, threads = sys.argv[1], [int(t) for t in sys.argv[2:]] or [1, 2]
    src, spans, names, points = opened(path)
    ways = {"fewer calls": NOW, "before": BEFORE}
    for way in ways.values():       # both give the same batch
        use(way)
        batch = src.parse(spans[0], 0, np.zeros(3), names)
        if way is NOW:
            first = batch
        else:
            assert all(np.array_equal(first.attributes[n], batch.attributes[n]) for n in first.attributes)
            assert first.nonfinite_values == batch.nonfinite_values
    print(f"{path}: {len(spans)} batches, {points:,} points, attributes {names}, rounds {ROUNDS}")
    alternate(ways, use, src, spans, names, points, threads)


if __name__ == "__main__":
    main()
