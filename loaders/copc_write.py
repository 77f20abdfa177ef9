"""Writing COPC: LAS/LAZ files as one LAZ 1.4 whose chunks are the nodes of an octree.

The octree is built by spacing, as PDAL and Untwine build it: the root cube holds a grid
of CELLS³ cells and each level halves the cell; a node keeps one point per occupied cell
(the first of a fixed pseudo-random order, so that a level is an even sample of what is
below it) and passes the rest to its children, until a node has at most
LEAF_POINTS points left (it keeps them all) or MAX_DEPTH is reached. Nodes are written
root first, level by level, each one LAZ chunk (lazrs, on every core); the hierarchy is
one page in an EVLR, and the COPC info VLR comes first after the header, as the
specification (https://copc.io) requires.

The root cube is placed from the inputs' header bounds (their union, as Untwine's
preflight does), so that the points need not be read first for it: each point's Morton
code is computed as it is read, and its coordinates checked to lie within those bounds
(give or take the scale step the cube is widened by). If one does not (a header that
lies), both builds place the cube from the points' own bounds, so that they give the
same nodes: out of core, the pass goes on for those bounds alone and the inputs are read
again into the cubes. The output header holds the points' own bounds and counts,
gathered in the same pass.

Point records keep every field: point formats 6-8 are written as they are (9 and 10 as 6
and 8, without their waveform fields), older ones converted field by field as laspy
converts them (numpy copies of runs of fields and bit operations; laspy's own
conversion where fields do not match), scan angles from whole degrees to 0.006° steps
(the nearest).

A cloud of up to IN_MEMORY_POINTS (or `memory_points`) is held in memory while its
octree is built. A larger one is built out of core, with the same nodes: the inputs are read once, into files of a
scratch folder, one for each of the octree's cubes at TOP_DEPTH (the records, and apart
each point's Morton code and index; parts are coded and sorted by cube on `workers`
threads while the next is read). Every cell of the levels above that depth lies in
one cube, and a point's rank is a hash of its index, so each cube picks its points of
those levels alone; only whether a node of those levels keeps every point left (at most
LEAF_POINTS) needs the counts of all its cubes, summed first from the codes files alone.
Then each cube's own subtree is built in memory and compressed apart, on `workers`
threads (numpy sorts and gathers run without the GIL) with at most memory_points points
of the cubes in flight (by default what half the free memory holds), and the file is assembled from the compressed chunks in cube
order, whatever the number of workers: the upper levels' nodes first, level by level,
then each cube's.
"""

from __future__ import annotations

import os
import struct
import tempfile
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass
from functools import partial as partial_call
from pathlib import Path

import laspy
import lazrs
import numpy as np
from laspy.vlrs.known import (
    ExtraBytesVlr,
    GeoAsciiParamsVlr,
    GeoDoubleParamsVlr,
    GeoKeyDirectoryVlr,
    LasZipVlr,
    WktCoordinateSystemVlr,
)

from progressive.errors import InputError
from progressive.loaders.copc import ENTRY, EVLR_HEADER, HIERARCHY_RECORD, INFO, INFO_RECORD, USER_ID, CopcInfo
from progressive.loaders.las import (
    HEADER_PREFIX,
    SCAN_ANGLE_STEP,
    LasSource,
    RawHeader,
    Span,
    TruncatedInput,
    read_span,
    text_patches,
)
from progressive.loaders.laz import TABLE_OFFSET_BYTES, open_patched
from progressive.loaders.laz_pool import DEFAULTS as LAZ_DEFAULTS
from progressive.loaders.laz_pool import DecoderPool, LazOptions
from progressive.loaders.pipeline import open_sources
from progressive.loaders.types import BATCH_POINTS, available_cores, available_memory
from progressive.loaders.validate import fail, open_binary, shown

CELLS = 128
"""Cells along each axis of a node's grid: the root spacing is the cube's side / CELLS."""
LEAF_POINTS = 100_000
"""A node left with at most this many points keeps them all and has no children."""
MAX_DEPTH = 12
"""Deepest level: every point left there stays (keys of CELLS·2^12 cells fit 64 bits)."""
CELL_BITS = CELLS.bit_length() - 1
GRID_BITS = CELL_BITS + MAX_DEPTH      # bits of a point's cell at MAX_DEPTH, per axis
SPREAD_BITS = 10
"""Bits of a cell coordinate spread at a time through a table (GRID_BITS in two looks)."""
SEED = 0x5EED
COMPRESS_POINTS = 1 << 22
"""Points handed to the parallel compressor at a time."""
MEMORY_POINTS = 50_000_000
"""Points of the parts in flight while the inputs are spilled into the cubes, and of the
cubes built at once where the system's free memory is not known (build_limit)."""
BUILD_BYTES = 128
"""Memory a point of a cube takes at the peak of its build: its record, codes, ranks,
orders and sorted copies (tracemalloc's peak of _cube_nodes, 127.9 bytes a point)."""
MEMORY_SHARE = 0.5
"""The share of the available memory the cubes built at once may take by default."""
IN_MEMORY_POINTS = 2_000_000
"""The largest cloud built in memory at once: a larger one is built out of core, whose
cubes are built on every core (the sample tiled to 12 M points: 3.81 s against 7.54 s in
memory on 2 cores, bench/results/llvmpipe/convert.md)."""
TOP_DEPTH = 3
"""The depth of the cubes a cloud is split into out of core (at most 8^3 files; a cube
over memory_points is still built whole in memory). At most CELL_BITS: each cell of the
levels above lies in one cube."""
COPY_BYTES = 64 << 20
"""Compressed chunks copied into the output at a time, out of core."""
TARGET_FORMAT = {0: 6, 1: 6, 4: 6, 6: 6, 9: 6, 2: 7, 3: 7, 5: 7, 7: 7, 8: 8, 10: 8}
"""The COPC point format (6, 7 or 8) that holds a point format's fields."""
LEGACY_FIELDS = {"bit_fields", "raw_classification", "scan_angle_rank"}
"""Fields of point formats 0-5 whose bits move in formats 6-10 (_fast_converted)."""
NEW_BIT_FIELDS = {"bit_fields", "classification_flags", "classification", "scan_angle"}
"""Fields of point formats 6-10 made from LEGACY_FIELDS."""
DROPPED_VLRS = (LasZipVlr, ExtraBytesVlr, GeoKeyDirectoryVlr, GeoDoubleParamsVlr, GeoAsciiParamsVlr,
                WktCoordinateSystemVlr)
