"""Writing COPC: LAS/LAZ files as one LAZ 1.4 whose chunks are the nodes of an octree.

The octree is built by spacing, as PDAL and Untwine build it: the root cube holds a grid
of CELLS³ cells and each level halves the cell; a node keeps one point per occupied cell
(the first of a fixed pseudo-random order, so that a level is an even sample of what is
below it) and passes the rest to its children, until a node has at most
LEAF_POINTS points left (it keeps them all) or MAX_DEPTH is reached. Nodes are written
root first, level by level, each one LAZ chunk (lazrs, on every core); the hierarchy is
one page in an EVLR, and the COPC info VLR comes first after the header, as the
specification (https://copc.io) requires.

Point records keep every field: point formats 6-8 are written as they are (9 and 10 as 6
and 8, without their waveform fields), older ones converted by laspy, field by field
(scan angle from whole degrees to 0.006° steps: the nearest).

A cloud of up to `memory_points` is held in memory while its octree is built. A larger
one is built out of core, with the same nodes: the inputs are read once for the bounds
(which place the root cube) and again into files of a scratch folder, one for each of
the octree's cubes at TOP_DEPTH. Every cell of the levels above that depth lies in one
cube, and a point's rank is a hash of its index, so each cube picks its points of those
levels alone; only whether a node of those levels keeps every point left (at most
LEAF_POINTS) needs the counts of all its cubes, summed first. Then each cube's own
subtree is built in memory and compressed apart, and the file is assembled from the
compressed chunks: the upper levels' nodes first, level by level, then each cube's.
"""

from __future__ import annotations

import os
import struct
import tempfile
from dataclasses import dataclass
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
from progressive.loaders.pipeline import open_sources
from progressive.loaders.types import BATCH_POINTS
from progressive.loaders.validate import fail, open_binary, shown

CELLS = 128
"""Cells along each axis of a node's grid: the root spacing is the cube's side / CELLS."""
LEAF_POINTS = 100_000
"""A node left with at most this many points keeps them all and has no children."""
MAX_DEPTH = 12
"""Deepest level: every point left there stays (keys of CELLS·2^12 cells fit 64 bits)."""
CELL_BITS = CELLS.bit_length() - 1
GRID_BITS = CELL_BITS + MAX_DEPTH      # bits of a point's cell at MAX_DEPTH, per axis
SEED = 0x5EED
COMPRESS_POINTS = 1 << 22
"""Points handed to the parallel compressor at a time."""
MEMORY_POINTS = 50_000_000
"""Points whose octree is built in memory at a time (about 100 bytes each with their
codes and ranks): a larger cloud is built out of core, a cube at a time."""
TOP_DEPTH = 3
"""The depth of the cubes a cloud is split into out of core (at most 8^3 files; a cube
over memory_points is still built whole in memory). At most CELL_BITS: each cell of the
levels above lies in one cube."""
COPY_BYTES = 64 << 20
"""Compressed chunks copied into the output at a time, out of core."""
TARGET_FORMAT = {0: 6, 1: 6, 4: 6, 6: 6, 9: 6, 2: 7, 3: 7, 5: 7, 7: 7, 8: 8, 10: 8}
"""The COPC point format (6, 7 or 8) that holds a point format's fields."""
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


def write_copc(stream, inputs: list[str], *, partial: bool = False, memory_points: int | None = None,
               scratch: str | os.PathLike | None = None) -> Written:
    """Write `inputs` (LAS/LAZ files, one cloud) to `stream` (opened w+b, at 0) as COPC;
    a cloud of more than memory_points (default MEMORY_POINTS) is built out of core in a
    temporary folder made in `scratch` (default: the system's), removed whatever happens."""
    memory_points = MEMORY_POINTS if memory_points is None else memory_points
    _, sources = open_sources(inputs, partial=partial)
    for s in sources:
        if not isinstance(s, LasSource):
            raise fail(s.info.path, f"is {s.info.format}: COPC is written from LAS/LAZ files")
    warnings: list[str] = []
    first = _laspy_header(sources[0].info.path)
    header = _output_header(sources, first, warnings)
    if sum(s.info.points for s in sources) > memory_points:
        with tempfile.TemporaryDirectory(prefix=".progressive-copc-", dir=scratch) as folder:
            written = _out_of_core(stream, sources, header, partial, warnings, memory_points, Path(folder))
        return written
    records = np.concatenate(list(_record_parts(sources, header, partial, warnings)))
    order, level, key = octree_order(records, header)
    records = records[order]
    starts = np.r_[0, np.nonzero((np.diff(level) != 0) | (np.diff(key) != 0))[0] + 1]
    counts = np.diff(np.r_[starts, records.size])
    _fill_header(header, records)
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
    gps = records["gps_time"]
    _write_hierarchy(stream, header, copc_vlr, point_data, level[starts], key[starts], table,
                     (float(gps.min()), float(gps.max())))
    return Written(int(records.size), int(counts.size), int(level.max()) + 1, tuple(warnings))


