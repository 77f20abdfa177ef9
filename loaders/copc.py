"""COPC (Cloud Optimized Point Cloud) input: the octree hierarchy of a LAZ 1.4 file and
reading it by level of detail.

A COPC file is a LAZ whose every chunk is one octree node; the hierarchy (an EVLR, in
pages) says where each node's chunk is and how many points it holds. A child does not
repeat its parent's points, so the nodes of levels 0..d are a set of points without
duplicates, spread over the whole cloud: where the cloud does not fit in the GPU memory
limit, keeping the deepest such set that fits shows every part of the cloud at an even
density instead of a uniform random subset; for a view, the nodes it needs most
(copc_choice) show more where the camera is near.

Read in full, a COPC source is its LAZ: the same points in the same order. Read down to
a level, the cloud holds the kept nodes' points in file order, numbered from 0; its
FileInfo.runs say which points of the file those are (picks read them back).

Nodes are read by the hierarchy either way, so a node whose chunk does not decode is
one line (InputError), or with partial a skipped node (its points not loaded, the
others at their own indices) and a warning at the end of the file. The file's
CopcFileInfo tallies what the reader has read, for a session's status.

An http(s):// URL of a COPC file is read the same way by range requests
(loaders/http.py): its header, VLRs, chunk table and hierarchy, then the kept nodes'
chunks, a few requests in flight ahead of the decoder. The checks are the local
file's, so the same file gives the same source either way. A node whose connection
drops on every try is, with partial, skipped as a damaged one is.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import os
import struct
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import laspy
import lazrs
import numpy as np

from progressive.errors import InputError
from progressive.loaders import las
from progressive.loaders.copc_choice import Nodes, View, choose
from progressive.loaders.http import DEFAULTS as HTTP_DEFAULTS
from progressive.loaders.http import FetchFailed, HttpOptions, Prefetch, RemoteFile, Tally, is_url
from progressive.loaders.las import LasSource, TruncatedInput, is_decode_error, open_las, selection
from progressive.loaders.laz import TABLE_OFFSET_BYTES, laz_layout
from progressive.loaders.laz_pool import DecodeFailed, DecoderPool
from progressive.loaders.types import BATCH_POINTS, RGB8_MAX, AttributeInfo, Batch, FileInfo
from progressive.loaders.validate import contradicted_bounds, fail, one_line, open_binary, shown

HEADER_14 = 375                          # bytes of a LAS 1.4 header
VLR_HEADER = 54
EVLR_HEADER = 60
USER_ID = b"copc"
INFO_RECORD = 1                          # the COPC info VLR: first after the header
HIERARCHY_RECORD = 1000                  # the hierarchy EVLR
INFO = struct.Struct("<3dddQQdd88x")     # center, halfsize, spacing, root page offset and size, GPS min and max
ENTRY = np.dtype([("level", "<i4"), ("x", "<i4"), ("y", "<i4"), ("z", "<i4"),
                  ("offset", "<u8"), ("byte_size", "<i4"), ("point_count", "<i4")])
"""One hierarchy entry: a node's key, then its chunk (point_count > 0), a child page
(point_count -1) or nothing (0)."""
PAGE = -1
MAX_LEVEL = 30                           # keys are int32: deeper levels cannot be addressed
READ_POINTS = 1 << 17
"""Points of kept nodes decoded in one lazrs call (several chunks, decoded on every core;
at least one node). lazrs holds the GIL while it decodes: a short call lets the parser
threads and the render loop run between calls."""
FIRST_READ_POINTS = 1 << 16
"""The first call decodes only the first nodes up to this many points: the first image
comes sooner."""
NAMED_NODES = 5
"""Damaged nodes a warning names; it counts the others."""


COPC_SUFFIX = ".copc.laz"
"""The name COPC files are given (the specification's convention): convert writes COPC
to it, and streaming takes a URL of that name for a COPC file."""


def is_copc(path: str | os.PathLike) -> bool:
    """A LAS 1.4 file whose first VLR is the COPC info VLR (as the specification requires)."""
    try:
        with open_binary(path) as stream:
            head = stream.read(HEADER_14 + VLR_HEADER)
    except (OSError, InputError):
        return False
    return copc_head(head)


def copc_head(head: bytes) -> bool:
    """is_copc of a file's first HEADER_14 + VLR_HEADER bytes."""
    if len(head) < HEADER_14 + VLR_HEADER or head[:4] != b"LASF" or head[24:26] != b"\x01\x04":
        return False
    (header_size,) = struct.unpack_from("<H", head, 94)
    if header_size != HEADER_14:
        return False
    vlr = head[HEADER_14:]
    user, record = vlr[2:18].rstrip(b"\0"), struct.unpack_from("<H", vlr, 18)[0]
    return user == USER_ID and record == INFO_RECORD


@dataclass(frozen=True)
class CopcInfo:
    """The COPC info VLR: the root node's cube and the root spacing between points."""

    center: tuple[float, float, float]
    halfsize: float
    spacing: float
    root_offset: int
    root_size: int
    gps_min: float
    gps_max: float

    @classmethod
    def parse(cls, data: bytes) -> CopcInfo:
        cx, cy, cz, half, spacing, offset, size, gmin, gmax = INFO.unpack(data[:INFO.size])
        return cls((cx, cy, cz), half, spacing, offset, size, gmin, gmax)

    def pack(self) -> bytes:
        return INFO.pack(*self.center, self.halfsize, self.spacing, self.root_offset, self.root_size,
                         self.gps_min, self.gps_max)


@dataclass(frozen=True)
class Hierarchy:
    """Every node that holds points, in file order (by chunk offset), with the file-order
    index of its first point."""

    info: CopcInfo
    nodes: np.ndarray            # ENTRY rows
    first: np.ndarray            # int64 file-order index of each node's first point

    @property
    def levels(self) -> int:
        return int(self.nodes["level"].max()) + 1 if self.nodes.size else 0

    def per_level(self) -> list[tuple[int, int]]:
        """(nodes, points) of each level from the root down."""
        level = self.nodes["level"]
        counts = self.nodes["point_count"].astype(np.int64)
        return [(int(np.count_nonzero(level == d)), int(counts[level == d].sum())) for d in range(self.levels)]

    def points_through(self, depth: int) -> int:
        return int(self.nodes["point_count"][self.nodes["level"] <= depth].astype(np.int64).sum())

    def summary(self) -> dict:
        """What `info` reports of the hierarchy."""
        return {"levels": self.levels, "nodes": int(self.nodes.size),
                "per_level": [{"level": d, "nodes": n, "points": p} for d, (n, p) in enumerate(self.per_level())],
                "center": list(self.info.center), "halfsize": self.info.halfsize, "spacing": self.info.spacing}


def read_hierarchy(path: str, point_data: int, points: int) -> Hierarchy:
    """The hierarchy of a COPC file, every page followed, checked: pages inside the file,
    none read twice, node keys inside the octree, node chunks tiling the LAZ chunk data
    from its start in file order, and their points adding up to the header's `points`.
    InputError naming what is wrong otherwise."""
    with open_binary(path) as stream:
        return hierarchy_of(path, stream, os.fstat(stream.fileno()).st_size, point_data, points)


def hierarchy_of(path: str, stream, size: int, point_data: int, points: int) -> Hierarchy:
    """read_hierarchy from a stream of the file (of `size` bytes)."""
    stream.seek(HEADER_14 + VLR_HEADER)
    raw = stream.read(INFO.size)
    if len(raw) < INFO.size:
        raise fail(path, "COPC info VLR is cut short")
    info = CopcInfo.parse(raw)
    if not (np.isfinite(info.halfsize) and info.halfsize > 0 and all(np.isfinite(info.center))):
        raise fail(path, f"COPC info VLR: invalid octree cube (centre {info.center}, halfsize {info.halfsize})")
    pages, seen, found = [(info.root_offset, info.root_size)], set(), []
    while pages:
        offset, length = pages.pop()
        if offset in seen:
            raise fail(path, f"COPC hierarchy page at {offset} is referenced twice")
        seen.add(offset)
        if length <= 0 or length % ENTRY.itemsize or offset + length > size or offset < HEADER_14:
            raise fail(path, f"COPC hierarchy page at {offset} of {length} bytes is outside the file "
                             f"or not a whole number of {ENTRY.itemsize}-byte entries")
        stream.seek(offset)
        page = np.frombuffer(stream.read(length), ENTRY)
        children = page[page["point_count"] == PAGE]
        pages += [(int(e["offset"]), int(e["byte_size"])) for e in children]
        found.append(page[page["point_count"] != PAGE])
    entries = np.concatenate(found)
    return _checked(path, info, entries, point_data, points)


def _checked(path: str, info: CopcInfo, entries: np.ndarray, point_data: int, points: int) -> Hierarchy:
    level = entries["level"]
    if np.any((level < 0) | (level > MAX_LEVEL)):
        raise fail(path, f"COPC hierarchy has a node of level {int(level[(level < 0) | (level > MAX_LEVEL)][0])}")
    span = np.left_shift(1, level.astype(np.int64))
    for axis in "xyz":
        if np.any((entries[axis] < 0) | (entries[axis] >= span)):
            raise fail(path, f"COPC hierarchy has a node key outside the octree ({axis} out of range for its level)")
    if np.any(entries["point_count"] < 0):
        raise fail(path, "COPC hierarchy has a node with a negative point count")
    keys = entries[["level", "x", "y", "z"]]
    if np.unique(keys).size != keys.size:
        raise fail(path, "COPC hierarchy lists a node twice")
    nodes = entries[entries["point_count"] > 0]
    nodes = nodes[np.argsort(nodes["offset"], kind="stable")]
    ends = nodes["offset"] + nodes["byte_size"].astype(np.uint64)
    starts = np.r_[np.uint64(point_data + TABLE_OFFSET_BYTES), ends[:-1]].astype(np.uint64)
    if np.any(nodes["byte_size"] <= 0) or not np.array_equal(nodes["offset"], starts):
        raise fail(path, "COPC hierarchy does not match the LAZ chunks (node chunks must follow one another "
                         "from the start of the point data)")
    counts = nodes["point_count"].astype(np.int64)
    if int(counts.sum()) != points:
        raise fail(path, f"COPC hierarchy holds {int(counts.sum()):,} points, the header {points:,}")
    return Hierarchy(info, nodes, np.r_[0, np.cumsum(counts)[:-1]].astype(np.int64))


class NodeReads:
    """What the reader thread has read of a COPC file's kept nodes so far: nodes, points
    and compressed bytes read, and the damaged nodes skipped (partial). Written by the
    reader, read by a session at any moment, under a lock."""

    def __init__(self):
        self._lock = threading.Lock()
        self.nodes = self.points = self.bytes = 0
        self.skipped: list[tuple[tuple[int, int, int, int], int, str]] = []    # (key, points, why) of each

    def read(self, nodes: int, points: int, nbytes: int) -> None:
        with self._lock:
            self.nodes, self.points, self.bytes = self.nodes + nodes, self.points + points, self.bytes + nbytes

    def skip(self, key: tuple[int, int, int, int], points: int, why: str) -> None:
        with self._lock:
            self.skipped.append((key, points, why))

    def snapshot(self) -> tuple[int, int, int, tuple]:
        with self._lock:
            return self.nodes, self.points, self.bytes, tuple(self.skipped)


@dataclass(frozen=True)
class CopcStatus:
    """One COPC file at one moment: levels, nodes and points kept for the GPU (whole
    levels from the root, or a view's nodes: levels kept is then the deepest one's + 1)
    of the file's, what has been read of them (compressed bytes of its nodes' chunks)
    and the damaged nodes skipped (their points not loaded). Over
    HTTP, what was fetched: bytes of every answer (headers, hierarchy and nodes), requests
    answered and in flight; 0 for a local file."""

    levels: int
    levels_kept: int
    nodes: int
    nodes_kept: int
    points: int
    points_kept: int
    nodes_read: int
    points_read: int
    bytes_read: int
    nodes_skipped: int
    points_skipped: int
    bytes_fetched: int = 0
    requests: int = 0
    requests_in_flight: int = 0


class RemoteCopc:
    """A URL's COPC file read again once loaded (its loader may have closed): one point
    for a pick, from the node its hierarchy says holds it (one range request; the last
    node kept, as a pick reads its point twice), and the header with its EVLRs for the
    CRS. Each read has a RemoteFile of its own, counted in the file's tally."""

    def __init__(self, url: str, options: HttpOptions, tally: Tally, hierarchy: Hierarchy, vlr_data: bytes,
                 point_format: laspy.PointFormat, scales: np.ndarray, offsets: np.ndarray):
        self.url, self.options, self.tally, self.hierarchy = url, options, tally, hierarchy
        self.vlr_data, self.point_format, self.scales, self.offsets = vlr_data, point_format, scales, offsets
        self._lock = threading.Lock()
        self._node: tuple[int, bytes] | None = None         # (node, its compressed chunk) last fetched

    def node_of(self, index: int) -> tuple[bytes, int, int]:
        """(compressed chunk, points, the point's index in it) of the node holding the
        file-order point `index`; InputError where it cannot be fetched."""
        k = int(np.searchsorted(self.hierarchy.first, index, side="right")) - 1
        node = self.hierarchy.nodes[k]
        at, count = index - int(self.hierarchy.first[k]), int(node["point_count"])
        if not (0 <= index and at < count):
            raise IndexError(f"point {index} outside the COPC nodes of {self.url}")
        with self._lock:
            if self._node is None or self._node[0] != k:
                remote = RemoteFile(self.url, self.options, self.tally)
                try:
                    self._node = (k, remote.read(int(node["offset"]), int(node["byte_size"])))
                finally:
                    remote.close()
            return self._node[1], count, at

    def header(self) -> laspy.LasHeader:
        """The header, VLRs and EVLRs as laspy reads them (laspy's errors as it raises them;
        InputError where the server fails)."""
        remote = RemoteFile.open(self.url, self.options, self.tally)
        try:
            return laspy.LasHeader.read_from(remote.stream(), read_evlrs=True)
        finally:
            remote.close()


@dataclass(frozen=True)
class CopcFileInfo(FileInfo):
    """The FileInfo of a COPC file read by its hierarchy (`points` counts the kept
    nodes' points), with the hierarchy's totals and the reader's tally; over HTTP, what
    reads the file again (picks, the CRS)."""

    copc_levels: int = 0
    copc_nodes: int = 0
    copc_points: int = 0
    levels_kept: int = 0
    nodes_kept: int = 0
    reads: NodeReads = field(default_factory=NodeReads, compare=False, repr=False)
    fetches: Tally | None = field(default=None, compare=False, repr=False)     # over HTTP
    remote: RemoteCopc | None = field(default=None, compare=False, repr=False)  # over HTTP

    def status(self) -> CopcStatus:
        nodes, points, nbytes, skipped = self.reads.snapshot()
        fetched = (0, 0, 0) if self.fetches is None else self.fetches.snapshot()
        return CopcStatus(self.copc_levels, self.levels_kept, self.copc_nodes, self.nodes_kept, self.copc_points,
                          self.points, nodes, points, nbytes, len(skipped), sum(n for _, n, _ in skipped), *fetched)


def copc_status(info: FileInfo) -> CopcStatus | None:
    """A file's COPC status; None for other files (and COPC files read as plain LAZ)."""
    return info.status() if isinstance(info, CopcFileInfo) else None


@dataclass(frozen=True)
class AfterGap:
    """Records that follow damaged nodes skipped in a file: `len` spans both, so the
    loader numbers the next records from after these as well."""

    records: np.ndarray
    gap: int

    def __len__(self) -> int:
        return self.gap + len(self.records)


@dataclass(frozen=True)
class CopcSource(LasSource):
    """A COPC file: its LAZ source, its hierarchy (None where it could not be used: the
    file is then read as the plain LAZ it also is), the deepest level kept (None: all)
    or the nodes kept for a view and, for a URL, the remote file its nodes are fetched
    from and the chunks fetched while it was opened (by offset; read from here, not
    fetched again)."""

    hierarchy: Hierarchy | None = None
    depth: int | None = None
    chosen: tuple[int, ...] | None = None   # the nodes kept for a view (indices into hierarchy.nodes); None: by depth
    problem: str | None = None              # why the hierarchy cannot be used
    remote: RemoteFile | None = field(default=None, compare=False, repr=False)
    held: dict[int, bytes] = field(default_factory=dict, compare=False, repr=False)

    def chunks(self, batch_points: int, *, salvage: bool = False, names: tuple[str, ...] | None = None,
               decoders: DecoderPool | None = None) -> Iterator[np.ndarray | AfterGap]:
        """As a LAZ's (`decoders` decode a file without a hierarchy); else node by node,
        each decoded here."""
        if self.hierarchy is None:
            return super().chunks(batch_points, salvage=salvage, names=names, decoders=decoders)
        return self._node_chunks(self.kept_nodes(), batch_points, None if names is None else selection(names), salvage)

    def parse(self, chunk, start: int, origin: np.ndarray, names: tuple[str, ...]) -> Batch:
        if isinstance(chunk, AfterGap):
            return super().parse(chunk.records, start + chunk.gap, origin, names)
        return super().parse(chunk, start, origin, names)

    def close(self) -> None:
        """Stop the fetches in flight (a loader that stops)."""
        if self.remote is not None:
            self.remote.close()

    def node_batch(self, k: int, start: int, origin: np.ndarray, names: tuple[str, ...],
                   decoders: DecoderPool | None = None,
                   lane: Callable[[], contextlib.AbstractContextManager[int]] | None = None) -> Batch:
        """Node k (an index into hierarchy.nodes) read on its own, its points numbered from
        `start`: for a streaming reader's threads (each read opens the file, or fetches the
        node's range, for itself). Where `decoders` are given, a process of theirs decodes
        the node, held through `lane()` while it does (lazrs holds the GIL while it
        decodes: in this process a node stalls the frame loop); else, or where the
        processes fail, it is decoded here. InputError where the node cannot be read or
        decoded. A fetched node takes its process once its bytes are here: a slow server
        leaves the processes to the nodes that have arrived. Records the processes decoded
        are parsed under their pool's parse_gate, as the loader's parser threads parse
        them: every reading thread parsing at once would contend for the GIL
        (laz_pool.CORES_PER_PARSER)."""
        node = self.hierarchy.nodes[k]
        count, size = int(node["point_count"]), int(node["byte_size"])
        elsewhere = None
        if decoders is not None and self.remote is None:
            try:
                with lane() as process:
                    records = decoders.decode_run(process, self.info.path, int(node["offset"]), ((count, size),),
                                                  self.laz.vlr_data, las.layers(names), self.records.dtype)
            except DecodeFailed:
                pass
            else:
                self.info.reads.read(1, count, size)
                with decoders.parse_gate:
                    return self.parse(records, start, origin, names)
        elif decoders is not None:
            def elsewhere(compressed: bytes, records: np.ndarray, table: list) -> bool:
                try:
                    with lane() as process:
                        decoders.decode_bytes(process, compressed, tuple(table), self.laz.vlr_data, las.layers(names),
                                              records)
                except DecodeFailed:
                    return False        # decoded here, which names what is wrong with it
                return True
        pieces = list(self._node_chunks(np.array([k]), max(1, count), selection(names), salvage=False,
                                        elsewhere=elsewhere))
        records = pieces[0] if len(pieces) == 1 else np.concatenate(pieces)
        with decoders.parse_gate if decoders is not None else contextlib.nullcontext():
            return self.parse(records, start, origin, names)

    def kept_nodes(self) -> np.ndarray:
        """Indices (into hierarchy.nodes, so in file order) of the nodes read."""
        level = self.hierarchy.nodes["level"]
        if self.chosen is not None:
            return np.asarray(self.chosen, np.int64)
        return np.arange(level.size) if self.depth is None else np.nonzero(level <= self.depth)[0]

    def _node_chunks(self, kept: np.ndarray, batch_points: int, chosen,
                     salvage: bool, elsewhere: Callable[[bytes, np.ndarray, list], bool] | None = None
                     ) -> Iterator[np.ndarray | AfterGap]:
        """The records of the nodes `kept` in file order, in pieces of at most
        batch_points; up to READ_POINTS at a time (FIRST_READ_POINTS first) are read and
        decoded by lazrs on every core (or by `elsewhere`: see _decoded). With salvage,
        damaged nodes are skipped (the next piece is an AfterGap) and named at the end by
        a TruncatedInput (the loader's warning)."""
        nodes = self.hierarchy.nodes
        dtype = self.records.dtype
        gap, read = 0, 0
        with self._node_bytes(nodes[kept]) as fetch:
            at = 0
            while at < kept.size:
                group, total, end = [], 0, at
                most = FIRST_READ_POINTS if at == 0 else READ_POINTS
                while end < kept.size and (not group or total + int(nodes["point_count"][kept[end]]) <= most):
                    group.append(kept[end])
                    total += int(nodes["point_count"][kept[end]])
                    end += 1
                for records, skipped in self._decode(fetch, range(at, end), nodes[group], dtype, chosen, salvage,
                                                     elsewhere):
                    gap += skipped
                    for first in range(0, len(records), batch_points):
                        piece = records[first:first + batch_points]
                        yield AfterGap(piece, gap) if gap else piece
                        read, gap = read + len(piece), 0
                at = end
        _, _, _, skipped = self.info.reads.snapshot()
        if skipped:
            named = ", ".join(f"level {k[0]} key ({k[1]}, {k[2]}, {k[3]}) ({n:,} points, {why})"
                              for k, n, why in skipped[:NAMED_NODES])
            more = f" and {len(skipped) - NAMED_NODES} more" if len(skipped) > NAMED_NODES else ""
            raise TruncatedInput(f"{shown(self.info.path)}: {len(skipped)} COPC node(s) skipped, their "
                                 f"{sum(n for _, n, _ in skipped):,} points not loaded: {named}{more}", read)

    @contextlib.contextmanager
    def _node_bytes(self, nodes: np.ndarray):
        """fetch(k): the compressed chunk of nodes[k], the nodes asked for in order: read
        from the file, or fetched ahead by range requests (FetchFailed where a node's
        connection drops on every try)."""
        if self.remote is not None:
            spans = list(zip(nodes["offset"].tolist(), nodes["byte_size"].tolist()))
            wanted = [k for k, (offset, _) in enumerate(spans) if offset not in self.held]
            order = {k: i for i, k in enumerate(wanted)}
            with Prefetch(self.remote, [spans[k] for k in wanted]) as ahead:
                yield lambda k: self.held[spans[k][0]] if k not in order else ahead.take(order[k])
            return
        with open_binary(self.info.path) as stream:
            def read(k: int) -> bytes:
                stream.seek(int(nodes["offset"][k]))
                data = stream.read(int(nodes["byte_size"][k]))
                if len(data) != int(nodes["byte_size"][k]):
                    raise fail(self.info.path, "the file ends inside a COPC node's chunk")
                return data
            yield read

    def _decode(self, fetch, positions: range, group: np.ndarray, dtype: np.dtype, chosen,
                salvage: bool, elsewhere=None) -> Iterator[tuple[np.ndarray, int]]:
        """(records, damaged points skipped before them) of the group's nodes, whose
        compressed bytes fetch(k) gives for k in `positions`: decoded in one call,
        or where a node cannot be fetched or that call fails node by node to find the
        damaged ones (InputError naming the first without salvage)."""
        counts, sizes = group["point_count"].tolist(), group["byte_size"].tolist()
        parts: list[bytes | str] = []
        for k, node in zip(positions, group):
            try:
                parts.append(fetch(k))
            except FetchFailed as exc:
                problem = one_line(exc).removeprefix(shown(self.info.path) + ": ")
                if not salvage:
                    raise fail(self.info.path, f"COPC node of level {node['level']} key ({node['x']}, {node['y']}, "
                                               f"{node['z']}) could not be fetched ({problem})") from None
                parts.append(f"not fetched: {problem}")
        fetched = [i for i, p in enumerate(parts) if isinstance(p, bytes)]
        self.info.reads.read(len(fetched), sum(counts[i] for i in fetched), sum(sizes[i] for i in fetched))
        if len(fetched) == len(parts):
            records = np.empty(sum(counts), dtype)
            if self._decoded(b"".join(parts), records, list(zip(counts, sizes)), chosen, elsewhere) is None:
                yield records, 0
                return
        skipped = 0
        for node, count, size, part in zip(group, counts, sizes, parts):
            one = np.empty(count, dtype)
            problem = part if isinstance(part, str) else self._decoded(part, one, [(count, size)], chosen)
            if problem is None:
                yield one, skipped
                skipped = 0
                continue
            key = (int(node["level"]), int(node["x"]), int(node["y"]), int(node["z"]))
            if not salvage:
                raise fail(self.info.path, f"COPC node of level {key[0]} key ({key[1]}, {key[2]}, {key[3]}) "
                                           f"does not decode ({problem})")
            self.info.reads.skip(key, count, problem if isinstance(part, str) else "does not decode")
            skipped += count
        if skipped:
            yield np.empty(0, dtype), skipped

    def _decoded(self, compressed, records: np.ndarray, table: list, chosen, elsewhere=None) -> str | None:
        """Decode chunks into records; None, or the decoder's error in one line.
        elsewhere(compressed, records, table): decodes them in a decoder process, False
        where it could not (then they are decoded here)."""
        if elsewhere is not None and elsewhere(compressed, records, table):
            return None
        try:
            lazrs.decompress_points_with_chunk_table(compressed, self.laz.vlr_data, memoryview(records).cast("B"),
                                                     table, chosen)
        except BaseException as exc:
            if not is_decode_error(exc):
                raise
            return one_line(exc)
        return None

    def through(self, depth: int, budget: int) -> CopcSource:
        """This source read down to level `depth` (every node of it and above), with the
        warning that says so."""
        if depth >= self.hierarchy.levels - 1:
            return self
        kept = np.nonzero(self.hierarchy.nodes["level"] <= depth)[0]
        return self._cut(dataclasses.replace(self, depth=depth), kept,
                         lambda count: f"{shown(self.info.path)}: the cloud's points do not fit in the GPU memory "
                                       f"limit (room for {budget:,}): showing this COPC file's octree levels "
                                       f"0-{depth} of 0-{self.hierarchy.levels - 1}, {count:,} of its "
                                       f"{self.info.points:,} points (every point of those levels)")

    def for_view(self, kept: np.ndarray, budget: int) -> CopcSource:
        """This source read at the nodes `kept` (indices into hierarchy.nodes, a tree cut
        from the root that copc_choice chose for a view), with the warning that says so."""
        if kept.size == self.hierarchy.nodes.size:
            return self
        deepest = int(self.hierarchy.nodes["level"][kept].max())
        return self._cut(dataclasses.replace(self, chosen=tuple(kept.tolist())), kept,
                         lambda count: f"{shown(self.info.path)}: the cloud's points do not fit in the GPU memory "
                                       f"limit (room for {budget:,}): showing this COPC file's {kept.size:,} of "
                                       f"{self.hierarchy.nodes.size:,} octree nodes the view needs most (levels "
                                       f"0-{deepest} of 0-{self.hierarchy.levels - 1}, deeper near the camera), "
                                       f"{count:,} of its {self.info.points:,} points (every point of those nodes)")

    def _cut(self, source: CopcSource, kept: np.ndarray, note) -> CopcSource:
        """`source` (this one reading only the nodes `kept`) with its info and the warning
        note(points kept)."""
        nodes = self.hierarchy.nodes[kept]
        count = int(nodes["point_count"].astype(np.int64).sum())
        info = dataclasses.replace(self.info, points=count, runs=_runs(self.hierarchy.first[kept], nodes["point_count"]),
                                   levels_kept=int(nodes["level"].max()) + 1, nodes_kept=int(nodes.size))
        return dataclasses.replace(source, info=info, warnings=(*self.warnings, note(count)))


def _runs(first: np.ndarray, counts: np.ndarray) -> tuple[tuple[int, int], ...]:
    """(first, count) runs of file-order indices, adjacent nodes merged."""
    runs: list[list[int]] = []
    for f, n in zip(first.tolist(), counts.tolist()):
        if runs and runs[-1][0] + runs[-1][1] == f:
            runs[-1][1] += n
        else:
            runs.append([f, n])
    return tuple((f, n) for f, n in runs)


def open_copc(path: str | os.PathLike, *, partial: bool = False) -> CopcSource:
    """A COPC file checked as LAS/LAZ, with its hierarchy; a hierarchy that cannot be used
    is a warning, and the file is read in full as LAZ."""
    source = open_las(path, partial=partial)
    fields = {f.name: getattr(source, f.name) for f in dataclasses.fields(LasSource)}
    hierarchy = problem = None
    if source.laz is None:
        problem = f"{shown(source.info.path)}: has a COPC info VLR but is not compressed"
    else:
        try:
            hierarchy = read_hierarchy(source.info.path, source.laz.point_data, source.info.points)
        except InputError as exc:
            problem = one_line(exc)
    warnings = source.warnings + ((f"{problem}; read as plain LAS/LAZ (every point, no levels of detail)",)
                                  if problem else ())
    if hierarchy is not None:
        info = {f.name: getattr(source.info, f.name) for f in dataclasses.fields(FileInfo)}
        fields["info"] = CopcFileInfo(**info, copc_levels=hierarchy.levels, copc_nodes=int(hierarchy.nodes.size),
                                      copc_points=source.info.points, levels_kept=hierarchy.levels,
                                      nodes_kept=int(hierarchy.nodes.size))
    return CopcSource(**{**fields, "warnings": warnings}, hierarchy=hierarchy, problem=problem)


def open_copc_url(url: str, *, partial: bool = False, http: HttpOptions = HTTP_DEFAULTS) -> CopcSource:
    """A COPC file at an http(s):// URL, checked as open_copc and open_las check a local
    one, so the source is the local file's but for where its nodes come from. Over HTTP
    a COPC file is read by its hierarchy only: a file that is not COPC, or whose
    hierarchy cannot be used, is one line."""
    remote = RemoteFile.open(url, http)
    try:
        return _remote_source(remote, partial)
    except BaseException:
        remote.close()
        raise


def _remote_source(remote: RemoteFile, partial: bool) -> CopcSource:
    """open_las's checks and facts, and open_copc's hierarchy, from the remote file's
    bytes (las.py reads local paths); the first points from the first nodes."""
    url, size = remote.url, remote.size
    head = remote.cached(0, HEADER_14 + VLR_HEADER)
    raw = las.RawHeader.parse(url, head[:las.HEADER_PREFIX])
    if not copc_head(head) or not raw.compressed:
        raise fail(url, "is not a COPC file (a LAZ 1.4 whose first VLR is the COPC info VLR): only COPC files "
                        "are read over HTTP")
    if raw.count == 0:
        raise fail(url, "has no points")
    prefix = bytearray(remote.cached(0, raw.point_data))
    patches, bad_text = las.text_patches(io.BytesIO(prefix), raw)
    for at, patch in patches:
        prefix[at:at + len(patch)] = patch
    try:
        header = laspy.LasHeader.read_from(io.BytesIO(bytes(prefix)), read_evlrs=False)
    except Exception as exc:
        raise las.header_error(url, exc) from exc
    warnings = [f"{shown(url)}: {len(bad_text)} text field(s) of its VLRs are not UTF-8 ({bad_text[0]}"
                f"{', ...' if len(bad_text) > 1 else ''}); read them with '?' for the bad bytes"] if bad_text else []
    las._check_numbers(url, header)
    stream = remote.stream()
    laz = laz_layout(url, stream, header, raw.record_length, raw.count, size, patches, partial, warnings)
    count = laz.points
    try:
        hierarchy = hierarchy_of(url, stream, size, laz.point_data, count)
    except InputError as exc:
        raise InputError(f"{one_line(exc)} (over HTTP a COPC file is read by its hierarchy)") from None
    pf = header.point_format
    records = las.Records(pf, header.offset_to_point_data, np.asarray(header.scales, np.float64),
                          np.asarray(header.offsets, np.float64))
    has_rgb = "red" in pf.dimension_names
    columns = las._columns(pf)
    info = CopcFileInfo(
        path=url, format="LAZ", version=f"{raw.version[0]}.{raw.version[1]}", point_format=raw.point_format,
        points=count, scale=tuple(float(v) for v in header.scales), offset=tuple(float(v) for v in header.offsets),
        bounds_min=tuple(float(v) for v in header.mins), bounds_max=tuple(float(v) for v in header.maxs),
        rgb_max=None, crs=las.crs_name(header), copc_levels=hierarchy.levels, copc_nodes=int(hierarchy.nodes.size),
        copc_points=count, levels_kept=hierarchy.levels, nodes_kept=int(hierarchy.nodes.size), fetches=remote.tally,
        remote=RemoteCopc(url, remote.options, remote.tally, hierarchy, laz.vlr_data, pf,
                          np.asarray(header.scales, np.float64), np.asarray(header.offsets, np.float64)))
    source = CopcSource(info, (), columns, None, laz, records, (), hierarchy=hierarchy, remote=remote)
    max_rgb, first, seen = _probe(source, has_rgb, partial)
    if wrong := las.unreachable_bounds(header) or contradicted_bounds(header.mins, header.maxs, seen,
                                                                      np.abs(header.scales)):
        lo, hi = _node_bounds(source, partial)
        info = dataclasses.replace(info, bounds_min=lo, bounds_max=hi)
        warnings.append(f"{shown(url)}: header bounds {wrong}; ignored them and used the bounds of the points")
    info = dataclasses.replace(info, rgb_max=max_rgb if has_rgb else None, reads=NodeReads())
    names = tuple(n for n in las.STANDARD if n in columns or n in ("scan_angle", "elevation")
                  or (n == "rgb" and has_rgb)) + tuple(n for n in columns if n not in las.STANDARD)
    source = dataclasses.replace(source, info=info, warnings=tuple(warnings),
                                 first_gps_time=float(first["gps_time"][0]) if "gps_time" in columns else None)
    sample = source.parse(first, 0, np.zeros(3), names).attributes
    attributes = tuple(
        AttributeInfo(n, las.attribute_kind(n), np.dtype(np.float64) if n == "elevation" else sample[n].dtype)
        for n in names
    )
    return dataclasses.replace(source, attributes=attributes)


def _leading(source: CopcSource, points: int) -> np.ndarray:
    """The first nodes in file order that hold `points` points."""
    ends = np.cumsum(source.hierarchy.nodes["point_count"].astype(np.int64))
    return np.arange(int(np.searchsorted(ends, points)) + 1)


def _probe(source: CopcSource, has_rgb: bool, partial: bool) -> tuple[int, np.ndarray, np.ndarray]:
    """las._probe's max of R, G, B over the file's first BATCH_POINTS points (stopping
    once it exceeds 255), first point and min and max of the first PROBE_PIECE
    coordinates, from the file's first nodes: the first piece's nodes fetched first, the
    rest only where colours are still 8-bit."""
    count = source.info.points
    wanted = min(count, BATCH_POINTS if has_rgb else las.BOUNDS_SAMPLE)
    piece = min(wanted, las.PROBE_PIECE)
    first_nodes = _leading(source, piece)
    _hold(source, first_nodes)
    head = _node_records(source, first_nodes, partial)
    records = [head]
    if has_rgb and wanted > len(head) and las.rgb_max(head) <= RGB8_MAX:
        rest = _leading(source, wanted)[first_nodes.size:]
        _hold(source, rest)
        records.append(_node_records(source, rest, partial))
    first = np.concatenate(records)[:wanted]
    max_rgb = las.rgb_max(first) if has_rgb else 0
    with np.errstate(over="ignore", invalid="ignore"):
        seen = las.record_ends(first[:piece], source.records)
    return max_rgb, first[:1].copy(), seen


HELD_RUN_BYTES = 1 << 23
"""Bytes of consecutive node chunks the open fetches in one range request at most: the
file's first nodes lie back to back, and each request to a far server costs a round
trip (one a node, the open of a 20 M-point COPC whose answers came 50 ms late read for
0.69 s against 0.47 s: bench/results/llvmpipe/http_open/)."""


def _hold(source: CopcSource, kept: np.ndarray) -> None:
    """Fetch the chunks of the nodes `kept` into source.held, the first image's nodes:
    loading reads them from there. Chunks that lie back to back are fetched in one
    request (up to HELD_RUN_BYTES). A node that cannot be fetched is left to the read
    that follows (which names it, or skips it with partial)."""
    nodes = source.hierarchy.nodes[kept]
    runs: list[list[tuple[int, int]]] = []
    for offset, size in zip(nodes["offset"].tolist(), nodes["byte_size"].tolist()):
        last = runs[-1][-1] if runs else None
        if last is not None and last[0] + last[1] == offset and offset + size - runs[-1][0][0] <= HELD_RUN_BYTES:
            runs[-1].append((offset, size))
        else:
            runs.append([(offset, size)])
    spans = [(run[0][0], run[-1][0] + run[-1][1] - run[0][0]) for run in runs]
    with Prefetch(source.remote, spans) as ahead:
        for i, run in enumerate(runs):
            try:
                data = ahead.take(i)
            except FetchFailed:
                continue
            for offset, size in run:
                source.held[offset] = data[offset - run[0][0]: offset - run[0][0] + size]


def _node_records(source: CopcSource, kept: np.ndarray, partial: bool) -> np.ndarray:
    """Every record of the nodes `kept` (damaged ones left out with partial)."""
    pieces = []
    try:
        for chunk in source._node_chunks(kept, BATCH_POINTS, None, partial):
            pieces.append(chunk.records if isinstance(chunk, AfterGap) else chunk)
    except TruncatedInput:
        pass                # skipped nodes, partial: the rest is what there is
    if not sum(len(p) for p in pieces):
        raise fail(source.info.path, "no point of its first COPC nodes can be read")
    return np.concatenate(pieces)


def _node_bounds(source: CopcSource, partial: bool) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """las._data_bounds from every node: exact min and max of the file coordinates."""
    ends = las.CoordinateEnds(source.records)
    try:
        for chunk in source._node_chunks(np.arange(source.hierarchy.nodes.size), BATCH_POINTS, None, partial):
            ends.add(chunk.records if isinstance(chunk, AfterGap) else chunk)
    except TruncatedInput:
        pass
    return ends.bounds()


def keep_levels(sources: tuple, point_budget: int | None, view: View | Callable[..., View] | None = None) -> tuple:
    """Where the cloud has more points than `point_budget` (what fits on the GPU), its
    COPC files read down to the deepest level at which the whole cloud fits (at least the
    root: the store then keeps a uniform random subset of what is left); other sources
    as they are. With a `view` (or a function of the cloud's least and greatest corners
    that gives one: the auto camera frames the bounds), the nodes that view needs most
    instead (copc_choice), every file's root at least."""
    total = sum(s.info.points for s in sources)
    copc = [s for s in sources if isinstance(s, CopcSource) and s.hierarchy is not None]
    if point_budget is None or total <= point_budget or not copc:
        return sources
    fixed = total - sum(s.info.points for s in copc)
    if view is not None:
        return _keep_for_view(sources, copc, point_budget, fixed, view)
    deepest = max(s.hierarchy.levels for s in copc) - 1
    depth = 0
    for d in range(1, deepest + 1):
        if fixed + sum(s.hierarchy.points_through(d) for s in copc) <= point_budget:
            depth = d
    chosen = {id(s) for s in copc}     # by identity: sources hold arrays, and one file may come twice
    return tuple(s.through(depth, point_budget) if id(s) in chosen else s for s in sources)


def _keep_for_view(sources: tuple, copc: list, point_budget: int, fixed: int, view) -> tuple:
    """keep_levels with a view: one choice over the nodes of every COPC file."""
    if not isinstance(view, View):
        view = view(np.min([s.info.bounds_min for s in sources], axis=0).astype(np.float64),
                    np.max([s.info.bounds_max for s in sources], axis=0).astype(np.float64))
    h = [s.hierarchy for s in copc]
    nodes = hierarchy_nodes(h)
    rows = choose(nodes, view, max(point_budget - fixed, 0))
    starts = np.cumsum([0] + [x.nodes.size for x in h])
    cut = {id(s): s.for_view(rows[(rows >= a) & (rows < b)] - a, point_budget)
           for s, a, b in zip(copc, starts[:-1], starts[1:])}
    return tuple(cut.get(id(s), s) for s in sources)


def hierarchy_nodes(hierarchies) -> Nodes:
    """The node choice's rows of these files' hierarchies, file after file."""
    return Nodes.of_files([(x.info.center, x.info.halfsize, node_spacing(x.info), x.nodes) for x in hierarchies])


def node_spacing(info: CopcInfo) -> float:
    """The root's spacing between points: the info VLR's, or 0 where a writer left it
    unusable (every node of that file then has no error: it is cut by level and key,
    after other files' nodes)."""
    return info.spacing if np.isfinite(info.spacing) and info.spacing > 0 else 0.0


def describe_hierarchy(path: str | os.PathLike, http: HttpOptions = HTTP_DEFAULTS) -> dict | None:
    """The hierarchy summary of a COPC file for `info` (None for other files), or
    {"error": ...} where it cannot be used."""
    if is_url(path):
        source = open_copc_url(path, http=http)
        source.close()
        return source.hierarchy.summary()
    if not is_copc(path):
        return None
    source = open_copc(path)
    if source.hierarchy is None:
        return {"error": source.problem}
    return source.hierarchy.summary()


def format_hierarchy(path: str, summary: dict) -> str:
    """describe_hierarchy's result as text."""
    if "error" in summary:
        return f"COPC hierarchy of {path}: {summary['error']}"
    lines = [f"COPC hierarchy of {path}: {summary['levels']} levels, {summary['nodes']:,} nodes, "
             f"root spacing {summary['spacing']:.6g}",
             f"  {'level':<7}{'nodes':>10}{'points':>14}"]
    lines += [f"  {row['level']:<7}{row['nodes']:>10,}{row['points']:>14,}" for row in summary["per_level"]]
    return "\n".join(lines)
