"""What a streamed view's finest detail (SessionOptions.stream_detail_px) costs and
gives up: COPC files opened streamed under a GPU memory limit that holds a share of
their points, the auto camera held still until the view converges, once for each finest
detail; against the whole file's brute-force render (not streamed, every point), the
pixels it covers that the streamed view leaves empty, the pixels whose point differs and
the mean colour difference. The files: the real COPC files of ../shared/data (a few
hundred thousand points, in few nodes) on a small image, and the bundled sample tiled to
--points and converted (bench/stream.py build: a deep octree, several points a pixel as
a 1 B-point cloud has on a full-HD screen).

    python -m bench.detail [--points 5000000] [--share 0.25] [--details 0 0.125 0.25 0.5 1]

writes bench/results/<machine>/detail.{md,json}."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from bench.data import SHARED
from bench.report import RunInfo, Table
from bench.stream import build
from progressive import memory
from progressive.context import Capabilities
from progressive.reference import EMPTY
from progressive.session import Method, Session, SessionOptions, Streaming

RESULTS = Path(__file__).resolve().parent / "results"
FILES = ("lone-star.copc.laz", "lion_takanawa.copc.laz")
SIZE = "320x180"
TILED_SIZE = "640x360"
POINTS = 5_000_000
DETAILS = (0.0, 0.125, 0.25, 0.5, 1.0)
FRAMES = 2000
"""Most frames a still view is given to converge (the bench fails past them)."""
COLUMNS = ("file", "points", "image", "finest detail px", "resident points", "share of file", "nodes read",
           "MB read", "converged s", "frames", "pixels covered", "empty where the file has a point",
           "another point", "mean |ΔRGB|")


def converge(s: Session, camera) -> tuple[float, int]:
    """Seconds and frames until the still view is exact."""
    t0 = time.perf_counter()
    for n in range(1, FRAMES + 1):
        s.frame(camera)
        if s.converged:
            return time.perf_counter() - t0, n
    raise RuntimeError(f"the view did not converge in {FRAMES} frames")


def compare(ids: np.ndarray, image: np.ndarray, ref_ids: np.ndarray, ref_image: np.ndarray) -> dict:
    covered = ref_ids != EMPTY
    n = max(int(covered.sum()), 1)
    rgb = np.abs(image[..., :3].astype(np.int32) - ref_image[..., :3].astype(np.int32)).sum(axis=-1) / 3
    return {"covered": int(covered.sum()), "empty": int((covered & (ids == EMPTY)).sum()) / n,
            "other": int((covered & (ids != EMPTY) & (ids != ref_ids)).sum()) / n,
            "rgb": float(rgb[covered].mean())}


def measure(path: Path, size: tuple[int, int], share: float, details) -> tuple[list[dict], Capabilities]:
    """The rows of one file, and the device that drew them."""
    width, height = size
    with Session([str(path)], SessionOptions(width=width, height=height, color_by="intensity",
                                             method=Method.BRUTE)) as s:
        camera = s.auto_camera()
        points = s.info.points
        s.frame(camera)
        ref_ids, ref_image, caps = s.ids(), s.image(), s.glc.caps
    limit = memory.bytes_for(int(points * share), width * height)
    rows = []
    for detail in details:
        options = SessionOptions(width=width, height=height, color_by="intensity", stream=Streaming.ON,
                                 gpu_memory_limit=limit, stream_detail_px=detail)
        with Session([str(path)], options) as s:
            seconds, frames = converge(s, camera)
            status = s.status()
            rows.append({"file": path.name, "points": points, "size": f"{width}x{height}", "detail_px": detail,
                         "resident_points": status.stream.resident_points, "nodes_read": status.copc[0].nodes_read,
                         "bytes_read": status.copc[0].bytes_read, "seconds": seconds, "frames": frames,
                         **compare(s.ids(), s.image(), ref_ids, ref_image)})
    return rows, caps


def run(sources: list[tuple[Path, tuple[int, int]]], share: float, details) -> tuple[Table, RunInfo]:
    rows = []
    for path, size in sources:
        got, caps = measure(path, size, share, details)
        rows += got
    info = RunInfo.from_caps(caps, f"finest detail, limit {share:.0%} of the points")
    table = Table("detail", "Streamed views by finest detail: what they read and what they leave out",
                  ", ".join(p.name for p, _ in sources), ", ".join(f"{r['points']:,}" for r in rows[::len(details)]),
                  COLUMNS)
    for r in rows:
        table.rows.append((r["file"], r["points"], r["size"], r["detail_px"], r["resident_points"],
                           r["resident_points"] / r["points"], r["nodes_read"], r["bytes_read"] / 1e6, r["seconds"],
                           r["frames"],
                           r["covered"], r["empty"], r["other"], r["rgb"]))
    table.notes = [
        f"Each row: a session opened streamed (SessionOptions(stream=Streaming.ON)) with a GPU memory limit whose "
        f"store holds {share:.0%} of the file's points (memory.bytes_for), coloured by intensity, the auto camera "
        f"framed until Session.converged (wall seconds from the first frame). Finest detail: "
        f"SessionOptions.stream_detail_px, 0 = nodes until the memory is full. Reference: the same file, camera and "
        f"colouring rendered brute force with every point (not streamed). Pixels covered: the reference's; empty "
        f"where the file has a point and another point: shares of them (another point: the streamed view shows a "
        f"different point there, which a still view of every point would not); mean |ΔRGB|: the mean over the "
        f"covered pixels of the channels' absolute difference, 0-255."]
    table.raw = {"rows": rows, "share": share}
    return table, info


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.detail", description=__doc__.splitlines()[0])
    ap.add_argument("--size", default=SIZE, help="image WxH of the real files")
    ap.add_argument("--points", type=int, default=POINTS, help="points of the tiled sample (0: none)")
    ap.add_argument("--tiled-size", default=TILED_SIZE, help="image WxH of the tiled sample")
    ap.add_argument("--share", type=float, default=0.25, help="share of each file's points the store holds")
    ap.add_argument("--details", type=float, nargs="+", default=list(DETAILS))
    ap.add_argument("--data", type=Path, default=SHARED, help="folder holding the real COPC files")
    ap.add_argument("--out", type=Path, default=None, help="default: bench/results/<machine>/")
    args = ap.parse_args(argv)
    size, tiled_size = (tuple(int(v) for v in text.split("x")) for text in (args.size, args.tiled_size))
    sources = [(args.data / name, size) for name in FILES]
    if args.points:
        sources.append((build(args.points).path, tiled_size))
    table, info = run(sources, args.share, args.details)
    table.publish(info, args.out, RESULTS)
    return 0


if __name__ == "__main__":
    sys.exit(main())
