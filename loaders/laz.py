"""How a LAZ file is handed to lazrs: its LASzip VLR and chunk table checked first, and
views of the file (patched bytes, a stand-in chunk table) where its own cannot be trusted.

A sound chunk table lets decode_chunks read several chunks' bytes at once and have lazrs
decode them on every core (`decompress_points_with_chunk_table`). lazrs holds the GIL
while it decodes, so a read is kept to a few rounds of chunks per core: short enough
that the render loop and the parser threads get the GIL back soon. A large file is
decoded by decoder processes instead, through the same table (laz_pool.py).

lazrs trusts the chunk table: it allocates for every chunk declared (aborting the process
when it cannot), panics on byte counts that make no sense ("capacity overflow"), and with
no table may take garbage for a chunk header. A table is therefore used only when its
byte counts add up to the chunk data exactly; otherwise a partial load decodes the
chunks in sequence through a well-formed stand-in table.
"""

from __future__ import annotations

import dataclasses
import io
import math
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass

import laspy
import lazrs
import numpy as np

from progressive.loaders.streams import PositionedReader
from progressive.loaders.validate import check_laszip, fail, open_binary, shown

Patch = tuple[int, bytes]
"""Bytes read in place of the file's own at an offset."""
Chunk = tuple[int, int]
"""A LAZ chunk: its points, its compressed bytes."""
LAZ_POINTWISE = 1                       # LASzip compressor without chunks or chunk table
MIN_CHUNK_BYTES = 20                    # a LAZ chunk starts with one raw point record
TAIL_GAP = 1                            # bytes of end of file before a stand-in chunk table
TABLE_OFFSET_BYTES = 8                  # the chunk table's offset, first in the point data
TABLE_HEAD = struct.Struct("<II")       # chunk table version, chunk count
PARALLEL_CHUNK_BYTES = 1 << 26
"""Largest decoded chunk handed to the parallel decoder, which allocates a whole chunk
per chunk (a chunk size of 4e9 points in a damaged VLR aborted the process); larger
chunks are decoded in sequence, which does not."""
ROUNDS_PER_READ = 2
"""Chunks per core in one read: two rounds keep every core busy until a read's last
chunks, and a read short (lazrs holds the GIL for all of it)."""
READ_BYTES = 1 << 27
"""Most decoded bytes in one read, however many cores there are."""
SHORT_READS_POINTS = 1_000_000
"""Points after the first read that are decoded in reads of one chunk per core: lazrs
holds the GIL through a read, and while the consumer builds its renderer and draws the
first image (about what the loader's queues hold ahead of it) a short read lets it run
sooner; later reads hold ROUNDS_PER_READ chunks per core."""