"""VLRs of the input not copied as they are: written anew (LASzip, extra bytes, the CRS
as WKT) or not valid in the output (the input's own COPC records, waveform descriptors)."""
WAVEFORM_RECORDS = range(100, 355)
EVLR_HEAD = struct.Struct("<H16sHQ32s")


@dataclass(frozen=True)
class Written:
    """What convert reports."""

    points: int
    nodes: int
    levels: int
    warnings: tuple[str, ...]


@dataclass(frozen=True)
class Bounds:
    """Mins and maxs of x, y, z; `slack`: how far outside a point may lie and still be in
    the cube placed around them (the scale step the cube is widened by)."""

    mins: np.ndarray
    maxs: np.ndarray
    slack: float

    def holds(self, mins: np.ndarray, maxs: np.ndarray) -> bool:
        return bool(np.all(mins >= self.mins - self.slack) and np.all(maxs <= self.maxs + self.slack))


class Tally:
    """What the output header says of the points seen so far: their count, bounds,
    points by return and GPS time range."""

    def __init__(self):
        self.points = 0
        self.mins, self.maxs = np.full(3, np.inf), np.full(3, -np.inf)
        self.returns = np.zeros(16, np.int64)
        self.gps = (np.inf, -np.inf)

    def add(self, records: np.ndarray, mins: np.ndarray, maxs: np.ndarray) -> None:
        if records.size == 0:
            return
        seen = Tally()
        seen.points, seen.mins, seen.maxs = records.size, mins, maxs
        seen.returns = np.bincount(records["bit_fields"] & 0x0F, minlength=16)
        gps = records["gps_time"]
        seen.gps = (float(gps.min()), float(gps.max()))
        self.merge(seen)

    def merge(self, other: Tally) -> None:
        """Add the points another tally saw (a part's, tallied on a worker thread)."""
        self.points += other.points
        self.mins, self.maxs = np.minimum(self.mins, other.mins), np.maximum(self.maxs, other.maxs)
        self.returns += other.returns
        self.gps = (min(self.gps[0], other.gps[0]), max(self.gps[1], other.gps[1]))

    def fill(self, header: laspy.LasHeader) -> None:
        header.mins, header.maxs, header.point_count = self.mins, self.maxs, self.points
        header.number_of_points_by_return = self.returns[1:16].astype(np.uint64)


def write_copc(stream, inputs: list[str], *, partial: bool = False, memory_points: int | None = None,
               scratch: str | os.PathLike | None = None, workers: int | None = None,
               laz: LazOptions = LAZ_DEFAULTS) -> Written:
    """Write `inputs` (LAS/LAZ files, one cloud) to `stream` (opened w+b, at 0) as COPC;
    a cloud of more than memory_points (default IN_MEMORY_POINTS) is built out of core in
    a temporary folder made in `scratch` (default: the system's), removed whatever
    happens, its cubes on `workers` threads (default: one a core; the file is the same)
    with at most memory_points (default build_limit) of their points in flight; LAZ
    inputs decoded as `laz` says (the loader's rule: processes for a large file)."""
    in_memory = IN_MEMORY_POINTS if memory_points is None else memory_points
    _, sources = open_sources(inputs, partial=partial)
    for s in sources:
        if not isinstance(s, LasSource):
            raise fail(s.info.path, f"is {s.info.format}: COPC is written from LAS/LAZ files")
    warnings: list[str] = []
    first = _laspy_header(sources[0].info.path)
    header = _output_header(sources, first, warnings)
    claimed = _header_bounds(sources, header)
    total = sum(s.info.points for s in sources)
    decoders = DecoderPool.chosen(laz)
    try:
        if total > in_memory:
            with tempfile.TemporaryDirectory(prefix=".progressive-copc-", dir=scratch) as folder:
                return _out_of_core(stream, sources, header, claimed, partial, warnings, memory_points,
                                    workers or available_cores(), Path(folder), decoders)
        return _in_memory(stream, sources, header, claimed, partial, warnings, total, decoders)
    finally:
        if decoders is not None:
            decoders.close()


