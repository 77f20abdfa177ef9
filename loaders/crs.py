"""A file's coordinate system as pyproj reads it, for reprojection and latitude and
longitude. FileInfo.crs is only a label (a WKT name need not carry an EPSG code), so
LAS/LAZ headers are read again here, through laspy's own CRS parsing (a URL's over
HTTP, by range requests)."""

from __future__ import annotations

import re

from progressive.errors import InputError
from progressive.loaders.types import FileInfo

EPSG = re.compile(r"EPSG:(\d+)")


def file_crs(info: FileInfo):
    """The pyproj CRS of a file (LAS/LAZ: its WKT or GeoTIFF keys; E57: its
    coordinateMetadata), or None where it names none or pyproj cannot read it."""
    import pyproj

    if info.format in ("LAS", "LAZ"):
        crs = _header_crs(info)
        if crs is not None:
            return crs
    if not info.crs:
        return None
    code = EPSG.search(info.crs)
    try:
        return pyproj.CRS.from_epsg(int(code.group(1))) if code else pyproj.CRS.from_user_input(info.crs)
    except pyproj.exceptions.CRSError:
        return None


def _header_crs(info: FileInfo):
    """laspy's CRS of a LAS/LAZ header (a URL's fetched again); None where laspy or
    pyproj refuse a malformed CRS record, as the file then names none usable."""
    import laspy

    from progressive.loaders.copc import CopcFileInfo

    try:
        if isinstance(info, CopcFileInfo) and info.remote is not None:
            return info.remote.header().parse_crs()
        with laspy.open(info.path) as reader:
            return reader.header.parse_crs()
    except InputError:          # the server failing is no missing CRS: one line
        raise
    except Exception:
        return None


def epsg_code(info: FileInfo, crs) -> int | None:
    """The EPSG code of a file's CRS: pyproj's identification, else the code the file's
    label names (GeoTIFF keys give one even where the WKT name matches no entry)."""
    found = crs.to_epsg() if crs is not None else None
    if found is None and info.crs and (code := EPSG.search(info.crs)):
        return int(code.group(1))
    return found
