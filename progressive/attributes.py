"""Attribute names as users type them: laspy spelling, PDAL spelling, any case."""

from __future__ import annotations

import re

from progressive.errors import ProgressiveError
from progressive.loaders.types import AttributeInfo, AttributeKind, CloudInfo

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


def default_attribute(info: CloudInfo) -> AttributeInfo:
    """RGB where the files have it, else intensity, else elevation."""
    kinds = {a.name: a for a in info.attributes}
    for name in ("rgb", "intensity", "elevation"):
        if name in kinds:
            return kinds[name]
    return next(a for a in info.attributes if a.kind is not AttributeKind.RGB)
