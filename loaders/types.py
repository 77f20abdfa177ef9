"""Data that loaders hand to the renderer: one cloud description and many batches."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

BATCH_POINTS = 500_000
"""Largest batch a reader yields; also the size of the GPU distribute buffer."""


class AttributeKind(enum.Enum):
    """How an attribute is shown, and so how it is packed into the 4-byte GPU word."""

    RGB = "rgb"            # (n, 3) uint8, packed as RGBA8
    SCALAR = "scalar"      # float, packed as float32 of (value - AttributeInfo.offset)
    CATEGORY = "category"  # small unsigned integer codes (classification), packed as uint32


@dataclass(frozen=True)
class AttributeInfo:
    """One per-point attribute of a cloud.

    `offset` is subtracted in float64 before a SCALAR is cast to float32, so values such
    as GPS time (~1e8 s) keep their sub-millisecond detail on the GPU.
    """

    name: str
    kind: AttributeKind
    dtype: np.dtype
    offset: float = 0.0


@dataclass(frozen=True)
class FileInfo:
    """Header facts of one input file, for `progressive info` and for errors."""

    path: str
    format: str                 # "LAS", "LAZ" or "PRGS" (the fast format)
    version: str                # "1.2", "1.4", ...
    point_format: int           # LAS point data record format, -1 for the fast format
    points: int
    scale: tuple[float, float, float]
    offset: tuple[float, float, float]
    bounds_min: tuple[float, float, float]
    bounds_max: tuple[float, float, float]
    rgb_16bit: bool | None      # None: the file has no RGB
    crs: str | None = None


@dataclass(frozen=True)
class CloudInfo:
    """Several files loaded as one cloud, concatenated in the order given.

    Positions on the GPU are float32 relative to `origin` (float64, the centre of the
    union of the header bounds), which keeps millimetres at UTM magnitudes.
    """

    files: tuple[FileInfo, ...]
    points: int
    origin: np.ndarray          # (3,) float64
    bounds_min: np.ndarray      # (3,) float64, file coordinates
    bounds_max: np.ndarray      # (3,) float64, file coordinates
    attributes: tuple[AttributeInfo, ...]

    def attribute(self, name: str) -> AttributeInfo:
        for a in self.attributes:
            if a.name == name:
                return a
        raise KeyError(name)


@dataclass(frozen=True)
class Batch:
    """A contiguous run of points in file order (files concatenated).

    `start` is the global file-order index of the first point. `attributes` maps names
    of CloudInfo.attributes to 1-D arrays (RGB: (n, 3) uint8). Batches read from the
    fast format carry `records` instead: (n, 4) uint32 rows already in GPU layout
    (xyz float32 bits relative to the origin, one attribute word).
    """

    start: int
    positions: np.ndarray                       # (n, 3) float32, relative to CloudInfo.origin
    attributes: dict[str, np.ndarray] = field(default_factory=dict)
    records: np.ndarray | None = None

    @property
    def count(self) -> int:
        return int(self.positions.shape[0])
