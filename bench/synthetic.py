"""Clouds at scale made from a real file: the file tiled on a grid with offsets, so
local structure stays real. Records are made per tile and streamed to the GPU."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from progressive.attributes import default_attribute
from progressive.loaders import CloudLoader
from progressive.loaders.types import AttributeInfo, CloudInfo
from progressive.packing import pack_records


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
