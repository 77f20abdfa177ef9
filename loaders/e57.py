"""E57 input (terrestrial scanners) through pye57's binding of libE57Format: every scan
(data3D entry) in order, its pose applied in float64, Cartesian or spherical
coordinates, colour and intensity where every scan has them.

Points whose invalid state is not 0 (no valid coordinates) are kept with NaN
coordinates, as a LAS point that is not finite is: never drawn, counted, and the ids of
the others stay their file order. E57 has no bounds of the posed points, so opening a
file reads it once for them (and for the colour depth); the load reads it again.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from progressive.errors import InputError
from progressive.loaders.types import (
    BATCH_POINTS,
    AttributeInfo,
    AttributeKind,
    Batch,
    FileInfo,
    ScanInfo,
    channel8,
    nonfinite_count,
    nonfinite_rows,
    quiet_nans,
)
from progressive.loaders.validate import fail, open_binary, shown

MAGIC = b"ASTM-E57"
CARTESIAN = ("cartesianX", "cartesianY", "cartesianZ")
SPHERICAL = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
INVALID = {"cartesian": "cartesianInvalidState", "spherical": "sphericalInvalidState"}
COLOURS = ("colorRed", "colorGreen", "colorBlue")
INTENSITY = "intensity"
INTENSITY_INVALID = "isIntensityInvalid"
FIELD_TYPES = {**dict.fromkeys(CARTESIAN + SPHERICAL, np.float64), **dict.fromkeys(COLOURS, np.uint16),
               INTENSITY: np.float32, INTENSITY_INVALID: np.int8, **dict.fromkeys(INVALID.values(), np.int8)}
"""The buffer type each field is read into (libE57 converts and scales): colours up to
16 bits, for the LAS rule to decide their depth."""
ATTRIBUTE_FIELDS = {"rgb": COLOURS, "intensity": (INTENSITY,)}


def is_e57(path: str | os.PathLike) -> bool:
    """Decided by the file signature; unreadable paths are left to the LAS checks."""
    try:
        with open_binary(path) as stream:
            return stream.read(len(MAGIC)) == MAGIC
    except (InputError, OSError):
        return False


def rotation_matrix(q: tuple[float, float, float, float]) -> np.ndarray:
    """(3, 3) float64 rotation of the unit quaternion w, x, y, z."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


@dataclass(frozen=True)
class _Scan:
    """A scan as the reader needs it: its data3D index, the fields read, its pose."""

    index: int
    info: ScanInfo
    fields: tuple[str, ...]

    def file_coordinates(self, data: dict[str, np.ndarray]) -> np.ndarray:
        """(n, 3) float64 file coordinates of a chunk; NaN where the point is invalid."""
        if self.info.coordinates == "cartesian":
            local = np.stack([data[f] for f in CARTESIAN], axis=1)
        else:
            r, azimuth, elevation = (data[f] for f in SPHERICAL)
            local = np.stack([r * np.cos(elevation) * np.cos(azimuth), r * np.cos(elevation) * np.sin(azimuth),
                              r * np.sin(elevation)], axis=1)
        with np.errstate(over="ignore", invalid="ignore"):
            xyz = local @ rotation_matrix(self.info.rotation).T + np.asarray(self.info.translation)
        invalid = INVALID[self.info.coordinates]
        if invalid in data:
            xyz[data[invalid] != 0] = np.nan
        return xyz


@dataclass(frozen=True)
class E57Chunk:
    scan: _Scan
    data: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(next(iter(self.data.values())))