def _write_head(stream, header: laspy.LasHeader):
    """The header and VLRs, the COPC info VLR (filled in last) first: (it, the LAZ VLR)."""
    laz_vlr = lazrs.LazVlr.new_for_compression(header.point_format.id, header.point_format.num_extra_bytes, True)
    copc_vlr = laspy.VLR(USER_ID.decode(), INFO_RECORD, "COPC info VLR", bytes(INFO.size))
    header.vlrs.insert(0, copc_vlr)
    header.vlrs.insert(1, LasZipVlr(laz_vlr.record_data()))
    header.write_to(stream)
    return copc_vlr, laz_vlr


def _write_hierarchy(stream, header: laspy.LasHeader, copc_vlr, point_data: int, levels: np.ndarray,
                     keys: np.ndarray, table, gps: tuple[float, float]) -> None:
    """The hierarchy EVLR after the chunks (one a node, in the chunk table's order), then
    the header again with the info VLR filled in."""
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
    info = _cube(header)
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


def _record_parts(sources, header: laspy.LasHeader, partial: bool, warnings: list[str]):
    """Every input point as a record of the output's format, on the output's scale grid,
    a loader batch at a time."""
    requantized = False
    for s in sources:
        records = s.records
        same_grid = np.array_equal(records.scales, header.scales) and np.array_equal(records.offsets, header.offsets)
        requantized |= not same_grid
        try:
            for chunk in s.chunks(BATCH_POINTS, salvage=partial):
                if isinstance(chunk, Span):
                    chunk = read_span(s.info.path, records, chunk, s.info.points)
                yield _converted(s.info.path, chunk, records, header, same_grid)
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
    """A chunk of input records as records of the output's point format (laspy copies the
    fields by name), on the output's scale grid."""
    out = laspy.PackedPointRecord.from_point_record(laspy.PackedPointRecord(chunk, records.point_format),
                                                    header.point_format).array
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


def _cube(header_or_bounds) -> CopcInfo:
    """The octree's root cube around the header's bounds (a scale step wider on each side,
    so that rounding never leaves a point on the outside), and its spacing."""
    lo, hi = np.asarray(header_or_bounds.mins, np.float64), np.asarray(header_or_bounds.maxs, np.float64)
    half = float((hi - lo).max()) / 2 + float(np.abs(header_or_bounds.scales).max())
    center = tuple(float(c) for c in (lo + hi) / 2)
    return CopcInfo(center, half, 2 * half / CELLS, 0, 0, 0.0, 0.0)


def _fill_header(header: laspy.LasHeader, records: np.ndarray) -> None:
    """Count and points by return of the records (octree_order sets the bounds)."""
    header.point_count = int(records.size)
    returns = np.asarray(laspy.PackedPointRecord(records, header.point_format)["return_number"])
    header.number_of_points_by_return = np.bincount(returns, minlength=16)[1:16].astype(np.uint64)


def octree_order(records: np.ndarray, header: laspy.LasHeader) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points in the order they are written (node by node, root first, level by level,
    nodes of a level and points of a node in Morton order), with each one's
    level and node key (the Morton code of its cell at that level). Octree by spacing: a
    node keeps the point of least rank (_rank) of each occupied cell of its CELLS³ grid,
    unless it has at most LEAF_POINTS left, which it keeps all. In Morton order every
    node and every cell of every level is a run of points, so each level takes a few
    passes over the points left and no sort. Sets the header's bounds."""
    scaled = [records["XYZ"[a]] * header.scales[a] + header.offsets[a] for a in range(3)]
    header.mins = np.array([c.min() for c in scaled])
    header.maxs = np.array([c.max() for c in scaled])
    del scaled
    morton = _morton(records, header, _cube(header))
    by_code = np.argsort(morton, kind="stable")
    morton = morton[by_code]
    level = _levels(morton, _rank(by_code.astype(np.uint64)))
    order = np.argsort(level, kind="stable")
    level = level[order]
    return by_code[order], level, _keys(morton[order], level)


def _morton(records: np.ndarray, header: laspy.LasHeader, info: CopcInfo) -> np.ndarray:
    """Each point's Morton code of its cell at MAX_DEPTH in the root cube."""
    lo = np.asarray(info.center) - info.halfsize
    side = 1 << GRID_BITS
    morton = np.zeros(records.size, np.uint64)
    for a in range(3):
        scaled = records["XYZ"[a]] * header.scales[a] + header.offsets[a]
        cell = np.clip(np.floor((scaled - lo[a]) / (2 * info.halfsize) * side), 0, side - 1).astype(np.uint64)
        morton |= _spread(cell) << np.uint64(2 - a)
    return morton


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


