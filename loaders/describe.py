"""`progressive info`: what a cloud holds, from its headers and from every point."""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np

from progressive.loaders.pipeline import CloudLoader
from progressive.loaders.types import AttributeInfo, AttributeKind, Batch, CloudInfo, FileInfo
from progressive.packing import ELEVATION


@dataclass
class _Range:
    """Running min/max of one quantity (per channel for RGB)."""

    lo: np.ndarray | None = None
    hi: np.ndarray | None = None

    def add(self, values: np.ndarray) -> None:
        if values.size == 0:
            return
        axis = 0 if values.ndim > 1 else None
        floats = np.issubdtype(values.dtype, np.floating)
        lo = np.nanmin(values, axis=axis) if floats else np.min(values, axis=axis)
        hi = np.nanmax(values, axis=axis) if floats else np.max(values, axis=axis)
        self.lo = lo if self.lo is None else np.fmin(self.lo, lo)
        self.hi = hi if self.hi is None else np.fmax(self.hi, hi)

    def merge(self, other: _Range) -> None:
        if other.lo is not None:
            self.add(np.stack([other.lo, other.hi]))


@dataclass
class _FileStats:
    info: FileInfo
    points: int = 0
    positions: _Range = field(default_factory=_Range)
    attributes: dict[str, _Range] = field(default_factory=dict)

    def add(self, batch: Batch, cloud: CloudInfo) -> None:
        self.points += batch.count
        self.positions.add(batch.positions)
        for attr in cloud.attributes:
            if attr.name != ELEVATION:
                self.attributes.setdefault(attr.name, _Range()).add(_values(batch, attr))

    def bounds(self, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """File coordinates in float64: the float32 extremes plus the origin, snapped back to
        the file's scale grid (exact wherever float32 resolves half a scale step)."""
        if self.positions.lo is None:
            return None
        lo, hi = (origin + v.astype(np.float64) for v in (self.positions.lo, self.positions.hi))
        if self.info.point_format >= 0:
            scale, offset = np.array(self.info.scale), np.array(self.info.offset)
            lo, hi = (offset + np.round((v - offset) / scale) * scale for v in (lo, hi))
        return lo, hi


def _values(batch: Batch, attr: AttributeInfo) -> np.ndarray:
    """The attribute's values; fast-format batches carry only the packed word."""
    if batch.records is None:
        return np.asarray(batch.attributes[attr.name])
    word = np.ascontiguousarray(batch.records[:, 3])
    if attr.kind is AttributeKind.RGB:
        return word.view(np.uint8).reshape(-1, 4)[:, :3]
    if attr.kind is AttributeKind.SCALAR:
        return word.view(np.float32).astype(np.float64) + attr.offset
    return word


def _plain(value):
    """JSON-ready Python numbers (lists for RGB); None for an empty range."""
    if value is None:
        return None
    value = np.asarray(value)
    if value.ndim:
        return [_plain(v) for v in value]
    if value.dtype.kind == "f" and np.isnan(value):
        return None
    return value.item()


def _summary(info: FileInfo, points: int, bounds, attributes: dict, cloud: CloudInfo) -> dict:
    return {
        "path": info.path,
        "format": info.format,
        "version": info.version,
        "point_format": info.point_format,
        "points": points,
        "header_points": info.points,
        "scale": list(info.scale),
        "offset": list(info.offset),
        "crs": info.crs,
        "rgb_16bit": info.rgb_16bit,
        "bounds": {"min": _plain(bounds[0]) if bounds else None, "max": _plain(bounds[1]) if bounds else None},
        "header_bounds": {"min": list(info.bounds_min), "max": list(info.bounds_max)},
        "attributes": {attr.name: _attribute(attr, bounds, attributes) for attr in cloud.attributes},
    }


def _attribute(attr: AttributeInfo, bounds, ranges: dict[str, _Range]) -> dict:
    """Kind and range; elevation is the z of the bounds, having no array of its own."""
    if attr.name == ELEVATION:
        lo, hi = (bounds[0][2], bounds[1][2]) if bounds else (None, None)
    else:
        rng = ranges.get(attr.name, _Range())
        lo, hi = rng.lo, rng.hi
    return {"kind": attr.kind.value, "min": _plain(lo), "max": _plain(hi)}


def describe(paths, *, partial: bool = False) -> dict:
    """Header facts and data ranges of a cloud; top-level per-file facts (format, version,
    point format, scale, offset, CRS) are the first file's."""
    with CloudLoader(paths, partial=partial) as loader:
        cloud = loader.info
        stats = [_FileStats(f) for f in cloud.files]
        ends = np.cumsum([f.points for f in cloud.files]).tolist()
        for batch in loader:
            stats[bisect.bisect_right(ends, batch.start)].add(batch, cloud)
        warnings = list(loader.warnings)
    per_file = [s.bounds(cloud.origin) for s in stats]
    files = [_summary(s.info, s.points, b, s.attributes, cloud) for s, b in zip(stats, per_file)]
    present = [b for b in per_file if b is not None]
    bounds = (np.min([b[0] for b in present], axis=0), np.max([b[1] for b in present], axis=0)) if present else None
    merged: dict[str, _Range] = {}
    for s in stats:
        for name, rng in s.attributes.items():
            merged.setdefault(name, _Range()).merge(rng)
    desc = _summary(cloud.files[0], sum(s.points for s in stats), bounds, merged, cloud)
    del desc["path"], desc["rgb_16bit"], desc["header_points"]
    desc["header_bounds"] = {"min": cloud.bounds_min.tolist(), "max": cloud.bounds_max.tolist()}
    desc.update(origin=cloud.origin.tolist(), files=files, warnings=warnings)
    return desc


def _num(value) -> str:
    if isinstance(value, list):
        return "(" + ", ".join(_num(v) for v in value) + ")"
    if isinstance(value, float):
        return f"{value:.10g}"
    return "-" if value is None else str(value)


def format_text(desc: dict) -> str:
    """A human-readable table of describe()'s result."""
    rows = [
        ("points", f"{desc['points']:,}"),
        ("format", f"{desc['format']} {desc['version']}, point format {desc['point_format']}"),
        ("crs", desc["crs"] or "-"),
        ("scale", _num(desc["scale"])),
        ("offset", _num(desc["offset"])),
        ("bounds min", _num(desc["bounds"]["min"])),
        ("bounds max", _num(desc["bounds"]["max"])),
    ]
    lines = [f"{k:<12}{v}" for k, v in rows]
    width = max([9] + [len(n) for n in desc["attributes"]]) + 2
    lines += ["", f"{'attribute':<{width}}{'kind':<10}{'min':<28}max"]
    lines += [f"{name:<{width}}{a['kind']:<10}{_num(a['min']):<28}{_num(a['max'])}"
              for name, a in desc["attributes"].items()]
    if len(desc["files"]) > 1:
        lines += ["", f"files ({len(desc['files'])}):"]
        lines += [f"  {f['path']}  {f['points']:,} points, {f['format']} {f['version']} PF {f['point_format']}"
                  for f in desc["files"]]
    lines += [f"warning: {w}" for w in desc["warnings"]]
    return "\n".join(lines)
