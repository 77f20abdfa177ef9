"""Clouds at scale made from a real file: the file tiled on a grid with offsets, so
local structure stays real. Records are made per tile and streamed to the GPU, in one
of three file orders (what ordering costs is part of what the benchmarks show)."""

from __future__ import annotations

import argparse
import enum
import functools
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from progressive.attributes import default_attribute
from progressive.batches import BatchOrder
from progressive.context import GLContext, create_context
from progressive.encoding import Encoding
from progressive.loaders import CloudLoader
from progressive.loaders.records import pack_records
from progressive.loaders.types import AttributeInfo, Batch, CloudInfo
from progressive.permutation import LAYOUT, FillOrder
from progressive.pointstore import RecordOrder
from progressive.scene import Scene

SAMPLE = Path(__file__).resolve().parents[1] / "progressive" / "data" / "autzen_trim.las"


class Order(enum.Enum):
    """The order points have in the (virtual) file."""

    FILE = "file"          # the source file's own order, tile after tile (airborne: flight lines)
    MORTON = "morton"      # tiles in Z-order, points in 3D Morton order within a tile
    SCAN = "scan"          # terrestrial-style: a scanner station per tile, vertical scan lines by azimuth


def morton_order(xyz: np.ndarray, bits: int = 21) -> np.ndarray:
    """Indices sorting points by their 3D Morton (Z-order) code on a 2^bits grid."""
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    q = ((xyz - lo) / np.maximum(hi - lo, 1e-12) * (2**bits - 1)).astype(np.uint64)
    code = np.zeros(len(xyz), dtype=np.uint64)
    for b in range(bits):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(b)) & np.uint64(1)) << np.uint64(3 * b + axis)
    return np.argsort(code, kind="stable")


def scan_order(xyz: np.ndarray, azimuth_steps: int = 2048) -> np.ndarray:
    """Indices in the order a terrestrial scanner at the tile centre (1.5 % of the tile
    size above the lowest point) records them: vertical scan lines swept by azimuth,
    each from the lowest elevation angle up; near and far points interleave in a line."""
    centre = (xyz.min(axis=0) + xyz.max(axis=0)) / 2
    extent = float(np.ptp(xyz[:, :2], axis=0).max())
    station = np.array([centre[0], centre[1], xyz[:, 2].min() + 0.015 * extent])
    d = xyz - station
    azimuth = np.arctan2(d[:, 1], d[:, 0])
    column = ((azimuth + np.pi) / (2 * np.pi) * azimuth_steps).astype(np.int64)
    elevation = np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1]))
    return np.lexsort((elevation, column))


def z_order_key(ij: tuple[int, int]) -> int:
    """Interleaved bits of a tile's grid coordinates."""
    i, j = ij
    return sum(((i >> b) & 1) << (2 * b) | ((j >> b) & 1) << (2 * b + 1) for b in range(16))


@dataclass(frozen=True)
class TiledCloud:
    info: CloudInfo
    attribute: AttributeInfo
    tile_records: np.ndarray     # (n, 4) uint32 of one tile, positions relative to the tile centre
    tile_size: np.ndarray        # (3,) float64
    grid: tuple[int, int]
    points: int

    @functools.cached_property
    def _tile_xyz(self) -> np.ndarray:
        return self.tile_records[:, :3].view(np.float32).astype(np.float64)

    def tile_permutation(self, order: Order) -> np.ndarray:
        if order is Order.MORTON:
            return morton_order(self._tile_xyz)
        if order is Order.SCAN:
            return scan_order(self._tile_xyz)
        return np.arange(self.tile_records.shape[0])

    def batches(self, order: Order = Order.FILE) -> Iterator[tuple[int, np.ndarray]]:
        """(start, records) per tile: the same tiles and points in every order (the last
        tile keeps the first points of the source file), visited row by row in FILE and
        SCAN order and in Z-order in MORTON, each tile's points in `order`."""
        n = self.tile_records.shape[0]
        gx, gy = self.grid
        perm = self.tile_permutation(order)
        used = [(i, j) for j in range(gy) for i in range(gx)][: math.ceil(self.points / n)]
        counts = {t: min(n, self.points - k * n) for k, t in enumerate(used)}
        key = z_order_key if order is Order.MORTON else None
        start = 0
        for i, j in sorted(used, key=key) if key else used:
            count = counts[(i, j)]
            keep = perm if count == n else perm[perm < count]
            yield start, self.tile(keep, i, j)
            start += count

    def tile(self, index: np.ndarray, i: int, j: int) -> np.ndarray:
        """Records `index` of the source, moved to tile (i, j)."""
        gx, gy = self.grid
        shift = np.array([(i - (gx - 1) / 2) * self.tile_size[0], (j - (gy - 1) / 2) * self.tile_size[1], 0.0])
        rec = self.tile_records[index]
        rec[:, :3] = (self._tile_xyz[index] + shift).astype(np.float32).view(np.uint32)
        return rec


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


def load(glc: GLContext, cloud: TiledCloud, order: Order = Order.FILE, fill: FillOrder = LAYOUT,
         records: RecordOrder = RecordOrder.BATCHES, position_encoding: Encoding = Encoding.WORDS,
         batch_order: BatchOrder = BatchOrder.FILE) -> tuple[Scene, float]:
    """The tiled cloud on the GPU once, shared by every run; seconds to upload it (a
    tile a loaded batch)."""
    t0 = time.perf_counter()
    scene = Scene(glc, cloud.info, cloud.attribute, order=fill, records=records, position_encoding=position_encoding,
                  batch_order=batch_order)
    for start, rec in cloud.batches(order):
        scene.add_batch(Batch(start=start, xyz=rec[:, :3].view(np.float32), records=rec))
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