@dataclass(frozen=True)
class E57Source:
    """One checked E57 file: its facts, its scans and how to read and parse their points."""

    info: FileInfo
    attributes: tuple[AttributeInfo, ...]
    scans: tuple[_Scan, ...]
    warnings: tuple[str, ...] = ()
    first_gps_time: float | None = None

    def chunks(self, batch_points: int, *, salvage: bool = False) -> Iterator[E57Chunk]:
        """Chunks of at most batch_points points, never across scans."""
        return _chunks(self.info.path, self.scans, batch_points)

    def parse(self, chunk: E57Chunk, start: int, origin: np.ndarray, names: tuple[str, ...]) -> Batch:
        xyz = chunk.scan.file_coordinates(chunk.data)
        finite = xyz[np.isfinite(xyz).all(axis=1)]
        with np.errstate(over="ignore", invalid="ignore"):
            positions = (xyz - origin).astype(np.float32)
        attributes = {name: self._values(chunk.data, name) for name in names if name != "elevation"}
        counts = {name: n for name, v in attributes.items() if (n := nonfinite_count(v))}
        for name in counts:
            quiet_nans(attributes[name])
        return Batch(start=start, xyz=positions, attributes=attributes,
                     bounds=(finite.min(axis=0), finite.max(axis=0)) if len(finite) else None,
                     nonfinite_positions=nonfinite_rows(positions), nonfinite_values=counts)

    def _values(self, data: dict[str, np.ndarray], name: str) -> np.ndarray:
        if name == "rgb":
            rgb = np.empty((len(data[COLOURS[0]]), 3), dtype=np.uint8)
            for i, f in enumerate(COLOURS):
                rgb[:, i] = channel8(data[f], self.info.rgb_16bit)
            return rgb
        values = data[INTENSITY].copy()
        if INTENSITY_INVALID in data:
            values[data[INTENSITY_INVALID] != 0] = np.nan
        return values


class _Image:
    """libE57's ImageFile, closed on exit; its exceptions become one line naming the file."""

    def __init__(self, path: str):
        self.path = path

    def __enter__(self):
        from pye57 import libe57  # here, not at the top: every other start would pay its import

        try:
            self.image = libe57.ImageFile(self.path, "r")
        except Exception as exc:
            raise e57_error(self.path, exc) from None
        return self.image

    def __exit__(self, *exc_info) -> None:
        try:
            self.image.close()
        except Exception:
            if exc_info[0] is None:
                raise


def e57_error(path: str, exc: BaseException) -> InputError:
    """libE57's first line (what went wrong, its error code), without the debug context."""
    if isinstance(exc, InputError):
        return exc
    lines = [line for line in str(exc).splitlines() if line.strip()]
    return fail(path, f"invalid E57 file: {lines[0].split(' **** ')[0] if lines else type(exc).__name__}")


def _chunks(path: str, scans: tuple[_Scan, ...], batch_points: int) -> Iterator[E57Chunk]:
    try:
        with _Image(path) as image:
            data3d = image.root()["data3D"]
            for scan in scans:
                if scan.info.points:
                    yield from _scan_chunks(image, data3d[scan.index]["points"], scan, batch_points, path)
    except InputError:
        raise
    except Exception as exc:
        raise e57_error(path, exc) from None


def _scan_chunks(image, points, scan: _Scan, batch_points: int, path: str) -> Iterator[E57Chunk]:
    from pye57 import libe57

    capacity = min(batch_points, scan.info.points)
    arrays = {f: np.empty(capacity, dtype=FIELD_TYPES[f]) for f in scan.fields}
    buffers = libe57.VectorSourceDestBuffer()
    for f, array in arrays.items():
        buffers.append(libe57.SourceDestBuffer(image, f, array, capacity, True, True))
    reader = points.reader(buffers)
    try:
        read = 0
        while read < scan.info.points:
            n = reader.read()
            if n == 0:
                raise fail(path, f"scan {scan.index} ({scan.info.name!r}) ends after {read} of its "
                                 f"{scan.info.points} points")
            n = min(n, scan.info.points - read)
            read += n
            yield E57Chunk(scan, {f: a[:n].copy() for f, a in arrays.items()})
    finally:
        reader.close()


def _text(node, name: str) -> str:
    return str(node[name].value()) if node.isDefined(name) else ""


