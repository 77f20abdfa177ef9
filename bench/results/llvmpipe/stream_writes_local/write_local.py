"""The host's cost of Streamer._write alone (no reading threads beside it): a streamed
still overview is run until it converges, keeping each node as it arrives; then the first
60 are written again one at a time, each between two glFinish, timed (wall and the
thread's CPU) and profiled.

    python write_local.py POINTS LIMIT_BYTES
"""
import cProfile
import pstats
import sys
import time

from bench.stream import build
from progressive import streaming
from progressive.session import Session, SessionOptions, Streaming

built = build(int(sys.argv[1]))
opts = SessionOptions(width=640, height=360, stream=Streaming.ON, gpu_memory_limit=int(sys.argv[2]))
calls = []
orig = streaming.Streamer._write


def kept(self, row):
    calls.append((self, row, self._arrived[row]))
    orig(self, row)


streaming.Streamer._write = kept
with Session([str(built.path)], opts) as s:
    cam = s.auto_camera()
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < 20 and not s.converged:
        s.frame(cam)
    print(len(calls), "nodes written; converged", s.converged)
    finish = s.renderer.glc.ctx.finish
    finish()
    prof = cProfile.Profile()
    wall = cpu = 0.0
    points = 0
    again = calls[:60]
    for streamer, row, batch in again:
        streamer._arrived[row] = batch
        t, c = time.perf_counter(), time.thread_time()
        prof.enable()
        orig(streamer, row)
        prof.disable()
        wall += time.perf_counter() - t
        cpu += time.thread_time() - c
        points += batch.count
        finish()
    n = len(again)
    print(f"{n} writes: {wall / n * 1e3:.3f} ms wall, {cpu / n * 1e3:.3f} ms CPU a node; {points / n:.0f} points a node; "
          f"{points / wall / 1e6:.1f} M points/s")
    pstats.Stats(prof).sort_stats("tottime").print_stats(18)
