"""Load: points/s and GB/s of the loader for LAS, LAZ and the fast format at 1, 2, 4
parser threads, the default and the cores available, cold and warm page cache, each
beside what the same file costs to (a) `laspy.read()` plus the conversion a user would
write, (b) read raw and (c) for LAZ, decode with lazrs's own parallel decoder alone; a
LAZ is loaded both ways, decoded by lazrs's threads in the loader's process and by
decoder processes (loaders/laz_pool.py); then time to first image and to fully loaded
through `progressive.open()`."""

from __future__ import annotations

import argparse
import contextlib
import functools
import itertools
import statistics
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import laspy
import lazrs
import numpy as np

import progressive
from bench.data import drop_cache
from bench.report import Table
from bench.startup import frame_until_first_image
from progressive.budget import BudgetParams
from progressive.context import GLContext
from progressive.loaders import CloudLoader, open_cloud
from progressive.loaders.copc import is_copc
from progressive.loaders.laz_pool import MIN_AUTO_PROCESSES, MIN_PROCESS_POINTS, Decoders, LazOptions
from progressive.loaders.types import PARSER_THREADS, available_cores, default_parser_threads

BLOCK = 8 << 20
LAZRS_PIECE = 10_000_000
"""Points per `decompress_many` of the lazrs ceiling: 200 chunks, every core busy."""
ONE_CORE_POINTS = 2_000_000
"""Points lazrs decodes on one core for its one-core rate (about a second on the GPU machines' cores)."""
COLD_MIN_SLOWDOWN = 1.2
"""A cold raw read must be at least this much slower than a warm one to count as cold."""


@dataclass(frozen=True)
class LoadCase:
    label: str
    format: str
    path: Path
    points: int
    scaled: bool = False     # a generated file (the sample tiled), not a real file as it is


def raw_read(path: Path) -> None:
    """The file read in 8 MiB blocks into one buffer and dropped: the disk/cache ceiling."""
    buf = bytearray(BLOCK)
    view = memoryview(buf)
    with open(path, "rb", buffering=0) as f:
        while f.readinto(view):
            pass


@contextlib.contextmanager
def _at_points(path: Path) -> Iterator[tuple[BinaryIO, laspy.LasHeader, bytes]]:
    """A LAZ file open at its first point, with its header and LASzip VLR data: where a
    lazrs decompressor starts."""
    with open(path, "rb") as f:
        header = laspy.LasHeader.read_from(f)
        f.seek(header.offset_to_point_data)
        yield f, header, header.vlrs.get("LasZipVlr")[0].record_data


def lazrs_decode(path: Path) -> None:
    """lazrs's `ParLasZipDecompressor` alone over every point (all cores, pieces of
    LAZRS_PIECE into one buffer): the LAZ decoding ceiling."""
    with _at_points(path) as (f, header, vlr):
        decoder = lazrs.ParLasZipDecompressor(f, vlr)
        size = header.point_format.size
        buffer = bytearray(min(header.point_count, LAZRS_PIECE) * size)
        view = memoryview(buffer)
        left = header.point_count
        while left:
            n = min(left, LAZRS_PIECE)
            decoder.decompress_many(view[:n * size])
            left -= n


def lazrs_one_core(path: Path) -> float:
    """Points a second that lazrs's sequential `LasZipDecompressor` decodes on one core,
    over the first ONE_CORE_POINTS points: times the cores, the ceiling of any decoding
    spread over them (perfect scaling)."""
    with _at_points(path) as (f, header, vlr):
        n = min(header.point_count, ONE_CORE_POINTS)
        buffer = bytearray(n * header.point_format.size)
        t = time.perf_counter()
        lazrs.LasZipDecompressor(f, vlr).decompress_many(buffer)
        return n / (time.perf_counter() - t)


LAZ_DECODERS = (Decoders.THREADS, Decoders.PROCESSES)
"""The two ways a LAZ is decoded, side by side in one run."""


def pipeline(path: Path, threads: int, decoders: Decoders = Decoders.AUTO, attributes: tuple[str, ...] | None = None) -> None:
    """The loader over the whole file: every attribute (what a viewer keeps for switching), or only `attributes`."""
    with CloudLoader([path], parser_threads=threads, laz=LazOptions(decoders), attributes=attributes) as loader:
        for _ in loader:
            pass


