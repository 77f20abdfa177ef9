"""PLY input (photogrammetry, research clouds) through plyfile: the vertex element's
x, y, z, its colours and every other scalar property; faces and list properties are
ignored.

Binary vertices are memory-mapped, ASCII ones parsed by plyfile once when the file is
opened; either way the source holds them, so the pass that finds the bounds (PLY has no
header bounds) and the load read the file only once.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
import plyfile

from progressive.errors import InputError
from progressive.loaders.types import (
    BATCH_POINTS,
    AttributeInfo,
    AttributeKind,
    Batch,
    FileInfo,
    channel8,
    nonfinite_count,
    nonfinite_rows,
    quiet_nans,
)
from progressive.loaders.validate import fail, open_binary, shown

MAGIC = (b"ply\n", b"ply\r")
VERTEX = "vertex"
END_HEADER = b"end_header"
VERSION = "1.0"                         # the only PLY version there is
COLOURS = (("red", "green", "blue"), ("r", "g", "b"))
"""Property names that make up RGB, in order of preference."""
COLOUR_TYPES = (np.uint8, np.uint16)
"""Colour property types taken as RGB (the LAS rule then decides 8 or 16 bits); colours
of other types are plain scalars under their own names."""
RESERVED = {"rgb": "RGB", "elevation": "the z coordinate"}
"""Attribute names a property cannot take: they are derived from other data."""
CATEGORY_NAMES = ("classification",)
"""Properties shown as categories (ASPRS codes) when of an unsigned integer type."""
ORDER = ("rgb", "intensity", "classification", "elevation")
"""Attributes in the order a LAS file lists them (so clouds of both agree); other
properties follow in the file's order."""


def is_ply(path: str | os.PathLike) -> bool:
    """Decided by the magic line; unreadable paths are left to the LAS checks."""
    try:
        with open_binary(path) as stream:
            return stream.read(4) in MAGIC
    except (InputError, OSError):
        return False


@dataclass(frozen=True, eq=False)
class PlySource:
    """One checked PLY file: its facts, its vertices and which properties make which
    attribute."""

    info: FileInfo
    attributes: tuple[AttributeInfo, ...]
    vertices: np.ndarray = field(repr=False)
    columns: dict[str, tuple[str, ...]] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    first_gps_time: float | None = None

    def chunks(self, batch_points: int, *, salvage: bool = False) -> Iterator[np.ndarray]:
        """Runs of at most batch_points vertices (views of the mapped file)."""
        for first in range(0, self.info.points, batch_points):
            yield self.vertices[first:first + batch_points]

    def parse(self, chunk: np.ndarray, start: int, origin: np.ndarray, names: tuple[str, ...]) -> Batch:
        """Positions computed in float64 and rounded to float32 once, as for LAS."""
        xyz = coordinates(chunk)
        lo, hi = finite_bounds(xyz)
        with np.errstate(over="ignore", invalid="ignore"):
            positions = (xyz - origin).astype(np.float32)
        attributes = {name: self._values(chunk, name) for name in names if name != "elevation"}
        counts = {name: n for name, v in attributes.items() if (n := nonfinite_count(v))}
        for name in counts:
            quiet_nans(attributes[name])
        return Batch(start=start, xyz=positions, attributes=attributes,
                     bounds=None if lo is None else (lo, hi),
                     nonfinite_positions=nonfinite_rows(positions), nonfinite_values=counts)

    def _values(self, chunk: np.ndarray, name: str) -> np.ndarray:
        columns = self.columns[name]
        if name == "rgb":
            rgb = np.empty((len(chunk), 3), dtype=np.uint8)
            for i, column in enumerate(columns):
                rgb[:, i] = channel8(chunk[column], self.info.rgb_16bit)
            return rgb
        values = chunk[columns[0]]
        return np.array(values, dtype=values.dtype.newbyteorder("="))


def coordinates(vertices: np.ndarray) -> np.ndarray:
    """(n, 3) float64 x, y, z of vertices (any numeric type, any byte order)."""
    xyz = np.empty((len(vertices), 3), dtype=np.float64)
    for axis, name in enumerate("xyz"):
        xyz[:, axis] = vertices[name]
    return xyz


