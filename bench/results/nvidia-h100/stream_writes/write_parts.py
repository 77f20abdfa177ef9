"""The frame thread's time in each part of a streamed node's write, while a still
overview streams with its reading threads busy beside it: wall and the thread's own CPU
(time.thread_time) inside each part, a node's write and its parts only, so that running
and waiting (the GIL, the driver) are told apart part by part, where cProfile mixes the
threads.

    python write_parts.py PATH LIMIT_BYTES WxH SECONDS [DETAIL_PX]

DETAIL_PX: the finest detail (SessionOptions.stream_detail_px; default the session's).
Then the node reading threads' time, summed over the threads: a node's read whole
(CopcSource.node_batch: its read, decoding, waiting for a decoder process) and its parse
in it, wall and CPU, so that parsing and waiting for the GIL are told apart there too.
"""
import sys
import threading
import time
from collections import defaultdict
from dataclasses import replace

from progressive import scene as scene_module
from progressive import streaming
from progressive.loaders.copc import CopcSource
from progressive.passes import distribute
from progressive.pointstore import PointStore
from progressive.programs import ComputeProgram
from progressive.session import Session, SessionOptions, Streaming

FRAME_THREAD = threading.get_ident()
WHOLE = "Streamer._write (the whole write)"
wall, cpu, calls = defaultdict(float), defaultdict(float), defaultdict(int)
inside = [False]


def timed(name, fn):
    """fn, timed where the frame thread calls it inside a node's write."""
    def run(*args, **kwargs):
        whole = name == WHOLE
        if threading.get_ident() != FRAME_THREAD or not (whole or inside[0]):
            return fn(*args, **kwargs)
        inside[0] = True
        t, c = time.perf_counter(), time.thread_time()
        try:
            return fn(*args, **kwargs)
        finally:
            wall[name] += time.perf_counter() - t
            cpu[name] += time.thread_time() - c
            calls[name] += 1
            inside[0] = inside[0] and not whole
    return run


PARTS = [
    (streaming.Streamer, "_write", WHOLE),
    (PointStore, "reorder", "PointStore.reorder (ids)"),
    (PointStore, "place_run", "PointStore.place_run (ids, a start a batch)"),
    (scene_module, "frame_parts", "frame_parts (batch frames)"),
    (PointStore, "set_frames", "PointStore.set_frames"),
    (scene_module.Scene, "_upload_records", "Scene._upload_records"),
    (scene_module, "stage_cells", "stage_cells (into the ring)"),
    (scene_module.Scene, "_upload_flags", "Scene._upload_flags"),
    (distribute.StagingRing, "acquire", "StagingRing.acquire"),
    (ComputeProgram, "run", "ComputeProgram.run (dispatch)"),
]
for owner, attr, name in PARTS:
    setattr(owner, attr, timed(name, getattr(owner, attr)))

READERS = [(CopcSource, "node_batch", "CopcSource.node_batch (a node's read)"),
           (CopcSource, "parse", "CopcSource.parse (in the read)")]
read_lock = threading.Lock()


def summed(name, fn):
    """fn timed in every thread but the frame thread's, summed."""
    def run(*args, **kwargs):
        if threading.get_ident() == FRAME_THREAD:
            return fn(*args, **kwargs)
        t, c = time.perf_counter(), time.thread_time()
        try:
            return fn(*args, **kwargs)
        finally:
            with read_lock:
                wall[name] += time.perf_counter() - t
                cpu[name] += time.thread_time() - c
                calls[name] += 1
    return run


for owner, attr, name in READERS:
    setattr(owner, attr, summed(name, getattr(owner, attr)))

path, limit, size, seconds = sys.argv[1], int(float(sys.argv[2])), sys.argv[3], float(sys.argv[4])
w, h = (int(v) for v in size.split("x"))
opts = SessionOptions(width=w, height=h, stream=Streaming.ON, gpu_memory_limit=limit)
if len(sys.argv) > 5:
    opts = replace(opts, stream_detail_px=float(sys.argv[5]))
with Session([path], opts) as s:
    cam = s.auto_camera()
    t0 = time.perf_counter()
    frames = 0
    while time.perf_counter() - t0 < seconds and not s.converged:
        s.frame(cam)
        frames += 1
    print(f"{frames} frames in {time.perf_counter() - t0:.2f} s; converged {s.converged}")
nodes = max(1, calls[WHOLE])
print(f"{'part':40s} {'calls':>7s} {'wall ms/node':>13s} {'CPU ms/node':>12s} {'running':>8s}")
for _, _, name in PARTS:
    if calls[name]:
        print(f"{name:40s} {calls[name]:7d} {wall[name] / nodes * 1e3:13.3f} {cpu[name] / nodes * 1e3:12.3f} "
              f"{cpu[name] / max(wall[name], 1e-12):8.0%}")
print(f"{'in the reading threads, summed':40s} {'calls':>7s} {'wall ms/call':>13s} {'CPU ms/call':>12s} {'running':>8s}")
for _, _, name in READERS:
    if calls[name]:
        print(f"{name:40s} {calls[name]:7d} {wall[name] / calls[name] * 1e3:13.3f} {cpu[name] / calls[name] * 1e3:12.3f} "
              f"{cpu[name] / max(wall[name], 1e-12):8.0%}")
