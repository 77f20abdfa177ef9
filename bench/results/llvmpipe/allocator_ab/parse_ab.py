"""A/B of keep_large_blocks: one 500,000-point batch of a LAS parsed 25 times (every
attribute, then RGB only) in a fresh process, with and without the allocator's setting.

    python parse_ab.py FILE kept|default
"""

import statistics
import sys
import time

import numpy as np

from progressive.loaders import las as L
from progressive.loaders.allocator import keep_large_blocks

path, mode = sys.argv[1], sys.argv[2]
if mode == "kept":
    assert keep_large_blocks()
src = L.open_las(path)
chunk = L.read_span(src.info.path, src.records, list(src.chunks(500_000))[1], src.info.points)
every = tuple(a.name for a in src.attributes)
for label, names in (("every", every), ("rgb", ("rgb",))):
    ms = []
    for _ in range(25):
        t = time.perf_counter()
        src.parse(chunk, 0, np.zeros(3), names)
        ms.append((time.perf_counter() - t) * 1e3)
    print(f"{mode} {label}: median {statistics.median(ms):.2f} ms, best {min(ms):.2f} ms", flush=True)