def _out_of_core(stream, sources, header: laspy.LasHeader, partial: bool, warnings: list[str],
                 memory_points: int, folder: Path) -> Written:
    """write_copc for a cloud of more than memory_points (see the module): the inputs read
    once for the bounds and again into the cubes of depth TOP_DEPTH (files in `folder`:
    each record and its index, 40 bytes a point for point format 7), the upper levels'
    nodes that keep every point decided from all cubes' counts, each cube's subtree
    built and compressed, the file assembled."""
    n, mins, maxs, returns, gps = 0, np.full(3, np.inf), np.full(3, -np.inf), np.zeros(16, np.int64), [np.inf, -np.inf]
    dtype = None
    for part in _record_parts(sources, header, partial, warnings):
        dtype = part.dtype
        n += part.size
        for a in range(3):
            scaled = part["XYZ"[a]] * header.scales[a] + header.offsets[a]
            mins[a], maxs[a] = min(mins[a], scaled.min()), max(maxs[a], scaled.max())
        returns += np.bincount(np.asarray(laspy.PackedPointRecord(part, header.point_format)["return_number"]),
                               minlength=16)[:16]
        gps = [min(gps[0], float(part["gps_time"].min())), max(gps[1], float(part["gps_time"].max()))]
    header.mins, header.maxs, header.point_count = mins, maxs, n
    header.number_of_points_by_return = returns[1:16].astype(np.uint64)
    info = _cube(header)
    cube = np.dtype([("index", "<u4" if n <= 2**32 else "<u8"), ("record", dtype)])
    shift = np.uint64(3 * (GRID_BITS - TOP_DEPTH))
    at = 0
    for part in _record_parts(sources, header, partial, []):     # the same records again, warned of once
        ids = _morton(part, header, info) >> shift
        order = np.argsort(ids, kind="stable")
        block = np.empty(part.size, cube)
        block["record"], block["index"] = part[order], np.arange(at, at + part.size)[order]
        ids = ids[order]
        for start, end in zip(*_run_bounds(ids)):
            with open(folder / f"cube-{int(ids[start])}", "ab") as f:
                block[start:end].tofile(f)
        at += part.size
    if at != n:
        raise InputError("internal error: the inputs read back a different number of points")
    cubes = sorted((int(path.name.split("-")[1]), path) for path in folder.glob("cube-*"))
    keeps_all = _upper_nodes_keeping_all(cubes, cube, header, info)
    laz_vlr = lazrs.LazVlr.new_for_compression(header.point_format.id, header.point_format.num_extra_bytes, True)
    upper, parts = [], []
    for code, path in cubes:
        points, morton = _cube_points(path, cube, header, info)
        level = _levels(morton, _rank(points["index"]), keeps_all)
        above = level < TOP_DEPTH
        upper.append((points[above], morton[above], level[above]))
        deep = np.argsort(level, kind="stable")[np.count_nonzero(above):]
        parts.append(_compressed(folder / f"nodes-{code}", points["record"][deep], level[deep], morton[deep],
                                 laz_vlr))
        path.unlink()
    points, morton, level = (np.concatenate([u[k] for u in upper]) for k in range(3))
    order = np.lexsort((points["index"], morton, level))
    parts.insert(0, _compressed(folder / "nodes-upper", points["record"][order], level[order], morton[order],
                                laz_vlr))
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
    _write_hierarchy(stream, header, copc_vlr, point_data, levels, keys, table, tuple(gps))
    return Written(n, len(table), int(levels.max()) + 1, tuple(warnings))


def _cube_points(path: Path, cube: np.dtype, header: laspy.LasHeader, info: CopcInfo):
    """A cube file's points in Morton order (ties in cloud order), and their codes."""
    points = np.fromfile(path, cube)
    morton = _morton(points["record"], header, info)
    order = np.argsort(morton, kind="stable")
    return points[order], morton[order]


def _upper_nodes_keeping_all(cubes, cube: np.dtype, header: laspy.LasHeader, info: CopcInfo) -> list[np.ndarray]:
    """For each depth above TOP_DEPTH, the codes of the nodes that keep every point left:
    at most LEAF_POINTS left in all their cubes together, and no such node above them."""
    totals: list[dict[int, int]] = [{} for _ in range(TOP_DEPTH)]
    none = [np.zeros(0, np.uint64)] * TOP_DEPTH
    for _, path in cubes:
        points, morton = _cube_points(path, cube, header, info)
        counts: list[tuple[np.ndarray, np.ndarray]] = []
        _levels(morton, _rank(points["index"]), none, counts)
        for d, (codes, sizes) in enumerate(counts):
            for c, k in zip(codes.tolist(), sizes.tolist()):
                totals[d][c] = totals[d].get(c, 0) + k
    keeps: list[np.ndarray] = []
    for d in range(TOP_DEPTH):
        chosen = [c for c, k in totals[d].items() if k <= LEAF_POINTS
                  and not any(np.isin(np.uint64(c) >> np.uint64(3 * (d - a)), keeps[a]) for a in range(d))]
        keeps.append(np.array(sorted(chosen), np.uint64))
    return keeps


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