def shown(path: Path) -> tuple[str, ...]:
    """The attribute laspy_user converts (RGB where present, else intensity): what the loader parses beside the
    positions in the rows that compare like with like, as `render` does without --color-by."""
    names = {a.name for a in open_cloud([path]).attributes}
    return ("rgb",) if "rgb" in names else ("intensity",)


def laspy_user(path: Path) -> None:
    """What a user would write: read everything, then float32 positions relative to
    the centre of the bounds and one attribute (RGB where present, else intensity)."""
    las = laspy.read(path)
    origin = (las.header.mins + las.header.maxs) / 2
    xyz = np.empty((len(las.points), 3), dtype=np.float32)
    xyz[:, 0] = las.x - origin[0]
    xyz[:, 1] = las.y - origin[1]
    xyz[:, 2] = las.z - origin[2]
    names = set(las.point_format.dimension_names)
    if {"red", "green", "blue"} <= names:
        np.stack([las.red, las.green, las.blue], axis=1)
    else:
        np.asarray(las.intensity, dtype=np.float32)


def timed(fn: Callable[[], None], path: Path, cold: bool, repeats: int) -> float:
    """Median seconds; cold drops the file's pages before each run, warm reads it once first."""
    times = []
    if not cold:
        raw_read(path)
    for _ in range(repeats):
        if cold:
            drop_cache(path)
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


SESSIONS = {
    "shown": {},
    "viewer, others later": {"switchable": True, "class_filter": True},
    "viewer, all at once": {"switchable": True, "class_filter": True, "read_later": False},
}
"""The sessions first_image opens: what `render` and a headless `view` read (the shown
attribute), and what the window reads (every attribute kept to switch to; the class
and returns for its filters), the attributes not shown read after every point or with
them (SessionOptions.read_later)."""


def first_image(glc: GLContext, path: Path, width: int, height: int, cold: bool, max_frames: int,
                session: str = "shown", parser_threads: int | None = None) -> dict:
    """Seconds from progressive.open() to the first finished frame with points, to every
    point on the GPU, to the converged image (adaptive budget at 16.6 ms), and to every
    attribute read (a switchable session: framed on until the later pass is in)."""
    from progressive.viewer.app import IDLE_WAIT_SECONDS

    if cold:
        drop_cache(path)
    else:
        raw_read(path)
    opts = progressive.SessionOptions(width=width, height=height, **SESSIONS[session], parser_threads=parser_threads,
                                      progressive=progressive.ProgressiveOptions(budget=BudgetParams(target_ns=16_600_000)))
    t0 = time.perf_counter()
    first = full = converged = every = None
    with progressive.open([path], opts, glc=glc) as s:
        cam = s.auto_camera()
        for _ in range(max_frames):
            s.frame(cam)
            if first is None and s.status().loaded > 0:
                glc.ctx.finish()
                first = time.perf_counter() - t0
            if full is None and s.status().complete:
                glc.ctx.finish()
                full = time.perf_counter() - t0
            if converged is None and s.converged:
                converged = time.perf_counter() - t0
            if every is None and opts.switchable and full is not None and not s.later:
                every = time.perf_counter() - t0
            if converged is not None and (every is not None or not opts.switchable):
                break
            if s.idle:
                time.sleep(IDLE_WAIT_SECONDS)   # as the window, idle, waits for events between frames
        frames = s.status().frames
    return {"first_image_s": first, "loaded_s": full, "converged_s": converged, "every_attribute_s": every,
            "frames": frames}


