"""LAS/LAZ input: header facts, raw point chunks, and chunk -> Batch parsing.

laspy reads the header and decodes damaged or unusual files; this module adds the checks
laspy does not make (size against the header count, LAS version, empty files) so that
every bad file fails with one clear line. Repairing what laspy would refuse, and reading
what is left of a damaged LAZ when the caller asks for partial input, is
loaders/salvage.py's.

Points are numpy structured arrays of the point format's dtype. An uncompressed file's
records are read by the parser threads themselves, a batch in one read that releases the
GIL; a LAZ with a sound chunk table is decoded by lazrs several chunks at a time on every
core (loaders/laz.py). Parsing is whole-array numpy, no per-point Python.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import os
import re
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import laspy
import lazrs
import numpy as np

from progressive.errors import InputError
from progressive.loaders.laz import LazLayout, decode_chunks, laz_layout, open_patched
from progressive.loaders.laz_pool import DecoderPool, PoolClosed
from progressive.loaders.salvage import (
    VLR_HEADER,
    checked_count,
    is_decode_error,
    salvaged,
    text_patches,
    unreachable_bounds,
)
from progressive.loaders.types import (
    BATCH_POINTS,
    FIRST_BATCH_POINTS,
    RGB8_MAX,
    AttributeInfo,
    AttributeKind,
    Batch,
    FileInfo,
    Grid,
    available_cores,
    nonfinite_count,
    nonfinite_rows,
    quiet_nans,
)
from progressive.loaders.validate import (
    contradicted_bounds,
    fail,
    one_line,
    open_binary,
    shown,
)

SIGNATURE = b"LASF"
MAX_POINT_FORMAT = 10
MAX_MINOR_VERSION = 4
HEADER_PREFIX = 375                     # the LAS 1.4 header; older ones are shorter
MIN_HEADER = {0: 227, 1: 227, 2: 227, 3: 235, 4: 375}
SCAN_ANGLE_STEP = 0.006                 # degrees per unit of the PF 6-10 scan_angle
PROBE_PIECE = 65_536                    # points per read while looking for 16-bit colour
FROM_INTEGERS = frozenset({"scan_angle"})
"""Float attributes made from a record's integers: never NaN or infinite, not checked."""
KEPT_BYTES = 1 << 26
"""Most bytes of records the probe of a loader's first LAZ keeps for its first batches
(KeptRecords); what lies past them is decoded again."""
BOUNDS_SAMPLE = 4_096                   # first points checked against the header bounds
STANDARD = (
    "rgb", "intensity", "classification", "elevation", "return_number",
    "number_of_returns", "gps_time", "point_source_id", "user_data", "scan_angle",
)
"""Standard attributes in the order a cloud lists them; extra bytes follow."""
LAYERS = {
    "rgb": laspy.DecompressionSelection.RGB,
    "intensity": laspy.DecompressionSelection.INTENSITY,
    "classification": laspy.DecompressionSelection.CLASSIFICATION,
    "gps_time": laspy.DecompressionSelection.GPS_TIME,
    "point_source_id": laspy.DecompressionSelection.POINT_SOURCE_ID,
    "user_data": laspy.DecompressionSelection.USER_DATA,
    "scan_angle": laspy.DecompressionSelection.SCAN_ANGLE,
}
"""The LAZ layer (point formats 6-10) each standard attribute is decoded from; x, y and
return numbers are in the base layer, z (positions, elevation) in its own, extra bytes
in theirs."""
PROBED = ("rgb", "gps_time")
"""What opening a file reads of its first points besides the positions: the colour depth
and the first GPS time (the offset of gps_time)."""
ALL_LAYERS = laspy.DecompressionSelection.all()
"""What batches of every attribute need decoded (a selection of None)."""
PLAIN = ("intensity", "classification", "return_number", "number_of_returns",
         "gps_time", "point_source_id", "user_data")
"""Standard attributes copied from the laspy dimension of the same name."""


class TruncatedInput(InputError):
    """Points stop before the header count; with partial=True the loader keeps what it read."""

    def __init__(self, message: str, read: int):
        super().__init__(message)
        self.read = read


def header_error(path: str, exc: Exception) -> InputError:
    """laspy's complaint about a header."""
    return fail(path, f"invalid LAS header: {exc}")


