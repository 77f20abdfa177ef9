"""`progressive` command line: info, render, convert. Every user error ends as one
line `progressive: error: ...` on stderr with exit status 2."""

from __future__ import annotations

import argparse
import contextlib
import enum
import os
import signal
import sys
import threading
from importlib import resources
from pathlib import Path

import numpy as np

from progressive.errors import ProgressiveError

MAX_SIZE = 16384
MAX_FRAMES = 16384
"""Frames of --frames, --max-frames and cameras of --camera-path."""
MAX_HEADLESS_FRAMES = 1000
SHOWN_CHARS = 40
STDOUT = "-"
"""The output name that prints instead (`render --stats -`), for pipelines that read it."""


class UsageError(ProgressiveError):
    pass


class Parser(argparse.ArgumentParser):
    """argparse prints usage and exits; we want one line through the same path as
    every other error."""

    def error(self, message: str):
        raise UsageError(message)


def sample_path() -> Path:
    return Path(str(resources.files("progressive.data").joinpath("autzen_trim.las")))


def shown(text: str) -> str:
    """A value as a message quotes it: cut short (5,000 digits would fill the screen),
    control characters escaped."""
    return repr(text if len(text) <= SHOWN_CHARS else text[:SHOWN_CHARS] + "...")


def enum_arg(cls: type[enum.Enum]):
    def parse(text: str):
        try:
            return cls[text.upper().replace("-", "_")]
        except KeyError:
            choices = ", ".join(m.name.lower() for m in cls)
            raise argparse.ArgumentTypeError(f"{shown(text)} is not one of: {choices}") from None
    parse.__name__ = cls.__name__.lower()
    return parse


def path_arg(text: str) -> str:
    """A file name: no NUL byte (the system cannot take one)."""
    if "\0" in text:
        raise argparse.ArgumentTypeError(f"{shown(text)} is not a file name (it holds a NUL byte)")
    return text


