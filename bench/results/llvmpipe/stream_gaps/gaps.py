"""Where a still streamed overview's seconds go between the session's open and the view
settled and converged: the open, the frames (Session.frame), the loop's Session.status()
calls, and the rest (between them: nothing but the loop itself, so time the main thread
waits to get the GIL back from the reader threads). Runs take turns between interpreter
switch intervals (sys.setswitchinterval): if the rest is the GIL, a shorter interval
shrinks it. The last round is profiled (cProfile, the main thread).

    PYTHONPATH=. python bench/results/llvmpipe/stream_gaps/gaps.py POINTS LIMIT WxH OUT.json [ROUNDS [INTERVAL...]]

POINTS: bench.stream's tiled COPC of that many points (built into its cache if absent,
as `bench/gpu.sh copc-1B` builds the 1 B-point one); intervals in seconds (default 0.005,
Python's, and 0.0005).
"""
import cProfile
import io
import json
import pstats
import sys
import time

from bench.stream import build
from progressive.cli import bytes_arg
from progressive.session import Session, SessionOptions, Streaming

LIMIT_S = 60.0
"""Longest a run waits for its view to settle and converge."""


def run(path: str, options: SessionOptions, interval: float, profile: bool) -> dict:
    before = sys.getswitchinterval()
    sys.setswitchinterval(interval)
    prof = cProfile.Profile() if profile else None
    frame_s = status_s = 0.0
    frames, settled = 0, None
    try:
        t0 = time.perf_counter()
        with Session([path], options) as s:
            opened = time.perf_counter() - t0
            camera = s.auto_camera()
            if prof:
                prof.enable()
            while time.perf_counter() - t0 < LIMIT_S:
                a = time.perf_counter()
                s.status()
                b = time.perf_counter()
                s.frame(camera)
                c = time.perf_counter()
                st = s.status()
                d = time.perf_counter()
                frame_s += c - b
                status_s += (b - a) + (d - c)
                frames += 1
                if st.stream.settled and s.converged:
                    settled = time.perf_counter() - t0
                    break
            if prof:
                prof.disable()
            first_image, startup, resident = s.first_image_seconds, dict(s.startup), st.stream.resident_points
    finally:
        sys.setswitchinterval(before)
    end = settled if settled is not None else time.perf_counter() - t0
    out = {"interval_s": interval, "open_s": opened, "first_image_s": first_image, "settled_s": settled,
           "frames": frames, "frame_s": frame_s, "status_s": status_s, "rest_s": end - opened - frame_s - status_s,
           "resident_points": resident, "startup": startup}
    if prof:
        text = io.StringIO()
        pstats.Stats(prof, stream=text).sort_stats("cumulative").print_stats(40)
        out["profile"] = text.getvalue()
    return out


def main() -> None:
    points, limit, size, out = int(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4]
    rounds = int(sys.argv[5]) if len(sys.argv) > 5 else 3
    intervals = [float(v) for v in sys.argv[6:]] or [0.005, 0.0005]
    built = build(points)
    w, h = map(int, size.split("x"))
    options = SessionOptions(width=w, height=h, stream=Streaming.ON, gpu_memory_limit=bytes_arg(limit))
    run(str(built.path), options, intervals[0], profile=False)     # warm: program cache, page cache
    runs = [run(str(built.path), options, interval, profile=k == rounds - 1)
            for k in range(rounds) for interval in intervals]
    for r in runs:
        print({k: (round(v, 3) if isinstance(v, float) and k != "interval_s" else v)
               for k, v in r.items() if k not in ("profile", "startup")})
    for r in runs[-len(intervals):]:
        print(f"profile, switch interval {r['interval_s']} s:\n{r['profile']}")
    with open(out, "w") as f:
        json.dump({"points": built.points, "nodes": built.nodes, "limit": limit, "size": size, "runs": runs}, f, indent=1)


if __name__ == "__main__":
    main()
