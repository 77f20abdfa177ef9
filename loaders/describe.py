"""`progressive info`: what a cloud holds, from its headers and from every point."""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np

from progressive.loaders.http import DEFAULTS as HTTP_DEFAULTS
from progressive.loaders.http import HttpOptions
from progressive.loaders.pipeline import CloudLoader
from progressive.loaders.records import ELEVATION
from progressive.loaders.types import AttributeInfo, AttributeKind, Batch, CloudInfo, FileInfo


@dataclass
class _Range:
    """Running min/max of one quantity (per channel for RGB, per axis for positions) over
    its finite values: a float row with any NaN/Inf is left out (and counted elsewhere)."""

    lo: np.ndarray | None = None
    hi: np.ndarray | None = None

    def add(self, values: np.ndarray) -> None:
        if values.dtype.kind == "f":
            finite = np.isfinite(values)
            values = values[finite.all(axis=1) if values.ndim > 1 else finite]
        if values.size == 0:
            return
        lo, hi = values.min(axis=0), values.max(axis=0)
        self.lo = lo if self.lo is None else np.minimum(self.lo, lo)
        self.hi = hi if self.hi is None else np.maximum(self.hi, hi)

    def merge(self, other: _Range) -> None:
        if other.lo is not None:
            self.add(np.stack([other.lo, other.hi]))


@dataclass
class _FileStats:
    info: FileInfo
    points: int = 0
    nonfinite_positions: int = 0
    nonfinite_values: dict[str, int] = field(default_factory=dict)
    bounds: _Range = field(default_factory=_Range)
    attributes: dict[str, _Range] = field(default_factory=dict)

    def add(self, batch: Batch, cloud: CloudInfo) -> None:
        """LAS batches bring exact float64 bounds; fast-format ones are exactly their
        float32 positions plus the origin."""
        self.points += batch.count
        self.nonfinite_positions += batch.nonfinite_positions
        for name, n in batch.nonfinite_values.items():
            self.nonfinite_values[name] = self.nonfinite_values.get(name, 0) + n
        if batch.bounds is not None:
            self.bounds.add(np.stack(batch.bounds))
        else:
            self.bounds.add(cloud.origin + batch.positions.astype(np.float64))
        for attr in cloud.attributes:
            if attr.name != ELEVATION:
                self.attributes.setdefault(attr.name, _Range()).add(_values(batch, attr))

    def merge(self, other: _FileStats) -> None:
        self.points += other.points
        self.nonfinite_positions += other.nonfinite_positions
        for name, n in other.nonfinite_values.items():
            self.nonfinite_values[name] = self.nonfinite_values.get(name, 0) + n
        self.bounds.merge(other.bounds)
        for name, rng in other.attributes.items():
            self.attributes.setdefault(name, _Range()).merge(rng)


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
    return value.item()


def _summary(info: FileInfo, stats: _FileStats, cloud: CloudInfo) -> dict:
    bounds = stats.bounds
    return {
        "path": info.path,
        "format": info.format,
        "version": info.version,
        "point_format": info.point_format,
        "points": stats.points,
        "header_points": info.points,
        "scale": list(info.scale),
        "offset": list(info.offset),
        "crs": info.crs,
        "rgb_16bit": info.rgb_16bit,
        "bounds": {"min": _plain(bounds.lo), "max": _plain(bounds.hi)},
        "header_bounds": {"min": list(info.bounds_min), "max": list(info.bounds_max)},
        "attributes": {attr.name: _attribute(attr, bounds, stats.attributes) for attr in cloud.attributes},
        "nonfinite_positions": stats.nonfinite_positions,
        "nonfinite_values": dict(stats.nonfinite_values),
        "scans": [{"name": s.name, "points": s.points, "coordinates": s.coordinates,
                   "rotation": list(s.rotation), "translation": list(s.translation)} for s in info.scans],
    }


def _attribute(attr: AttributeInfo, bounds: _Range, ranges: dict[str, _Range]) -> dict:
    """Kind and range of the finite values; elevation is the z of the bounds, having no
    array of its own."""
    if attr.name == ELEVATION:
        lo, hi = (None, None) if bounds.lo is None else (bounds.lo[2], bounds.hi[2])
    else:
        rng = ranges.get(attr.name, _Range())
        lo, hi = rng.lo, rng.hi
    return {"kind": attr.kind.value, "min": _plain(lo), "max": _plain(hi)}


def describe(paths, *, partial: bool = False, http: HttpOptions = HTTP_DEFAULTS) -> dict:
    """Header facts and data ranges of a cloud; top-level per-file facts (format, version,
    point format, scale, offset, CRS) are the first file's. `nonfinite_positions` counts
    the points never drawn, `nonfinite_values` the NaN/Inf values of float attributes.
    `http`: how a URL's COPC file is fetched."""
    with CloudLoader(paths, partial=partial, http=http) as loader:
        cloud = loader.info
        stats = [_FileStats(f) for f in cloud.files]
        ends = np.cumsum([f.points for f in cloud.files]).tolist()
        for batch in loader:
            stats[bisect.bisect_right(ends, batch.start)].add(batch, cloud)
        warnings = list(loader.warnings)
    files = [_summary(s.info, s, cloud) for s in stats]
    total = _FileStats(cloud.files[0])
    for s in stats:
        total.merge(s)
    desc = _summary(cloud.files[0], total, cloud)
    del desc["path"], desc["rgb_16bit"], desc["header_points"], desc["scans"]
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
        ("format", f"{desc['format']} {desc['version']}"
                   + (f", point format {desc['point_format']}" if desc["point_format"] >= 0 else "")),
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
    for f in desc["files"]:
        if f["scans"]:
            lines += ["", f"scans of {f['path']} ({len(f['scans'])}):"]
            lines += [f"  {s['name']}: {s['points']:,} points, {s['coordinates']}, rotation (w, x, y, z) "
                      f"{_num(s['rotation'])}, translation {_num(s['translation'])}" for s in f["scans"]]
    if desc["nonfinite_positions"]:
        lines += ["", f"{desc['nonfinite_positions']:,} points have a non-finite x, y or z and are never drawn"]
    lines += [f"{name}: {n:,} non-finite values" for name, n in desc["nonfinite_values"].items()]
    lines += [f"warning: {w}" for w in desc["warnings"]]
    return "\n".join(lines)
