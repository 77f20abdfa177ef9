"""Measurements between picked points, in float64 file coordinates (GPU-free): the
distance of each segment in 3D, horizontally and vertically, the running length of
the polyline, and the area of the polygon the points close (in the XY plane, the
shoelace formula), in the file's own units."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Measurement:
    points: tuple[tuple[float, float, float], ...]

    def add(self, point) -> Measurement:
        return Measurement((*self.points, tuple(float(v) for v in point)))

    @property
    def _xyz(self) -> np.ndarray:
        return np.asarray(self.points, dtype=np.float64).reshape(-1, 3)

    def segments(self) -> list[dict[str, float]]:
        """Per segment: 3D, horizontal (XY) and vertical (|dz|) lengths."""
        d = np.diff(self._xyz, axis=0)
        return [{"distance": float(np.linalg.norm(s)), "horizontal": float(np.hypot(s[0], s[1])),
                 "vertical": float(abs(s[2]))} for s in d]

    @property
    def length(self) -> float:
        """The polyline's running length in 3D."""
        return float(sum(s["distance"] for s in self.segments()))

    @property
    def area(self) -> float:
        """The area in XY of the polygon through the points, closed back to the first
        (0 for fewer than three points)."""
        if len(self.points) < 3:
            return 0.0
        xy = self._xyz[:, :2] - self._xyz[0, :2]     # relative to the first point: no cancellation at UTM sizes
        x, y = xy[:, 0], xy[:, 1]
        return float(abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2.0)

    def to_dict(self) -> dict:
        return {"points": [list(p) for p in self.points], "segments": self.segments(), "length": self.length,
                "area": self.area}
