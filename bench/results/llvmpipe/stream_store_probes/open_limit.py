"""A streamed session opened on a COPC file at 1280x720 until its first image, for each GPU
memory limit given (MiB), twice each (the first fills the program cache for that store):
the store's points, the first image and the open's phases.

    PYTHONPATH=. python bench/results/llvmpipe/stream_store_probes/open_limit.py FILE.copc.laz 256 512 1024
"""
import sys

from bench.startup import frame_until_first_image
from progressive.permutation import BATCH_POINTS
from progressive.session import Session, SessionOptions, Streaming

path = sys.argv[1]
for mib in sys.argv[2:]:
    opts = SessionOptions(width=1280, height=720, stream=Streaming.ON, gpu_memory_limit=int(float(mib)) << 20)
    for _ in range(2):
        with Session([path], opts) as s:
            frame_until_first_image(s, s.auto_camera(), path)
            print(f"{mib} MiB: store {s.streamer.state.capacity * BATCH_POINTS:,} points, first image "
                  f"{s.first_image_seconds:.3f} s, " + ", ".join(f"{k} {v:.3f}" for k, v in s.startup.items()),
                  flush=True)