@dataclass(frozen=True)
class LazLayout:
    """How to decode a LAZ: the backend, and what salvaging a damaged file needs."""

    backend: laspy.LazBackend
    vlr_data: bytes
    point_data: int
    points: int
    chunk_size: int | None      # fixed-size chunks; None: pointwise or variable-size
    table_ok: bool
    table_at: int | None = None
    """Where the chunk data ends: the offset of the chunk table, where one was found."""
    stand_in: bool = False
    """The chunk table is missing or corrupt (`problem` says how): lazrs must not see it."""
    problem: str | None = None
    patches: tuple[Patch, ...] = ()
    """The file's text patches (text_patches), applied wherever laspy reads the header."""
    chunks: tuple[Chunk, ...] = ()
    """Where the chunks can be decoded in parallel (a sound table, chunks that fit
    PARALLEL_CHUNK_BYTES): each chunk's points and bytes, up to `points` (the last chunk
    holds what is left of them), in file order; else empty."""

    def open(self, path: str):
        """The file as lazrs may see it."""
        return self._stand_in(path) if self.stand_in else open_patched(path, self.patches)

    def salvage_stream(self, path: str):
        """A stream the sequential decoder can start on, or None when nothing can be read.
        A truncated chunked LAZ has lost its chunk table (stored last); with fixed-size
        chunks a stand-in table of full chunks lets decoding start again."""
        pointwise = struct.unpack_from("<H", self.vlr_data, 0)[0] == LAZ_POINTWISE
        if pointwise or self.table_ok:
            return open_patched(path, self.patches)
        return None if self.chunk_size is None else self._stand_in(path)

    def _stand_in(self, path: str):
        """The file up to the end of its chunk data (its own table's offset, else its end)
        and then a table of full fixed-size chunks (as many as it has room for); with
        variable-size chunks, with none, which fails cleanly. Decoding fails where the
        chunk data ends instead of decoding the damaged table as points."""
        table = io.BytesIO()
        if self.chunk_size is not None:
            entries = [(self.chunk_size, 1)] * min(math.ceil(self.points / self.chunk_size),
                                                   os.path.getsize(path) // MIN_CHUNK_BYTES + 1)
            lazrs.write_chunk_table(table, entries, lazrs.LazVlr(self.vlr_data))
        end = self.table_at or os.path.getsize(path)
        return open_patched(path, (*self.patches, (self.point_data, struct.pack("<q", end + TAIL_GAP))),
                            table.getvalue(), end=end)


def decode_chunks(path: str, laz: LazLayout, points: int, first_read: int, dtype: np.dtype, cores: int,
                  selection: lazrs.DecompressionSelection | None = None, skip: int = 0) -> Iterator[np.ndarray]:
    """The first `points` points of laz.chunks in file order but for its first `skip`
    chunks (decoded already), as structured arrays of `dtype`, one per read, decoded by
    lazrs on every core; the compressed bytes are read without the GIL. The first read
    holds only the chunks of the first `first_read` points (a first batch, or a probe of
    the file's first points, comes sooner), the reads of the next SHORT_READS_POINTS one
    chunk per core, later ones ROUNDS_PER_READ (each at most READ_BYTES). Fields that
    `selection` leaves out are not decoded: they hold no values of the file's (a chunk's
    first point's, say)."""
    chunks = clipped(list(laz.chunks), points, None)
    done, chunks = chunks[:skip], chunks[skip:]
    if not chunks:
        return
    starts = read_starts(chunks, first_read, dtype.itemsize, cores)
    with open_binary(path) as stream:
        stream.seek(laz.point_data + TABLE_OFFSET_BYTES + sum(n for _, n in done))
        for first, end in zip(starts, [*starts[1:], len(chunks)], strict=True):
            group = chunks[first:end]
            compressed = bytearray(sum(n for _, n in group))
            if stream.readinto(compressed) != len(compressed):
                raise EOFError("the file ends inside its LAZ chunk data")
            records = np.empty(sum(n for n, _ in group), dtype)
            lazrs.decompress_points_with_chunk_table(compressed, laz.vlr_data, memoryview(records).cast("B"),
                                                     list(group), selection)
            yield records


def read_starts(chunks: tuple[Chunk, ...], first_read: int, record_bytes: int, cores: int) -> list[int]:
    """Index of the first chunk of each read (see decode_chunks)."""
    largest = max((n for n, _ in chunks), default=0) * record_bytes
    per_read = max(1, min(cores * ROUNDS_PER_READ, READ_BYTES // max(largest, 1)))
    short = min(cores, per_read)
    head = max(1, min(len(clipped(chunks, first_read, None)), per_read))
    short_until = len(clipped(chunks, sum(n for n, _ in chunks[:head]) + SHORT_READS_POINTS, None))
    starts, at = [0], head
    while at < len(chunks):
        starts.append(at)
        at += short if at < short_until else per_read
    return starts


def clipped(table: list[Chunk], points: int, chunk_size: int | None) -> tuple[Chunk, ...]:
    """The chunks that hold the first `points` points, the last one cut to what is left
    (lazrs decodes exactly the points an entry gives; a fixed-size table gives every
    chunk chunk_size, the last one's too)."""
    out, left = [], points
    for held, n in table:
        if left <= 0:
            break
        take = min(left, held if chunk_size is None else chunk_size)
        out.append((take, n))
        left -= take
    return tuple(out)


def open_patched(path: str, patches: tuple[Patch, ...] = (), tail: bytes = b"", end: int | None = None):
    """The file, or a read-only view of it with patches applied, cut at `end`, and `tail`
    after its end."""
    if not patches and not tail and end is None:
        return open_binary(path)
    return io.BufferedReader(PatchedFile(open_binary(path), patches, tail, end), 1 << 20)


class PatchedFile(PositionedReader):
    """A file as stored (up to `end`) but for the bytes of `patches`, with `tail` stored
    TAIL_GAP bytes past its end: laspy and lazrs read it without anything being written.
    A read at the end sees the end of the file, so that a decoder running off truncated
    point data fails there rather than decoding the tail."""

    def __init__(self, stream, patches: tuple[Patch, ...], tail: bytes, end: int | None = None):
        super().__init__()
        self._stream = stream
        size = os.fstat(stream.fileno()).st_size
        self._size = size if end is None else min(end, size)
        self._patches = patches
        self._tail = tail
        self._tail_at = self._size + TAIL_GAP if tail else self._size

    def end(self) -> int:
        return self._tail_at + len(self._tail)

    def readinto(self, buffer) -> int:
        """At most up to the end of the file, of the gap or of the tail: a short read."""
        if self._pos >= self._size:
            skip = self._pos - self._tail_at
            data = self._tail[skip:skip + len(buffer)] if skip >= 0 else b""
        else:
            self._stream.seek(self._pos)
            data = bytearray(self._stream.read(min(len(buffer), self._size - self._pos)))
            for at, patch in self._patches:
                lo, hi = max(at, self._pos), min(at + len(patch), self._pos + len(data))
                if lo < hi:
                    data[lo - self._pos:hi - self._pos] = patch[lo - at:hi - at]
        buffer[:len(data)] = data
        self._pos += len(data)
        return len(data)

    def close(self) -> None:
        self._stream.close()
        super().close()


def chunk_table_at(stream, point_data: int, size: int) -> int | None:
    """The chunk table's offset, found as lazrs finds it (at the start of the point data,
    else in the file's last 8 bytes); None where it points nowhere in the file."""
    def offset_at(position: int) -> int:
        stream.seek(position)
        raw = stream.read(TABLE_OFFSET_BYTES)
        return struct.unpack("<q", raw)[0] if len(raw) == TABLE_OFFSET_BYTES else -1

    offset = offset_at(point_data)
    if offset <= point_data:
        offset = offset_at(max(size - TABLE_OFFSET_BYTES, 0))
    return offset if point_data < offset <= size - TABLE_HEAD.size else None


def _table_damage(stream, vlr: lazrs.LazVlr, point_data: int, table_at: int, size: int) -> str | list:
    """The chunk table as (points, bytes) entries, or why it cannot be used: more chunks
    declared than the file has room for, unreadable, or byte counts that do not add up
    to the chunk data (which lazrs would allocate or seek by)."""
    stream.seek(table_at)
    _, declared = TABLE_HEAD.unpack(stream.read(TABLE_HEAD.size))
    if declared * MIN_CHUNK_BYTES > size:
        return f"it declares {declared} chunks, more than the file has room for"
    try:
        stream.seek(point_data)
        table = lazrs.read_chunk_table(stream, vlr)
    except Exception:
        return "it cannot be read"
    span = table_at - point_data - TABLE_OFFSET_BYTES
    counted = sum(n for _, n in table)
    if counted != span:
        return f"the byte counts of its {len(table)} chunks add up to {counted}, not to the {span} bytes of chunk data"
    if any((n <= 0) != (points == 0) if vlr.uses_variable_size_chunks() else n <= 0 for points, n in table):
        return "a chunk has points but no bytes, or bytes but no points"
    return table


def laz_layout(path: str, stream, header: laspy.LasHeader, record_length: int, count: int, size: int,
               patches: tuple[Patch, ...], partial: bool, warnings: list[str]) -> LazLayout:
    """LazrsParallel where the chunk table is sound and agrees with the header count; with
    partial, a table that disagrees bounds the count (a warning says so), and a damaged
    one is replaced by a stand-in read in sequence. Otherwise one error line."""
    if not laspy.LazBackend.Lazrs.is_available():
        raise fail(path, "is LAZ but no LAZ decoder is installed (pip install 'laspy[lazrs]')")
    found = header.vlrs.get("LasZipVlr")
    if not found:
        raise fail(path, "is compressed but has no LASzip VLR")
    vlr_data = bytes(found[0].record_data)
    check_laszip(path, vlr_data, header.point_format.id, record_length)
    try:
        vlr = lazrs.LazVlr(vlr_data)
    except Exception:
        raise fail(path, "is compressed but has no valid LASzip VLR") from None
    variable = vlr.uses_variable_size_chunks()
    chunked = struct.unpack_from("<H", vlr_data, 0)[0] != LAZ_POINTWISE
    point_data = header.offset_to_point_data
    layout = LazLayout(laspy.LazBackend.Lazrs, vlr_data, point_data, count,
                       None if variable or not chunked else vlr.chunk_size(), table_ok=False, patches=patches)
    if not chunked:
        return layout
    table_at = chunk_table_at(stream, point_data, size)
    table = "not found" if table_at is None else \
        _table_damage(stream, vlr, point_data, table_at, size)
    if isinstance(table, str):
        if variable:                    # lazrs needs the table's point counts to find the chunks
            raise fail(path, f"point data cannot be decoded: its LAZ chunk table is missing or corrupt ({table}) "
                             f"and its chunks are of variable size")
        if not partial:
            raise fail(path, f"point data is truncated or corrupt (its LAZ chunk table is missing or corrupt: "
                             f"{table}; a partial load reads what decodes)")
        if table_at is not None:        # a table not found is a cut file's: its TruncatedInput says so
            warnings.append(f"{shown(path)}: its LAZ chunk table is corrupt ({table}); read its chunks in sequence")
        return dataclasses.replace(layout, table_at=table_at, stand_in=True, problem=table)
    held = sum(points for points, _ in table) if variable else len(table) * vlr.chunk_size()
    if (count != held) if variable else (len(table) != math.ceil(count / vlr.chunk_size())):
        problem = (f"header says {count} points but the LAZ chunk table holds {held}" if variable else
                   f"header says {count} points but the LAZ chunk table has {len(table)} chunks of "
                   f"{vlr.chunk_size()}")
        if not partial:
            raise fail(path, problem)
        count = min(count, held)
        warnings.append(f"{shown(path)}: {problem}; read at most {count} points")
    largest = max((points for points, _ in table), default=0) if variable else vlr.chunk_size()
    parallel = laspy.LazBackend.LazrsParallel
    fits = parallel.is_available() and largest * record_length <= PARALLEL_CHUNK_BYTES
    return dataclasses.replace(layout, points=count, table_ok=True, table_at=table_at,
                               backend=parallel if fits else layout.backend,
                               chunks=clipped(table, count, None if variable else vlr.chunk_size()) if fits else ())