def _in_memory(stream, sources, header: laspy.LasHeader, claimed: Bounds, partial: bool, warnings: list[str],
               total: int, decoders: DecoderPool | None) -> Written:
    """write_copc for a cloud of at most its memory_points: sorted and compressed whole."""
    info, tally = _cube(claimed), Tally()
    records, morton = np.empty(total, header.point_format.dtype()), np.empty(total, np.uint64)
    for _, job in _record_parts(sources, header, partial, warnings, decoders):
        part = job()
        at = tally.points
        morton[at:at + part.size], mins, maxs = _codes(part, header, info)
        records[at:at + part.size] = part
        tally.add(part, mins, maxs)
    records, morton = records[:tally.points], morton[:tally.points]
    if not claimed.holds(tally.mins, tally.maxs):
        info = _cube(Bounds(tally.mins, tally.maxs, claimed.slack))
        morton, _, _ = _codes(records, header, info)
    order, level, key = octree_order(morton)
    del morton
    records = records.take(order)
    starts = np.r_[0, np.nonzero((np.diff(level) != 0) | (np.diff(key) != 0))[0] + 1]
    counts = np.diff(np.r_[starts, records.size])
    tally.fill(header)
    copc_vlr, laz_vlr = _write_head(stream, header)
    point_data = header.offset_to_point_data
    compressor = lazrs.ParLasZipCompressor(stream, laz_vlr)
    for group in _groups(counts):
        compressor.compress_chunks([records[starts[i]:starts[i] + counts[i]].view(np.uint8) for i in group])
    compressor.done()
    stream.seek(point_data)
    table = lazrs.read_chunk_table(stream, laz_vlr)
    if [n for n, _ in table] != counts.tolist():
        raise InputError("internal error: the LAZ chunk table does not list one chunk per octree node")
    _write_hierarchy(stream, header, info, copc_vlr, point_data, level[starts], key[starts], table, tally.gps)
    return Written(int(records.size), int(counts.size), int(level.max()) + 1, tuple(warnings))


def _header_bounds(sources, header: laspy.LasHeader) -> Bounds:
    """The union of the inputs' header bounds (those of the points where open_las found
    the header's wrong), which place the root cube unless a point lies outside."""
    mins = np.min([s.info.bounds_min for s in sources], axis=0).astype(np.float64)
    maxs = np.max([s.info.bounds_max for s in sources], axis=0).astype(np.float64)
    return Bounds(mins, maxs, float(np.abs(header.scales).max()))


def _write_head(stream, header: laspy.LasHeader):
    """The header and VLRs, the COPC info VLR (filled in last) first: (it, the LAZ VLR)."""
    laz_vlr = lazrs.LazVlr.new_for_compression(header.point_format.id, header.point_format.num_extra_bytes, True)
    copc_vlr = laspy.VLR(USER_ID.decode(), INFO_RECORD, "COPC info VLR", bytes(INFO.size))
    header.vlrs.insert(0, copc_vlr)
    header.vlrs.insert(1, LasZipVlr(laz_vlr.record_data()))
    header.write_to(stream)
    return copc_vlr, laz_vlr


def _write_hierarchy(stream, header: laspy.LasHeader, info: CopcInfo, copc_vlr, point_data: int,
                     levels: np.ndarray, keys: np.ndarray, table, gps: tuple[float, float]) -> None:
    """The hierarchy EVLR after the chunks (one a node, in the chunk table's order), then
    the header again with the info VLR (the root cube `info`) filled in."""
    sizes = np.array([b for _, b in table], np.int64)
    entries = np.zeros(len(table), ENTRY)
    entries["level"] = levels
    entries["x"], entries["y"], entries["z"] = _key_xyz(keys)
    entries["offset"] = point_data + TABLE_OFFSET_BYTES + np.r_[0, np.cumsum(sizes)[:-1]]
    entries["byte_size"], entries["point_count"] = sizes, [n for n, _ in table]
    evlr_start = stream.seek(0, os.SEEK_END)
    body = entries.tobytes()
    stream.write(EVLR_HEAD.pack(0, USER_ID, HIERARCHY_RECORD, len(body), b"COPC hierarchy"))
    stream.write(body)
    header.start_of_first_evlr, header.number_of_evlrs = evlr_start, 1
    copc_vlr.record_data = CopcInfo(info.center, info.halfsize, info.spacing, evlr_start + EVLR_HEADER, len(body),
                                    *gps).pack()
    stream.seek(0)
    header.write_to(stream, ensure_same_size=True)


def _laspy_header(path: str) -> laspy.LasHeader:
    """The file's header as laspy reads it, its VLR texts made valid UTF-8 as the loader does."""
    with open_binary(path) as stream:
        raw = RawHeader.parse(path, stream.read(HEADER_PREFIX))
        patches, _ = text_patches(stream, raw)
    with open_patched(path, patches) as patched:
        return laspy.LasHeader.read_from(patched, read_evlrs=False)


