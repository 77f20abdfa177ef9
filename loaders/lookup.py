"""One point's exact file coordinates, read back from its file: float64 as the file
defines them (integer record times scale plus offset), not the float32 the GPU holds."""

from __future__ import annotations

import math
from decimal import Decimal

import numpy as np

from progressive.loaders.copc import CopcFileInfo
from progressive.loaders.e57 import read_point as read_e57_point
from progressive.loaders.fastformat import HEADER_BYTES
from progressive.loaders.laz import TABLE_OFFSET_BYTES
from progressive.loaders.ply import read_point as read_ply_point
from progressive.loaders.types import CloudInfo, FileInfo
from progressive.loaders.validate import open_binary

FAST_FORMAT = "PRGS"


def locate(info: CloudInfo, index: int) -> tuple[FileInfo, int]:
    """The file holding cloud index `index` and the point's index in that file."""
    if not 0 <= index < info.points:
        raise IndexError(f"point {index} outside the cloud of {info.points} points")
    for file in info.files:
        if index < file.points:
            return file, file.file_index(index)
        index -= file.points
    raise IndexError(f"point {index} outside the files")


def read_point(info: CloudInfo, index: int) -> np.ndarray:
    """(3,) float64 x, y, z of the point with file-order `index` (files concatenated)."""
    file, index = locate(info, index)
    if file.format == FAST_FORMAT:
        with open(file.path, "rb") as stream:
            stream.seek(HEADER_BYTES + 16 * index)
            xyz = np.frombuffer(stream.read(12), dtype="<f4")
        return info.origin + xyz.astype(np.float64)
    if file.format == "PLY":
        return read_ply_point(file.path, index)
    if file.format == "E57":
        return read_e57_point(file.path, index)
    points = _las_point(file, index)
    return np.array([points.x[0], points.y[0], points.z[0]], dtype=np.float64)


def _las_point(file: FileInfo, index: int):
    """The one point record at `index` of a LAS/LAZ file, as laspy reads it; of a URL's
    COPC file, from its node fetched again."""
    import laspy
    import lazrs

    if isinstance(file, CopcFileInfo) and file.remote is not None:
        remote = file.remote
        compressed, count, at = remote.node_of(index)
        return _chunk_point(compressed, count, at, remote.vlr_data, remote.point_format, remote.scales,
                            remote.offsets)
    with laspy.open(file.path) as reader:
        laszip = reader.header.vlrs.get("LasZipVlr")
        if laszip and lazrs.LazVlr(laszip[0].record_data).uses_variable_size_chunks():
            return _variable_chunk_point(file.path, reader.header, laszip[0].record_data, index)
        reader.seek(index)
        return reader.read_points(1)


def _variable_chunk_point(path: str, header, vlr_data: bytes, index: int):
    """The point at `index` of a LAZ of variable-size chunks (COPC), decoded from its
    chunk alone: laspy's seek does not find the chunk in such files (it reads another
    point, or fails)."""
    import lazrs

    with open_binary(path) as stream:
        stream.seek(header.offset_to_point_data)
        table = lazrs.read_chunk_table(stream, lazrs.LazVlr(vlr_data))
        counts = np.array([n for n, _ in table], np.int64)
        sizes = np.array([b for _, b in table], np.int64)
        chunk = int(np.searchsorted(np.cumsum(counts), index, side="right"))
        stream.seek(header.offset_to_point_data + TABLE_OFFSET_BYTES + int(sizes[:chunk].sum()))
        compressed = stream.read(int(sizes[chunk]))
    return _chunk_point(compressed, int(counts[chunk]), index - int(counts[:chunk].sum()), vlr_data,
                        header.point_format, header.scales, header.offsets)


def _chunk_point(compressed: bytes, count: int, at: int, vlr_data: bytes, point_format, scales, offsets):
    """Point `at` of one LAZ chunk of `count` points, decoded alone."""
    import laspy
    import lazrs

    records = np.empty(count, point_format.dtype())
    lazrs.decompress_points_with_chunk_table(compressed, vlr_data, memoryview(records).cast("B"),
                                             [(count, len(compressed))], None)
    return laspy.ScaleAwarePointRecord(records[at:at + 1].copy(), point_format, scales, offsets)


def decimals(value: float) -> int:
    """Decimal places of a header's scale or offset as written (0.0025: 4, 0.005: 3)."""
    exponent = Decimal(repr(float(value))).normalize().as_tuple().exponent
    return max(0, -exponent) if isinstance(exponent, int) else 0


def _plain(value):
    """A JSON-safe attribute value: NaN and infinities become None."""
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return None if isinstance(value, float) and not math.isfinite(value) else value


def read_record(info: CloudInfo, index: int) -> dict:
    """All of one point, read back from its file: the file, the index in it, x, y, z in
    float64 (LAS: rounded to the decimals its scale and offset carry) and, for LAS/LAZ,
    every dimension of its point format with the extra bytes (scaled as laspy scales
    them; NaN as None). Other formats give their coordinates only."""
    file, local = locate(info, index)
    out = {"file": file.path, "index": int(local), "cloud_index": int(index)}
    attributes: dict = {}
    if file.format not in ("LAS", "LAZ"):
        xyz = read_point(info, index)
    else:
        points = _las_point(file, local)
        digits = [max(decimals(sc), decimals(of)) for sc, of in zip(file.scale, file.offset)]
        xyz = [round(float(points[axis][0]), d) for axis, d in zip("xyz", digits)]
        for name in points.point_format.dimension_names:
            if name in ("X", "Y", "Z"):
                continue
            value = np.asarray(points[name])[0]
            attributes[name] = _plain(value.tolist() if isinstance(value, np.ndarray) else value.item())
    out.update(x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]), attributes=attributes)
    return out
