"""A streamed overview's first reads asked for at the session's open, before the store
and passes are made (Streamer.request_first), against at its first frame (as before):
seconds to the first image and to the view settled and converged, taking turns in one
process; from the file, or over HTTP from tests/range_server.py's server in a process of
its own (each answer --http-ms late).

    PYTHONPATH=. python bench/results/llvmpipe/first_reads/first_reads.py POINTS ROUNDS OUT.json LIMIT:WxH... \
        [--http-ms MS] [--first-image-only] [--cores N]

POINTS: bench.stream's tiled COPC of that many points (built into its cache if absent);
each LIMIT:WxH a GPU memory limit and image size (64M:640x360 is the stream bench's here).
--first-image-only: each run ends at its first image (a view that takes long to settle).
--cores N: the session's cores patched (4 or more: decoder processes, as on a GPU machine,
here oversubscribing the 2 cores).
"""
import argparse
import contextlib
import json
import sys
import time
from pathlib import Path

import numpy as np

from bench.stream import NAME, TESTS, build
from progressive import session as session_module
from progressive.cli import bytes_arg
from progressive.session import Session, SessionOptions, Streaming
from progressive.streaming import Streamer

LIMIT_S = 120.0


def run(path: str, options: SessionOptions, first_only: bool) -> dict:
    t0 = time.perf_counter()
    with Session([path], options) as s:
        opened = time.perf_counter() - t0
        camera = s.auto_camera()
        while time.perf_counter() - t0 < LIMIT_S:
            s.frame(camera)
            if (first_only and s.first_image_seconds is not None) or (s.status().stream.settled and s.converged):
                break
        return {"open_s": opened, "first_image_s": s.first_image_seconds,
                "settled_s": None if first_only else time.perf_counter() - t0,
                "passes_s": s.startup["passes"], "resident_points": s.status().stream.resident_points}


@contextlib.contextmanager
def source(path: Path, http_ms: float | None):
    """The file's path, or its URL on a range server for the runs' time."""
    if http_ms is None:
        yield str(path)
        return
    sys.path.insert(0, str(TESTS))
    from range_server import RangeServerProcess

    with RangeServerProcess({NAME: path}, http_ms / 1e3) as server:
        yield server.url(NAME)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("points", type=int)
    ap.add_argument("rounds", type=int)
    ap.add_argument("out")
    ap.add_argument("settings", nargs="+", metavar="LIMIT:WxH")
    ap.add_argument("--http-ms", type=float, default=None)
    ap.add_argument("--first-image-only", action="store_true")
    ap.add_argument("--cores", type=int, default=None)
    args = ap.parse_args()
    if args.cores is not None:
        session_module.available_cores = lambda: args.cores
    built = build(args.points)
    early = Streamer.request_first
    arms = {"at open": early, "at the first frame": lambda *a, **k: None}
    keys = ("open_s", "first_image_s") + (() if args.first_image_only else ("settled_s",))
    results = {}
    with source(built.path, args.http_ms) as where:
        for setting in args.settings:
            limit, size = setting.split(":")
            w, h = map(int, size.split("x"))
            options = SessionOptions(width=w, height=h, stream=Streaming.ON, gpu_memory_limit=bytes_arg(limit))
            run(where, options, args.first_image_only)       # warm: program cache, page cache
            rows = {arm: [] for arm in arms}
            for k in range(args.rounds):
                for arm, way in (list(arms.items()) if k % 2 == 0 else list(arms.items())[::-1]):
                    Streamer.request_first = way
                    rows[arm].append(run(where, options, args.first_image_only))
            Streamer.request_first = early
            results[setting] = rows
            for arm, runs in rows.items():
                med = {k: float(np.median([r[k] for r in runs])) for k in keys}
                spread = {k: (min(r[k] for r in runs), max(r[k] for r in runs)) for k in keys}
                print(f"{setting} {arm:>18}: " + ", ".join(f"{k} {med[k]:.3f} ({spread[k][0]:.3f}-{spread[k][1]:.3f})"
                                                          for k in keys), flush=True)
    with open(args.out, "w") as f:
        json.dump({"points": built.points, "http_ms": args.http_ms, "first_image_only": args.first_image_only,
                   "cores": args.cores, "results": results}, f, indent=1)


if __name__ == "__main__":
    main()