def run(glc: GLContext, cases: list[LoadCase], threads: tuple[int, ...], repeats: int,
        size: tuple[int, int], max_frames: int) -> tuple[Table, Table]:
    cores, default = available_cores(), default_parser_threads()
    threads = tuple(sorted({*threads, default, cores}))
    load = Table("load", "Load: points/s and GB/s, against laspy, raw reads and lazrs alone", "", "", (
        "file", "format", "points", "MB", "cache", "parser threads", "LAZ decoders", "attributes", "s", "Mpoints/s", "GB/s",
        "× laspy.read + convert", "share of raw read GB/s", "lazrs alone Mpoints/s", "share of lazrs alone",
        "lazrs one core Mpoints/s"))
    rows = []
    cold_forced = {}
    for case in cases:
        size_b = case.path.stat().st_size
        baseline_path = case.path if case.format != "fast" else next(
            (c.path for c in cases if c.format == "LAS" and c.points == case.points), None)
        names = shown(case.path) if case.format != "fast" else None     # the fast format holds one attribute
        for cold in (True, False):
            raw_s = timed(functools.partial(raw_read, case.path), case.path, cold, repeats)
            laspy_s = timed(functools.partial(laspy_user, baseline_path), baseline_path, cold, repeats) if baseline_path else None
            lazrs_s = timed(functools.partial(lazrs_decode, case.path), case.path, cold, repeats) \
                if case.format == "LAZ" else None
            one_core = lazrs_one_core(case.path) if case.format == "LAZ" and not cold else None
            if cold:
                cold_forced[f"{case.label} {case.format}"] = raw_s
            pooled = case.format == "LAZ" and not is_copc(case.path)      # COPC nodes are decoded by loaders/copc.py
            runs = [(decoders, t, None) for decoders, t in itertools.product(LAZ_DECODERS if pooled else (None,), threads)]
            runs += [(decoders, default, names) for decoders in (LAZ_DECODERS if pooled else (None,))] if names else []
            for decoders, t, parsed in runs:
                s = timed(functools.partial(pipeline, case.path, t, decoders or Decoders.AUTO, parsed), case.path, cold,
                          repeats)
                row = {"file": case.label, "format": case.format, "scaled": case.scaled, "bytes": size_b, "points": case.points,
                       "cold": cold, "threads": t, "decoders": decoders.value if decoders else None,
                       "attributes": "every" if parsed is None else ", ".join(parsed),
                       "seconds": s, "points_per_s": case.points / s,
                       "gb_per_s": size_b / s / 1e9, "raw_seconds": raw_s, "laspy_seconds": laspy_s,
                       "laspy_file": baseline_path.name if baseline_path else None,
                       "vs_laspy": laspy_s / s if laspy_s else None, "share_of_raw": raw_s / s,
                       "cores": cores, "lazrs_seconds": lazrs_s, "share_of_lazrs": lazrs_s / s if lazrs_s else None,
                       "lazrs_one_core_points_per_s": one_core}
                rows.append(row)
        key = f"{case.label} {case.format}"
        warm_raw = next(r["raw_seconds"] for r in rows if (r["file"], r["format"], r["cold"]) == (case.label, case.format, False))
        cold_forced[key] = cold_forced[key] / warm_raw
    for r in rows:
        forced = cold_forced[f"{r['file']} {r['format']}"] >= COLD_MIN_SLOWDOWN
        cache = ("cold" if forced else "cold (not forced)") if r["cold"] else "warm"
        r["cold_forced"] = forced if r["cold"] else None
        load.rows.append((r["file"], r["format"], r["points"], r["bytes"] / 1e6, cache, r["threads"], r["decoders"],
                          r["attributes"], r["seconds"],
                          r["points_per_s"] / 1e6, r["gb_per_s"], r["vs_laspy"], f"{r['share_of_raw']:.2g}",
                          r["points"] / r["lazrs_seconds"] / 1e6 if r["lazrs_seconds"] else None,
                          f"{r['share_of_lazrs']:.2g}" if r["share_of_lazrs"] else None,
                          r["lazrs_one_core_points_per_s"] / 1e6 if r["lazrs_one_core_points_per_s"] else None))
    load.notes = [
        (f"Cores available to the process (`os.sched_getaffinity`): {cores}; the loader's default parser threads: "
         f"one a core, at most {PARSER_THREADS} ({default} rows). A LAZ is decoded on every core whatever the parser "
         "threads, either by "
         "lazrs's threads in the loader's process (LAZ decoders `threads`: lazrs holds the GIL through each read) "
         f"or by {cores} decoder processes, one a core, whose records the parser threads parse (`processes`; "
         f"the loader's default for a file with {MIN_PROCESS_POINTS:,} points or more left after its first batches "
         f"where {MIN_AUTO_PROCESSES} cores or more are available; "
         "a COPC file's nodes are decoded in the loader's process, one row). "
         "Loader: `CloudLoader` (reader thread + parser threads) to positions and attribute arrays (a LAS or LAZ "
         "batch's positions as the file's integers, which the GPU store takes as they are; float32 positions "
         "only where something asks; the fast format's as its float32 records): "
         "every attribute (what a viewer keeps to switch colouring), or only the one laspy converts here (what "
         "`render` keeps; at the default parser threads). "
        "× laspy = seconds of `laspy.read()` plus float32 positions relative to the bounds' centre and one attribute "
        "(RGB, else intensity), divided by the loader's seconds, same file and cache state, same run; for the fast "
        "format laspy reads the LAS file of the same cloud. Share of raw read = raw read seconds (8 MiB blocks, "
        "Python `readinto`) / loader seconds (1.0 = as fast as reading the bytes). lazrs alone = "
        f"`lazrs.ParLasZipDecompressor.decompress_many` over every point in pieces of {LAZRS_PIECE:,} (LAZ only), "
        "share of it = lazrs seconds / loader seconds: the decoding ceiling, without parsing. lazrs one core = "
        f"`lazrs.LasZipDecompressor` (sequential) over the first {ONE_CORE_POINTS:,} points, warm, once a file: "
        f"times the {cores} cores, the most any decoding spread over them could reach (perfect scaling)."),
        f"Each row's seconds: the median of {repeats} runs. "
        "Cold = `posix_fadvise(POSIX_FADV_DONTNEED)` after `fsync` before each run; it counts as forced only where "
        f"the cold raw read was ≥ {COLD_MIN_SLOWDOWN}× slower than the warm one (slowdown per file: "
        + ", ".join(f"{k} {v:.2f}×" for k, v in cold_forced.items()) + "). Where not forced, the cold rows "
        "measure a cached file: the page cache could not be dropped here (e.g. a virtual disk cached by the host).",
    ]
    load.raw = {"rows": rows, "cold_slowdown_raw": cold_forced, "default_threads": default, "repeats": repeats}

    return load, first_image_table(glc, cases, size, max_frames)