@dataclass(frozen=True)
class RawHeader:
    """The few fixed-header fields needed before trusting laspy with the file."""

    version: tuple[int, int]
    header_size: int
    vlr_count: int
    point_data: int
    point_format: int
    compressed: bool
    record_length: int
    count: int
    waveform_start: int
    evlr_start: int
    evlr_count: int
    internal_waveform: bool

    @classmethod
    def parse(cls, path: str, data: bytes) -> RawHeader:
        if not data:
            raise fail(path, "is empty")
        if data[:4] != SIGNATURE:
            raise fail(path, f"is not a LAS/LAZ or fast-format file, nor an E57 or PLY one (it starts with {data[:4]!r}, not b'LASF')")
        if len(data) < 26:
            raise fail(path, f"is too short for a LAS header ({len(data)} bytes)")
        major, minor = data[24], data[25]
        if major != 1 or minor > MAX_MINOR_VERSION:
            raise fail(path, f"unsupported LAS version {major}.{minor}")
        if len(data) < MIN_HEADER[minor]:
            raise fail(path, f"is too short for a LAS {major}.{minor} header ({len(data)} bytes)")
        (encoding,) = struct.unpack_from("<H", data, 6)
        (header_size,) = struct.unpack_from("<H", data, 94)
        point_data, vlrs, pf, record_length, legacy = struct.unpack_from("<IIBHI", data, 96)
        if vlrs * VLR_HEADER > point_data - header_size:
            # laspy would read that many VLRs, empty ones past the end of the file: for
            # a count near 2^32 it never returns
            raise fail(path, f"invalid LAS header: {vlrs} VLRs cannot fit in the "
                             f"{max(point_data - header_size, 0)} bytes before the point data")
        waveform = struct.unpack_from("<Q", data, 227)[0] if minor >= 3 else 0
        evlr_start, evlr_count, count64 = struct.unpack_from("<QIQ", data, 235) if minor >= 4 else (0, 0, 0)
        if pf & 0x3F > MAX_POINT_FORMAT:
            raise fail(path, f"unsupported point format {pf & 0x3F}")
        return cls(
            version=(major, minor), header_size=header_size, vlr_count=vlrs, point_data=point_data,
            point_format=pf & 0x3F,
            compressed=bool(pf & 0x80), record_length=record_length,
            count=(count64 or legacy) if minor >= 4 else legacy, waveform_start=waveform,
            evlr_start=evlr_start, evlr_count=evlr_count, internal_waveform=bool(encoding & 2),
        )

    def data_end(self, file_size: int) -> int:
        """Where uncompressed point records must end: at the EVLRs, internal waveforms or EOF."""
        ends = [file_size]
        if self.evlr_count and self.evlr_start:
            ends.append(self.evlr_start)
        if self.internal_waveform and self.waveform_start:
            ends.append(self.waveform_start)
        return min(ends)


@dataclass(frozen=True)
class Column:
    """Where one attribute comes from in a laspy record: a dimension and, for array-typed
    extra bytes, one element of it."""

    dimension: str
    index: int | None = None


@dataclass(frozen=True)
class Records:
    """Where a file's point records start and how to read them as numpy rows (laspy's
    header refuses a record length other than its point format's size)."""

    point_format: laspy.PointFormat
    point_data: int
    scales: np.ndarray          # (3,) float64, the header's
    offsets: np.ndarray         # (3,) float64, the header's

    @property
    def dtype(self) -> np.dtype:
        return self.point_format.dtype()

    def coordinates(self, array: np.ndarray, axis: int) -> np.ndarray:
        """Scaled float64 coordinates of one axis, computed as laspy computes them."""
        coords = array["XYZ"[axis]] * self.scales[axis]
        coords += self.offsets[axis]
        return coords


@dataclass(frozen=True)
class Span:
    """Records of an uncompressed file not read yet: the parser thread that gets a span
    reads it (one read, without the GIL), so reads run on every parser thread at once."""

    first: int
    count: int

    def __len__(self) -> int:
        return self.count


class KeptRecords:
    """The records the probe decoded of a LAZ's first points (whole chunks, the layers
    `layers` of point formats 6-10), handed once to the first chunks() so that the first
    image does not wait for them to be decoded again; taken, they are freed as the
    batches they make are parsed."""

    def __init__(self, parts: list[np.ndarray], chunks: int, layers: laspy.DecompressionSelection):
        self._parts = parts
        self._chunks = chunks
        self.layers = layers

    @property
    def nbytes(self) -> int:
        return sum(p.nbytes for p in self._parts)

    @property
    def chunks(self) -> int:
        """The LAZ chunks the records not taken yet hold."""
        return self._chunks

    def take(self) -> tuple[list[np.ndarray], int]:
        """The records in file order and the LAZ chunks they hold; nothing after the first take."""
        parts, chunks = self._parts, self._chunks
        self._parts, self._chunks = [], 0
        return parts, chunks


