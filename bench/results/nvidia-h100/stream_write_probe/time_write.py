"""Where the main thread's node writes go: wall and thread CPU of each part (main thread only)."""
import os
import sys
import threading
import time
from collections import defaultdict

import progressive.passes.distribute as dist_mod
import progressive.pointstore as ps_mod
import progressive.scene as scene_mod
import progressive.session as session_mod
import progressive.streaming as streaming_mod
from progressive.session import Session, SessionOptions, Streaming

MAIN = threading.main_thread()
acc = defaultdict(lambda: [0, 0.0, 0.0])

def wrap(owner, name, label=None):
    fn = getattr(owner, name)
    label = label or f"{getattr(owner, '__name__', owner)}.{name}"
    def inner(*a, **k):
        if threading.current_thread() is not MAIN:
            return fn(*a, **k)
        w, c = time.perf_counter(), time.thread_time()
        try:
            return fn(*a, **k)
        finally:
            e = acc[label]
            e[0] += 1
            e[1] += time.perf_counter() - w
            e[2] += time.thread_time() - c
    setattr(owner, name, inner)

wrap(session_mod.Session, "frame")
wrap(streaming_mod.Streamer, "update")
wrap(streaming_mod.Streamer, "_write")
wrap(streaming_mod, "plan")
wrap(scene_mod.Scene, "write_store_batches")
wrap(scene_mod.Scene, "_encode_group")
wrap(scene_mod.Scene, "_upload_records")
wrap(scene_mod.Scene, "_upload_flags")
wrap(scene_mod, "frame_parts")
wrap(scene_mod, "stage_cells")
wrap(scene_mod, "batch_words")
wrap(scene_mod, "pack_into")
wrap(ps_mod.PointStore, "reorder")
wrap(ps_mod.PointStore, "set_frames")
wrap(dist_mod.DistributePass, "_scatter")
wrap(dist_mod.StagingRing, "acquire")
wrap(streaming_mod.Streamer, "status")

if os.environ.get("READER_THREADS"):
    _NR = session_mod.NodeReader
    def _reader(sources, origin, names, threads, decoders, **kwargs):
        return _NR(sources, origin, names, int(os.environ["READER_THREADS"]), decoders, **kwargs)
    session_mod.NodeReader = _reader
path, limit_mib, seconds = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
w, h = (int(v) for v in (sys.argv[4] if len(sys.argv) > 4 else "1920x1080").split("x"))
opts = SessionOptions(width=w, height=h, stream=Streaming.ON, gpu_memory_limit=int(limit_mib * (1 << 20)))
t0 = time.perf_counter()
c0 = time.thread_time()
with Session([path], opts) as s:
    cam = s.auto_camera()
    n = 0
    while time.perf_counter() - t0 < seconds:
        s.frame(cam)
        n += 1
        if s.status().stream.settled:
            break
    st = s.status().stream
    print(f"{path} limit {limit_mib} MiB reader threads {os.environ.get('READER_THREADS', 'default')}: frames {n} wall {time.perf_counter() - t0:.2f} s, main thread CPU {time.thread_time() - c0:.2f} s, "
          f"resident {st.resident_points:,} points {st.resident_nodes} nodes, settled {st.settled}, threads {threading.active_count()}")
for k, (calls, wall, cpu) in sorted(acc.items(), key=lambda kv: -kv[1][1]):
    print(f"{k:45s} calls {calls:6d}  wall {wall:8.3f} s  cpu {cpu:8.3f} s  wall/call {wall / calls * 1e3:7.3f} ms")
