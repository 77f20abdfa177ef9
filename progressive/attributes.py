"""Attribute names as users type them: laspy spelling, PDAL spelling, any case."""

from __future__ import annotations

import re

import numpy as np

from progressive.errors import ProgressiveError
from progressive.loaders.types import AttributeInfo, AttributeKind, Batch, CloudInfo

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


def default_attribute(info: CloudInfo, sample: Batch | None = None) -> AttributeInfo:
    """RGB where the files have it, else elevation; with a sample batch, RGB that is
    all zero there is passed over (see default_choice)."""
    return default_choice(info, sample)[0]


def default_choice(info: CloudInfo, sample: Batch | None = None) -> tuple[AttributeInfo, str | None]:
    """The default attribute and, when RGB was passed over for being all zero in the
    sample (scanners that write empty RGB), a sentence saying so."""
    by_name = {a.name: a for a in info.attributes}
    skipped = []
    for name in DEFAULT_ORDER:
        if name not in by_name:
            continue
        values = None if sample is None else sample.attributes.get(name)
        if values is not None and values.size and not np.any(values):
            skipped.append(name)
            continue
        note = f"{' and '.join(skipped)} all zero in the first {sample.count:,} points; colouring by {name}" if skipped else None
        return by_name[name], note
    return next(a for a in info.attributes if a.kind is not AttributeKind.RGB), None