def warm_programs(glc: GLContext, path: Path, size: tuple[int, int], session: str) -> None:
    """A session of `session` opened on `path` and framed to its first image, untimed:
    its programs, which depend on the session and the store's size, are then compiled
    and in the program cache, so the timed runs measure a warm start (bench.startup's
    "first run" rows measure the compile)."""
    opts = progressive.SessionOptions(width=size[0], height=size[1], **SESSIONS[session])
    with progressive.open([path], opts, glc=glc) as s:
        frame_until_first_image(s, s.auto_camera(), f"{path.name} ({session})")


def first_image_table(glc: GLContext, cases: list[LoadCase], size: tuple[int, int], max_frames: int,
                      repeats: int = 1, parser_threads: tuple[int, ...] = ()) -> Table:
    """first_image for every case: cold and warm with the session `render` opens, warm
    with the window's (not for the fast format, which holds one attribute), and warm
    with `render`'s at each of `parser_threads` (the others at the default, one a core);
    each the median of `repeats` runs, the sessions taking turns within each repeat,
    after each session of the case opened once untimed (warm_programs)."""
    first = Table("first_image", "Time to first image and to fully loaded, through progressive.open()", "", "", (
        "file", "format", "points", "session", "parser threads", "cache", "first image s", "all points on GPU s",
        "converged s", "every attribute s", "frames", "first image / fully loaded"))
    keys = ("first_image_s", "loaded_s", "converged_s", "every_attribute_s", "frames")
    default = default_parser_threads()
    for case in cases:
        runs = [("shown", True, None), ("shown", False, None)]
        runs += [(session, False, None) for session in SESSIONS if session != "shown"] if case.format != "fast" else []
        runs += [("shown", False, t) for t in parser_threads if t != default]
        for session in dict.fromkeys(session for session, _, _ in runs):
            warm_programs(glc, case.path, size, session)
        taken: dict[tuple, list[dict]] = {run: [] for run in runs}
        for _ in range(repeats):
            for session, cold, threads in runs:
                taken[session, cold, threads].append(first_image(glc, case.path, *size, cold, max_frames, session,
                                                                 threads))
        for (session, cold, threads), results in taken.items():
            res = {k: median_or_none([r[k] for r in results]) for k in keys}
            res.update(file=case.label, format=case.format, cold=cold, points=case.points, scaled=case.scaled,
                       session=session, parser_threads=threads or default, repeats=repeats)
            first.raw.setdefault("rows", []).append(res)
            ratio = res["first_image_s"] / res["loaded_s"] if res["loaded_s"] else None
            first.rows.append((case.label, case.format, case.points, session, threads or default,
                               "cold" if cold else "warm", res["first_image_s"], res["loaded_s"], res["converged_s"],
                               res["every_attribute_s"], res["frames"], ratio))
    first.notes = [(f"Session with the progressive renderer at {size[0]}x{size[1]}, adaptive budget 16.6 ms, auto "
                   "camera; clock from before `progressive.open()` to `glFinish` after the first frame with points, "
                   "after the frame that distributed the last batch, to the frame that knew it had converged, and "
                   "(switchable sessions) to the frame after which every attribute was kept. Sessions: shown = what "
                   "`render` and a headless `view` read (the shown attribute); viewer = what the window reads "
                   "(SessionOptions(switchable=True, class_filter=True): every attribute, kept to switch to), the "
                   "attributes not shown after every point (others later, the default) or with them (all at once, "
                   "read_later=False); warm only. The fast format holds one attribute: shown only. Parser threads: "
                   f"the loader's (SessionOptions.parser_threads; {default} by default: one a core, at most "
                   f"{PARSER_THREADS}). "
                   f"Each row the median of {repeats} run{'s' if repeats > 1 else ''}"
                   f"{', the sessions taking turns' if repeats > 1 else ''}, after one untimed session of each kind "
                   "a file, to its first image: the programs (which depend on the session and the store's size) "
                   "compiled and in the program cache, as after a first run (`bench.startup` times the first run).")]
    return first


