"""What a streamed COPC node's decode costs in a LAZ decoder process (laz_pool's
decode_run: the job sent, the node read and decoded by the worker into a memfd made for
the job, the records copied out) against lazrs in this process (the node's bytes already
in memory, decoded into a fresh array), node by node, rounds alternating; then the pool's
throughput with P lanes decoding at once on P threads (each lane one process, as a
stream's reading threads use them). On the H200 machine a node of the 1 B-point COPC took
about 31 ms in its process, against about 16.5 ms that lazrs alone would take a core
(../../nvidia-h200/stream_writes_1B/).

    python node_decode.py COPC NODES ROUNDS [LANES...]
"""
import statistics
import sys
import threading
import time

import lazrs
import numpy as np

from progressive.loaders import las
from progressive.loaders.copc import open_copc
from progressive.loaders.laz_pool import DecoderPool

path, count, rounds = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
lanes = [int(a) for a in sys.argv[4:]] or [1]
src = open_copc(path)
nodes = src.hierarchy.nodes
order = np.argsort(nodes["level"], kind="stable")[:count]       # coarsest first, as an overview reads them
names = ("rgb",) if any(a.name == "rgb" for a in src.attributes) else ("intensity",)
layers, selection, dtype, vlr = las.layers(names), las.selection(names), src.records.dtype, src.laz.vlr_data
jobs = [(int(nodes[k]["offset"]), int(nodes[k]["point_count"]), int(nodes[k]["byte_size"])) for k in order]
with open(path, "rb") as f:
    compressed = [(f.seek(o), f.read(b))[1] for o, _, b in jobs]
points = sum(n for _, n, _ in jobs)


def in_process() -> None:
    for (_, n, b), data in zip(jobs, compressed, strict=True):
        out = np.empty(n, dtype)
        lazrs.decompress_points_with_chunk_table(data, vlr, memoryview(out).cast("B"), [(n, b)], selection)


def in_worker(pool: DecoderPool, lane: int, share) -> None:
    for o, n, b in share:
        pool.decode_run(lane, path, o, ((n, b),), vlr, layers, dtype)


print(f"{path}: {len(jobs)} nodes, {points:,} points ({points / len(jobs):,.0f} a node), layers of {names}, rounds {rounds}")
with DecoderPool(max(lanes)) as pool:
    in_worker(pool, 0, jobs[:1])        # the workers started
    times = {"in this process": [], "in a decoder process": []}
    for _ in range(rounds):
        t = time.perf_counter()
        in_process()
        times["in this process"].append(time.perf_counter() - t)
        t = time.perf_counter()
        in_worker(pool, 0, jobs)
        times["in a decoder process"].append(time.perf_counter() - t)
    for way, t in times.items():
        m = statistics.median(t)
        print(f"one at a time, {way}: median {m / len(jobs) * 1e3:.2f} ms a node ({points / m / 1e6:.1f} M points/s), "
              f"best {min(t) / len(jobs) * 1e3:.2f}")
    for p in lanes:
        t = time.perf_counter()
        threads = [threading.Thread(target=in_worker, args=(pool, lane, jobs[lane::p])) for lane in range(p)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        d = time.perf_counter() - t
        print(f"{p} lanes at once: {d:.3f} s, {d / len(jobs) * p * 1e3:.2f} ms a node a lane, {points / d / 1e6:.1f} M points/s")
