"""The fast format: a 256-byte header and the GPU's 16-byte records, so loading is one
large sequential read per batch with no per-point work.

Header (little-endian): magic, version, header size, count, origin, bounds min/max,
attribute kind, reserved, attribute offset, attribute name (64 bytes, NUL-padded).
"""

from __future__ import annotations

import dataclasses
import math
import os
import struct
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from progressive.errors import InputError
from progressive.loaders.las import BOUNDS_SAMPLE, attribute_kind
from progressive.loaders.records import ELEVATION, RECORD_BYTES, pack_records
from progressive.loaders.types import (
    BATCH_POINTS,
    AttributeInfo,
    AttributeKind,
    Batch,
    CloudInfo,
    FileInfo,
    nonfinite_records,
    quiet_nans,
)
from progressive.loaders.validate import BOUNDS_SLACK, contradicted_bounds, fail, open_binary, shown

MAGIC = b"PRGSPC\x00\x01"
VERSION = 1
HEADER_BYTES = 256
NAME_BYTES = 64
HEADER = struct.Struct("<8sIIQ3d3d3dIId64s")
KIND_CODES = {AttributeKind.RGB: 0, AttributeKind.SCALAR: 1, AttributeKind.CATEGORY: 2}
MAX_COORDINATE = 1e12
"""Largest origin (or attribute offset) a fast-format file may hold: float64 keeps a
tenth of a millimetre there, and beyond it float32 positions relative to it are lost."""
FLOAT32_STEP = 2.0 ** -22
"""Rounding of a float32 position relative to its magnitude, doubled."""
KIND_DTYPES = {AttributeKind.RGB: np.uint8, AttributeKind.SCALAR: np.float64, AttributeKind.CATEGORY: np.uint32}


MAGIC_STEM = MAGIC[:6]
"""Files starting with this are meant to be fast-format, so a wrong rest is 'bad magic'."""


def is_fast(path: str | os.PathLike) -> bool:
    """Decided by magic, not extension; unreadable paths (and what is not a regular file)
    are left to the LAS checks."""
    try:
        with open_binary(path) as stream:
            return stream.read(len(MAGIC_STEM)) == MAGIC_STEM
    except (InputError, OSError):
        return False


@dataclass(frozen=True)
class FastSource:
    """One fast-format file: its header facts and its single pre-packed attribute."""

    info: FileInfo
    attribute: AttributeInfo
    origin: np.ndarray
    warnings: tuple[str, ...] = ()

    def spans(self, batch_points: int) -> Iterator[tuple[int, int]]:
        """(first, count) of the file's batches of at most batch_points records."""
        for first in range(0, self.info.points, batch_points):
            yield first, min(batch_points, self.info.points - first)

    def read(self, first: int, count: int, start: int) -> Batch:
        """Records first .. first + count straight from disk in one read, as the batch of
        cloud index `start`, still to go through parse(); positions view the records' xyz.
        Each parser thread reads its own batches (the GIL released through the read), so
        the reads run on every parser thread at once."""
        records = np.empty((count, 4), dtype=np.uint32)
        with open_binary(self.info.path) as stream:
            stream.seek(HEADER_BYTES + first * RECORD_BYTES)
            _read_exactly(self.info.path, stream, memoryview(records).cast("B"))
        return Batch(start=start, xyz=records[:, :3].view(np.float32), records=records)

    def read_parsed(self, first: int, count: int, start: int) -> Batch:
        """read() then parse(): a parser thread's task."""
        return self.parse(self.read(first, count, start))

    def batches(self, batch_points: int, start: int) -> Iterator[Batch]:
        """The file's batches in order, read one after another (see read)."""
        for first, count in self.spans(batch_points):
            yield self.read(first, count, start + first)

    def record_bounds(self, limit: int | None = None) -> np.ndarray | None:
        """(2, 3) float64 min and max of origin + position over the first `limit` records
        (all of them: one pass over the file) with finite coordinates; None if there are
        none."""
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        total = self.info.points if limit is None else min(limit, self.info.points)
        with np.errstate(invalid="ignore"):
            for batch in self.batches(min(total, BATCH_POINTS), 0):
                if batch.start >= total:
                    break
                positions = batch.positions[:total - batch.start]
                finite = positions[np.isfinite(positions).all(axis=1)]
                if len(finite):
                    lo, hi = np.minimum(lo, finite.min(axis=0)), np.maximum(hi, finite.max(axis=0))
        if not np.isfinite(lo).all():
            return None
        return self.origin + np.stack([lo, hi]).astype(np.float64)

    def parse(self, batch: Batch) -> Batch:
        """The batch with its NaN/Inf coordinates and scalar values counted (elevation only
        as positions) and their NaNs made quiet: any bit pattern can be in a file."""
        positions, word = batch.positions, batch.records[:, 3].view(np.float32)
        nonfinite, values = nonfinite_records(batch.records)
        if nonfinite:
            quiet_nans(positions)
        scalar = self.attribute.kind is AttributeKind.SCALAR
        if values and scalar:
            quiet_nans(word)
        counted = scalar and values and self.attribute.name != ELEVATION
        return dataclasses.replace(batch, nonfinite_positions=nonfinite,
                                   nonfinite_values={self.attribute.name: values} if counted else {})


