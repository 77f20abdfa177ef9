"""Probe: a cold load of the tiled sample (LAS and fast format) with the kernel told that
each span is read in order (validate.open_binary(in_order=True): POSIX_FADV_SEQUENTIAL),
against the same loader without it, beside laspy.read() plus conversion and the raw read
of the same file; every run cold (bench.load.drop_cache), the ways taking turns.

    python las_readahead.py LAS FAST ROUNDS
"""
import statistics
import sys
import time
from pathlib import Path

from bench.load import drop_cache, laspy_user, pipeline, raw_read
from progressive.loaders import fastformat, las

las_path, fast_path, rounds = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3])
advised = {m: m.open_binary for m in (las, fastformat)}


def ignoring_order(opener):
    """The opener as it was before `in_order`: no advice given."""
    return lambda path, in_order=False: opener(path)


plain = {m: ignoring_order(f) for m, f in advised.items()}


def timed(fn, path):
    drop_cache(path)
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


ways = {
    "LAS, advised": (advised, las_path, lambda: pipeline(las_path, 2)),
    "LAS, not advised": (plain, las_path, lambda: pipeline(las_path, 2)),
    "fast, advised": (advised, fast_path, lambda: pipeline(fast_path, 2)),
    "fast, not advised": (plain, fast_path, lambda: pipeline(fast_path, 2)),
    "LAS raw read": (advised, las_path, lambda: raw_read(las_path)),
    "LAS laspy.read + convert": (advised, las_path, lambda: laspy_user(las_path)),
}
times = {k: [] for k in ways}
for _ in range(rounds):
    for name, (openers, path, fn) in ways.items():
        for module, opener in openers.items():
            module.open_binary = opener
        times[name].append(timed(fn, path))
for name, t in times.items():
    print(f"{name:>26}: median {statistics.median(t) * 1e3:6.1f} ms, all " + " ".join(f"{x * 1e3:.0f}" for x in t))
