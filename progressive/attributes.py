"""Attribute names as users type them: laspy spelling, PDAL spelling, any case."""

from __future__ import annotations

import re

from progressive.errors import ProgressiveError
from progressive.loaders.types import BATCH_POINTS, AttributeInfo, AttributeKind, CloudInfo

ALIASES = {
    "color": "rgb", "colour": "rgb", "red": "rgb", "green": "rgb", "blue": "rgb",
    "z": "elevation", "height": "elevation",
    "gpstime": "gps_time", "scananglerank": "scan_angle", "scan_angle_rank": "scan_angle",
    "class": "classification",
}


def _snake(name: str) -> str:
    return re.sub(r"(?<=[a-z0-9])([A-Z])", r"_\1", name).lower()


def find_attribute(info: CloudInfo, name: str) -> AttributeInfo:
    """The attribute a user means by `name`, or an error listing what exists."""
    names = {a.name: a for a in info.attributes}
    for candidate in (name, name.lower(), _snake(name)):
        key = ALIASES.get(candidate.replace("_", ""), ALIASES.get(candidate, candidate))
        if key in names:
            return names[key]
    lowered = {n.lower(): a for n, a in names.items()}
    if name.lower() in lowered:
        return lowered[name.lower()]
    raise ProgressiveError(f"unknown attribute '{name}'; this cloud has: {', '.join(names)}")


DEFAULT_ORDER = ("rgb", "elevation")
"""RGB where it is real, else elevation: intensity of forest and terrestrial lidar reads
as noise at a first look, elevation reads as the terrain (issue 13)."""


def default_attribute(info: CloudInfo) -> AttributeInfo:
    """RGB where the files have it and it is not all zero, else elevation (default_choice)."""
    return default_choice(info)[0]


def default_choice(info: CloudInfo) -> tuple[AttributeInfo, str | None]:
    """The default attribute and, when RGB was passed over for being zero in every file's
    first points (FileInfo.rgb_zero: scanners that write empty colour fields), a
    sentence saying so. Decided from the files' probes, before any batch is loaded, so
    a session that shows only this attribute loads only it."""
    by_name = {a.name: a for a in info.attributes}
    skipped = []
    for name in DEFAULT_ORDER:
        if name not in by_name:
            continue
        if name == "rgb" and all(f.rgb_zero for f in info.files):
            skipped.append(name)
            continue
        where = f"the first {min(BATCH_POINTS, info.files[0].points):,} points" if len(info.files) == 1 else \
            f"the first points of every file (up to {BATCH_POINTS:,} each)"
        return by_name[name], f"{' and '.join(skipped)} all zero in {where}; colouring by {name}" if skipped else None
    return next(a for a in info.attributes if a.kind is not AttributeKind.RGB), None
