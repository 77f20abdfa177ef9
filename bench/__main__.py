"""Every benchmark section in one run, written to bench/results/<machine>/: a Markdown
table per section (device, driver, date, data set, N), the plots as PNG, the raw
JSON, and headline.md with the ratios the README quotes.

    python -m bench --quick                  # llvmpipe-sized, under 3 minutes
    python -m bench --full --sections raster --raster-points 1000000000   # one GPU chunk (bench/gpu.sh)
    python -m bench --quick --readme         # also put headline.md into README.md
"""

from __future__ import annotations

import argparse
import dataclasses
import enum
import time
from dataclasses import dataclass
from pathlib import Path

from bench import accuracy, attributes, data, headline, load, progressive, raster
from bench.report import RunInfo, Table
from bench.synthetic import load as load_tiled
from bench.synthetic import tiled
from progressive.context import GLContext, create_context

RESULTS = Path(__file__).resolve().parent / "results"


class Section(enum.Enum):
    LOAD = "load"
    RASTER = "raster"
    PROGRESSIVE = "progressive"
    ACCURACY = "accuracy"
    ATTRIBUTES = "attributes"


@dataclass(frozen=True)
class Scale:
    """Sizes of one mode; --max-points caps every point count."""

    mode: str
    load_points: int
    threads: tuple[int, ...]
    load_repeats: int
    first_image_size: tuple[int, int]
    raster_points: tuple[int, ...]
    raster_sizes: tuple[tuple[int, int], ...]
    raster_repeats: int
    copy_bytes: int
    progressive_points: tuple[int, ...]
    progressive_size: tuple[int, int]
    fixed_budgets: tuple[int, ...]
    targets_ms: tuple[float, ...]
    motion_frames: int
    max_frames: int
    accuracy_points: int | None          # None: the real file as it is
    accuracy_size: tuple[int, int]
    accuracy_fixed: tuple[float, ...]      # fixed budgets as shares of the cloud
    accuracy_max_frames: int
    real_files: bool = True              # load the real files too (../shared/data where present)

    def capped(self, limit: int | None) -> Scale:
        if limit is None:
            return self

        def cap(ns):
            return tuple(sorted({min(n, limit) for n in ns}))
        return dataclasses.replace(
            self, load_points=min(self.load_points, limit), raster_points=cap(self.raster_points),
            progressive_points=cap(self.progressive_points),
            fixed_budgets=cap(self.fixed_budgets),
            accuracy_points=None if self.accuracy_points is None else min(self.accuracy_points, limit))


QUICK = Scale("quick", load_points=2_000_000, threads=(1, 2, 4), load_repeats=3, first_image_size=(640, 360),
              raster_points=(1_000_000,), raster_sizes=((640, 360), (1280, 720)), raster_repeats=3,
              copy_bytes=64 << 20, progressive_points=(1_000_000,), progressive_size=(640, 360),
              fixed_budgets=(100_000,), targets_ms=(16.6, 11.1), motion_frames=15, max_frames=150,
              accuracy_points=None, accuracy_size=(640, 360), accuracy_fixed=(0.01, 0.05), accuracy_max_frames=120)
FULL = Scale("full", load_points=100_000_000, threads=(1, 2, 4), load_repeats=2, first_image_size=(1920, 1080),
             raster_points=(100_000_000, 1_000_000_000), raster_sizes=((1920, 1080), (2560, 1440)), raster_repeats=5,
             copy_bytes=2 << 30, progressive_points=(100_000_000, 1_000_000_000), progressive_size=(1920, 1080),
             fixed_budgets=(1_000_000, 10_000_000), targets_ms=(16.6, 11.1), motion_frames=60, max_frames=600,
             accuracy_points=100_000_000, accuracy_size=(1920, 1080), accuracy_fixed=(0.01, 0.05),
             accuracy_max_frames=300)

SMOKE = Scale("smoke", load_points=30_000, threads=(1, 2), load_repeats=1, first_image_size=(96, 64),
              raster_points=(30_000,), raster_sizes=((96, 64),), raster_repeats=1, copy_bytes=1 << 20,
              progressive_points=(30_000,), progressive_size=(96, 64), fixed_budgets=(10_000,), targets_ms=(16.6,),
              motion_frames=2, max_frames=12, accuracy_points=20_000, accuracy_size=(96, 64),
              accuracy_fixed=(0.25,), accuracy_max_frames=12, real_files=False)


def section_load(glc: GLContext, s: Scale, cache: Path, formats: tuple[str, ...] = data.FORMATS) -> list[Table]:
    """The load tables of the tiled sample and the real files, in the formats named."""
    files = data.scaled(s.load_points, cache, fast="fast" in formats, laz="LAZ" in formats)
    n = f"{s.load_points:,} (scaled files); real files as they are"
    cases = [load.LoadCase(f"{data.SAMPLE.stem} tiled", fmt, path, files.points, scaled=True)
             for fmt, path in files.formats() if fmt in formats]
    from progressive.loaders import open_cloud

    real = data.real_files() if s.real_files else []
    for path in real:
        fmt = "LAZ" if path.suffix.lower() == ".laz" else "LAS"
        if fmt in formats:
            cases.append(load.LoadCase(path.name, fmt, path, open_cloud([path]).points))
    tables = load.run(glc, cases, s.threads, s.load_repeats, s.first_image_size, 10_000)
    written = {"LAS": "LAS", "LAZ": "LAZ (laspy/lazrs)", "fast": "fast format (`progressive convert`)"}
    for t in tables:
        t.data = (f"{data.SAMPLE.name} tiled on a grid and written as " + ", ".join(written[f] for f in formats)
                  + "; " + ", ".join(p.name for p in real) + " as they are")
        t.points = n
    return tables