def _output_header(sources, first: laspy.LasHeader, warnings: list[str]) -> laspy.LasHeader:
    """LAS 1.4, the smallest COPC point format holding every input's fields, the extra
    bytes every input has, the first input's scale, offset, CRS (as WKT) and other VLRs."""
    formats = [s.records.point_format for s in sources]
    target = max(TARGET_FORMAT[f.id] for f in formats)
    if any(f.id in (9, 10) for f in formats):
        warnings.append("point formats 9 and 10 are written as 6 and 8: their waveform fields are left out")
    header = laspy.LasHeader(version="1.4", point_format=target)
    named = [{d.name: d for d in f.extra_dimensions if d.name} for f in formats]
    common = [d for d in formats[0].extra_dimensions if d.name and all(
        d.name in n and n[d.name].type_str() == d.type_str() for n in named[1:])]
    if dropped := sorted({d for n in named for d in n} - {d.name for d in common}):
        warnings.append(f"extra bytes not in every input left out: {', '.join(dropped)}")
    if common:
        header.add_extra_dims([laspy.ExtraBytesParams(d.name, d.type_str(), d.description or "", d.offsets,
                                                      d.scales, d.no_data) for d in common])
    header.scales, header.offsets = np.array(first.scales, np.float64), np.array(first.offsets, np.float64)
    header.system_identifier, header.generating_software = "progressive", "progressive convert"
    header.global_encoding.gps_time_type = first.global_encoding.gps_time_type
    header.global_encoding.wkt = True
    header.are_points_compressed = True
    header.vlrs.extend(v for v in first.vlrs if not isinstance(v, DROPPED_VLRS) and not _copc_or_waveform(v))
    wkt = [v for v in first.vlrs if isinstance(v, WktCoordinateSystemVlr)]
    if wkt:
        header.vlrs.append(wkt[0])
    else:
        _add_crs(header, first, sources[0].info.path, warnings)
    return header


def _copc_or_waveform(vlr) -> bool:
    user = vlr.user_id.rstrip("\0")
    return user == USER_ID.decode() or (user == "LASF_Spec" and vlr.record_id in WAVEFORM_RECORDS)


def _add_crs(header: laspy.LasHeader, first: laspy.LasHeader, path: str, warnings: list[str]) -> None:
    """The first input's GeoTIFF CRS as WKT (point formats 6-10 have no GeoTIFF keys)."""
    if not any(isinstance(v, GeoKeyDirectoryVlr) for v in first.vlrs):
        return
    try:
        crs = first.parse_crs()
    except Exception:       # pyproj's errors for keys it does not understand
        crs = None
    if crs is None:
        warnings.append(f"{shown(path)}: its GeoTIFF CRS could not be read as WKT; the COPC file has no CRS")
    else:
        header.add_crs(crs, keep_compatibility=False)


def _record_parts(sources, header: laspy.LasHeader, partial: bool, warnings: list[str],
                  decoders: DecoderPool | None) -> Iterator[tuple[int, Callable[[], np.ndarray]]]:
    """Every input point, a loader batch at a time (a LAZ decoded by `decoders` where they
    take it: lazrs in this process holds the GIL, which stalls the threads coding the
    parts): each batch's size, and what makes its records of the output's format on the
    output's scale grid (a job for a worker thread)."""
    requantized = False
    for s in sources:
        records = s.records
        same_grid = np.array_equal(records.scales, header.scales) and np.array_equal(records.offsets, header.offsets)
        requantized |= not same_grid
        try:
            for chunk in s.chunks(BATCH_POINTS, salvage=partial, decoders=decoders):
                if isinstance(chunk, Span):
                    chunk = read_span(s.info.path, records, chunk, s.info.points)
                yield chunk.size, partial_call(_converted, s.info.path, chunk, records, header, same_grid)
        except TruncatedInput as exc:         # with partial: what decoded before the damage, and a warning
            if not partial:
                raise
            warnings.append(str(exc))
    if requantized:
        warnings.append("the inputs' scales or offsets differ: coordinates were put on the first input's grid "
                        "(to the nearest step)")
    if any("scan_angle_rank" in s.records.dtype.names for s in sources):
        warnings.append(f"scan angles in whole degrees were written in {SCAN_ANGLE_STEP}° steps (to the nearest step)")


def _converted(path: str, chunk: np.ndarray, records, header: laspy.LasHeader, same_grid: bool) -> np.ndarray:
    """A chunk of input records as records of the output's point format (as laspy copies
    the fields by name), on the output's scale grid."""
    out = _fast_converted(chunk, records.point_format, header.point_format)
    if out is None:
        out = laspy.PackedPointRecord.from_point_record(laspy.PackedPointRecord(chunk, records.point_format),
                                                        header.point_format).array
    elif out is chunk and not same_grid:
        out = chunk.copy()
    if "scan_angle_rank" in chunk.dtype.names:
        out["scan_angle"] = np.rint(chunk["scan_angle_rank"] / SCAN_ANGLE_STEP).astype(np.int16)
    if not same_grid:
        for axis, name in enumerate("XYZ"):
            grid = np.rint((records.coordinates(chunk, axis) - header.offsets[axis]) / header.scales[axis])
            if np.any(np.abs(grid) > 2**31 - 1):
                raise fail(path, f"its {name.lower()} coordinates cannot be written on the first input's scale "
                                 f"and offset (they overflow 32 bits)")
            out[name] = grid.astype(np.int32)
    return out


