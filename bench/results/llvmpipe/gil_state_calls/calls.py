"""Raw GL calls a frame makes (a camera moving every frame, 1280x720): count and time
per entry point, over 40 frames after 30 still ones.

    PYTHONPATH=. python bench/results/llvmpipe/gil_state_calls/calls.py FILE
"""

import collections
import sys
import time

import numpy as np

from progressive import glext

made = glext._entry
calls = collections.defaultdict(lambda: [0, 0.0])


def _entry(loader, name, *argtypes, restype=None, state=None):
    call = made(loader, name, *argtypes, restype=restype, state=state)

    def timed(*args):
        t0 = time.perf_counter()
        out = call(*args)
        tally = calls[name]
        tally[0] += 1
        tally[1] += time.perf_counter() - t0
        return out
    return timed


glext._entry = _entry

from progressive.camera import Camera  # noqa: E402  (after the entry points are wrapped)
from progressive.session import Session, SessionOptions  # noqa: E402

FRAMES = 40
with Session([sys.argv[1]], SessionOptions(width=1280, height=720)) as s:
    camera = s.auto_camera()
    for _ in range(30):
        s.frame(camera)
    calls.clear()
    t0 = time.perf_counter()
    for i in range(FRAMES):
        p = np.array(camera.position) * (1 + 0.01 * (i % 2))
        s.frame(Camera(tuple(p), camera.target, camera.up, camera.fov_y_deg, camera.near, camera.far))
    seconds = time.perf_counter() - t0
    counted = dict(calls)       # before the session's close releases its objects
print(f"frame {seconds / FRAMES * 1e3:.1f} ms")
for name, (count, spent) in sorted(counted.items(), key=lambda kv: -kv[1][1]):
    print(f"{name:32s} {count / FRAMES:6.1f}/frame {spent / FRAMES * 1e3:7.3f} ms/frame")