def int_arg(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{shown(text)} is not an integer") from None


def float_arg(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{shown(text)} is not a number") from None


def detail_arg(text: str) -> float:
    """A number of pixels, 0 or more."""
    value = float_arg(text)
    if not (np.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"{shown(text)} is not a number of pixels, 0 or more")
    return value


def seconds_arg(text: str) -> float:
    """A positive number of seconds."""
    value = float_arg(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{shown(text)} is not a positive number of seconds")
    return value


def bounded_int(limit: int):
    """An integer in 1..limit."""
    def parse(text: str) -> int:
        value = int_arg(text)
        if not 1 <= value <= limit:
            raise argparse.ArgumentTypeError(f"{shown(text)} is outside 1..{limit}")
        return value
    parse.__name__ = "integer"
    return parse


size_arg = bounded_int(MAX_SIZE)
frames_arg = bounded_int(MAX_FRAMES)


def rgb_arg(text: str) -> tuple[int, int, int]:
    parts = text.split(",")
    try:
        values = tuple(int(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(0 <= v <= 255 for v in values):
        raise argparse.ArgumentTypeError(f"{shown(text)} is not R,G,B with values 0..255")
    return values


def classes_arg(text: str) -> frozenset[int]:
    try:
        codes = frozenset(int(c) for c in text.split(",") if c.strip())
    except ValueError:
        codes = frozenset({-1})
    if not codes or not all(0 <= c <= 255 for c in codes):
        raise argparse.ArgumentTypeError(f"{shown(text)} is not a comma-separated list of class codes 0..255")
    return codes


def range_arg(text: str) -> tuple[float, float]:
    """LO,HI in the attribute's own units: finite, LO < HI."""
    parts = text.split(",")
    try:
        lo, hi = (float(p) for p in parts)
    except ValueError:
        lo = hi = float("nan")
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise argparse.ArgumentTypeError(f"{shown(text)} is not LO,HI with finite LO < HI")
    return lo, hi


def floats_arg(count: int, what: str):
    """COUNT comma-separated finite numbers."""
    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(p) for p in text.split(","))
        except ValueError:
            values = ()
        if len(values) != count or not all(np.isfinite(values)):
            raise argparse.ArgumentTypeError(f"{shown(text)} is not {what}")
        return values
    parse.__name__ = what
    return parse


def clip_from(args):
    """The clip of --clip-box, --clip-z and --clip-section (all given: their
    intersection), file coordinates."""
    from progressive.camera import NO_CLIP, CameraError, Clip, Section

    try:
        box = Clip(args.clip_box[:3], args.clip_box[3:]) if args.clip_box else NO_CLIP
        slab = Clip((-np.inf, -np.inf, args.clip_z[0]), (np.inf, np.inf, args.clip_z[1])) if args.clip_z else NO_CLIP
        s = args.clip_section
        section = Clip(section=Section(start=(s[0], s[1]), end=(s[2], s[3]), width=s[4])) if s else NO_CLIP
    except CameraError as exc:
        raise UsageError(str(exc)) from None
    try:
        return box.intersect(slab).intersect(section)
    except CameraError:
        raise UsageError("--clip-box and --clip-z do not overlap: nothing would be drawn") from None


def eye_dome_from(args):
    """--eye-dome-strength and --eye-dome-radius, checked wherever eye-dome lighting may
    be on: asked for, or left to the viewer's rules (None); None where it is off."""
    from progressive.effects import EyeDome

    if args.eye_dome is False:
        return None
    try:
        return EyeDome(args.eye_dome_strength, args.eye_dome_radius)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def effects_from(args):
    """The screen-space effects asked for on the command line; what `view` leaves to
    the viewer's rules (None) is 1 pixel and no eye-dome lighting here, as `render`."""
    from progressive.effects import Effects

    try:
        size = 1 if args.point_size is None else args.point_size
        return Effects(size, eye_dome_from(args) if args.eye_dome else None)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def add_cloud_args(parser) -> None:
    """Options shared by render and view: the files, the frame size, loading, colouring."""
    from progressive.batches import BATCH_ORDER, BatchOrder
    from progressive.memory import SOFTWARE_STREAM_BYTES, STREAM_BYTES
    from progressive.streaming import FINEST_PX

    parser.add_argument("files", nargs="*", type=path_arg, help="LAS/LAZ/fast-format files, one cloud (default: the bundled sample)")
    parser.add_argument("--width", type=size_arg, default=1280)
    parser.add_argument("--height", type=size_arg, default=720)
    parser.add_argument("--color-by", help="attribute to colour by (default: rgb where it is real, else elevation)")
    parser.add_argument("--range", type=range_arg, dest="value_range", metavar="LO,HI",
                        help="scalar values at the colormap's ends (default: the 1st-99th percentile of the loaded points)")
    parser.add_argument("--partial", action="store_true", help="show what a truncated file holds, with a warning")
    parser.add_argument("--gpu-memory-limit", type=bytes_arg, help="GPU memory to use, e.g. 4G; a larger cloud shows "
                        "whole levels of its COPC files, else a uniform random subset (the free memory the driver "
                        "reports also counts); a streamed COPC keeps the nodes each view needs within it "
                        f"(default {STREAM_BYTES / 2**30:g}G, {SOFTWARE_STREAM_BYTES >> 20}M on a software "
                        "renderer such as llvmpipe)")
    parser.add_argument("--batch-order", type=enum_arg(BatchOrder), default=BATCH_ORDER,
                        help="file (store batches of consecutive points in file order) or morton (each loaded "
                             "batch's whole store batches sorted by Morton code first: compacter batches where the "
                             "file's order wanders)")
    parser.add_argument("--stream", action=argparse.BooleanOptionalAction, default=None,
                        help="COPC files: keep on the GPU the octree nodes each view needs, read in the background "
                             "as the camera moves, within the GPU memory (progressive frames; view streams COPC "
                             "files unless told --no-stream)")
    parser.add_argument("--stream-detail", type=detail_arg, default=FINEST_PX, metavar="PX",
                        help="a streamed COPC cloud larger than the GPU memory reads no node whose points lie closer "
                             "than PX pixels on screen: fewer reads and bytes fetched, a coarser still image "
                             f"(default {FINEST_PX:g}: nodes until the memory is full)")
    add_reproject_arg(parser)
    add_http_arg(parser)
    parser.add_argument("--palette", type=path_arg, metavar="FILE.json",
                        help='classification colours overriding the default ones: {"2": [166, 116, 66], "6": "#ff8c1e"}')


def add_http_arg(parser) -> None:
    from progressive.loaders.http import MAX_REQUESTS_IN_FLIGHT, REQUESTS_IN_FLIGHT, TIMEOUT_S

    parser.add_argument("--http-timeout", type=seconds_arg, default=TIMEOUT_S, metavar="SECONDS",
                        help=f"how long a request for an http(s):// COPC file may wait for the server "
                             f"(default {TIMEOUT_S:g})")
    parser.add_argument("--http-requests", type=bounded_int(MAX_REQUESTS_IN_FLIGHT), default=REQUESTS_IN_FLIGHT,
                        metavar="N", help=f"range requests in flight at once to an http(s):// COPC file "
                                          f"(default {REQUESTS_IN_FLIGHT}; fewer for a server that limits clients)")


def http_from(args):
    from progressive.loaders.http import HttpOptions

    return HttpOptions(timeout_s=args.http_timeout, in_flight=args.http_requests)


def add_reproject_arg(parser) -> None:
    parser.add_argument("--reproject", type=reproject_arg, metavar="EPSG:CODE",
                        help="load files in any coordinate systems as one cloud in this one (float64, pyproj)")


def reproject_arg(text: str) -> str:
    """A CRS code pyproj knows, checked before any file is read."""
    from progressive.reproject import target_crs

    try:
        target_crs(text)
    except ProgressiveError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--reproject ")) from None
    return text.strip().upper()


def palette_from(args):
    """The classification palette: the default, with --palette's entries in place."""
    from progressive.colors import DEFAULT_PALETTE, Palette

    return Palette.from_json(args.palette) if args.palette else DEFAULT_PALETTE


def add_look_args(parser, chosen: bool = False) -> None:
    """Options shared by render and view: effects, filters and clip boxes. `chosen`
    (view): --point-size and --eye-dome/--no-eye-dome default to None, the viewer's
    rules (viewer/defaults.py), so that any value given, 1 and off included, stays."""
    from progressive.camera import Returns

    if chosen:
        parser.add_argument("--point-size", type=int_arg, default=None,
                            help="pixels across a point (a screen-space pass; default: from the density on screen)")
        parser.add_argument("--eye-dome", action=argparse.BooleanOptionalAction, default=None,
                            help="eye-dome lighting on or off (default: on where it helps and its cost fits the frame)")
    else:
        parser.add_argument("--point-size", type=int_arg, default=1, help="pixels across a point (a screen-space pass)")
        parser.add_argument("--eye-dome", action="store_true", help="eye-dome lighting")
    parser.add_argument("--eye-dome-strength", type=float_arg, default=1.0)
    parser.add_argument("--eye-dome-radius", type=float_arg, default=1.4, help="pixels")
    parser.add_argument("--hide-classes", type=classes_arg, default=frozenset(),
                        help="classification codes left out, e.g. 7,18 (whatever the colouring)")
    parser.add_argument("--returns", type=enum_arg(Returns), default=Returns.ALL,
                        help="all, first (return 1), last (return = number of returns) or single returns")
    parser.add_argument("--clip-box", type=floats_arg(6, "xmin,ymin,zmin,xmax,ymax,zmax"),
                        help="draw only points inside this box (file coordinates, sides included)")
    parser.add_argument("--clip-z", type=floats_arg(2, "zmin,zmax"), help="draw only points between these heights")
    parser.add_argument("--clip-section", type=floats_arg(5, "x0,y0,x1,y1,width"),
                        help="draw only points within width/2 of the segment (x0,y0)-(x1,y1) in XY, between its "
                             "ends: a vertical slab for profiles")


def one_line(text: str) -> str:
    """text with every control or other unprintable character escaped, so a message
    naming a file called "a\\nb" is still one line."""
    return "".join(c if c.isprintable() else c.encode("unicode_escape", "backslashreplace").decode("ascii")
                   for c in str(text))


def warn(text: str) -> None:
    print(f"progressive: warning: {one_line(text)}", file=sys.stderr)


def input_paths(files: list[str]) -> list[str]:
    return files or [str(sample_path())]


def load_camera(text: str):
    from progressive.camera import Camera, CameraError, read_json_file

    if text.lstrip().startswith("{"):
        return Camera.from_json(text)
    if not os.path.lexists(text):
        raise CameraError(f"camera file {text} not found (give 'auto', a JSON file or JSON text)")
    return Camera.from_dict(read_json_file(text, "camera file"))


def cmd_info(args) -> int:
    import json

    from progressive.loaders import describe, format_text
    from progressive.reproject import describe_crs, describe_reprojected, format_crs

    paths = input_paths(args.files)
    http = http_from(args)
    if args.reproject:
        desc, own = describe_reprojected(paths, args.reproject, http=http)
        say(json.dumps(desc, indent=2) if args.json else format_crs(desc, "\n\n".join(map(format_text, own))))
        return 0
    desc = describe(paths, http=http)
    for summary, f in zip(desc["files"], _file_infos(paths, http)):
        summary.update(describe_crs(f))
    desc.update({k: desc["files"][0][k] for k in ("crs_name", "epsg")})
    hierarchies = _hierarchies(desc, http)
    text = "" if args.json else format_crs(desc, format_text(desc))
    say(json.dumps(desc, indent=2) if args.json else "\n\n".join([text, *hierarchies]))
    return 0


def _hierarchies(desc: dict, http) -> list[str]:
    """Each COPC file's octree (levels, nodes, points per level), into its summary as
    "copc" (null for other files); the text of each."""
    from progressive.loaders.copc import describe_hierarchy, format_hierarchy

    texts = []
    for summary in desc["files"]:
        summary["copc"] = describe_hierarchy(summary["path"], http)
        if summary["copc"] is not None:
            texts.append(format_hierarchy(summary["path"], summary["copc"]))
    return texts


def _file_infos(paths, http):
    from progressive.loaders import open_cloud

    return open_cloud(paths, http=http).files


def budget_arg(text: str) -> int | None:
    """A fixed number of points per frame, or None for 'auto' (the adaptive budget)."""
    if text.lower() == "auto":
        return None
    try:
        value = int(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{shown(text)} is not a number of points or 'auto'") from None
    if not 1 <= value < 2**32:
        raise argparse.ArgumentTypeError(f"budget {shown(text)} is outside 1..2^32-1")
    return value


def bytes_arg(text: str) -> int:
    """A size such as 512M, 2G or 1.5GiB (powers of 1024)."""
    units = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
    t = text.strip().upper().removesuffix("IB").removesuffix("B")
    unit = t[-1] if t and t[-1] in units else ""
    try:
        value = float(t[: len(t) - len(unit)]) * units[unit]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{shown(text)} is not a size like 512M or 2G") from None
    if not 1 <= value < 2**50:
        raise argparse.ArgumentTypeError(f"size {shown(text)} is outside 1 byte..1P")
    return int(value)


def positive_float(text: str) -> float:
    value = float_arg(text)
    if not 0.0 < value < 10_000.0:
        raise argparse.ArgumentTypeError(f"{shown(text)} is outside (0, 10000)")
    return value


def load_camera_path(path: str):
    """A JSON list of cameras (or {"cameras": [...]}), one per frame."""
    from progressive.camera import Camera, CameraError, read_json_file

    data = read_json_file(path, "camera path")
    if isinstance(data, dict):
        data = data.get("cameras")
    if not isinstance(data, list) or not data:
        raise CameraError(f"camera path {path} must be a non-empty list of cameras")
    if len(data) > MAX_FRAMES:
        raise CameraError(f"camera path {path} has {len(data):,} cameras (at most {MAX_FRAMES:,} frames)")
    cameras = []
    for i, item in enumerate(data):
        try:
            cameras.append(Camera.from_dict(item))
        except CameraError as exc:
            raise CameraError(f"camera path {path}, camera {i}: {exc}") from None
    return cameras


def session_options(args):
    from progressive.budget import BudgetParams
    from progressive.frame_loop import ProgressiveOptions
    from progressive.session import SessionOptions, Streaming

    budget = BudgetParams(target_ns=int(args.target_ms * 1e6), fixed=args.budget)
    progressive = ProgressiveOptions(budget=budget, reference=args.reference or args.converge)
    return SessionOptions(width=args.width, height=args.height, method=args.method, raster=args.raster,
                          progressive=progressive, color_by=args.color_by,
                          colormap=args.colormap, background=args.background, partial=args.partial,
                          gpu_memory_limit=args.gpu_memory_limit, value_range=args.value_range,
                          class_filter=filters(args), palette=palette_from(args), reproject=args.reproject, http=http_from(args),
                          precision=args.precision, batch_order=args.batch_order,
                          stream=streaming(args.stream, Streaming.OFF), stream_detail_px=args.stream_detail)


def cmd_render(args) -> int:
    import json
    from dataclasses import replace

    from progressive.encoding import Precision
    from progressive.output import Outputs, check_outputs, json_text, json_writer, npy_writer, png_writer
    from progressive.session import Method, Session

    paths = input_paths(args.files)
    camera_file = None if args.camera == "auto" or args.camera.lstrip().startswith("{") else args.camera
    stats_out = args.stats == STDOUT
    if stats_out and args.pick:
        raise UsageError("--stats - and --pick both print to standard output: give --stats a file")
    check_outputs((args.out, args.ids, None if stats_out else args.stats, args.save_camera),
                  [*paths, *(p for p in (camera_file, args.camera_path) if p)])
    cameras = load_camera_path(args.camera_path) if args.camera_path else None
    camera = None if args.camera == "auto" or cameras else load_camera(args.camera)
    if args.method is Method.BRUTE and (args.converge or args.reference or cameras):
        raise UsageError("--converge, --reference and --camera-path need --method progressive")
    if args.precision is not Precision.EXACT and args.method is not Method.BRUTE:
        raise UsageError("--precision adaptive needs --method brute: progressive frames reproject each point at its "
                         "exact position")
    effects, clip = effects_from(args), clip_from(args)       # bad values are one line before any work
    first = camera or (cameras[0] if cameras else None)      # a COPC cloud over the limit keeps what it needs
    with Session(paths, replace(session_options(args), camera=first)) as session, Outputs() as outputs:
        check_classes(session, args)
        if cameras is None:
            cameras = [camera or session.auto_camera()]
        converged_at, frames = _run_frames(session, cameras, args, effects, clip)
        for w in session.warnings:
            warn(w)
        stats = _stats(session, cameras[-1], frames, converged_at, clip)
        stats["returns"] = args.returns.name.lower()
        image, ids = session.image(), session.ids()
        if args.out:
            outputs.write(args.out, png_writer(image))
        if args.ids:
            outputs.write(args.ids, npy_writer(ids))
        if args.save_camera:
            outputs.write(args.save_camera, json_writer(cameras[-1].to_dict()))
        if args.stats:
            stats["covered_pixels"] = int((ids != 0xFFFFFFFF).sum())
            if not stats_out:
                outputs.write(args.stats, json_writer(stats))
        if args.pick:
            picked = session.pick(*args.pick)
            commit_saying(outputs, json.dumps({"found": picked is not None, **(picked or {})}))
        elif stats_out:
            commit_saying(outputs, json_text(stats))
        else:
            outputs.commit()
    if args.converge and converged_at is None:
        warn(f"did not converge within {frames} frames")
        return 1
    return 0


def filters(args) -> bool:
    """Whether the GPU must keep each point's class and return flags."""
    from progressive.camera import Returns

    return bool(args.hide_classes) or args.returns is not Returns.ALL


def check_classes(session, args) -> None:
    if filters(args) and not session.filters_classes:
        raise UsageError(f"--{'hide-classes' if args.hide_classes else 'returns'}: this cloud has no classification")


def _run_frames(session, cameras, args, effects, clip) -> tuple[int | None, int]:
    """Frames as asked: a fixed count, the camera path, or until equal to brute force."""
    hidden, returns = args.hide_classes, args.returns
    if not session.progressive:
        session.frame(cameras[0], None, effects, hidden, clip, returns)
        return None, 1
    limit = args.frames or (args.max_frames if args.converge else len(cameras))
    limit = max(limit, len(cameras)) if not args.frames else limit
    converged_at = None
    for k in range(limit):
        session.frame(cameras[min(k, len(cameras) - 1)], None, effects, hidden, clip, returns)
        if args.converge and k + 1 >= len(cameras):
            converged_at = _first_equal(session.history, len(cameras) - 1)
            if converged_at is not None:
                return converged_at, k + 1
    if args.converge:
        converged_at = _first_equal(session.stats(), len(cameras) - 1)
    return converged_at, limit


def _first_equal(history, after: int) -> int | None:
    return next((s.frame for s in history if s.frame >= after and s.equal_fraction == 1.0), None)


def _stats(session, camera, frames: int, converged_at: int | None, clip) -> dict:
    """What --stats writes; "copc": per file, its levels, nodes and points kept and read
    (null for files other than COPC); "stream": a streamed cloud's nodes (else null)."""
    import dataclasses

    from progressive import memory

    status = session.status()
    out = {
        "device": session.glc.caps.description,
        "method": session.options.method.value,
        "raster": status.raster,
        "points": status.points,
        "points_loaded": status.loaded,
        "points_on_gpu": status.on_gpu,
        "points_not_drawn": status.not_drawn,
        "load_seconds": session.load_seconds,
        "load_points_per_second": status.loaded / session.load_seconds if session.load_seconds else None,
        "first_image_seconds": session.first_image_seconds,
        "startup_seconds": session.startup,
        "programs": session.glc.programs.stats.as_dict(),
        "width": session.options.width,
        "height": session.options.height,
        "attribute": session.attribute.name,
        "color_range": session.color_range(),
        "precision": session.options.precision.value,
        "batch_order": session.options.batch_order.value,
        "batches": session.batch_counts(camera, clip),
        "clip": {"min": [v if np.isfinite(v) else None for v in clip.lo],
                 "max": [v if np.isfinite(v) else None for v in clip.hi],
                 "section": None if clip.section is None else {
                     "start": list(clip.section.start), "end": list(clip.section.end), "width": clip.section.width}},
        "peak_rss_bytes": memory.peak_rss_bytes(),
        "camera": camera.to_dict(),
        "frames_rendered": frames,
        "copc": [None if c is None else dataclasses.asdict(c) for c in status.copc],
        "stream": None if status.stream is None else status.stream.as_dict(),
    }
    if session.progressive:
        history = session.stats()
        out["frames"] = [s.as_dict() for s in history]
        out["converged_frame"] = converged_at
        timed = [s for s in history if s.gpu_ms]
        if timed:
            out["median_fill_fraction"] = float(np.median([s.gpu_ms["fill"] / s.gpu_ms["frame"] for s in timed
                                                           if s.gpu_ms["frame"] > 0]))
    else:
        out["gpu_ms"] = session.last_frame.gpu_ms
    return out


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def cmd_view(args) -> int:
    """A window where there is a display; elsewhere the same cloud rendered headless
    to a PNG, so the README's first command works on any machine."""
    from progressive.context import GLCapabilityError
    from progressive.output import check_outputs

    paths = input_paths(args.files)
    effects, edl, clip = effects_from(args), eye_dome_from(args), clip_from(args)   # bad values: one line, no window
    options = view_session_options(args)
    check_cloud(paths, args)        # a bad file or attribute is one line, before any notice or window
    if has_display():
        from progressive.effects import EyeDome
        from progressive.viewer.app import Viewer, ViewerOptions

        try:
            viewer = Viewer(paths, ViewerOptions(session=options, ui=not args.no_ui, point_size=args.point_size,
                                                 eye_dome=args.eye_dome,
                                                 eye_dome_params=edl or EyeDome(),
                                                 hidden_classes=args.hide_classes, clip=clip, returns=args.returns))
        except GLCapabilityError as exc:
            print(f"progressive: cannot open a window ({one_line(exc)}); rendering headless instead", file=sys.stderr)
        else:
            viewer.run()
            return 0
    else:
        check_outputs([args.out], paths)
        print(f"progressive: no display (DISPLAY and WAYLAND_DISPLAY are unset); rendering headless to "
              f"{one_line(args.out)}", file=sys.stderr)
    return _view_headless(paths, effects, clip, args, options)


def check_cloud(paths: list[str], args) -> None:
    """Open the files' headers (reprojected as asked) and find --color-by."""
    from progressive.attributes import find_attribute
    from progressive.reproject import open_info, target_crs

    info = open_info(paths, partial=args.partial, reproject=target_crs(args.reproject) if args.reproject else None,
                     http=http_from(args))
    if args.color_by:
        find_attribute(info, args.color_by)


def view_session_options(args):
    """What `view` asks of its session, in a window or headless."""
    from progressive.session import SessionOptions, Streaming

    return SessionOptions(width=args.width, height=args.height, color_by=args.color_by, partial=args.partial,
                          gpu_memory_limit=args.gpu_memory_limit, value_range=args.value_range,
                          class_filter=filters(args), palette=palette_from(args), reproject=args.reproject, http=http_from(args),
                          batch_order=args.batch_order, stream=streaming(args.stream, Streaming.AUTO),
                          stream_detail_px=args.stream_detail)


def streaming(flag: bool | None, default):
    """--stream: required; --no-stream: off; neither: the command's default."""
    from progressive.session import Streaming

    return default if flag is None else Streaming.ON if flag else Streaming.OFF


def _view_headless(paths: list[str], effects, clip, args, options) -> int:
    from progressive.output import Outputs, check_outputs, png_writer
    from progressive.session import Session

    check_outputs([args.out], paths)
    with Session(paths, options) as session, Outputs() as outputs:
        check_classes(session, args)
        camera = session.auto_camera()
        frames = 0
        while not session.converged and frames < MAX_HEADLESS_FRAMES:
            drawn = session.frame(camera, None, effects, args.hide_classes, clip, args.returns)
            session.stats()
            if drawn:
                frames += 1         # frames that rested while points load do not count
            elif not session.status().loading:
                break               # nothing to draw and nothing on its way

        for w in session.warnings:
            warn(w)
        outputs.write(args.out, png_writer(session.image()))
        state = "exact" if session.converged else "not converged"
        status = session.status()
        shown = f"{status.on_gpu:,} of {status.points:,}" if status.stream is not None else f"{status.points:,}"
        commit_saying(outputs, f"wrote {Path(args.out).resolve()} ({shown} points, {state} after "
                               f"{frames} frames, first image {session.first_image_seconds:.2f} s after opening)")
    return 0


def say(message: str) -> None:
    """Print to stdout and flush: stdout that cannot take it (a full disk, a closed
    pipe) is an error, not a traceback or a message lost at exit."""
    try:
        print(message, flush=True)
    except OSError as exc:
        raise UsageError(f"cannot write to standard output: {exc.strerror or exc}") from None


def commit_saying(outputs, message: str) -> None:
    """Print the final message, then commit: when it cannot be written the run fails
    and the outputs are removed."""
    say(message)
    outputs.commit()


def cmd_convert(args) -> int:
    from progressive.attributes import default_attribute, find_attribute
    from progressive.loaders import positioned, write_fast_stream
    from progressive.loaders.copc import COPC_SUFFIX
    from progressive.output import Outputs, check_outputs
    from progressive.reproject import open_loader

    check_outputs([args.output], args.inputs)
    if args.output.lower().endswith(COPC_SUFFIX):
        return _convert_copc(args)
    with open_loader(args.inputs, partial=args.partial, on_parsed=positioned) as loader, Outputs() as outputs:
        info = loader.info
        attr = find_attribute(info, args.attribute) if args.attribute else default_attribute(info)
        loader.start()
        with open(outputs.reserve(args.output), "wb") as stream:     # the transaction's temporary, no other
            written = write_fast_stream(stream, loader, info, attr, args.output)
        commit_saying(outputs, f"wrote {written:,} points ({attr.name}) to {args.output}")
    return 0


def _convert_copc(args) -> int:
    """OUT.copc.laz: the inputs as one COPC file (loaders/copc_write.py)."""
    from progressive.loaders.copc import COPC_SUFFIX
    from progressive.loaders.copc_write import write_copc
    from progressive.output import Outputs

    if args.attribute:
        raise UsageError(f"--attribute is for the fast format; a {COPC_SUFFIX} file keeps every attribute")
    with Outputs() as outputs:
        with open(outputs.reserve(args.output), "w+b") as stream:     # the transaction's temporary, no other
            written = write_copc(stream, args.inputs, partial=args.partial,
                                 scratch=os.path.dirname(os.path.abspath(args.output)))
        for w in written.warnings:
            warn(w)
        commit_saying(outputs, f"wrote {written.points:,} points to {args.output} (COPC: {written.levels} levels, "
                               f"{written.nodes:,} nodes)")
    return 0


def build_parser() -> Parser:
    from progressive.colors import Colormap
    from progressive.encoding import Precision
    from progressive.loaders.copc import COPC_SUFFIX
    from progressive.renderer import Raster
    from progressive.session import Method

    parser = Parser(prog="progressive", description="Progressive rendering of LAS/LAZ point clouds on the GPU.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)

    info = sub.add_parser("info", help="describe LAS/LAZ files (header, bounds, attributes)")
    info.add_argument("files", nargs="*", type=path_arg, help="LAS/LAZ files (default: the bundled sample)")
    info.add_argument("--json", action="store_true", help="machine-readable output")
    add_reproject_arg(info)
    add_http_arg(info)
    info.set_defaults(func=cmd_info)

    render = sub.add_parser("render", help="render a cloud headless to PNG")
    add_cloud_args(render)
    render.add_argument("-o", "--out", type=path_arg, help="PNG to write")
    render.add_argument("--camera", default="auto", help="auto, a camera JSON file, or JSON text")
    render.add_argument("--save-camera", type=path_arg, help="write the camera used as JSON")
    render.add_argument("--colormap", type=enum_arg(Colormap), default=Colormap.VIRIDIS)
    render.add_argument("--background", type=rgb_arg, default=(0, 0, 0), help="R,G,B")
    render.add_argument("--raster", type=enum_arg(Raster), default=Raster.COMPUTE,
                        help="compute (64-bit atomics where available), compute32, or points (GL_POINTS baseline)")
    render.add_argument("--precision", type=enum_arg(Precision), default=Precision.EXACT,
                        help="exact (every point's full 30-bit position: the render contract) or adaptive (with "
                             "--method brute: a distant batch's points from fewer bits, each within half a pixel of "
                             "where it projects)")
    add_look_args(render)
    render.add_argument("--ids", type=path_arg, help="write the (H, W) uint32 file-order index of each pixel (.npy)")
    render.add_argument("--stats", type=path_arg, help="write timings and counts (.json; - prints them)")
    render.add_argument("--pick", type=floats_arg(2, "X,Y"), metavar="X,Y",
                        help="print the point shown nearest to image pixel X,Y (row 0 at the top) as one JSON "
                             "object: file, index, x, y, z in file coordinates, every attribute")
    render.add_argument("--method", type=enum_arg(Method), default=Method.BRUTE,
                        help="brute (every point in one frame) or progressive (reproject + budgeted fill)")
    render.add_argument("--budget", type=budget_arg, default=None, help="points filled per frame, or auto (default)")
    render.add_argument("--target-ms", type=positive_float, default=1000.0 / 60.0, help="frame time target (auto budget)")
    render.add_argument("--frames", type=frames_arg, help="progressive frames to render")
    render.add_argument("--converge", action="store_true", help="render until the ids equal the brute-force ids")
    render.add_argument("--max-frames", type=frames_arg, default=1000, help="limit for --converge")
    render.add_argument("--camera-path", type=path_arg, help="JSON list of cameras, one per frame")
    render.add_argument("--reference", action="store_true", help="report per frame the share of pixels equal to brute force")
    render.set_defaults(func=cmd_render)

    view = sub.add_parser("view", help="open a window on the cloud (without a display: render it to a PNG)")
    add_cloud_args(view)
    view.add_argument("--no-ui", action="store_true", help="no panel (keys still work)")
    add_look_args(view, chosen=True)
    view.add_argument("-o", "--out", type=path_arg, default="progressive-view.png", help="PNG written when there is no display")
    view.set_defaults(func=cmd_view)

    convert = sub.add_parser("convert", help=f"write the fast GPU-layout format, or COPC where OUT ends in {COPC_SUFFIX}")
    convert.add_argument("inputs", nargs="+", type=path_arg, metavar="IN")
    convert.add_argument("output", type=path_arg, metavar="OUT")
    convert.add_argument("--attribute", help="attribute stored in the 4-byte word (default as render)")
    convert.add_argument("--partial", action="store_true")
    convert.set_defaults(func=cmd_convert)
    return parser


class Interrupted(BaseException):
    """A signal that ends the run, raised in the main thread so that every `finally`
    and cleanup (temporary outputs, loader threads, the GL context) runs."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


EXIT_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


@contextlib.contextmanager
def signals_raise():
    """For one run: SIGINT, SIGTERM and SIGHUP raise Interrupted (once; later ones are
    ignored so that the cleanup is not cut short). Signals the caller ignores (nohup)
    stay ignored; the previous handlers come back after."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handle(signum, frame):
        for s in previous:
            signal.signal(s, signal.SIG_IGN)
        raise Interrupted(signum)

    previous = {s: signal.getsignal(s) for s in EXIT_SIGNALS if signal.getsignal(s) is not signal.SIG_IGN}
    try:
        for s in previous:
            signal.signal(s, handle)
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def main(argv: list[str] | None = None) -> int:
    try:
        with signals_raise():
            return _main(sys.argv[1:] if argv is None else argv)
    except Interrupted as exc:
        return 128 + exc.signum
    except KeyboardInterrupt:
        return 128 + signal.SIGINT


def _main(argv: list[str]) -> int:
    try:
        if len(argv) == 2 and argv[0] == "convert":
            raise UsageError("convert needs at least one input and one output")
        args = build_parser().parse_args(argv)
        if args.command == "render" and not (args.out or args.ids or args.stats or args.save_camera or args.pick):
            raise UsageError("render needs --out (or --ids/--stats/--save-camera/--pick)")
        return args.func(args)
    except (ProgressiveError, OSError) as exc:
        error = exc
    except MemoryError:
        error = "out of memory"
    print(f"progressive: error: {one_line(error)}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