def _fast_converted(chunk: np.ndarray, source: laspy.PointFormat, target: laspy.PointFormat) -> np.ndarray | None:
    """What laspy's conversion gives (fields of the same name copied, the others zero;
    scan_angle left for the caller), by runs of fields copied whole and, from point
    formats 0-5, the bits of LEGACY_FIELDS moved; the chunk itself where the formats
    match; None where a field of the same name has another type."""
    src, dst = chunk.dtype, target.dtype()
    if src == dst:
        return chunk
    legacy = source.id < 6
    out = np.empty(chunk.size, dst)
    runs: list[list[int]] = []          # [source offset, target offset, bytes]
    for name in sorted(dst.names, key=lambda n: dst.fields[n][1]):
        if legacy and name in NEW_BIT_FIELDS:
            continue
        dtype, offset = dst.fields[name][:2]
        if name not in src.names or (legacy and name in LEGACY_FIELDS):
            out[name] = 0
            continue
        if src.fields[name][0] != dtype:
            return None
        at = src.fields[name][1]
        if runs and runs[-1][0] + runs[-1][2] == at and runs[-1][1] + runs[-1][2] == offset:
            runs[-1][2] += dtype.itemsize
        else:
            runs.append([at, offset, dtype.itemsize])
    for at, offset, size in runs:
        _bytes(out, offset, size)[...] = _bytes(chunk, at, size)
    if legacy:
        bits, classes = chunk["bit_fields"], chunk["raw_classification"]
        out["bit_fields"] = (bits & 0x07) | ((bits & 0x38) << 1)              # return number, number of returns
        out["classification_flags"] = ((classes >> 5) & 0x07) | (bits & 0xC0)   # synthetic.. withheld; scan, edge
        out["classification"] = classes & 0x1F
        out["scan_angle"] = 0
    return out


def _bytes(records: np.ndarray, offset: int, size: int) -> np.ndarray:
    """`size` bytes at `offset` of each record, as one void field (a view)."""
    return records.view(np.dtype({"names": ["v"], "formats": [f"V{size}"], "offsets": [offset],
                                  "itemsize": records.dtype.itemsize}))["v"]


def _cube(bounds: Bounds) -> CopcInfo:
    """The octree's root cube around `bounds` (bounds.slack wider on each side, so that
    rounding never leaves a point on the outside), and its spacing."""
    half = float((bounds.maxs - bounds.mins).max()) / 2 + bounds.slack
    center = tuple(float(c) for c in (bounds.mins + bounds.maxs) / 2)
    return CopcInfo(center, half, 2 * half / CELLS, 0, 0, 0.0, 0.0)


def octree_order(morton: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points (their Morton codes in cloud order, sorted in place) in the order they
    are written (node by node, root first, level by level, nodes of a level and points of
    a node in Morton order), with each one's level and node key (the Morton code of its
    cell at that level). Octree by spacing: a node keeps the point of least rank (_rank)
    of each occupied cell of its CELLS³ grid, unless it has at most LEAF_POINTS left,
    which it keeps all. In Morton order every node and every cell of every level is a run
    of points, so each level takes a few passes over the points left and no sort."""
    by_code = _morton_order(morton)
    level = _levels(morton, _rank(by_code.astype(np.uint64)))
    order = np.argsort(level, kind="stable")
    level = level[order]
    return by_code[order], level, _keys(morton[order], level)


def _morton_order(morton: np.ndarray) -> np.ndarray:
    """The stable argsort of `morton` (ties in the order given), from numpy's faster
    unstable one with the runs of equal codes put back in order; `morton` is sorted in
    place (no second array of codes held)."""
    order = np.argsort(morton)
    morton[...] = morton[order]
    tied = morton[1:] == morton[:-1]
    if tied.any():
        runs = np.r_[0, np.cumsum(~tied)]
        at = np.flatnonzero(np.r_[tied, False] | np.r_[False, tied])
        ties = order[at]
        order[at] = ties[np.lexsort((ties, runs[at]))]
    return order


def _codes(records: np.ndarray, header: laspy.LasHeader, info: CopcInfo):
    """Each point's Morton code of its cell at MAX_DEPTH in the root cube, and the
    points' mins and maxs (inf and -inf for none)."""
    lo = np.asarray(info.center) - info.halfsize
    side = 1 << GRID_BITS
    table = _spread(np.arange(1 << SPREAD_BITS, dtype=np.uint64))
    low, high = np.uint64((1 << SPREAD_BITS) - 1), np.uint64(SPREAD_BITS)
    morton = np.zeros(records.size, np.uint64)
    mins, maxs = np.full(3, np.inf), np.full(3, -np.inf)
    for a in range(3):
        scaled = records["XYZ"[a]] * header.scales[a] + header.offsets[a]
        if scaled.size:
            mins[a], maxs[a] = scaled.min(), scaled.max()
        scaled -= lo[a]
        scaled /= 2 * info.halfsize
        scaled *= side
        np.floor(scaled, out=scaled)
        np.clip(scaled, 0, side - 1, out=scaled)
        cell = scaled.astype(np.uint64)
        spread = table.take(cell & low)
        spread |= table.take(cell >> high) << np.uint64(3 * SPREAD_BITS)
        morton |= spread << np.uint64(2 - a)
    return morton, mins, maxs


