"""How long a still streamed overview takes to settle with 1, 2 or more node reads in
flight per LAZ decoder process (laz_pool.READS_PER_PROCESS): a read holds its process
only while the node decodes, then parses and encodes on its own thread, so with one read
a process the process idles meanwhile. Each setting opens its own session (its decoder
processes started anew); settings alternate round after round. A FACTOR ending in `e`
(`2e`) parses each node as the parse did before LAS batches kept their integers alone:
its float32 positions computed too (bench/results/llvmpipe/las_lazy_positions/).

    python stream_reads.py PATH LIMIT_BYTES WxH SECONDS DETAIL_PX ROUNDS FACTOR...

MIN_PROCESSES=2 in the environment lets a 2-core machine start its decoder processes
(laz_pool.MIN_AUTO_PROCESSES), to try the probe there.
"""
import dataclasses
import os
import statistics
import sys
import time

from progressive.loaders import laz_pool
from progressive.loaders.las import LasSource
from progressive.session import Session, SessionOptions, Streaming

path, limit, size, seconds = sys.argv[1], int(float(sys.argv[2])), sys.argv[3], float(sys.argv[4])
detail, rounds, factors = float(sys.argv[5]), int(sys.argv[6]), sys.argv[7:]
if "MIN_PROCESSES" in os.environ:
    laz_pool.MIN_AUTO_PROCESSES = int(os.environ["MIN_PROCESSES"])
w, h = (int(v) for v in size.split("x"))
opts = SessionOptions(width=w, height=h, stream=Streaming.ON, gpu_memory_limit=limit, stream_detail_px=detail)
settled = {f: [] for f in factors}
print(f"{path}: {os.cpu_count()} CPUs, limit {limit:,} B, {size}, detail {detail} px, rounds {rounds}", flush=True)
lazy = LasSource.parse


def eager(self, *args, **kwargs):
    batch = lazy(self, *args, **kwargs)
    return dataclasses.replace(batch, xyz=batch.grid.positions())


for r in range(rounds):
    for factor in factors:
        laz_pool.READS_PER_PROCESS = int(factor.rstrip("e"))
        LasSource.parse = eager if factor.endswith("e") else lazy
        t0 = time.perf_counter()
        with Session([path], opts) as s:
            cam = s.auto_camera()
            frames, first = 0, None
            while time.perf_counter() - t0 < seconds and not s.converged:
                s.frame(cam)
                frames += 1
                first = first or time.perf_counter() - t0
            took = time.perf_counter() - t0
            stream, converged = s.status().stream, s.converged
        settled[factor].append(took if converged else float("inf"))
        print(f"round {r} reads/process {factor}: first frame {first:.2f} s, settled {took:.2f} s "
              f"(converged {converged}, {frames} frames, resident {stream.resident_points if stream else '?'} points)",
              flush=True)
for factor, t in settled.items():
    print(f"reads/process {factor}: settled median {statistics.median(t):.2f} s, best {min(t):.2f} s, all "
          + ", ".join(f"{x:.2f}" for x in t))
