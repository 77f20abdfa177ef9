"""Reading damaged LAS/LAZ files: what laspy would refuse repaired in what it reads (VLR
text that is not UTF-8), counts and bounds that the data contradicts, and, for a partial
load, the points of a damaged LAZ that still decode. loaders/las.py reads sound files and
turns here where one is not."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from typing import TYPE_CHECKING

import laspy
import lazrs
import numpy as np

from progressive.loaders.laz import LazLayout, Patch
from progressive.loaders.validate import BOUNDS_SLACK, fail, shown

if TYPE_CHECKING:
    from progressive.loaders.las import RawHeader

VLR_HEADER = 54                         # bytes of each VLR before its data
VLR_TEXT = ((2, 16), (22, 32))          # user_id, description: offset, length in the VLR header
EXTRA_BYTES_STRUCT = 192                # one extra-bytes dimension in the LASF_Spec VLR 4
EXTRA_BYTES_TEXT = ((4, 32), (160, 32))  # name, description
SALVAGE_PIECE = 1_000                   # points per read while salvaging a damaged LAZ
RECORD_INT = (-2**31, 2**31 - 1)        # the int32 X, Y, Z of a point record


def is_decode_error(exc: BaseException) -> bool:
    """Anything laspy/lazrs raise on bad data, including lazrs panics (BaseExceptions)."""
    return isinstance(exc, Exception) or type(exc).__name__ == "PanicException"


def text_patches(stream, raw: RawHeader) -> tuple[tuple[Patch, ...], list[str]]:
    """Patches that make every VLR user_id and description, and every extra-bytes name and
    description, valid UTF-8 ('?' for each bad byte, so lengths stay), and the fields they
    fix. laspy decodes these strictly and rejected the whole file (a Latin-1 'é' in a
    VLR's user_id, say); patching what laspy reads leaves laspy itself untouched."""
    patches: list[Patch] = []
    bad: list[str] = []

    def check(at: int, field: bytes, name: str) -> None:
        text = field.decode("utf-8", errors="surrogateescape")
        if any("\udc80" <= c <= "\udcff" for c in text):
            patches.append((at, "".join("?" if "\udc80" <= c <= "\udcff" else c for c in text).encode()))
            bad.append(f"{name} {field.rstrip(bytes(1))!r}")

    at = raw.header_size
    for index in range(raw.vlr_count):
        stream.seek(at)
        head = stream.read(VLR_HEADER)
        if len(head) < VLR_HEADER:
            break
        for (offset, length), name in zip(VLR_TEXT, ("user_id", "description"), strict=True):
            check(at + offset, head[offset:offset + length], f"VLR {index} {name}")
        record_id, length = struct.unpack_from("<HH", head, 18)
        if head[2:18].rstrip(bytes(1)) == b"LASF_Spec" and record_id == 4:
            data = stream.read(length)
            for i in range(len(data) // EXTRA_BYTES_STRUCT):
                base = i * EXTRA_BYTES_STRUCT
                for (offset, size), name in zip(EXTRA_BYTES_TEXT, ("name", "description"), strict=True):
                    check(at + VLR_HEADER + base + offset, data[base + offset:base + offset + size],
                          f"extra bytes {i} {name}")
        at += VLR_HEADER + length
    return tuple(patches), bad


def unreachable_bounds(header: laspy.LasHeader) -> str | None:
    """The header bounds no int32 record coordinate can give under the header's scale and
    offset, described, or None. Such bounds (1e300, say) must not set the cloud's origin:
    positions relative to it would overflow float32."""
    bad = []
    for axis, name in enumerate("xyz"):
        scale, offset = float(header.scales[axis]), float(header.offsets[axis])
        lo, hi = sorted(offset + scale * v for v in RECORD_INT)
        slack = abs(scale) + BOUNDS_SLACK * max(abs(lo), abs(hi))
        for bound, value in (("min", header.mins[axis]), ("max", header.maxs[axis])):
            if not lo - slack <= value <= hi + slack:
                bad.append(f"{bound} {name} {float(value):g} is outside [{lo:g}, {hi:g}]")
    return f"cannot be reached with its scale and offset ({'; '.join(bad)})" if bad else None


def checked_count(path: str, raw: RawHeader, size: int, partial: bool, warnings: list[str]) -> int:
    """The header count, checked against the bytes the point records occupy."""
    if raw.record_length <= 0:
        raise fail(path, "has a point record length of 0")
    available = max(raw.data_end(size) - raw.point_data, 0)
    expected = raw.count * raw.record_length
    if available == expected:
        return raw.count
    complete = available // raw.record_length
    if available < expected:
        problem = (f"is truncated: header says {raw.count} points but the file holds "
                   f"{complete} ({available} of {expected} bytes of point data)")
        if partial and complete > 0:
            warnings.append(f"{shown(path)}: {problem}; read the first {complete} points")
            return complete
    else:
        problem = (f"header says {raw.count} points but the file holds more point data "
                   f"({available} bytes, {expected} expected)")
        if partial:
            warnings.append(f"{shown(path)}: {problem}; read the first {raw.count} points")
            return raw.count
    raise fail(path, problem)


def salvaged(path: str, laz: LazLayout, count: int, start: int, piece: int) -> Iterator[np.ndarray]:
    """Decode again with lazrs's sequential decoder and yield, in chunks of `piece`, every
    point from `start` on that decodes before its first failure. The decoder cannot go on
    (or back) after a failed read, and a failed read of n points tells nothing of how many
    decoded: so the read that failed first (start to start + piece) is read again one point
    at a time, further on reads are of SALVAGE_PIECE, and should one of those fail, the
    decoder starts over and reads its points one at a time."""
    at, careful = start, min(start + piece, count)
    while at < count:
        stream = laz.salvage_stream(path)
        if stream is None:
            return
        failed = 0
        with stream:
            try:
                decoder = _Sequential(stream, laz, at, piece)
            except BaseException as exc:
                if not is_decode_error(exc):
                    raise
                return
            buffer, filled = bytearray(piece * decoder.size), 0
            while at < count:
                n = 1 if at < careful else min(SALVAGE_PIECE, count - at, piece - filled)
                try:
                    decoder.read_into(buffer, filled, n)
                except BaseException as exc:
                    if not is_decode_error(exc):
                        raise
                    failed = n
                    break
                at, filled = at + n, filled + n
                if filled == piece:
                    yield decoder.records(buffer, filled)
                    filled = 0
            if filled:
                yield decoder.records(buffer, filled)
        if failed <= 1:
            return
        careful = at + failed


class _Sequential:
    """lazrs's sequential decoder on a salvage stream, at a given point, and what turns
    its bytes into laspy records. It skips points by decoding them, never by seeking: a
    seek trusts the byte offsets of a chunk table that may be the damaged part."""

    def __init__(self, stream, laz: LazLayout, at: int, piece: int):
        header = laspy.LasHeader.read_from(stream, read_evlrs=False)
        self._dtype = header.point_format.dtype()
        self.size = header.point_format.size
        stream.seek(laz.point_data)
        self._decoder = lazrs.LasZipDecompressor(stream, laz.vlr_data)
        scratch, skipped = bytearray(min(at, piece) * self.size), 0
        while skipped < at:
            n = min(piece, at - skipped)
            self.read_into(scratch, 0, n)
            skipped += n

    def read_into(self, buffer: bytearray, first: int, n: int) -> None:
        """Decode n points into buffer, from point slot `first` on."""
        with memoryview(buffer) as view:
            self._decoder.decompress_many(view[first * self.size:(first + n) * self.size])

    def records(self, buffer: bytearray, n: int) -> np.ndarray:
        """The first n points of buffer, copied."""
        return np.frombuffer(buffer[:n * self.size], dtype=self._dtype).copy()