@dataclass(frozen=True)
class LasSource:
    """One checked LAS/LAZ file: its facts and how to read and parse its points."""

    info: FileInfo
    attributes: tuple[AttributeInfo, ...]   # offsets 0; the cloud sets them
    columns: dict[str, Column]
    first_gps_time: float | None
    laz: LazLayout | None
    records: Records
    warnings: tuple[str, ...] = ()
    kept: KeptRecords | None = field(default=None, compare=False, repr=False)

    def chunks(self, batch_points: int, *, salvage: bool = False, names: tuple[str, ...] | None = None,
               decoders: DecoderPool | None = None) -> Iterator[np.ndarray | Span]:
        """Record arrays of at most batch_points, info.points in total, else TruncatedInput;
        the first of about FIRST_BATCH_POINTS, so that the first image comes soon;
        with salvage, a damaged LAZ first yields what still decodes. An uncompressed file
        yields Spans, which parse() reads. Given the attribute `names` that will be
        parsed, a LAZ of point format 6-10 decodes only the layers they need (what
        `selection` says); the other fields of its records hold no meaningful values.
        The records `kept` by the probe come first where they hold those layers; the
        rest is decoded by `decoders` where they take the file (pool_for)."""
        head = min(batch_points, FIRST_BATCH_POINTS)
        if self.laz is None:
            count = self.info.points
            starts = [0, *range(head, count, batch_points)]
            return (Span(first, min(count, end) - first) for first, end in zip(starts, [*starts[1:], count], strict=True))
        pool = self.pool_for(decoders, names)
        parts, skip = self.kept.take() if self.kept is not None else ([], 0)
        if parts and not self._reuses(names):
            parts, skip = [], 0         # the probe left out layers that the batches need
        decoded = decode(self.info.path, self.laz, self.records, self.info.points, batch_points, salvage=salvage,
                         selection=None if names is None else layers(names), head=head, skip=skip, decoders=pool)
        return itertools.chain(_batches(parts, head, batch_points), decoded) if parts else decoded

    def _reuses(self, names: tuple[str, ...] | None) -> bool:
        """Whether the kept records hold every layer that batches of `names` need."""
        needed = ALL_LAYERS if names is None else layers(names)
        return self.info.point_format < 6 or needed | self.kept.layers == self.kept.layers

    def pool_for(self, decoders: DecoderPool | None, names: tuple[str, ...] | None = None) -> DecoderPool | None:
        """`decoders` where chunks() hands them this file: a LAZ decoded in parallel with
        the points they take left after the kept records that batches of `names` reuse."""
        if decoders is None or self.laz is None or not self.laz.chunks:
            return None
        skip = self.kept.chunks if self.kept is not None and self._reuses(names) else 0
        return decoders if decoders.takes(self.info.points - sum(n for n, _ in self.laz.chunks[:skip])) else None

    def parse(self, chunk: np.ndarray | Span, start: int, origin: np.ndarray, names: tuple[str, ...]) -> Batch:
        """A Batch of the named attributes, its positions kept as the file's integers
        (Grid: what the word store takes; float32 positions computed only where asked
        for). The whole batch in a few large numpy calls: each releases the GIL, and each
        return to Python waits for it while another thread (the frame loop's) holds it."""
        if isinstance(chunk, Span):
            chunk = read_span(self.info.path, self.records, chunk, self.info.points)
        n = len(chunk)
        raw = _record_bytes(chunk)
        cells = _cells(raw)
        scales, offsets = self.records.scales, self.records.offsets
        grid = Grid(cells, tuple(map(float, scales)), tuple(map(float, offsets)), tuple(map(float, origin)))
        with np.errstate(over="ignore", invalid="ignore"):     # overflow is counted, not warned
            lo, hi = _coordinate_ends(cells, self.records) if n else (np.full(3, np.inf), np.full(3, -np.inf))
            # Rounding is monotonic: where the least and greatest coordinates of each axis
            # are finite as float32 positions, every position is (no pass over them).
            ends_finite = np.isfinite(np.float32([lo - origin, hi - origin])).all()
        record = laspy.PackedPointRecord(chunk, self.records.point_format)
        attributes = {name: self._values(record, raw, name) for name in names if name != "elevation"}
        counts = {name: bad for name, v in attributes.items() if name not in FROM_INTEGERS and (bad := nonfinite_count(v))}
        for name in counts:
            quiet_nans(attributes[name])
        return Batch(start=start, attributes=attributes, bounds=(lo, hi),
                     nonfinite_positions=0 if ends_finite else nonfinite_rows(grid.positions()), nonfinite_values=counts,
                     grid=grid)

    def _values(self, chunk: laspy.PackedPointRecord, raw: np.ndarray, name: str) -> np.ndarray:
        """One attribute's own array (a copy, not a view of the records). `raw`: the
        records as (n, record length) bytes."""
        if name == "rgb":
            # The depth is decided once per file (FileInfo.rgb_16bit); 8-bit files clip.
            # Red, green and blue are consecutive 16-bit fields in every point format.
            red = chunk.array.dtype.fields["red"][1]
            if self.info.rgb_16bit:
                # A 16-bit channel's value >> 8 is its high byte, the second (little
                # endian): copied a channel at a time, 1.6x faster than shifting the words.
                out = np.empty((raw.shape[0], 3), np.uint8)
                for channel in range(3):
                    out[:, channel] = raw[:, red + 2 * channel + 1]
                return out
            channels = _rows_of(raw, red, 6).view("<u2").reshape(-1, 3)
            return np.minimum(channels, RGB8_MAX, out=np.empty(channels.shape, np.uint8), casting="unsafe")
        if name == "scan_angle":
            if self.info.point_format < 6:
                return np.asarray(chunk["scan_angle_rank"], dtype=np.float32)
            return (np.asarray(chunk["scan_angle"], dtype=np.float64) * SCAN_ANGLE_STEP).astype(np.float32)
        column = self.columns[name]
        composed, field = chunk.sub_fields_dict.get(column.dimension, (None, None))
        if column.index is not None and field is not None:
            values = _extra_bytes(chunk, column.dimension)     # an array named like a bit field, which laspy's name finds
        elif field is not None and (bits := _bit_field(chunk.array[composed], field.mask)) is not None:
            return bits
        else:
            values = np.asarray(chunk[column.dimension])
        return np.ascontiguousarray(values if column.index is None else values[:, column.index])


