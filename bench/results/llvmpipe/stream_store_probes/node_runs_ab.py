"""The frame loop's frame_parts per streamed node with a node's per-batch integer ranges
found on its reading thread (encoding.node_runs, as sessions do) and without (the hook
made a no-op: frame_parts reduces the node's cells itself), alternating, the COPC file
streamed whole with a 1 GiB limit at 640x360 until settled; main thread wall and CPU.

    PYTHONPATH=. python bench/results/llvmpipe/stream_store_probes/node_runs_ab.py FILE.copc.laz 2
"""
import sys
import threading
import time

import progressive.scene as scene_mod
from progressive import encoding
from progressive.session import Session, SessionOptions, Streaming

MAIN = threading.main_thread()
real_parts, real_runs = scene_mod.frame_parts, encoding.node_runs
spent = [0, 0.0, 0.0]


def timed_parts(*args, **kwargs):
    w, c = time.perf_counter(), time.thread_time()
    try:
        return real_parts(*args, **kwargs)
    finally:
        if threading.current_thread() is MAIN:
            spent[0] += 1
            spent[1] += time.perf_counter() - w
            spent[2] += time.thread_time() - c


scene_mod.frame_parts = timed_parts
path, rounds = sys.argv[1], int(sys.argv[2])
opts = SessionOptions(width=640, height=360, stream=Streaming.ON, gpu_memory_limit=1 << 30)
for r in range(rounds):
    for arm in ("without", "with"):
        encoding.node_runs = real_runs if arm == "with" else (lambda node: node)
        spent[:] = [0, 0.0, 0.0]
        t0 = time.perf_counter()
        with Session([path], opts) as s:
            cam = s.auto_camera()
            while not s.status().stream.settled and time.perf_counter() - t0 < 120:
                s.frame(cam)
            n, wall, cpu = spent
            print(f"round {r + 1}, {arm} node_runs: {n} nodes, frame_parts {wall / n * 1e3:.3f} ms wall, "
                  f"{cpu / n * 1e3:.3f} ms CPU a node; settled after {time.perf_counter() - t0:.2f} s", flush=True)
