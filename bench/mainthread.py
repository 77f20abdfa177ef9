"""How busy the frame loop's thread is while a session loads: the wall and CPU time
(time.thread_time) of its frames until every point is on the GPU, beside the loader
alone over the same file. CPU close to the frames' wall time: the frame loop bounds
loading; far below: it waits (for the GIL or the loader).

    python -m bench.mainthread [--points 100000000] [--repeats 3] [--label TREE] [--out DIR] [--profile 40]
                               [--parser-threads 4 16] [--formats LAS fast]

--parser-threads: a row for each count of the loader's parser threads, in the sessions
and the loader alone (default: the loader's own, one a core up to PARSER_THREADS).
--formats: which of the tiled files (bench/data.py): LAS, LAZ and the fast format (its
one attribute shown: `render`'s session only, as the window's keeps every attribute).

--profile also runs one session of each kind under cProfile, enabled around its frames,
and writes the functions that took longest, by their own time and with what they call,
to profile_<format>_<threads>_<session>.txt: where the CPU goes, not timings to quote (the profiler
slows small Python calls most). Before Python 3.12 it records the frame loop's thread
alone; from 3.12 (cProfile on sys.monitoring) every thread's calls while frames run,
the parser threads' among them, and what nests across threads is mangled.

Only the session's API is timed (progressive.open, Session.frame), so the same module
measures an older tree put first on PYTHONPATH.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import itertools
import pstats
import statistics
import sys
import time
from pathlib import Path

import progressive
from bench import data
from bench.load import SESSIONS, pipeline, raw_read, shown
from bench.report import RunInfo, Table
from progressive.budget import BudgetParams
from progressive.context import GLContext, create_context
from progressive.loaders.types import default_parser_threads


def loading(glc: GLContext, path: Path, session: str, size: tuple[int, int],
            profile: cProfile.Profile | None = None, threads: int | None = None) -> dict:
    """One warm session framed back to back (as bench.load does) until every point is
    on the GPU; `profile` enabled around each frame."""
    raw_read(path)
    opts = progressive.SessionOptions(width=size[0], height=size[1], **SESSIONS[session], parser_threads=threads,
                                      progressive=progressive.ProgressiveOptions(budget=BudgetParams(target_ns=16_600_000)))
    frames_wall = frames_cpu = 0.0
    frames = 0
    t0 = time.perf_counter()
    with progressive.open([path], opts, glc=glc) as s:
        opened = time.perf_counter() - t0
        cam = s.auto_camera()
        while not s.status().complete:
            w, c = time.perf_counter(), time.thread_time()
            if profile is not None:
                profile.enable()
            s.frame(cam)
            if profile is not None:
                profile.disable()
            frames_cpu += time.thread_time() - c
            frames_wall += time.perf_counter() - w
            frames += 1
        glc.ctx.finish()
        loaded = time.perf_counter() - t0
    return {"open_s": opened, "loaded_s": loaded, "frames": frames, "frames_wall_s": frames_wall,
            "frames_cpu_s": frames_cpu}


FORMATS = ("LAS", "LAZ", "fast")


def tiled_file(fmt: str, points: int, cache: Path) -> Path:
    """The tiled file of one of FORMATS (the fast format converted from the LAS)."""
    if fmt == "fast":
        return data.scaled(points, cache).fast
    return data.tiled(points, fmt == "LAZ", cache)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="The frame loop's wall and CPU time while a session loads")
    parser.add_argument("--points", type=int, default=2_000_000)
    parser.add_argument("--size", default="1920x1080")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--label", default="", help="what tree this is (a column of its own)")
    parser.add_argument("--cache", type=Path, default=data.CACHE, help="where the tiled files are kept")
    parser.add_argument("--out", type=Path, default=None, help="results folder (default bench/results/<machine>)")
    parser.add_argument("--profile", type=int, default=0, metavar="TOP",
                        help="also profile one session of each kind: its TOP functions by own time")
    parser.add_argument("--parser-threads", type=int, nargs="+", default=[default_parser_threads()],
                        help="the loader's parser threads, a row each")
    parser.add_argument("--formats", nargs="+", choices=FORMATS, default=list(FORMATS), help="the files, a row each")
    args = parser.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    glc = create_context()
    table = Table("mainthread", "The frame loop's thread while a session loads", "", f"{args.points:,}", (
        "tree", "format", "parser threads", "session", "loader alone s", "all points on GPU s", "open s", "frames",
        "frames' wall s", "frames' CPU s", "CPU / wall of frames", "frames' wall / loading"))
    profiles = []
    for fmt, threads in itertools.product(args.formats, args.parser_threads):
        path = tiled_file(fmt, args.points, args.cache)
        raw_read(path)
        alone = []
        for _ in range(args.repeats):
            t = time.perf_counter()
            pipeline(path, threads, attributes=shown(path))
            alone.append(time.perf_counter() - t)
        for session in ("shown",) if fmt == "fast" else ("shown", "viewer, others later"):
            loading(glc, path, session, size, threads=threads)   # untimed: programs compiled and cached, caches warm
            runs = [loading(glc, path, session, size, threads=threads) for _ in range(args.repeats)]
            median = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
            table.raw.setdefault("rows", []).append({"tree": args.label, "format": fmt, "parser_threads": threads,
                                                     "session": session, "loader_alone_s": statistics.median(alone),
                                                     **median, "runs": runs})
            table.rows.append((args.label, fmt, threads, session, statistics.median(alone), median["loaded_s"],
                               median["open_s"], median["frames"], median["frames_wall_s"], median["frames_cpu_s"],
                               median["frames_cpu_s"] / median["frames_wall_s"],
                               median["frames_wall_s"] / median["loaded_s"]))
            if args.profile:
                profiles.append((fmt, threads, session, profiled(glc, path, session, size, args.profile, threads)))
    table.data = "autzen_trim.las tiled on a grid (bench/data.py), written as " + ", ".join(args.formats)
    table.notes = [f"Warm cache, {size[0]}x{size[1]}, adaptive budget 16.6 ms, auto camera, frames issued back to "
                   "back from `progressive.open()` until `status().complete` (then glFinish); a frame where "
                   "everything loaded was drawn waits up to `RESTING_WAIT_S` for the next batch (in its wall time). Frames' CPU = "
                   "`time.thread_time()` of the frame loop's thread inside `Session.frame`. Loader alone = the "
                   "loader over the file at the row's parser threads reading the attribute `render` shows, nothing "
                   f"else running. Sessions as bench.load's. Each value the median of {args.repeats} runs after "
                   "one untimed run of the same session."]
    run = RunInfo.from_caps(glc.caps, "main thread")
    table.publish(run, args.out, Path(__file__).resolve().parent / "results")
    out = args.out or Path(__file__).resolve().parent / "results" / run.machine
    for fmt, threads, session, text in profiles:
        (out / f"profile_{fmt}_{threads}_{session.split(',')[0]}.txt").write_text(text)
    return 0


def profiled(glc: GLContext, path: Path, session: str, size: tuple[int, int], top: int, threads: int) -> str:
    """One more session's frames under cProfile: the header line, then its `top`
    functions by own time and by time with what they call."""
    profile = cProfile.Profile()
    result = loading(glc, path, session, size, profile, threads)
    text = io.StringIO()
    stats = pstats.Stats(profile, stream=text)
    stats.sort_stats("tottime").print_stats(top)
    stats.sort_stats("cumulative").print_stats(top)
    threads = "every thread's calls while frames ran" if sys.version_info >= (3, 12) else "the frames' thread"
    return (f"{path.name}, session {session}: {result['frames']} frames, every point after {result['loaded_s']:.2f} s "
            f"(profiled: {threads})\n{text.getvalue()}")


if __name__ == "__main__":
    raise SystemExit(main())