def _extra_bytes(chunk: laspy.PackedPointRecord, name: str) -> np.ndarray:
    """The extra-bytes dimension `name` of the records, scaled as laspy scales it, where
    laspy's record[name] would give the bit field of that name instead (a file may name
    its extra bytes so)."""
    dim = next(d for d in chunk.point_format.extra_dimensions if d.name == name)
    values = chunk.array[name]
    return values * dim.scales + dim.offsets if dim.is_scaled else values


def _bit_field(packed: np.ndarray, mask: int) -> np.ndarray | None:
    """laspy's (packed & mask) >> lowest bit of mask in one numpy call where one does it:
    a field from the lowest bit (class, return number) is the mask alone, one up to the
    highest bit (point format 6-10's number of returns) the shift alone; else None."""
    ones = np.iinfo(packed.dtype).max
    low = (mask & -mask).bit_length() - 1
    if low == 0:
        return np.bitwise_and(packed, packed.dtype.type(mask))
    if mask == ones >> low << low:
        return np.right_shift(packed, packed.dtype.type(low))
    return None


def _record_bytes(chunk: np.ndarray) -> np.ndarray:
    """Structured records as (n, record length) uint8 (a copy only where `chunk` is a
    strided slice)."""
    chunk = np.ascontiguousarray(chunk)
    return chunk.view(np.uint8).reshape(len(chunk), chunk.dtype.itemsize)


def _cells(raw: np.ndarray) -> np.ndarray:
    """The (n, 3) int32 X, Y, Z of records as (n, record length) bytes (they lead every
    point format), contiguous."""
    return _rows_of(raw, 0, 12).view("<i4").reshape(-1, 3)


def _coordinate_ends(cells: np.ndarray, records: Records) -> np.ndarray:
    """(2, 3) least and greatest scaled coordinates of (n > 0, 3) integers, as laspy
    computes them: scaling is monotonic, so the ends of the integers give them with no
    pass over the float64 coordinates."""
    ends = np.float64(_column_ends(cells)) * records.scales + records.offsets
    return np.array([ends.min(axis=0), ends.max(axis=0)])