def _rank(index: np.ndarray) -> np.ndarray:
    """A point's rank from its index in the cloud (splitmix64's finalizer, a bijection of
    64-bit words: distinct points, distinct ranks), the same in memory and out of core."""
    with np.errstate(over="ignore"):
        z = index.astype(np.uint64) + np.uint64(SEED)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


def _keys(morton: np.ndarray, level: np.ndarray) -> np.ndarray:
    return morton >> (np.uint64(3) * (np.uint64(GRID_BITS) - level.astype(np.uint64)))


def _levels(morton: np.ndarray, rank: np.ndarray, keeps_all: list[np.ndarray] | None = None,
            counts: list[tuple[np.ndarray, np.ndarray]] | None = None) -> np.ndarray:
    """The level of each point (`morton` sorted, `rank` of each). keeps_all[d]: out of
    core, the node codes of depth d whose nodes keep every point left, as the counts of
    every cube decided; those depths' other nodes keep a point a cell (None: each node
    by its own count). counts: collect, for each of those depths, the codes of the
    nodes with points left and how many, then stop (what those decisions are made of)."""
    top = len(keeps_all) if keeps_all is not None else 0
    level = np.full(morton.size, MAX_DEPTH, np.int8)
    remaining = np.arange(morton.size)
    for d in range(MAX_DEPTH):
        if remaining.size == 0 or (counts is not None and d == top):
            break
        codes = morton[remaining]
        node_codes = codes >> np.uint64(3 * (GRID_BITS - d))
        nodes = _runs(node_codes)
        sizes = np.diff(np.r_[nodes, codes.size])
        if counts is not None:
            counts.append((node_codes[nodes], sizes))
        if d < top:
            keep = np.isin(node_codes, keeps_all[d])
        else:
            keep = np.repeat(sizes <= LEAF_POINTS, sizes)
        cells = _runs(codes >> np.uint64(3 * (GRID_BITS - d - CELL_BITS)))
        ranks = rank[remaining]
        least = np.minimum.reduceat(ranks, cells)
        keep |= ranks == np.repeat(least, np.diff(np.r_[cells, codes.size]))
        level[remaining[keep]] = d
        remaining = remaining[~keep]
    return level


