"""A streamed overview's first reads asked for at the session's open, before the store
and passes are made (Streamer.request_first), against at its first frame (as before):
seconds to the first image and to the view settled and converged, taking turns in one
process.

    PYTHONPATH=. python bench/results/llvmpipe/first_reads/first_reads.py POINTS ROUNDS OUT.json LIMIT:WxH...

POINTS: bench.stream's tiled COPC of that many points (built into its cache if absent);
each LIMIT:WxH a GPU memory limit and image size (64M:640x360 is the stream bench's here).
"""
import json
import sys
import time

import numpy as np

from bench.stream import build
from progressive.cli import bytes_arg
from progressive.session import Session, SessionOptions, Streaming
from progressive.streaming import Streamer

LIMIT_S = 120.0


def run(path: str, options: SessionOptions) -> dict:
    t0 = time.perf_counter()
    with Session([path], options) as s:
        opened = time.perf_counter() - t0
        camera = s.auto_camera()
        while time.perf_counter() - t0 < LIMIT_S:
            s.frame(camera)
            if s.status().stream.settled and s.converged:
                break
        return {"open_s": opened, "first_image_s": s.first_image_seconds, "settled_s": time.perf_counter() - t0,
                "passes_s": s.startup["passes"], "resident_points": s.status().stream.resident_points}


def main() -> None:
    points, rounds, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
    settings = [(limit, *map(int, size.split("x"))) for limit, size in (a.split(":") for a in sys.argv[4:])]
    built = build(points)
    early = Streamer.request_first
    arms = {"at open": early, "at the first frame": lambda *a, **k: None}
    results = {}
    for limit, w, h in settings:
        options = SessionOptions(width=w, height=h, stream=Streaming.ON, gpu_memory_limit=bytes_arg(limit))
        run(str(built.path), options)       # warm: program cache, page cache
        rows = {arm: [] for arm in arms}
        for k in range(rounds):
            for arm, way in (list(arms.items()) if k % 2 == 0 else list(arms.items())[::-1]):
                Streamer.request_first = way
                rows[arm].append(run(str(built.path), options))
        Streamer.request_first = early
        results[f"{limit} {w}x{h}"] = rows
        for arm, runs in rows.items():
            med = {k: float(np.median([r[k] for r in runs])) for k in ("open_s", "first_image_s", "settled_s")}
            print(f"{limit} {w}x{h} {arm:>18}: " + ", ".join(f"{k} {v:.3f}" for k, v in med.items())
                  + f"; settled {min(r['settled_s'] for r in runs):.3f}-{max(r['settled_s'] for r in runs):.3f}"
                  + f"; resident {runs[0]['resident_points']:,}")
    with open(out, "w") as f:
        json.dump({"points": built.points, "results": results}, f, indent=1)


if __name__ == "__main__":
    main()
