"""A/B: the frame loop beside a busy Python thread, with the GL state calls holding the
GIL (this tree, progressive/glext.py STATE_CALLS) or every raw GL call releasing it (before).

    PYTHONPATH=. python bench/results/llvmpipe/gil_state_calls/gil_ab.py before|after spin FILE
    PYTHONPATH=. python bench/results/llvmpipe/gil_state_calls/gil_ab.py before|after stream FILE.copc.laz LIMIT_MIB

spin: frames per second of a camera moving every frame (1280x720) alone, then beside a
thread counting in pure Python (the worst case of a thread that wants the GIL), and
that thread's count per second. stream: a streamed COPC session held still until
settled (640x360, every node fitting the limit): seconds, frames, median frame ms.
"""

import sys
import threading
import time

import numpy as np

from progressive import glext

mode, what = sys.argv[1], sys.argv[2]
if mode == "before":
    made = glext._entry

    def _entry(loader, name, *argtypes, restype=None, state=None):
        return made(loader, name, *argtypes, restype=restype, state=False)     # every call releases the GIL
    glext._entry = _entry

from progressive.camera import Camera  # noqa: E402  (after the entry points are chosen)
from progressive.session import Session, SessionOptions, Streaming  # noqa: E402


def moving(s: Session, camera: Camera, seconds: float) -> float:
    """Frames per second of a camera that moves every frame."""
    t0, n = time.perf_counter(), 0
    while time.perf_counter() - t0 < seconds:
        p = np.array(camera.position) * (1 + 0.01 * (n % 2))
        s.frame(Camera(tuple(p), camera.target, camera.up, camera.fov_y_deg, camera.near, camera.far))
        n += 1
    return n / (time.perf_counter() - t0)


if what == "spin":
    stop, count = False, [0]

    def spin():
        while not stop:
            count[0] += 1

    with Session([sys.argv[3]], SessionOptions(width=1280, height=720)) as s:
        camera = s.auto_camera()
        for _ in range(30):
            s.frame(camera)
        alone = moving(s, camera, 2.0)
        threading.Thread(target=spin, daemon=True).start()
        c0, t0 = count[0], time.perf_counter()
        beside = moving(s, camera, 2.0)
        rate = (count[0] - c0) / (time.perf_counter() - t0)
        stop = True
    print(f"{mode}: frames/s alone {alone:.1f}, beside the spinning thread {beside:.1f}; the thread {rate / 1e6:.2f} M counts/s")
else:
    limit = int(float(sys.argv[4]) * 2**20)
    options = SessionOptions(width=640, height=360, stream=Streaming.ON, gpu_memory_limit=limit)
    t0, frames = time.perf_counter(), []
    with Session([sys.argv[3]], options) as s:
        camera = s.auto_camera()
        while time.perf_counter() - t0 < 60:
            f0 = time.perf_counter()
            s.frame(camera)
            frames.append(time.perf_counter() - f0)
            status = s.status().stream
            if status.settled:
                break
    print(f"{mode}: settled after {time.perf_counter() - t0:.2f} s, {len(frames)} frames, median "
          f"{np.median(frames) * 1e3:.1f} ms, {status.resident_points:,} points resident")