def section_accuracy(glc: GLContext, s: Scale, out: Path) -> list[Table]:
    """A real file as it is (the terrestrial lone-star scan where ../shared/data has it,
    else the bundled sample), or in full mode the sample tiled to accuracy_points."""
    paths = [progressive.CameraPath.ORBIT, progressive.CameraPath.ZOOM, progressive.CameraPath.FLY]
    if s.accuracy_points is None:
        path = data.accuracy_file()
        info, make = accuracy.file_scenes(glc, path)
        name = f"{path.name} (real, as it is)"
    else:
        cloud = tiled(str(data.SAMPLE), s.accuracy_points)
        info = cloud.info

        def make(order):
            return load_tiled(glc, cloud, fill=order)[0]
        name = f"{data.SAMPLE.name} tiled on a grid"
    fixed = [max(1, round(f * info.points)) for f in s.accuracy_fixed]
    buds = progressive.budgets(fixed, list(s.targets_ms))
    motion_buds = progressive.budgets(fixed[-1:], list(s.targets_ms[:1]))
    return list(accuracy.run(glc, name, info, make, s.accuracy_size, buds, motion_buds, paths, s.motion_frames,
                             s.accuracy_max_frames, out))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench", description=__doc__.split("\n\n")[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--quick", action="store_true", help="small clouds and frames (llvmpipe; the default)")
    mode.add_argument("--full", action="store_true", help="100M points per section, 1B for raster/progressive")
    mode.add_argument("--smoke", action="store_true", help="seconds: tiny clouds and frames (tests/test_bench.py)")
    ap.add_argument("--out", type=Path, help="results folder (default bench/results/<machine>)")
    ap.add_argument("--out-root", type=Path, help="results go to OUT_ROOT/<machine> (bench/gpu.sh: $OUT)")
    ap.add_argument("--max-points", type=int, help="cap every point count")
    ap.add_argument("--sections", nargs="+", type=Section, default=list(Section), metavar="SECTION",
                    help=", ".join(s.value for s in Section))
    ap.add_argument("--raster-points", type=int, nargs="+", help="override the raster section's point counts")
    ap.add_argument("--raster-layouts", nargs="+", choices=[layout.label for layout in raster.LAYOUTS],
                    help="store orders of the raster section (default: all)")
    ap.add_argument("--progressive-points", type=int, nargs="+", help="override the progressive section's counts")
    ap.add_argument("--load-threads", type=int, nargs="+",
                    help="override the load section's parser threads (the default and every core are always run)")
    ap.add_argument("--load-repeats", type=int, help="override the load section's repeats a row (median)")
    ap.add_argument("--load-formats", nargs="+", choices=data.FORMATS, default=data.FORMATS,
                    help="the load section's formats (default: all; LAS alone fits a device call at 100M points)")
    ap.add_argument("--cache", type=Path, default=data.CACHE, help="where generated files are kept")
    ap.add_argument("--readme", action="store_true", help="insert headline.md into README.md")
    args = ap.parse_args(argv)
    scale = (FULL if args.full else SMOKE if args.smoke else QUICK).capped(args.max_points)
    if args.raster_points:
        scale = dataclasses.replace(scale, raster_points=tuple(args.raster_points))
    if args.progressive_points:
        scale = dataclasses.replace(scale, progressive_points=tuple(args.progressive_points))
    if args.load_threads:
        scale = dataclasses.replace(scale, threads=tuple(args.load_threads))
    if args.load_repeats:
        scale = dataclasses.replace(scale, load_repeats=args.load_repeats)
    glc = create_context()
    out = args.out or (args.out_root or RESULTS) / RunInfo.from_caps(glc.caps, "").machine
    run = RunInfo.from_caps(glc.caps, scale.mode + (f", ≤ {args.max_points:,} points" if args.max_points else ""))
    t_start = time.perf_counter()
    for section in args.sections:
        t0 = time.perf_counter()
        if section is Section.LOAD:
            tables = section_load(glc, scale, args.cache, tuple(args.load_formats))
        elif section is Section.RASTER:
            layouts = [x for x in raster.LAYOUTS if not args.raster_layouts or x.label in args.raster_layouts]
            tables = [raster.run(glc, list(scale.raster_points), list(scale.raster_sizes), scale.raster_repeats,
                                 scale.copy_bytes, layouts)]
        elif section is Section.PROGRESSIVE:
            tables = [progressive.run(glc, n, scale.progressive_size, list(scale.fixed_budgets),
                                      list(scale.targets_ms), list(progressive.CameraPath), scale.motion_frames,
                                      scale.max_frames) for n in scale.progressive_points]
        elif section is Section.ACCURACY:
            tables = section_accuracy(glc, scale, out)
        else:
            tables = [attributes.run(glc, n) for n in scale.progressive_points]
        for t in tables:
            t.write(out, run)
        print(f"{section.value}: {time.perf_counter() - t0:.1f} s -> " + ", ".join(f"{t.name}.md" for t in tables),
              flush=True)
    text = headline.build(out)
    if text:
        (out / "headline.md").write_text(text)
    if text and args.readme:
        headline.insert(headline.README, out.name, text)
    print(text)
    print(f"all sections: {time.perf_counter() - t_start:.1f} s; results in {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