def finite_bounds(xyz: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
    """float64 min and max of the rows whose x, y and z are finite; (None, None) if none is."""
    finite = xyz[np.isfinite(xyz).all(axis=1)]
    if not len(finite):
        return None, None
    return finite.min(axis=0), finite.max(axis=0)


def _read(path: str) -> plyfile.PlyData:
    """The parsed file; plyfile's complaints (and numpy's, on a header that makes no
    sense) as one line."""
    try:
        return plyfile.PlyData.read(path, mmap="r")
    except plyfile.PlyParseError as exc:
        raise fail(path, f"invalid PLY file: {exc}") from None
    except (ValueError, TypeError, OverflowError, MemoryError, UnicodeDecodeError, IndexError) as exc:
        raise fail(path, f"invalid PLY file: {exc}") from None


def _trailing(path: str, data: plyfile.PlyData, vertices: np.ndarray, size: int) -> None:
    """A binary file whose last element is the vertices must end with them: bytes after
    them mean the header's count is short of what the file holds."""
    if data.elements[-1].name != VERTEX or not isinstance(vertices, np.memmap):
        return
    end = vertices.offset + vertices.dtype.itemsize * len(vertices)
    if size != end:
        raise fail(path, f"header says {len(vertices)} vertices but the file holds {size - end} more bytes "
                         f"after them")


def _ascii_rows(path: str, data: plyfile.PlyData) -> None:
    """An ASCII file holds one line per element row: more lines than the header's counts
    mean a count is short of what the file holds (plyfile stops reading at the count)."""
    with open_binary(path) as stream:
        body = stream.read().partition(END_HEADER)[2]
    rows = sum(1 for line in body.splitlines() if line.strip())
    expected = sum(e.count for e in data.elements)
    if rows != expected:
        raise fail(path, f"header says {expected} rows ({', '.join(f'{e.count} {e.name}' for e in data.elements)}) "
                         f"but the file holds {rows} lines of data")


def _columns(path: str, properties: list, warnings: list[str]) -> dict[str, tuple[str, ...]]:
    """Attribute name -> the vertex properties it is made of."""
    types = {p.name: np.dtype(p.val_dtype) for p in properties if not isinstance(p, plyfile.PlyListProperty)}
    columns: dict[str, tuple[str, ...]] = {}
    for names in COLOURS:
        if all(n in types and types[n].type in COLOUR_TYPES for n in names):
            columns["rgb"] = names
            break
    used = {"x", "y", "z", *columns.get("rgb", ())}
    for name, dtype in types.items():
        if name in used:
            continue
        if name in RESERVED or (name in CATEGORY_NAMES and dtype.kind != "u"):
            warnings.append(f"{shown(path)}: vertex property {name!r} ({dtype}) is left out: "
                            f"{RESERVED.get(name, 'classification codes are unsigned integers')}")
            continue
        if dtype.kind in "uif":
            columns[name] = (name,)
    return columns


def kind_of(name: str) -> AttributeKind:
    if name == "rgb":
        return AttributeKind.RGB
    return AttributeKind.CATEGORY if name in CATEGORY_NAMES else AttributeKind.SCALAR


def open_ply(path: str | os.PathLike, *, partial: bool = False) -> PlySource:
    """Check and describe one PLY file; its bounds and colour depth come from its vertices
    (one pass over them)."""
    path = os.fspath(path)
    with open_binary(path) as stream:
        size = os.fstat(stream.fileno()).st_size
    if size == 0:
        raise fail(path, "is empty")
    data = _read(path)
    if VERTEX not in data:
        raise fail(path, "has no vertex element")
    element = data[VERTEX]
    missing = [a for a in "xyz" if a not in {p.name for p in element.properties}
               or isinstance(element.ply_property(a), plyfile.PlyListProperty)]
    if missing:
        raise fail(path, f"has no vertex {', '.join(missing)} (its vertex properties are "
                         f"{', '.join(p.name for p in element.properties) or 'none'})")
    vertices = element.data
    if len(vertices) == 0:
        raise fail(path, "has no vertices")
    if data.text:
        _ascii_rows(path, data)
    else:
        _trailing(path, data, vertices, size)
    warnings: list[str] = []
    columns = _columns(path, list(element.properties), warnings)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    max_rgb = 0
    for first in range(0, len(vertices), BATCH_POINTS):
        piece = vertices[first:first + BATCH_POINTS]
        low, high = finite_bounds(coordinates(piece))
        if low is not None:
            lo, hi = np.minimum(lo, low), np.maximum(hi, high)
        if "rgb" in columns and first == 0:
            max_rgb = max(int(np.max(piece[c])) for c in columns["rgb"])
    if not np.isfinite(lo).all():
        raise fail(path, "has no vertex with finite x, y and z")
    info = FileInfo(
        path=path, format="PLY", version=f"{VERSION} {_encoding(data)}", point_format=-1,
        points=len(vertices), scale=(1.0, 1.0, 1.0), offset=(0.0, 0.0, 0.0),
        bounds_min=tuple(map(float, lo)), bounds_max=tuple(map(float, hi)),
        rgb_max=max_rgb if "rgb" in columns else None,
    )
    names = [n for n in ORDER if n in columns or n == "elevation"] + [n for n in columns if n not in ORDER]
    attributes = tuple(
        AttributeInfo(n, kind_of(n), np.dtype(np.float64) if n == "elevation" else
                      np.dtype(np.uint8) if n == "rgb" else vertices.dtype[columns[n][0]].newbyteorder("="))
        for n in names
    )
    return PlySource(info, attributes, vertices, columns, tuple(warnings))


def _encoding(data: plyfile.PlyData) -> str:
    if data.text:
        return "ascii"
    return {"<": "binary_little_endian", ">": "binary_big_endian"}.get(data.byte_order, "binary")


def read_point(path: str, index: int) -> np.ndarray:
    """(3,) float64 x, y, z of vertex `index`, read back from the file."""
    return coordinates(_read(path)[VERTEX].data[index:index + 1])[0]
