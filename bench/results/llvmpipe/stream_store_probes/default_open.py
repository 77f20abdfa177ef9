"""First image of a streamed COPC opened with no limit configured (the default memory), twice
(the first fills the program cache).

    PYTHONPATH=. python bench/results/llvmpipe/stream_store_probes/default_open.py FILE.copc.laz
"""
import sys

from bench.startup import frame_until_first_image
from progressive.session import Session, SessionOptions, Streaming

path = sys.argv[1]
opts = SessionOptions(width=1280, height=720, stream=Streaming.ON)
for _ in range(2):
    with Session([path], opts) as s:
        frame_until_first_image(s, s.auto_camera(), path)
        print(f"limit {s.memory.available_bytes / 2**20:.0f} MiB ({s.memory.source}), first image {s.first_image_seconds:.3f} s, "
              + ", ".join(f"{k} {v:.3f}" for k, v in s.startup.items()), flush=True)