def _out_of_core(stream, sources, header: laspy.LasHeader, claimed: Bounds, partial: bool, warnings: list[str],
                 memory_points: int | None, workers: int, folder: Path, decoders: DecoderPool | None) -> Written:
    """write_copc for a cloud of more than memory_points (see the module): the inputs read
    once into the cubes of depth TOP_DEPTH (files in `folder`: each record, 36 bytes for
    point format 7, and its Morton code and index, 12 bytes) and once more where a point
    lies outside the header bounds; the upper levels' nodes that keep every point decided
    from all cubes' counts; each cube's subtree built and compressed; the file assembled."""
    index = "<u4" if sum(s.info.points for s in sources) <= 2**32 else "<u8"
    coded = np.dtype([("morton", "<u8"), ("index", index)])
    info = _cube(claimed)
    spill_points = MEMORY_POINTS if memory_points is None else memory_points
    window = max(1, min(workers, spill_points // BATCH_POINTS - 2))    # parts in flight, one read, one written
    with ThreadPoolExecutor(workers) as pool:
        tally, spilled = _spill(_record_parts(sources, header, partial, warnings, decoders), header, info, claimed,
                                coded, folder, pool, window)
        if not spilled:
            info = _cube(Bounds(tally.mins, tally.maxs, claimed.slack))
            again, _ = _spill(_record_parts(sources, header, partial, [], decoders), header, info, None, coded,
                              folder, pool, window)
            if again.points != tally.points:
                raise InputError("internal error: the inputs read back a different number of points")
        tally.fill(header)
        cubes = sorted(int(path.name.split("-")[1]) for path in folder.glob("codes-*"))
        sizes = [(folder / f"codes-{c}").stat().st_size // coded.itemsize for c in cubes]
        laz_vlr = lazrs.LazVlr.new_for_compression(header.point_format.id, header.point_format.num_extra_bytes,
                                                   True)
        limit = build_limit() if memory_points is None else memory_points
        counts = _bounded(pool, _cube_counts, [(folder, c, coded) for c in cubes], sizes, limit)
        keeps_all = _keeping_all(counts)
        built = _bounded(pool, _cube_nodes, [(folder, c, header.point_format.dtype(), coded, keeps_all, laz_vlr)
                                             for c in cubes], sizes, limit)
    records, morton, level, index = (np.concatenate([upper[k] for upper, _ in built]) for k in range(4))
    order = np.lexsort((index, morton, level))
    parts = [_compressed(folder / "nodes-upper", records.take(order), level[order], morton[order], laz_vlr)]
    parts += [part for _, part in built]
    copc_vlr, _ = _write_head(stream, header)
    point_data = header.offset_to_point_data
    stream.seek(point_data)
    stream.write(bytes(TABLE_OFFSET_BYTES))
    table, levels, keys = [], [], []
    for path, part_table, part_levels, part_keys in parts:
        with open(path, "rb") as f:
            f.seek(TABLE_OFFSET_BYTES)
            left = sum(b for _, b in part_table)
            while left > 0:
                left -= stream.write(f.read(min(COPY_BYTES, left)))
        table += part_table
        levels.append(part_levels)
        keys.append(part_keys)
    table_at = stream.tell()
    lazrs.write_chunk_table(stream, table, laz_vlr)
    stream.seek(point_data)
    stream.write(struct.pack("<q", table_at))
    levels, keys = np.concatenate(levels), np.concatenate(keys)
    _write_hierarchy(stream, header, info, copc_vlr, point_data, levels, keys, table, tally.gps)
    return Written(tally.points, len(table), int(levels.max()) + 1, tuple(warnings))


def build_limit() -> int:
    """The points of the cubes built at once by default: MEMORY_SHARE of the memory
    available once the inputs are spilled (where the scratch is in /dev/shm, that memory
    is taken), BUILD_BYTES a point; MEMORY_POINTS where that is not known. A flat cloud
    fills few of the 512 cubes, each large (64 cubes of 16 M points from 1 B points of
    tiled terrain): a fixed 50 M points kept three of the H200 machine's 16 cores busy."""
    available = available_memory()
    return MEMORY_POINTS if available is None else max(BATCH_POINTS, int(available * MEMORY_SHARE) // BUILD_BYTES)


def _spill(parts, header: laspy.LasHeader, info: CopcInfo, claimed: Bounds | None, coded: np.dtype,
           folder: Path, pool: ThreadPoolExecutor, window: int) -> tuple[Tally, bool]:
    """The records of `parts` appended to the files of their cubes (cube-C the records,
    codes-C their Morton codes in `info` and indices), in cloud order, and the tally of
    them all; False, and no files left, where a point lies outside `claimed` (the rest is
    tallied only). Parts are coded and sorted by cube on `pool`, `window` at a time,
    while the next is read and the files are written in order here."""
    tally, spilling = Tally(), True
    pending: deque = deque()
    at = 0
    for size, job in parts:
        pending.append(pool.submit(_by_cube, job, header, info, at, coded))
        at += size
        if len(pending) > window:
            spilling = _append(pending.popleft(), tally, claimed, spilling, folder)
    while pending:
        spilling = _append(pending.popleft(), tally, claimed, spilling, folder)
    return tally, spilling


def _append(coding: Future, tally: Tally, claimed: Bounds | None, spilling: bool, folder: Path) -> bool:
    """A part's records and codes (its _by_cube future) appended to its cubes' files, and
    tallied: whether the spill goes on (see _spill)."""
    cubes, records, codes, seen = coding.result()
    tally.merge(seen)
    if spilling and claimed is not None and not claimed.holds(seen.mins, seen.maxs):
        for path in [*folder.glob("cube-*"), *folder.glob("codes-*")]:
            path.unlink()
        return False
    if spilling:
        for start, end in zip(*_run_bounds(cubes)):
            with open(folder / f"cube-{int(cubes[start])}", "ab") as f:
                records[start:end].tofile(f)
            with open(folder / f"codes-{int(cubes[start])}", "ab") as f:
                codes[start:end].tofile(f)
    return spilling


def _by_cube(job: Callable[[], np.ndarray], header: laspy.LasHeader, info: CopcInfo, at: int, coded: np.dtype):
    """A part's records (made by `job`, the first of index `at`) sorted by their cube at
    TOP_DEPTH, in cloud order within one: (each one's cube, the records, their codes,
    their tally)."""
    part = job()
    morton, mins, maxs = _codes(part, header, info)
    seen = Tally()
    seen.add(part, mins, maxs)
    cubes = (morton >> np.uint64(3 * (GRID_BITS - TOP_DEPTH))).astype(np.uint16)   # < 8^TOP_DEPTH: a radix sort
    order = np.argsort(cubes, kind="stable")
    codes = np.empty(part.size, coded)
    codes["morton"] = morton.take(order)
    codes["index"] = order + at
    return cubes[order], part.take(order), codes, seen


def _bounded(pool: ThreadPoolExecutor, work, jobs: list[tuple], sizes: list[int], limit: int) -> list:
    """work(*job) for each job on `pool`, at most `limit` points (`sizes`) in flight, or
    one job alone where it has more: the results in the jobs' order."""
    results: list = [None] * len(jobs)
    running: dict = {}
    held = 0
    for i, (job, size) in enumerate(zip(jobs, sizes, strict=True)):
        while running and held + size > limit:
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                j, s = running.pop(future)
                held -= s
                results[j] = future.result()
        running[pool.submit(work, *job)] = (i, size)
        held += size
    for future, (j, _) in running.items():
        results[j] = future.result()
    return results


def _cube_counts(folder: Path, code: int, coded: np.dtype) -> list[tuple[np.ndarray, np.ndarray]]:
    """For each depth above TOP_DEPTH, the codes of the cube's nodes with points left (no
    node keeping them all) and how many, from its codes file alone (ties in any order:
    the counts do not depend on it)."""
    codes = np.fromfile(folder / f"codes-{code}", coded)
    order = np.argsort(codes["morton"])
    counts: list[tuple[np.ndarray, np.ndarray]] = []
    _levels(codes["morton"][order], _rank(codes["index"][order]), [np.zeros(0, np.uint64)] * TOP_DEPTH, counts)
    return counts


def _keeping_all(counts: list[list[tuple[np.ndarray, np.ndarray]]]) -> list[np.ndarray]:
    """For each depth above TOP_DEPTH, the codes of the nodes that keep every point left:
    at most LEAF_POINTS left in all their cubes together (`counts`, _cube_counts of each),
    and no such node above them."""
    totals: list[dict[int, int]] = [{} for _ in range(TOP_DEPTH)]
    for cube in counts:
        for d, (codes, sizes) in enumerate(cube):
            for c, k in zip(codes.tolist(), sizes.tolist(), strict=True):
                totals[d][c] = totals[d].get(c, 0) + k
    keeps: list[np.ndarray] = []
    for d in range(TOP_DEPTH):
        chosen = [c for c, k in totals[d].items() if k <= LEAF_POINTS
                  and not any(np.isin(np.uint64(c) >> np.uint64(3 * (d - a)), keeps[a]) for a in range(d))]
        keeps.append(np.array(sorted(chosen), np.uint64))
    return keeps


def _cube_nodes(folder: Path, code: int, record: np.dtype, coded: np.dtype, keeps_all: list[np.ndarray], laz_vlr):
    """A cube's points of the upper levels (records, Morton codes, levels, indices) and
    its own subtree compressed (_compressed), its files removed."""
    records = np.fromfile(folder / f"cube-{code}", record)
    codes = np.fromfile(folder / f"codes-{code}", coded)
    morton = codes["morton"].copy()
    order = _morton_order(morton)
    index = codes["index"][order]
    del codes
    level = _levels(morton, _rank(index), keeps_all)
    by_level = np.argsort(level, kind="stable")
    above = np.count_nonzero(level < TOP_DEPTH)
    up, deep = by_level[:above], by_level[above:]
    upper = records.take(order[up]), morton[up], level[up], index[up]
    part = _compressed(folder / f"nodes-{code}", records.take(order[deep]), level[deep], morton[deep], laz_vlr)
    (folder / f"cube-{code}").unlink()
    (folder / f"codes-{code}").unlink()
    return upper, part


def _compressed(path: Path, records: np.ndarray, level: np.ndarray, morton: np.ndarray, laz_vlr):
    """Records in node order (level, then Morton code) compressed to `path`, a chunk a
    node: (path, its chunk table, each node's level and key)."""
    key = _keys(morton, level)
    starts = np.r_[0, np.nonzero((np.diff(level) != 0) | (np.diff(key) != 0))[0] + 1] if records.size else \
        np.zeros(0, np.int64)
    counts = np.diff(np.r_[starts, records.size])
    with open(path, "w+b") as f:
        compressor = lazrs.ParLasZipCompressor(f, laz_vlr)
        for group in _groups(counts):
            compressor.compress_chunks([records[starts[i]:starts[i] + counts[i]].view(np.uint8) for i in group])
        compressor.done()
        f.seek(0)
        table = lazrs.read_chunk_table(f, laz_vlr) if counts.size else []
    if [c for c, _ in table] != counts.tolist():
        raise InputError("internal error: the LAZ chunk table does not list one chunk per octree node")
    return path, table, level[starts], key[starts]


def _run_bounds(sorted_values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    starts = _runs(sorted_values) if sorted_values.size else np.zeros(0, np.int64)
    return starts, np.r_[starts[1:], sorted_values.size].astype(np.int64)


def _runs(sorted_codes: np.ndarray) -> np.ndarray:
    """Where each run of equal values of a sorted array starts."""
    return np.r_[0, np.nonzero(sorted_codes[1:] != sorted_codes[:-1])[0] + 1]


def _spread(v: np.ndarray) -> np.ndarray:
    """The bits of v (up to 21) spread out to every third bit, for Morton codes."""
    v = v & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


def _compact(v: np.ndarray) -> np.ndarray:
    """Every third bit of v gathered: the inverse of _spread."""
    v = v & np.uint64(0x1249249249249249)
    for shift, mask in ((2, 0x10C30C30C30C30C3), (4, 0x100F00F00F00F00F), (8, 0x1F0000FF0000FF),
                        (16, 0x1F00000000FFFF), (32, 0x1FFFFF)):
        v = (v | (v >> np.uint64(shift))) & np.uint64(mask)
    return v


def _key_xyz(key: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A node's x, y, z from its Morton code."""
    return tuple(_compact(key >> np.uint64(2 - a)).astype(np.int32) for a in range(3))


def _groups(counts: np.ndarray):
    """Node indices in runs of about COMPRESS_POINTS points."""
    group, held = [], 0
    for i, n in enumerate(counts.tolist()):
        group.append(i)
        held += n
        if held >= COMPRESS_POINTS:
            yield group
            group, held = [], 0
    if group:
        yield group
