"""One point's exact file coordinates, read back from its file: float64 as the file
defines them (integer record times scale plus offset), not the float32 the GPU holds."""

from __future__ import annotations

import numpy as np

from progressive.loaders.e57 import read_point as read_e57_point
from progressive.loaders.fastformat import HEADER_BYTES
from progressive.loaders.ply import read_point as read_ply_point
from progressive.loaders.types import CloudInfo

FAST_FORMAT = "PRGS"


def read_point(info: CloudInfo, index: int) -> np.ndarray:
    """(3,) float64 x, y, z of the point with file-order `index` (files concatenated)."""
    if not 0 <= index < info.points:
        raise IndexError(f"point {index} outside the cloud of {info.points} points")
    for file in info.files:
        if index < file.points:
            break
        index -= file.points
    if file.format == FAST_FORMAT:
        with open(file.path, "rb") as stream:
            stream.seek(HEADER_BYTES + 16 * index)
            xyz = np.frombuffer(stream.read(12), dtype="<f4")
        return info.origin + xyz.astype(np.float64)
    if file.format == "PLY":
        return read_ply_point(file.path, index)
    if file.format == "E57":
        return read_e57_point(file.path, index)
    import laspy

    with laspy.open(file.path) as reader:
        reader.seek(index)
        points = reader.read_points(1)
    return np.array([points.x[0], points.y[0], points.z[0]], dtype=np.float64)
