"""Data that loaders hand to the renderer: one cloud description and many batches."""

from __future__ import annotations

import enum
import os
import queue
from dataclasses import dataclass, field, replace

import numpy as np

BATCH_POINTS = 500_000
"""Largest batch a reader yields; also the size of the GPU distribute buffer."""
FIRST_BATCH_POINTS = 100_000
"""Largest first batch of a LAS/LAZ file: the first image waits for it to be read (two
LAZ chunks of the usual 50,000 points), while later batches are large for throughput."""


RGB8_MAX = 255
"""A file is 16-bit colour iff a channel among its first BATCH_POINTS points exceeds this."""


class ReadyQueue(queue.Queue):
    """What loader threads hand to the frame loop: a frame loop with nothing to draw
    until something arrives waits here (without taking it) instead of spinning."""

    def wait(self, timeout: float) -> bool:
        """Whether an item is there, waiting at most `timeout` seconds for one."""
        with self.not_empty:
            return self.not_empty.wait_for(self._qsize, timeout)


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity, which a container or taskset
    narrows), not every core of the machine: the default for decoder processes."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:          # no sched_getaffinity (macOS, Windows)
        return os.cpu_count() or 1


PARSER_THREADS = 8
"""The most parser threads a loader starts by default: each return from a numpy call to
Python waits for the GIL, so many threads contend for it. On the H100 machine's 16 cores,
100 M points of LAS reached the GPU after 1.55 s in `render`'s session with 8, 1.83 s
with 4 and 1.89 s with 16 (the window's 1.97, 2.79, 2.00 s); a LAZ, bound by its decoder
processes, after 5.6-5.9 s with each (bench/results/nvidia-h100/mainthread_56f3cf2/)."""


def default_parser_threads() -> int:
    """Parser threads by default: one a core, at most PARSER_THREADS."""
    return min(available_cores(), PARSER_THREADS)


def available_memory() -> int | None:
    """Bytes the system can give this process without swapping (Linux's MemAvailable,
    which leaves out memory held by files in /dev/shm); None where it is not known."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


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
    format: str                 # "LAS", "LAZ", "PRGS" (the fast format), "E57" or "PLY"
    version: str                # "1.2", "1.4", ...; E57 "1.0"; PLY "1.0 binary_little_endian", ...
    point_format: int           # LAS point data record format, -1 for the other formats
    points: int
    scale: tuple[float, float, float]
    offset: tuple[float, float, float]
    bounds_min: tuple[float, float, float]
    bounds_max: tuple[float, float, float]
    rgb_max: int | None
    """None: no RGB. Else the greatest R, G or B among the file's first BATCH_POINTS
    points, read until one exceeds 255 (the probe stops there): what rgb_16bit and
    rgb_zero are decided by, once per file, so neither depends on the loader's batches."""
    crs: str | None = None
    scans: tuple[ScanInfo, ...] = ()
    """E57 only: the file's scans (data3D entries), in the order their points are loaded."""
    runs: tuple[tuple[int, int], ...] = ()
    """A COPC file read down to a level of detail (loaders/copc.py): the (first, count)
    runs of the file's points the cloud holds, in file order; `points` counts only them
    and the cloud numbers them from 0. Empty: every point, in file order."""

    @property
    def rgb_16bit(self) -> bool | None:
        """None: no RGB. True iff some R, G or B among the file's first BATCH_POINTS points
        exceeds 255; then every channel is shifted right by 8 bits. False: 8-bit, and any
        later value above 255 is clipped to 255."""
        return None if self.rgb_max is None else self.rgb_max > RGB8_MAX

    @property
    def rgb_zero(self) -> bool:
        """RGB is zero in every one of the first BATCH_POINTS points (scanners that write
        empty colour fields): the default colouring passes it over."""
        return self.rgb_max == 0

    def file_index(self, local: int) -> int:
        """The index in the file of the file's `local`-th point in the cloud."""
        for first, count in self.runs:
            if local < count:
                return first + local
            local -= count
        return local


