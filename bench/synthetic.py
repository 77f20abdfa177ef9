"""Clouds at scale made from a real file: the file tiled on a grid with offsets, so
local structure stays real. Records are made per tile and streamed to the GPU."""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from progressive.attributes import default_attribute
from progressive.context import GLContext, create_context
from progressive.loaders import CloudLoader
from progressive.loaders.types import AttributeInfo, Batch, CloudInfo
from progressive.packing import pack_records
from progressive.scene import Scene

SAMPLE = Path(__file__).resolve().parents[1] / "progressive" / "data" / "autzen_trim.las"


@dataclass(frozen=True)
class TiledCloud:
    info: CloudInfo
    attribute: AttributeInfo
    tile_records: np.ndarray     # (n, 4) uint32 of one tile, positions relative to the tile centre
    tile_size: np.ndarray        # (3,) float64
    grid: tuple[int, int]
    points: int

    def batches(self) -> Iterator[tuple[int, np.ndarray]]:
        """(start, records) per tile, in file order (tile by tile, row by row)."""
        n = self.tile_records.shape[0]
        gx, gy = self.grid
        base = self.tile_records[:, :3].view(np.float32).astype(np.float64)
        start = 0
        for j in range(gy):
            for i in range(gx):
                if start >= self.points:
                    return
                count = min(n, self.points - start)
                shift = np.array([(i - (gx - 1) / 2) * self.tile_size[0], (j - (gy - 1) / 2) * self.tile_size[1], 0.0])
                rec = self.tile_records[:count].copy()
                rec[:, :3] = (base[:count] + shift).astype(np.float32).view(np.uint32)
                yield start, rec
                start += count


def tiled(path: str, points: int, attribute: str | None = None) -> TiledCloud:
    with CloudLoader([path]) as loader:
        info = loader.info
        attr = default_attribute(info) if attribute is None else info.attribute(attribute)
        loader.start()
        batches = sorted(loader, key=lambda b: b.start)
    records = np.concatenate([pack_records(b, attr, float(info.origin[2])) for b in batches])
    size = (info.bounds_max - info.bounds_min) * np.array([1.02, 1.02, 1.0])
    tiles = math.ceil(points / records.shape[0])
    gx = math.ceil(math.sqrt(tiles))
    gy = math.ceil(tiles / gx)
    half = size * np.array([gx, gy, 1]) / 2
    tiled_info = CloudInfo(files=info.files, points=points, origin=info.origin,
                           bounds_min=info.origin - half, bounds_max=info.origin + half, attributes=info.attributes)
    return TiledCloud(tiled_info, attr, records, size, (gx, gy), points)


def load(glc: GLContext, cloud: TiledCloud) -> tuple[Scene, float]:
    """The tiled cloud on the GPU once, shared by every run; seconds to upload it."""
    t0 = time.perf_counter()
    scene = Scene(glc, cloud.info, cloud.attribute)
    for start, rec in cloud.batches():
        scene.add_batch(Batch(start=start, positions=rec[:, :3].view(np.float32), records=rec))
    glc.ctx.finish()
    return scene, time.perf_counter() - t0


def add_cloud_args(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--out", default="bench/results/local")


@dataclass(frozen=True)
class Setup:
    glc: GLContext
    cloud: TiledCloud
    scene: Scene
    upload_seconds: float
    width: int
    height: int


def setup(args: argparse.Namespace) -> Setup:
    """A context and the sample tiled to --points, on the GPU, at --size."""
    width, height = (int(v) for v in args.size.split("x"))
    glc = create_context()
    cloud = tiled(str(SAMPLE), args.points)
    scene, seconds = load(glc, cloud)
    return Setup(glc, cloud, scene, seconds, width, height)
