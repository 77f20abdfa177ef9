"""A/B of loaders/las.py's PARSE_ROWS in one process: the batches of a LAS (spans, read
by the parse as the loader's parser threads read them) parsed with every attribute, on
1, 2, ... threads at once (each thread parses every batch), with the records parsed
PARSE_ROWS at a time against all of a batch's at once (PARSE_ROWS set above the batch
size), rounds alternating. Prints ns a point (wall time / points parsed by all threads).

    python parse_blocks.py FILE [THREADS...] [--rows ROWS...]

--rows: the block sizes to compare (default las.PARSE_ROWS), each against the whole batch.
"""

import os
import statistics
import sys
import threading
import time

import numpy as np

from progressive.loaders import las as L
from progressive.loaders.allocator import keep_large_blocks
from progressive.loaders.types import BATCH_POINTS

ROUNDS = int(os.environ.get("ROUNDS", 5))
args = sys.argv[1:]
rows = [int(r) for r in args[args.index("--rows") + 1:]] if "--rows" in args else [L.PARSE_ROWS]
args = args[:args.index("--rows")] if "--rows" in args else args
path, threads = args[0], [int(t) for t in args[1:]] or [1, 2]
keep_large_blocks()
src = L.open_las(path)
spans = list(src.chunks(BATCH_POINTS))[1:]
names = tuple(os.environ["NAMES"].split(",")) if os.environ.get("NAMES") else tuple(a.name for a in src.attributes)
points = sum(len(s) for s in spans)
ways = {**{f"blocks of {r:,}": r for r in rows}, "whole": BATCH_POINTS + 1}


def once(rows: int, count: int) -> float:
    L.PARSE_ROWS = rows

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


print(f"{path}: {len(spans)} batches, {points:,} points, attributes {names}, PARSE_ROWS {L.PARSE_ROWS:,}")
for count in threads:
    times = {way: [] for way in ways}
    for _ in range(ROUNDS):
        for way, rows in ways.items():
            times[way].append(once(rows, count))
    print(f"{count} thread(s): " + "; ".join(
        f"{way} median {statistics.median(t):.2f} ns/point (best {min(t):.2f})" for way, t in times.items()), flush=True)