@dataclass(frozen=True)
class ScanInfo:
    """One scan of an E57 file. Its pose (rotation quaternion w, x, y, z, normalised, and
    translation) takes its local coordinates to the file's, applied in float64."""

    name: str
    points: int
    coordinates: str            # "cartesian" or "spherical"
    rotation: tuple[float, float, float, float]
    translation: tuple[float, float, float]


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
class Runs:
    """The least and most coordinates of a batch's points in each run of `points`
    consecutive cloud indices its rows touch (run r: indices r·points ..), from run
    `first` on: what the word store frames its batches by, found on the thread that
    parsed the batch. A LAS batch's are of its integer cells (cell_runs, int64), a
    fast-format batch's of its float32 positions (progressive/batches.py boxes_of:
    +inf/-inf where a run holds no finite point). `start` and `count`: the rows they are
    of, so that a batch whose rows moved is not framed by another's runs."""

    points: int
    first: int
    least: np.ndarray                   # (k, 3)
    most: np.ndarray
    start: int
    count: int

    def of(self, start: int, count: int, points: int) -> bool:
        """Whether these are the runs of `count` rows from cloud index `start`, by runs of `points`."""
        return (self.start, self.count, self.points) == (start, count, points)

    def moved(self, start: int) -> Runs | None:
        """The same runs for these rows moved to cloud index `start` (a streamed node's
        rows, written at a store batch's first index), where both starts begin a run;
        else None."""
        if self.start % self.points or start % self.points:
            return None
        return Runs(self.points, start // self.points, self.least, self.most, start, self.count)

    def rows(self, lo: int, hi: int) -> Runs | None:
        """Those of rows lo..hi of the batch: the runs they touch, where each still holds
        the rows it held (the rows end at the batch's ends or at runs' ends); else None
        (a run cut short needs its rows again)."""
        p, start = self.points, self.start
        if hi <= lo or not (lo == 0 or (start + lo) % p == 0) or not (hi == self.count or (start + hi) % p == 0):
            return None
        a, b = (start + lo) // p - self.first, (start + hi - 1) // p - self.first + 1
        return Runs(p, self.first + a, self.least[a:b], self.most[a:b], start + lo, hi - lo)


def run_edges(start: int, n: int, points: int) -> np.ndarray:
    """Where each run of `points` cloud indices begins among n rows from cloud index
    `start` (the first at row 0): what reduceat cuts a batch's rows at."""
    cuts = np.arange((start // points + 1) * points, start + n, points) - start
    return np.concatenate([[0], cuts]).astype(np.int64)


def cell_runs(cells: np.ndarray, start: int, points: int) -> Runs:
    """The Runs of a batch's (n, 3) cells whose first has cloud index `start`."""
    edges = run_edges(start, cells.shape[0], points)
    return Runs(points, start // points, np.minimum.reduceat(cells, edges, axis=0).astype(np.int64),
                np.maximum.reduceat(cells, edges, axis=0).astype(np.int64), start, cells.shape[0])


@dataclass(frozen=True)
class Grid:
    """A LAS batch's coordinates as the file stores them: coordinate = cell · scale +
    offset, per axis; its positions are relative to `origin` (CloudInfo.origin)."""

    cells: np.ndarray                   # (n, 3) int32, the records' X, Y, Z
    scale: tuple[float, float, float]
    offset: tuple[float, float, float]
    origin: tuple[float, float, float]
    runs: Runs | None = None
    """Their least and most by runs of cloud indices, where the loader was asked for
    them (CloudLoader's on_parsed)."""

    def positions(self, axes: tuple[int, ...] = (0, 1, 2)) -> np.ndarray:
        """(n, len(axes)) float32 positions relative to the origin: each cell scaled and
        offset in float64 as laspy computes coordinates (las.Records.coordinates), so
        that float32 rounding happens once; a column at a time, as numpy's loops over
        rows of 3 are slow."""
        n = self.cells.shape[0]
        positions = np.empty((n, len(axes)), np.float32)
        scaled = np.empty(n)
        with np.errstate(over="ignore", invalid="ignore"):
            for column, axis in enumerate(axes):
                np.multiply(self.cells[:, axis], self.scale[axis], out=scaled)
                scaled += self.offset[axis]
                np.subtract(scaled, self.origin[axis], out=positions[:, column], casting="same_kind")
        return positions


@dataclass(frozen=True)
class Batch:
    """A contiguous run of points in file order (files concatenated).

    `start` is the global file-order index of the first point. `attributes` maps names
    of CloudInfo.attributes to 1-D arrays (RGB: (n, 3) uint8). Batches read from the
    fast format carry `records` instead: (n, 4) uint32 rows already in GPU layout
    (xyz float32 bits relative to the origin, one attribute word).

    Points whose x, y or z is not finite are kept (so slots and ids stay in file order)
    but never drawn; `nonfinite_positions` counts them, and `nonfinite_values` counts
    NaN/Inf per float attribute (only attributes that have any).
    """

    start: int
    xyz: np.ndarray | None = None
    """(n, 3) float32 positions relative to CloudInfo.origin; None where `grid` holds
    them (a LAS batch: `positions` computes them on each use, so that parsing skips
    them, a large share of its parse, where the word store takes the integers)."""
    attributes: dict[str, np.ndarray] = field(default_factory=dict)
    records: np.ndarray | None = None
    bounds: tuple[np.ndarray, np.ndarray] | None = None
    """LAS only: float64 min and max of the file coordinates, exact where the float32
    positions are not (a 1e-7 scale, or coordinates far from the origin)."""
    nonfinite_positions: int = 0
    nonfinite_values: dict[str, int] = field(default_factory=dict)
    grid: Grid | None = None
    """LAS only: the points' own integer coordinates, from which `positions` are
    scaled; whoever changes the positions drops it (the word store keeps these
    integers, so a LAS position on the GPU is lossless)."""
    boxes: Runs | None = None
    """Fast format: the least and most of `positions` by runs of cloud indices, where the
    loader was asked for them (CloudLoader's on_parsed); whoever changes `positions`
    drops them."""

    def __post_init__(self):
        if self.xyz is None and self.grid is None:
            raise ValueError("a batch needs its positions or its grid")

    @property
    def positions(self) -> np.ndarray:
        """(n, 3) float32 positions relative to CloudInfo.origin: `xyz`, else computed
        from the grid (not kept: a caller on a hot path takes the grid's cells instead)."""
        return self.xyz if self.xyz is not None else self.grid.positions()

    def z(self) -> np.ndarray:
        """positions[:, 2], without computing x and y where they come from the grid."""
        return self.xyz[:, 2] if self.xyz is not None else self.grid.positions((2,))[:, 0]

    @property
    def count(self) -> int:
        return int((self.xyz if self.xyz is not None else self.grid.cells).shape[0])

    def rows(self, lo: int, hi: int) -> Batch:
        """Rows lo..hi as a batch of their own (views; the non-finite counts stay the
        whole batch's, which only say whether the rows may hold such points)."""
        if lo == 0 and hi == self.count:
            return self
        grid = None if self.grid is None else replace(
            self.grid, cells=self.grid.cells[lo:hi],
            runs=None if self.grid.runs is None else self.grid.runs.rows(lo, hi))
        return replace(self, start=self.start + lo, xyz=None if self.xyz is None else self.xyz[lo:hi],
                       attributes={k: v[lo:hi] for k, v in self.attributes.items()},
                       records=None if self.records is None else self.records[lo:hi], bounds=None,
                       grid=grid, boxes=None if self.boxes is None else self.boxes.rows(lo, hi))

    def reordered(self, lo: int, hi: int, order: np.ndarray) -> Batch:
        """The batch with rows lo..hi in the order `order` (indices into them): every
        per-point array, the same points (bounds and non-finite counts stay)."""
        rows = np.concatenate([np.arange(lo), lo + np.asarray(order, dtype=np.int64), np.arange(hi, self.count)])
        grid = None if self.grid is None else replace(self.grid, cells=self.grid.cells[rows], runs=None)
        return replace(self, xyz=None if self.xyz is None else self.xyz[rows],
                       attributes={k: v[rows] for k, v in self.attributes.items()},
                       records=None if self.records is None else self.records[rows], grid=grid, boxes=None)

    def with_positions(self, positions: np.ndarray, **changes) -> Batch:
        """The batch with other positions (reprojected, moved): its grid and boxes,
        which were of the old ones, dropped."""
        return replace(self, xyz=positions, grid=None, boxes=None, **changes)


def channel8(values: np.ndarray, sixteen_bit: bool) -> np.ndarray:
    """One colour channel (unsigned integers) as 8 bits by the rule of FileInfo.rgb_16bit:
    a 16-bit file's values shifted right by 8, an 8-bit file's clipped at RGB8_MAX."""
    return np.minimum(np.asarray(values) >> (8 if sixteen_bit else 0), RGB8_MAX)


def nonfinite_rows(positions: np.ndarray) -> int:
    """Points the GPU skips: any coordinate NaN or infinite (shaders/common.glsl)."""
    finite = np.isfinite(positions)
    return 0 if finite.all() else int(positions.shape[0] - np.count_nonzero(finite.all(axis=1)))


def nonfinite_records(records: np.ndarray) -> tuple[int, int]:
    """Of (n, 4) uint32 GPU records: the points with a non-finite x, y or z, and the
    attribute words that are non-finite as float32. One contiguous pass packs each row's
    four finite flags into one word (x in the low byte): a strided view of the columns
    costs ten times as much, and this runs once per batch of a billion-point file."""
    flags = np.isfinite(records.view(np.float32)).view("<u4")[:, 0]
    n = records.shape[0]
    return (n - int(np.count_nonzero((flags & 0x00FFFFFF) == 0x00010101)),
            n - int(np.count_nonzero(flags & 0x01000000)))


def nonfinite_count(values: np.ndarray) -> int:
    """NaN/Inf values of a float array; integer arrays have none. A finite sum means
    every value is finite: one pass and no mask for the usual case (the parser threads
    wait for the GIL after each numpy call); an infinite or NaN sum (a value that is not
    finite, or finite ones that overflow) is counted exactly."""
    if values.dtype.kind != "f":
        return 0
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(np.add.reduce(values, axis=None)):
            return 0
    return int(values.size - np.count_nonzero(np.isfinite(values)))


def quiet_nans(values: np.ndarray) -> None:
    """In place: signalling NaNs (any bit pattern can be in a file) become quiet ones,
    which numpy arithmetic downstream accepts without an 'invalid value' warning."""
    values[np.isnan(values)] = np.nan
