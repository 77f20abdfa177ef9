"""A/B of LasSource.parse with RGB only on a LAS of 16-bit colours: the tree on
PYTHONPATH parses one 500,000-point batch repeatedly; run alternately for two trees.

    python rgb16_ab.py make FILE          # 2,000,000 points of the bundled sample tiled, colours << 8
    PYTHONPATH=TREE python rgb16_ab.py time FILE LABEL
"""

import statistics
import sys
import time

import laspy
import numpy as np


def make(path: str) -> None:
    from bench.data import SAMPLE
    las = laspy.read(SAMPLE)
    reps = -(-2_000_000 // len(las.points))
    header = laspy.LasHeader(point_format=las.header.point_format.id, version=las.header.version)
    header.scales, header.offsets = las.header.scales, las.header.offsets
    out = laspy.LasData(header)
    points = np.tile(las.points.array, reps)[:2_000_000]
    out.points = laspy.ScaleAwarePointRecord(points, header.point_format, header.scales, header.offsets)
    for c in ("red", "green", "blue"):
        out[c] = (np.asarray(out[c], np.uint32) * 257).astype(np.uint16)     # 8-bit values spread to 16 bits
    out.write(path)


def timed(path: str, label: str) -> None:
    from progressive.loaders import las as L
    src = L.open_las(path)
    assert src.info.rgb_16bit
    span = list(src.chunks(500_000))[1]
    chunk = L.read_span(src.info.path, src.records, span, src.info.points)
    origin = np.zeros(3)
    ms = []
    for _ in range(25):
        t = time.perf_counter()
        src.parse(chunk, 0, origin, ("rgb",))
        ms.append((time.perf_counter() - t) * 1e3)
    print(f"{label} parse rgb {len(chunk):,} points: median {statistics.median(ms):.2f} ms, best {min(ms):.2f} ms")


if __name__ == "__main__":
    make(sys.argv[2]) if sys.argv[1] == "make" else timed(sys.argv[2], sys.argv[3])
