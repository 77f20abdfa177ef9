"""Checks made before laspy or lazrs see a file, and how error lines name files.

lazrs panics on some malformed LASzip VLRs, and a Rust panic prints its message on
stderr (through Rust's panic hook) before Python can catch anything: the only way to
keep stderr to one line is to refuse such a VLR first. Inputs that are not regular
files (a FIFO with no writer, a device) would block or never end, so they are refused
before anything is read.
"""

from __future__ import annotations

import os
import stat
import struct

import numpy as np

from progressive.errors import InputError

NOT_REGULAR = {stat.S_IFIFO: "a FIFO", stat.S_IFCHR: "a character device", stat.S_IFBLK: "a block device",
               stat.S_IFSOCK: "a socket", stat.S_IFDIR: "a directory"}

LASZIP_HEAD = struct.Struct("<HHBBHIIqqH")
"""compressor, coder, version major, minor, revision, options, chunk size, special
EVLR count and offset, item count; the items follow."""
LASZIP_ITEM = struct.Struct("<HHH")     # type, size, version
LASZIP_COMPRESSORS = {1: "pointwise", 2: "pointwise chunked", 3: "layered chunked"}
CHUNKED = (2, 3)
VARIABLE_CHUNKS = 2**32 - 1             # the chunk size of variable-size chunks (a chunk table of counts)
POINT_ITEMS = {
    0: (6,), 1: (6, 7), 2: (6, 8), 3: (6, 7, 8), 4: (6, 7, 9), 5: (6, 7, 8, 9),
    6: (10,), 7: (10, 11), 8: (10, 12), 9: (10, 13), 10: (10, 12, 13),
}
"""The LASzip items of each point format, in record order: Point10, GpsTime11, RGB12,
Wavepacket13; Point14, RGB14, RGBNIR14, Wavepacket14."""
ITEM_BYTES = {6: 20, 7: 8, 8: 6, 9: 29, 10: 30, 11: 6, 12: 8, 13: 29}
EXTRA_ITEM = (0, 14)
"""The item of the extra bytes after the standard fields: Byte (formats 0-5), Byte14 (6-10)."""
LAYERED_FORMATS = 6                     # point formats from 6 on use the layered items
BOUNDS_SLACK = 1e-9                     # relative rounding allowed to header bounds


def shown(path: str | os.PathLike) -> str:
    """The path as error lines show it: control characters (a newline in a file name)
    escaped, so that one error stays one line."""
    text = os.fspath(path)
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def one_line(problem: object) -> str:
    return " ".join(str(problem).split())


def fail(path: str | os.PathLike, problem: object) -> InputError:
    """One line naming the file, as the CLI prints it."""
    return InputError(f"{shown(path)}: {one_line(problem)}")


def open_binary(path: str | os.PathLike):
    """The file opened for reading, refused in one line unless it is a regular file. The
    open does not block (O_NONBLOCK), so a FIFO without a writer is refused, not waited on."""
    try:
        stream = open(path, "rb", opener=_nonblocking)
    except IsADirectoryError:
        raise fail(path, f"is {NOT_REGULAR[stat.S_IFDIR]}, not a point-cloud file") from None
    except OSError as exc:
        raise fail(path, f"cannot open: {exc.strerror or exc}") from exc
    try:
        mode = os.fstat(stream.fileno()).st_mode
        if not stat.S_ISREG(mode):
            kind = NOT_REGULAR.get(stat.S_IFMT(mode), "not a regular file")
            raise fail(path, f"is {kind}, not a point-cloud file")
        os.set_blocking(stream.fileno(), True)
        return stream
    except BaseException:
        stream.close()
        raise


def _nonblocking(path: str, flags: int) -> int:
    return os.open(path, flags | os.O_NONBLOCK)


def laszip_items(point_format: int, record_length: int) -> list[tuple[int, int]]:
    """(type, size) of the LASzip items that a record of this format and length needs."""
    items = [(kind, ITEM_BYTES[kind]) for kind in POINT_ITEMS[point_format]]
    extra = record_length - sum(size for _, size in items)
    if extra > 0:
        items.append((EXTRA_ITEM[point_format >= LAYERED_FORMATS], extra))
    return items


def check_laszip(path: str, data: bytes, point_format: int, record_length: int) -> None:
    """Refuse a LASzip VLR that lazrs could panic on: no items (a division by zero in
    lazrs), items whose types or sizes do not make up the header's record (slice bounds
    in lazrs), an unknown compressor, a chunk size of 0, variable-size chunks without a
    chunk table (lazrs panics looking for it)."""
    if len(data) < LASZIP_HEAD.size:
        raise fail(path, f"has a LASzip VLR of {len(data)} bytes, too short ({LASZIP_HEAD.size} at least)")
    compressor, _, _, _, _, _, chunk_size, _, _, count = LASZIP_HEAD.unpack_from(data)
    if compressor not in LASZIP_COMPRESSORS:
        raise fail(path, f"has an unknown LASzip compressor {compressor} in its LASzip VLR")
    if chunk_size == 0:
        raise fail(path, "has a LASzip chunk size of 0 in its LASzip VLR")
    if compressor not in CHUNKED and chunk_size == VARIABLE_CHUNKS:
        raise fail(path, "has variable-size chunks in its LASzip VLR but pointwise compression (no chunk table)")
    if count == 0 or len(data) < LASZIP_HEAD.size + count * LASZIP_ITEM.size:
        raise fail(path, f"has a LASzip VLR of {len(data)} bytes declaring {count} items")
    items = [LASZIP_ITEM.unpack_from(data, LASZIP_HEAD.size + i * LASZIP_ITEM.size)[:2] for i in range(count)]
    expected = laszip_items(point_format, record_length)
    if items != expected:
        raise fail(path, f"has LASzip items (type, size) {items} that do not make up point format "
                         f"{point_format} records of {record_length} bytes ({expected} expected)")


def contradicted_bounds(mins, maxs, seen, step) -> str | None:
    """Why header bounds cannot be the points' own, described, or None: inverted, or not
    holding the points seen ((2, 3) min and max; None: none seen) within `step` per axis
    (the scale) and rounding. Bounds wider than the points are kept: checking that
    would take a pass over the whole file."""
    mins, maxs = np.asarray(mins, dtype=np.float64), np.asarray(maxs, dtype=np.float64)
    bad = [f"min {name} {lo:g} > max {name} {hi:g}" for name, lo, hi in zip("xyz", mins, maxs, strict=True)
           if lo > hi]
    if bad:
        return f"are inverted ({'; '.join(bad)})"
    if seen is None:
        return None
    slack = np.asarray(step, dtype=np.float64) + BOUNDS_SLACK * np.maximum(np.abs(mins), np.abs(maxs))
    for name, lo, hi, low, high, tol in zip("xyz", mins, maxs, seen[0], seen[1], slack, strict=True):
        if low < lo - tol or high > hi + tol:
            bad.append(f"{name} of the points is {low:g} to {high:g}, the header says {lo:g} to {hi:g}")
    return f"do not hold the first points ({'; '.join(bad)})" if bad else None
