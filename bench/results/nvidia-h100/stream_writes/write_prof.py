"""Profile Streamer._write (the frame loop's node writes) on a streamed COPC: where the
host's time of a still overview's writes goes, how much of it the frame thread spent
running (time.thread_time) rather than waiting, and how the staging ring served them.

    python .probe/write_prof.py PATH LIMIT_BYTES WxH SECONDS
"""
import cProfile
import pstats
import sys
import time

from progressive import streaming
from progressive.session import Session, SessionOptions, Streaming

path, limit, size, seconds = sys.argv[1], int(float(sys.argv[2])), sys.argv[3], float(sys.argv[4])
w, h = (int(v) for v in size.split("x"))
opts = SessionOptions(width=w, height=h, stream=Streaming.ON, gpu_memory_limit=limit)
prof = cProfile.Profile()
orig = streaming.Streamer._write
total = [0.0, 0, 0, 0.0]


def timed(self, row):
    t0, c0 = time.perf_counter(), time.thread_time()
    prof.enable()
    orig(self, row)
    prof.disable()
    total[0] += time.perf_counter() - t0
    total[1] += int(self.state.nodes.points[row])
    total[2] += 1
    total[3] += time.thread_time() - c0


streaming.Streamer._write = timed
with Session([path], opts) as s:
    cam = s.auto_camera()
    t0 = time.perf_counter()
    frames = 0
    while time.perf_counter() - t0 < seconds and not s.converged:
        s.frame(cam)
        frames += 1
    wall = time.perf_counter() - t0
    stats = s.renderer.scene.distribute.stats
    print(f"{frames} frames in {wall:.2f} s; writes {total[0]:.3f} s for {total[2]} nodes, {total[1]:,} points: "
          f"{total[1] / max(total[0], 1e-9) / 1e6:.1f} M points/s; the frame thread's CPU in them {total[3]:.3f} s "
          f"(the rest waited: the GIL, or the driver); staging pieces ring {stats.ring}, copied {stats.copied}")
pstats.Stats(prof).sort_stats("tottime").print_stats(14)