def median_or_none(values: list):
    """The median of the values measured (None where a run never got there)."""
    present = [v for v in values if v is not None]
    return statistics.median(present) if len(present) == len(values) else None


def main(argv: list[str] | None = None) -> int:
    """The first-image table alone (first_image_table), of files tiled to --points as
    LAS and LAZ: `python -m bench.load --points 100000000 --sources SAMPLE OTHER.laz`."""
    from bench import data
    from bench.report import RunInfo
    from progressive.context import create_context

    parser = argparse.ArgumentParser(description="Time to the first image, to every point on the GPU and to every "
                                                 "attribute kept, by session, of files tiled as LAS and LAZ")
    parser.add_argument("--points", type=int, default=2_000_000)
    parser.add_argument("--sources", nargs="+", type=Path, default=[data.SAMPLE],
                        help="files to tile (default: the bundled sample)")
    parser.add_argument("--size", default="1920x1080")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--parser-threads", type=int, nargs="*", default=[],
                        help="also `render`'s session, warm, with these many parser threads")
    parser.add_argument("--max-frames", type=int, default=100_000)
    parser.add_argument("--out", type=Path, default=None, help="results folder (default bench/results/<machine>)")
    args = parser.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    glc = create_context()
    cases = []
    for source in args.sources:
        files = data.scaled(args.points, source=source, fast=False)
        cases += [LoadCase(f"{source.name} tiled", fmt, path, files.points, scaled=True)
                  for fmt, path in files.formats() if fmt != "fast"]
    table = first_image_table(glc, cases, size, args.max_frames, args.repeats, tuple(args.parser_threads))
    table.data = ", ".join(f"{p.name} (point format {laspy.open(p).header.point_format.id})" for p in args.sources) + \
        " tiled on a grid (bench/data.py) and written as LAS and LAZ (laspy/lazrs)"
    table.points = f"{args.points:,}"
    table.publish(RunInfo.from_caps(glc.caps, "first image"), args.out, Path(__file__).resolve().parent / "results")
    return 0


if __name__ == "__main__":
    sys.exit(main())