def record_ends(chunk: np.ndarray, records: Records) -> np.ndarray:
    """_coordinate_ends of (n > 0) structured records (a LAS probe's, a COPC node's)."""
    return _coordinate_ends(_cells(_record_bytes(chunk)), records)


class CoordinateEnds:
    """record_ends over chunks of records as they come (a bounds pass over a file or
    its nodes), kept so far where a chunk fails to decode."""

    def __init__(self, records: Records):
        self.records = records
        self.lo, self.hi = np.full(3, np.inf), np.full(3, -np.inf)

    def add(self, chunk: np.ndarray) -> None:
        if len(chunk):
            ends = record_ends(chunk, self.records)
            self.lo, self.hi = np.minimum(self.lo, ends[0]), np.maximum(self.hi, ends[1])

    def bounds(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        return tuple(map(float, self.lo)), tuple(map(float, self.hi))


def rgb_max(chunk: np.ndarray) -> int:
    """The greatest of the records' red, green and blue (consecutive 16-bit fields in
    every point format), over one contiguous copy of them rather than three strided
    reductions (with record_ends, 6-36 % off opening a LAS:
    bench/results/llvmpipe/las_open/)."""
    return int(_rows_of(_record_bytes(chunk), chunk.dtype.fields["red"][1], 6).view("<u2").max())


def _rows_of(raw: np.ndarray, at: int, size: int) -> np.ndarray:
    """Bytes at..at+size of every record ((n, record length) uint8) as one contiguous
    (n, size) copy, each row moved as one item: numpy copies a strided (n, 3) view
    element by element, several times slower."""
    out = np.empty((raw.shape[0], size), np.uint8)
    out.view(f"V{size}")[:, 0] = raw[:, at:at + size].view(f"V{size}")[:, 0]
    return out


COLUMN_ROWS = 1024
"""Rows per line of _column_ends' reduction (3 · COLUMN_ROWS values a line)."""


def _column_ends(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The least and most of each column of (n, 3) int32 cells, int64 (zeros if n is 0):
    whole lines of COLUMN_ROWS rows reduced down the lines first, then what is left
    across, as a column's own reduction is a strided loop, several times slower."""
    if cells.shape[0] == 0:
        return np.zeros(3, np.int64), np.zeros(3, np.int64)
    whole = cells.shape[0] - cells.shape[0] % COLUMN_ROWS
    ends = []
    for reduce in (np.min, np.max):
        rows = cells[whole:]
        if whole:
            lines = reduce(cells[:whole].reshape(-1, 3 * COLUMN_ROWS), axis=0).reshape(COLUMN_ROWS, 3)
            rows = np.concatenate([lines, rows])
        ends.append(reduce(rows, axis=0).astype(np.int64))
    return ends[0], ends[1]


def layers(names: tuple[str, ...]) -> laspy.DecompressionSelection:
    """The LAZ layers the named attributes are parsed from, with the positions' (lazrs
    ignores a selection below point format 6, whose records are not layered)."""
    chosen = laspy.DecompressionSelection.base() | laspy.DecompressionSelection.Z
    for name in names:
        chosen |= LAYERS.get(name, 0 if name in STANDARD else laspy.DecompressionSelection.ALL_EXTRA_BYTES)
    return chosen


def selection(names: tuple[str, ...]) -> lazrs.DecompressionSelection:
    """layers(names) as lazrs takes them."""
    return layers(names).to_lazrs()


def _batches(parts: list[np.ndarray], head: int, piece: int) -> Iterator[np.ndarray]:
    """`parts` in arrays of at most `piece` points, the first of at most `head` (views)."""
    for i, part in enumerate(parts):
        starts = [0, *range(head, len(part), piece)] if i == 0 else list(range(0, len(part), piece))
        for first, end in zip(starts, [*starts[1:], len(part)], strict=True):
            yield part[first:end]


def read_span(path: str, records: Records, span: Span, count: int) -> np.ndarray:
    """The records of `span` of an uncompressed file, in one read; TruncatedInput where the
    file ends first (it was cut after it was opened: its size was checked then)."""
    with open_binary(path) as stream:
        return _read_records(stream, path, records, span, count)


def _read_records(stream, path: str, records: Records, span: Span, count: int) -> np.ndarray:
    array = np.empty(span.count, records.dtype)
    stream.seek(records.point_data + span.first * records.dtype.itemsize)
    got = stream.readinto(memoryview(array).cast("B"))
    if got != array.nbytes:
        read = span.first + got // records.dtype.itemsize
        raise TruncatedInput(f"{shown(path)}: header says {count} points but only {read} could be read", read)
    return array


def _pieces(path: str, laz: LazLayout | None, records: Records, count: int, piece: int,
            layers: laspy.DecompressionSelection | None, head: int, skip: int = 0,
            decoders: DecoderPool | None = None) -> Iterator[np.ndarray]:
    """The first `count` records in file order, in arrays of any size, the first of about
    `head` points: read straight into numpy (the text patches of an uncompressed file lie
    before its points), decoded by lazrs over several chunks at once (only the `layers`
    selected; the first `skip` chunks left out) by `decoders` where given, else in this
    process, or else through laspy (every field)."""
    if laz is not None and (skip or laz.chunks):
        if decoders is not None:
            yield from decoders.decode(path, laz, count, head, records.dtype, piece, layers, skip)
        else:
            yield from decode_chunks(path, laz, count, head, records.dtype, available_cores(),
                                     None if layers is None else layers.to_lazrs(), skip)
    elif laz is None:
        with open_binary(path) as stream:
            for first in [0, *range(head, count, piece)]:
                yield _read_records(stream, path, records, Span(first, min(head if first == 0 else piece, count - first)),
                                    count)
    else:
        with _reader(laz.open(path), path, laz.backend, count) as reader:
            yield reader.read_points(min(head, count)).array
            for chunk in reader.chunk_iterator(piece):
                yield chunk.array


def decode(path: str, laz: LazLayout | None, records: Records, count: int, piece: int, *,
           salvage: bool = False, selection: laspy.DecompressionSelection | None = None,
           head: int | None = None, skip: int = 0, decoders: DecoderPool | None = None) -> Iterator[np.ndarray]:
    """Record arrays of at most `piece` points, `count` in total, else TruncatedInput,
    the first of about `head` (default `piece`; a LAZ's whole chunks); a LAZ decoded in
    parallel decodes only the layers of `selection` (None: all), and from its chunk
    `skip` on where the caller holds the points of those before (KeptRecords)."""
    read = sum(n for n, _ in laz.chunks[:skip]) if skip else 0
    try:
        for part in _pieces(path, laz, records, count, piece, selection, piece if head is None else head, skip,
                            decoders):
            for at in range(0, len(part), piece):
                chunk = part[at:at + piece]
                read += len(chunk)
                yield chunk
    except BaseException as exc:
        if not is_decode_error(exc) or isinstance(exc, (InputError, PoolClosed)):
            raise
        if salvage and laz is not None:
            for chunk in salvaged(path, laz, count, read, piece):
                read += len(chunk)
                yield chunk
        raise TruncatedInput(f"{shown(path)}: point data is truncated or corrupt after {read} of "
                             f"{count} points ({one_line(exc)})", read) from exc
    if read != count:
        raise TruncatedInput(f"{shown(path)}: header says {count} points but only {read} could be read", read)


def _reader(stream, path: str, backend: laspy.LazBackend | None, count: int) -> laspy.LasReader:
    """A laspy reader on `stream` that stops at `count` (the checked count, not laspy's)."""
    try:
        reader = laspy.LasReader(stream, laz_backend=backend or (), read_evlrs=False)
    except Exception as exc:
        stream.close()
        raise header_error(path, exc) from exc
    reader.header.point_count = count
    return reader


def open_las(path: str | os.PathLike, *, partial: bool = False, keep: bool = False,
             check_count: Callable[[str, int], None] | None = None) -> LasSource:
    """Check and describe one LAS/LAZ file, reading at most its first batch of points
    (and all of them where the header bounds are wrong); with keep (a loader's first
    file), a LAZ keeps what of them it decoded for its first batches (KeptRecords, at
    most KEPT_BYTES). check_count(path, points) is called once the header gives the
    points, before any is read: it raises to refuse a file too large for the caller (a
    sparse file of 2^32 - 1 points would otherwise be read whole for its bounds)."""
    path = os.fspath(path)
    warnings: list[str] = []
    with open_binary(path) as stream:
        try:
            size = os.fstat(stream.fileno()).st_size
            raw = RawHeader.parse(path, stream.read(HEADER_PREFIX))
            if raw.count == 0:
                raise fail(path, "has no points")
            patches, bad_text = text_patches(stream, raw)
            with open_patched(path, patches) as patched:
                header = laspy.LasHeader.read_from(patched, read_evlrs=False)
        except InputError:
            raise
        except Exception as exc:
            raise header_error(path, exc) from exc
        if bad_text:
            warnings.append(f"{shown(path)}: {len(bad_text)} text field(s) of its VLRs are not UTF-8 "
                            f"({bad_text[0]}{', ...' if len(bad_text) > 1 else ''}); read them with '?' "
                            f"for the bad bytes")
        _check_numbers(path, header)
        count, laz = raw.count, None
        if raw.compressed:
            laz = laz_layout(path, stream, header, raw.record_length, count, size, patches, partial, warnings)
            count = laz.points
        else:
            count = checked_count(path, raw, size, partial, warnings)
    if check_count is not None:
        check_count(path, count)
    pf = header.point_format
    records = Records(pf, header.offset_to_point_data, np.asarray(header.scales, np.float64),
                      np.asarray(header.offsets, np.float64))
    has_rgb = "red" in pf.dimension_names
    max_rgb, first, seen, kept = _probe(path, laz, records, count, has_rgb, partial, keep)
    columns = _columns(pf)
    info = FileInfo(
        path=path,
        format="LAZ" if raw.compressed else "LAS",
        version=f"{raw.version[0]}.{raw.version[1]}",
        point_format=raw.point_format,
        points=count,
        scale=tuple(float(v) for v in header.scales),
        offset=tuple(float(v) for v in header.offsets),
        bounds_min=tuple(float(v) for v in header.mins),
        bounds_max=tuple(float(v) for v in header.maxs),
        rgb_max=max_rgb if has_rgb else None,
        crs=crs_name(header),
    )
    names = tuple(n for n in STANDARD if n in columns or n in ("scan_angle", "elevation")
                  or (n == "rgb" and has_rgb)) + tuple(n for n in columns if n not in STANDARD)
    first_gps = float(first["gps_time"][0]) if "gps_time" in columns else None
    if wrong := unreachable_bounds(header) or contradicted_bounds(header.mins, header.maxs, seen,
                                                                  np.abs(header.scales)):
        lo, hi = _data_bounds(path, laz, records, count, partial)
        info = dataclasses.replace(info, bounds_min=lo, bounds_max=hi)
        warnings.append(f"{shown(path)}: header bounds {wrong}; ignored them and used the bounds of the points")
    source = LasSource(info, (), columns, first_gps, laz, records, tuple(warnings), kept)
    sample = source.parse(first, 0, np.zeros(3), names).attributes
    attributes = tuple(
        AttributeInfo(n, attribute_kind(n), np.dtype(np.float64) if n == "elevation" else sample[n].dtype)
        for n in names
    )
    return dataclasses.replace(source, attributes=attributes)


def _check_numbers(path: str, header: laspy.LasHeader) -> None:
    """Scale, offset and bounds set every position and the cloud's origin: one NaN among
    them would make every point non-finite, and a zero scale every point equal."""
    fields = {"scale": header.scales, "offset": header.offsets, "bounds": np.r_[header.mins, header.maxs]}
    for name, values in fields.items():
        if not np.all(np.isfinite(values)):
            raise fail(path, f"invalid LAS header: {name} is not finite ({', '.join(map(str, values))})")
    if np.any(header.scales == 0):
        raise fail(path, f"invalid LAS header: scale is 0 ({', '.join(map(str, header.scales))})")
    reach = [abs(float(o)) + abs(float(s)) * 2**31 for s, o in zip(header.scales, header.offsets, strict=True)]
    if not all(map(math.isfinite, reach)):
        raise fail(path, f"invalid LAS header: scale {', '.join(map(str, header.scales))} and offset "
                         f"{', '.join(map(str, header.offsets))} make the coordinates overflow")


def _data_bounds(path: str, laz: LazLayout | None, records: Records, count: int,
                 partial: bool) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Exact min and max of the file coordinates, computed as LasSource.parse computes them;
    with partial, of the points that can be read. One extra pass over the file."""
    ends = CoordinateEnds(records)
    try:
        for chunk in decode(path, laz, records, count, BATCH_POINTS, salvage=partial):
            ends.add(chunk)
    except TruncatedInput as exc:
        if not (partial and exc.read):
            raise fail(path, f"point data is truncated or corrupt ({one_line(exc.__cause__ or exc)})") from exc
    return ends.bounds()


def attribute_kind(name: str) -> AttributeKind:
    """How an attribute of this name is shown (the fast format stores it with the name)."""
    return {"rgb": AttributeKind.RGB, "classification": AttributeKind.CATEGORY}.get(name, AttributeKind.SCALAR)


def _columns(pf: laspy.PointFormat) -> dict[str, Column]:
    """Plain standard dimensions plus every numeric extra-bytes element that has a name
    (laspy cannot index a dimension whose name is empty or only NULs)."""
    standard = set(pf.dimension_names)
    columns = {n: Column(n) for n in PLAIN if n in standard}
    named = set(pf.dtype().names)
    for dim in pf.extra_dimensions:
        if not np.issubdtype(dim.dtype.base, np.number) or not dim.name or dim.name not in named:
            continue
        if dim.num_elements == 1:
            columns[dim.name] = Column(dim.name)
        else:
            columns.update({f"{dim.name}[{i}]": Column(dim.name, i) for i in range(dim.num_elements)})
    return columns


def _probe(path: str, laz: LazLayout | None, records: Records, count: int, has_rgb: bool,
           partial: bool, keep: bool) -> tuple[int, np.ndarray, np.ndarray, KeptRecords | None]:
    """Max of R, G, B over the first BATCH_POINTS points (the rule of FileInfo.rgb_16bit),
    read in pieces (a LAZ decoded in parallel: its reads) that stop once it exceeds 255;
    the first point; the (2, 3) min and max of the first PROBE_PIECE points' coordinates
    (at least BOUNDS_SAMPLE points), to check the header bounds against; and with keep,
    the first reads decoded in parallel, as many as fit in KEPT_BYTES (kept_records). A
    LAZ of point format 6-10 decodes only the layers these need (the first point's other
    fields serve for their dtypes only)."""
    wanted = min(count, BATCH_POINTS if has_rgb else BOUNDS_SAMPLE)
    head = min(wanted, PROBE_PIECE)
    parallel = laz is not None and bool(laz.chunks)
    keeping = keep and parallel
    max_rgb, first, seen, parts, held = 0, None, None, [], 0
    try:
        for chunk in decode(path, laz, records, wanted, wanted if parallel else head, salvage=partial,
                            selection=layers(PROBED), head=head):
            if first is None:
                first = chunk[:1].copy()
                with np.errstate(over="ignore", invalid="ignore"):
                    seen = record_ends(chunk[:head], records)
            keeping = keeping and held + chunk.nbytes <= KEPT_BYTES
            if keeping:
                parts.append(chunk)
                held += chunk.nbytes
            if has_rgb:
                max_rgb = max(max_rgb, rgb_max(chunk))
                if max_rgb > RGB8_MAX:
                    break
    except TruncatedInput as exc:
        if not (partial and first is not None):
            raise fail(path, f"point data is truncated or corrupt "
                             f"({one_line(exc.__cause__ or 'fewer points than the header says')})") from exc
        parts = []
    return max_rgb, first, seen, kept_records(laz, parts) if parts else None


def kept_records(laz: LazLayout, parts: list[np.ndarray]) -> KeptRecords | None:
    """The longest run of the probe's `parts` (whole reads of laz.chunks, from the first)
    that ends at a chunk's end: decoding goes on from the next chunk."""
    ends = {end: i + 1 for i, end in enumerate(itertools.accumulate(n for n, _ in laz.chunks))}
    kept, points = [], 0
    for part in parts:
        if points + len(part) not in ends:
            break
        kept.append(part)
        points += len(part)
    return KeptRecords(kept, ends[points], layers(PROBED)) if kept else None


def crs_name(header: laspy.LasHeader) -> str | None:
    """A short CRS label without pyproj: the WKT name and/or the EPSG code."""
    name = code = None
    for vlr in header.vlrs:
        kind = type(vlr).__name__
        if kind == "WktCoordinateSystemVlr":
            wkt = (vlr.string or "").strip().rstrip("\x00")
            match = re.match(r'\w+\s*\[\s*"([^"]*)"', wkt)
            name = match.group(1) if match else None
            top_id = re.search(r'(?:AUTHORITY|ID)\["EPSG",\s*"?(\d+)"?\]\]$', wkt)
            code = f"EPSG:{top_id.group(1)}" if top_id else code
        elif kind == "GeoKeyDirectoryVlr":
            keys = {k.id: k.value_offset for k in vlr.geo_keys}
            epsg = keys.get(3072) or keys.get(2048)      # projected, else geographic CRS
            code = f"EPSG:{epsg}" if epsg and epsg != 32767 else code
    if name and code:
        return f"{name} ({code})"
    return name or code