def _read_exactly(path: str, stream, buffer: memoryview) -> None:
    done = 0
    while done < len(buffer):
        n = stream.readinto(buffer[done:])
        if not n:
            raise fail(path, f"ended early while reading records ({done} of {len(buffer)} bytes)")
        done += n


def open_fast(path: str | os.PathLike, *, partial: bool = False) -> FastSource:
    """Validate every header field and the file length against the count; header bounds
    that the first records contradict are replaced by the records' own (one extra read)."""
    path = os.fspath(path)
    with open_binary(path) as stream:
        size = os.fstat(stream.fileno()).st_size
        head = stream.read(HEADER_BYTES)
    if len(head) < HEADER_BYTES:
        raise fail(path, f"is too short for a fast-format header ({len(head)} bytes)")
    (magic, version, header_size, count, *floats, kind_code, _, attr_offset, raw_name) = \
        HEADER.unpack_from(head)
    if magic != MAGIC:
        raise fail(path, f"has a bad fast-format magic {magic!r} (expected {MAGIC!r})")
    if version != VERSION:
        raise fail(path, f"unsupported fast-format version {version} (expected {VERSION})")
    if header_size != HEADER_BYTES:
        raise fail(path, f"bad fast-format header size {header_size} (expected {HEADER_BYTES})")
    kinds = {code: kind for kind, code in KIND_CODES.items()}
    if kind_code not in kinds:
        raise fail(path, f"unknown attribute kind {kind_code}")
    if count == 0:
        raise fail(path, "has no points")
    if not all(math.isfinite(v) for v in (*floats, attr_offset)):
        raise fail(path, "has a non-finite origin, bounds or attribute offset in its header")
    if max(abs(v) for v in (*floats[:3], attr_offset)) > MAX_COORDINATE:
        raise fail(path, f"has an origin or attribute offset beyond {MAX_COORDINATE:g} in its header "
                         f"({', '.join(f'{v:g}' for v in (*floats[:3], attr_offset))})")
    kind = kinds[kind_code]
    name = _attribute_name(path, raw_name, kind)
    warnings = []
    expected = HEADER_BYTES + RECORD_BYTES * count
    if size != expected:
        problem = f"length {size} bytes does not match its {count} points ({expected} bytes expected)"
        complete = (size - HEADER_BYTES) // RECORD_BYTES
        if not (partial and 0 < complete < count):
            raise fail(path, problem)
        warnings.append(f"{shown(path)}: {problem}; read the first {complete} points")
        count = complete
    origin, lo, hi = (tuple(floats[i:i + 3]) for i in (0, 3, 6))
    info = FileInfo(path=path, format="PRGS", version=str(version), point_format=-1, points=count,
                    scale=(1.0, 1.0, 1.0), offset=(0.0, 0.0, 0.0), bounds_min=lo, bounds_max=hi,
                    rgb_max=None)
    attribute = AttributeInfo(name, kind, np.dtype(KIND_DTYPES[kind]), attr_offset)
    source = FastSource(info, attribute, np.array(origin, dtype=np.float64))
    seen = source.record_bounds(BOUNDS_SAMPLE)
    step = None if seen is None else np.abs(seen - source.origin).max(axis=0) * FLOAT32_STEP
    if wrong := _off_centre(origin, lo, hi) or contradicted_bounds(lo, hi, seen, step):
        lo, hi = source.record_bounds()
        warnings.append(f"{shown(path)}: header bounds {wrong}; ignored them and used the bounds of the points")
        info = dataclasses.replace(info, bounds_min=tuple(map(float, lo)), bounds_max=tuple(map(float, hi)))
    return dataclasses.replace(source, info=info, warnings=tuple(warnings))


