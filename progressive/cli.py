"""`progressive` command line: info, render, convert. Every user error ends as one
line `progressive: error: ...` on stderr with exit status 2."""

from __future__ import annotations

import argparse
import enum
import os
import sys
import time
from importlib import resources
from pathlib import Path

from progressive.errors import ProgressiveError

MAX_SIZE = 16384


class UsageError(ProgressiveError):
    pass


class Parser(argparse.ArgumentParser):
    """argparse prints usage and exits; we want one line through the same path as
    every other error."""

    def error(self, message: str):
        raise UsageError(message)


def sample_path() -> Path:
    return Path(str(resources.files("progressive.data").joinpath("autzen_trim.las")))


def enum_arg(cls: type[enum.Enum]):
    def parse(text: str):
        try:
            return cls[text.upper().replace("-", "_")]
        except KeyError:
            choices = ", ".join(m.name.lower() for m in cls)
            raise argparse.ArgumentTypeError(f"'{text}' is not one of: {choices}") from None
    parse.__name__ = cls.__name__.lower()
    return parse


def size_arg(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not an integer") from None
    if not 1 <= value <= MAX_SIZE:
        raise argparse.ArgumentTypeError(f"{value} is outside 1..{MAX_SIZE}")
    return value


def rgb_arg(text: str) -> tuple[int, int, int]:
    parts = text.split(",")
    try:
        values = tuple(int(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(0 <= v <= 255 for v in values):
        raise argparse.ArgumentTypeError(f"'{text}' is not R,G,B with values 0..255")
    return values


def input_paths(files: list[str]) -> list[str]:
    return files or [str(sample_path())]


def load_camera(text: str):
    from progressive.camera import Camera, CameraError

    if text.lstrip().startswith("{"):
        return Camera.from_json(text)
    path = Path(text)
    if not path.is_file():
        raise CameraError(f"camera file {text} not found (give 'auto', a JSON file or JSON text)")
    try:
        return Camera.from_json(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise CameraError(f"cannot read camera file {text}: {exc}") from None


def cmd_info(args) -> int:
    import json

    from progressive.loaders import describe, format_text

    desc = describe(input_paths(args.files))
    print(json.dumps(desc, indent=2) if args.json else format_text(desc))
    return 0


def cmd_render(args) -> int:
    from progressive.attributes import default_attribute, find_attribute
    from progressive.camera import auto_camera
    from progressive.context import create_context
    from progressive.loaders import CloudLoader
    from progressive.output import check_writable, write_json, write_npy, write_png
    from progressive.renderer import Renderer

    outputs = [p for p in (args.out, args.ids, args.stats, args.save_camera) if p]
    for p in outputs:
        check_writable(p)
    camera = None if args.camera == "auto" else load_camera(args.camera)
    paths = input_paths(args.files)
    t0 = time.perf_counter()
    with CloudLoader(paths, partial=args.partial) as loader:
        info = loader.info
        attr = find_attribute(info, args.color_by) if args.color_by else default_attribute(info)
        glc = create_context()
        renderer = Renderer(glc, info, attr, raster=args.raster, width=args.width, height=args.height)
        loader.start()
        for batch in loader:
            renderer.add_batch(batch)
        warnings = list(getattr(loader, "warnings", []))
    load_seconds = time.perf_counter() - t0
    for w in warnings:
        print(f"progressive: warning: {w}", file=sys.stderr)
    if camera is None:
        camera = auto_camera(info.bounds_min, info.bounds_max, args.width / args.height)
    frame = renderer.render(camera, args.width, args.height, renderer.style(args.colormap, args.background))
    if args.out:
        write_png(args.out, frame.image)
    if args.ids:
        write_npy(args.ids, frame.ids)
    if args.save_camera:
        write_json(args.save_camera, camera.to_dict())
    if args.stats:
        covered = int((frame.ids != 0xFFFFFFFF).sum())
        write_json(args.stats, {
            "device": glc.caps.description,
            "raster": renderer.raster_path,
            "points": info.points,
            "points_loaded": renderer.loaded,
            "load_seconds": load_seconds,
            "load_points_per_second": renderer.loaded / load_seconds if load_seconds > 0 else None,
            "upload_seconds": renderer.upload_seconds,
            "gpu_ms": frame.gpu_ms,
            "width": args.width,
            "height": args.height,
            "attribute": attr.name,
            "covered_pixels": covered,
            "camera": camera.to_dict(),
        })
    renderer.release()
    glc.release()
    return 0


def cmd_convert(args) -> int:
    from progressive.attributes import default_attribute, find_attribute
    from progressive.loaders import CloudLoader, write_fast
    from progressive.output import check_writable

    check_writable(args.output)
    with CloudLoader(args.inputs, partial=args.partial) as loader:
        info = loader.info
        attr = find_attribute(info, args.attribute) if args.attribute else default_attribute(info)
        loader.start()
        write_fast(args.output, loader, info, attr)
    print(f"wrote {info.points:,} points ({attr.name}) to {args.output}")
    return 0


def build_parser() -> Parser:
    from progressive.colors import Colormap
    from progressive.renderer import Raster

    parser = Parser(prog="progressive", description="Progressive rendering of LAS/LAZ point clouds on the GPU.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)

    info = sub.add_parser("info", help="describe LAS/LAZ files (header, bounds, attributes)")
    info.add_argument("files", nargs="*", help="LAS/LAZ files (default: the bundled sample)")
    info.add_argument("--json", action="store_true", help="machine-readable output")
    info.set_defaults(func=cmd_info)

    render = sub.add_parser("render", help="render a cloud headless to PNG")
    render.add_argument("files", nargs="*", help="LAS/LAZ/fast-format files, one cloud (default: the bundled sample)")
    render.add_argument("--out", help="PNG to write")
    render.add_argument("--width", type=size_arg, default=1280)
    render.add_argument("--height", type=size_arg, default=720)
    render.add_argument("--camera", default="auto", help="auto, a camera JSON file, or JSON text")
    render.add_argument("--save-camera", help="write the camera used as JSON")
    render.add_argument("--color-by", help="attribute to colour by (default: rgb, else intensity, else elevation)")
    render.add_argument("--colormap", type=enum_arg(Colormap), default=Colormap.VIRIDIS)
    render.add_argument("--background", type=rgb_arg, default=(0, 0, 0), help="R,G,B")
    render.add_argument("--raster", type=enum_arg(Raster), default=Raster.COMPUTE,
                        help="compute (64-bit atomics where available), compute32, or points (GL_POINTS baseline)")
    render.add_argument("--ids", help="write the (H, W) uint32 file-order index of each pixel (.npy)")
    render.add_argument("--stats", help="write timings and counts (.json)")
    render.add_argument("--partial", action="store_true", help="render what a truncated file holds, with a warning")
    render.set_defaults(func=cmd_render)

    convert = sub.add_parser("convert", help="write the fast GPU-layout format")
    convert.add_argument("inputs", nargs="+", metavar="IN")
    convert.add_argument("output", metavar="OUT")
    convert.add_argument("--attribute", help="attribute stored in the 4-byte word (default as render)")
    convert.add_argument("--partial", action="store_true")
    convert.set_defaults(func=cmd_convert)
    return parser


def main(argv: list[str] | None = None) -> int:
    try:
        if argv is None:
            argv = sys.argv[1:]
        if len(argv) == 2 and argv[0] == "convert":
            raise UsageError("convert needs at least one input and one output")
        args = build_parser().parse_args(argv)
        if args.command == "render" and not (args.out or args.ids or args.stats or args.save_camera):
            raise UsageError("render needs --out (or --ids/--stats/--save-camera)")
        return args.func(args)
    except ProgressiveError as exc:
        print(f"progressive: error: {exc}", file=sys.stderr)
        return 2
    except (OSError, MemoryError) as exc:
        print(f"progressive: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
