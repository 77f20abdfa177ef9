"""A streamed session opened on a COPC URL until its first image: the requests the open
makes and its phases, with the range server's answers at once and 50 ms late (one process
of its own, RangeServerProcess); two opens each, the first filling the program cache.

    PYTHONPATH=. python bench/results/llvmpipe/http_open/http_open.py bench/.cache/autzen_trim_x20000000.copc.laz
"""
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[4] / "tests"))

from range_server import RangeServerProcess  # noqa: E402

from bench.startup import frame_until_first_image  # noqa: E402
from progressive.session import Session, SessionOptions, Streaming  # noqa: E402

if __name__ == "__main__":
    path = Path(sys.argv[1])
    for latency in (0.0, 0.05):
        with RangeServerProcess({"a.copc.laz": path}, latency) as server:
            url = server.url("a.copc.laz")
            opts = SessionOptions(width=1280, height=720, stream=Streaming.ON, gpu_memory_limit=256 << 20)
            for _ in range(2):
                before = server.counts()[0]
                t = time.perf_counter()
                with Session([url], opts) as s:
                    opened = time.perf_counter() - t
                    requests = server.counts()[0] - before
                    frame_until_first_image(s, s.auto_camera(), url)
                    print(f"answers {latency * 1e3:.0f} ms late: open {opened:.3f} s, first image "
                          f"{s.first_image_seconds:.3f} s, requests at the open {requests}, "
                          + ", ".join(f"{k} {v:.3f}" for k, v in s.startup.items()), flush=True)