def _off_centre(origin, lo, hi) -> str | None:
    """Bounds not centred on the origin, described: the writer puts the origin at their
    centre, and the records are relative to it, so such bounds are the damaged field."""
    centre = np.asarray(lo) / 2 + np.asarray(hi) / 2
    if np.allclose(centre, origin, rtol=BOUNDS_SLACK, atol=BOUNDS_SLACK):
        return None
    return (f"are not centred on its origin ({', '.join(f'{v:g}' for v in origin)}; their centre is "
            f"{', '.join(f'{v:g}' for v in centre)})")


def _attribute_name(path: str, raw: bytes, kind: AttributeKind) -> str:
    """The attribute name: UTF-8, printable, NUL-terminated and NUL-padded, and of the kind
    stored (a damaged 'rgb' must not pass for a scalar, nor the reverse)."""
    text, nul, padding = raw.partition(b"\x00")
    if not nul or padding.strip(b"\x00"):
        raise fail(path, f"has an attribute name field that is not NUL-terminated and NUL-padded ({raw!r})")
    try:
        name = text.decode("utf-8")
    except UnicodeDecodeError:
        raise fail(path, f"has an attribute name that is not UTF-8 ({text!r})") from None
    if not name or not name.isprintable():
        raise fail(path, f"has an empty or unprintable attribute name ({text!r})")
    if attribute_kind(name) is not kind:
        raise fail(path, f"stores attribute {name!r} as {kind.value}, but {name!r} is "
                         f"{attribute_kind(name).value}")
    return name


def fast_header(count: int, info: CloudInfo, attr: AttributeInfo) -> bytes:
    name = attr.name.encode("utf-8")
    if len(name) >= NAME_BYTES:
        raise InputError(f"attribute name {attr.name!r} is longer than {NAME_BYTES - 1} bytes")
    head = HEADER.pack(MAGIC, VERSION, HEADER_BYTES, count, *info.origin, *info.bounds_min,
                       *info.bounds_max, KIND_CODES[attr.kind], 0, attr.offset, name)
    return head.ljust(HEADER_BYTES, b"\x00")


def positioned(batch: Batch) -> Batch:
    """The batch with its float32 positions, which the fast format stores: a LAS batch's
    computed from its integers (CloudLoader's on_parsed, so on the parser threads, not on
    the thread that writes the file)."""
    return batch if batch.xyz is not None else batch.with_positions(batch.positions)


def write_fast_stream(stream: BinaryIO, loader_or_batches: Iterable[Batch], info: CloudInfo,
                      attr: AttributeInfo, name: str) -> int:
    """Write every batch at its offset (they may arrive out of order) into a seekable
    binary stream. A contiguous prefix, as a partial load of a truncated file gives, is
    written with its own count; anything else short is an error (`name` in its message)."""
    origin_z = float(info.origin[2])
    written = end = 0
    stream.write(fast_header(info.points, info, attr))
    for batch in loader_or_batches:
        stream.seek(HEADER_BYTES + RECORD_BYTES * batch.start)
        stream.write(np.ascontiguousarray(pack_records(batch, attr, origin_z)).data)
        written += batch.count
        end = max(end, batch.start + batch.count)
    if written != info.points:
        if written == 0 or written != end:
            raise InputError(f"{shown(name)}: only {written} of {info.points} points were read, "
                             f"not a contiguous run from the first; not written")
        stream.seek(0)
        stream.write(fast_header(written, info, attr))
        stream.truncate(HEADER_BYTES + RECORD_BYTES * written)
    return written


def write_fast(out_path: str | os.PathLike, loader_or_batches: Iterable[Batch], info: CloudInfo,
               attr: AttributeInfo) -> int:
    """write_fast_stream into a temporary file beside out_path, replaced into place only
    when complete (the CLI writes through its output transaction instead)."""
    out_path = Path(out_path)
    fd, tmp = tempfile.mkstemp(prefix=f".{out_path.name}.", suffix=".tmp", dir=out_path.parent)
    try:
        os.fchmod(fd, 0o644)
        with os.fdopen(fd, "wb") as stream:
            written = write_fast_stream(stream, loader_or_batches, info, attr, str(out_path))
        os.replace(tmp, out_path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return written