def _pose(path: str, node, index: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The scan's rotation (normalised) and translation; identity where absent."""
    rotation, translation = (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    if node.isDefined("pose"):
        pose = node["pose"]
        if pose.isDefined("rotation"):
            q = np.array([float(pose["rotation"][c].value()) for c in "wxyz"])
            norm = float(np.linalg.norm(q))
            if not (np.isfinite(q).all() and norm > 0):
                raise fail(path, f"scan {index} has a pose rotation that is not a rotation "
                                 f"(quaternion {', '.join(map(str, q))})")
            rotation = tuple(map(float, q / norm))
        if pose.isDefined("translation"):
            translation = tuple(float(pose["translation"][c].value()) for c in "xyz")
            if not np.isfinite(translation).all():
                raise fail(path, f"scan {index} has a pose translation that is not finite "
                                 f"({', '.join(map(str, translation))})")
    return rotation, translation


def _scan(path: str, node, index: int) -> _Scan:
    from pye57 import libe57

    points = node["points"]
    prototype = libe57.StructureNode(points.prototype())
    present = {prototype.get(i).elementName() for i in range(prototype.childCount())}
    if set(CARTESIAN) <= present:
        system, coords = "cartesian", CARTESIAN
    elif set(SPHERICAL) <= present:
        system, coords = "spherical", SPHERICAL
    else:
        raise fail(path, f"scan {index} has neither Cartesian nor spherical coordinates "
                         f"(its fields are {', '.join(sorted(present)) or 'none'})")
    optional = (INVALID[system], *COLOURS, INTENSITY, INTENSITY_INVALID)
    fields = coords + tuple(f for f in optional if f in present)
    if any(c in present for c in COLOURS) and not set(COLOURS) <= present:
        fields = tuple(f for f in fields if f not in COLOURS)
    rotation, translation = _pose(path, node, index)
    name = _text(node, "name") or f"scan {index}"
    return _Scan(index, ScanInfo(name, int(points.childCount()), system, rotation, translation), fields)


def open_e57(path: str | os.PathLike, *, partial: bool = False) -> E57Source:
    """Check and describe one E57 file, reading every point once for the bounds of the
    posed points and the colour depth."""
    path = os.fspath(path)
    with open_binary(path) as stream:
        if os.fstat(stream.fileno()).st_size == 0:
            raise fail(path, "is empty")
    try:
        with _Image(path) as image:
            root = image.root()
            if not root.isDefined("data3D"):
                raise fail(path, "has no data3D (no scans)")
            data3d = root["data3D"]
            scans = tuple(_scan(path, data3d[i], i) for i in range(data3d.childCount()))
            version = f"{_text(root, 'versionMajor') or '1'}.{_text(root, 'versionMinor') or '0'}"
            crs = _text(root, "coordinateMetadata") or None
    except InputError:
        raise
    except Exception as exc:
        raise e57_error(path, exc) from None
    total = sum(s.info.points for s in scans)
    if total == 0:
        raise fail(path, f"has no points ({len(scans)} scans)")
    loaded = [s for s in scans if s.info.points]
    names = [n for n, fields in ATTRIBUTE_FIELDS.items() if all(set(fields) <= set(s.fields) for s in loaded)]
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    max_rgb, seen = 0, 0
    for chunk in _chunks(path, scans, BATCH_POINTS):
        xyz = chunk.scan.file_coordinates(chunk.data)
        finite = xyz[np.isfinite(xyz).all(axis=1)]
        if len(finite):
            lo, hi = np.minimum(lo, finite.min(axis=0)), np.maximum(hi, finite.max(axis=0))
        if "rgb" in names and seen < BATCH_POINTS:
            max_rgb = max(max_rgb, *(int(chunk.data[c][:BATCH_POINTS - seen].max()) for c in COLOURS))
        seen += len(chunk)
    if not np.isfinite(lo).all():
        raise fail(path, f"has no valid point (all {total} are invalid or not finite)")
    info = FileInfo(
        path=path, format="E57", version=version, point_format=-1, points=total,
        scale=(1.0, 1.0, 1.0), offset=(0.0, 0.0, 0.0),
        bounds_min=tuple(map(float, lo)), bounds_max=tuple(map(float, hi)),
        rgb_max=max_rgb if "rgb" in names else None, crs=crs,
        scans=tuple(s.info for s in scans),
    )
    kinds = {"rgb": (AttributeKind.RGB, np.uint8), "intensity": (AttributeKind.SCALAR, np.float32),
             "elevation": (AttributeKind.SCALAR, np.float64)}
    attributes = tuple(AttributeInfo(n, kinds[n][0], np.dtype(kinds[n][1])) for n in (*names, "elevation"))
    warnings = tuple(f"{shown(path)}: {n} is left out: some of its scans have it, not all"
                     for n, fields in ATTRIBUTE_FIELDS.items()
                     if n not in names and any(set(fields) <= set(s.fields) for s in loaded))
    return E57Source(info, attributes, scans, warnings)


def read_point(path: str, index: int) -> np.ndarray:
    """(3,) float64 file coordinates of point `index` (scans concatenated), read back."""
    source = open_e57(path)
    for chunk in source.chunks(BATCH_POINTS):
        if index < len(chunk):
            return chunk.scan.file_coordinates(chunk.data)[index]
        index -= len(chunk)
    raise IndexError(index)
